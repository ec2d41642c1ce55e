"""dm-control suite environments for :func:`sim2real.make`, built from a per-process template of each kind.

The first env of a kind (domain, task, time limit, textures) is loaded by dm-control and kept as a template;
later ones copy its compiled model and deep-copy its task, with fresh entropy in the task's ``RandomState``
(about 10x faster than compiling the XML again). The copies step bitwise like ``suite.load`` (tested).

What is left of building an env is made cheap too:

* dm-control builds a named indexer for each of the ~400 model and data fields of every ``Physics`` (2-5 ms per
  env; a task reads a handful). The copies build each field's indexer on first use, from name axes shared with
  the template (copies have the same element names), and give the same indexers (tested field by field).
* ``textures=False`` (:mod:`sim2real.tasks.models`): the template is compiled without textures, whose copy is
  most of a copy's cost (reacher's skybox is 11.8 MB). For envs that are never rendered.
* reacher reads its two geoms by cached index instead of through the named indexer on every step
  (:func:`fast_reacher_physics`; bitwise the same values), and manipulator its observation and reward
  (:func:`sim2real.tasks.fast_manipulator.fast_bring`; bitwise the same values).

Example:
    >>> env = suite_env("reacher", "easy", textures=False)
    >>> env.physics.model.ntex, type(env.physics).__name__
    (0, 'FastReacherPhysics')
    >>> float(env.physics.named.model.geom_size["finger", 0])
    0.01
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import numpy as np

__all__ = ["SUITE_XML", "fast_reacher_physics", "fast_reacher_task", "lazy_named_physics", "suite_env"]


def _reacher_xml(task: str) -> tuple[str, dict[str, bytes]]:
    from dm_control.suite import reacher

    xml, assets = reacher.get_model_and_assets()
    return xml, dict(assets)


def _manipulator_xml(task: str) -> tuple[str, dict[str, bytes]]:
    from dm_control.suite import manipulator

    xml, assets = manipulator.make_model(use_peg=task.endswith("peg"), insert=task.startswith("insert"))
    return xml, dict(assets)


#: Domain -> (task -> the XML and assets dm-control compiles for it): the domains that can be built headless.
SUITE_XML: dict[str, Callable[[str], tuple[str, dict[str, bytes]]]] = {
    "reacher": _reacher_xml,
    "manipulator": _manipulator_xml,
}


@dataclass(frozen=True)
class _Template:
    """A pristine physics (of the class its copies get) and task, and the environment's settings."""

    physics: Any
    task: Any
    time_limit: float
    n_sub_steps: int
    flat_observation: bool


_TEMPLATES: dict[tuple[str, str, Any, bool], _Template] = {}


def suite_env(domain: str, task: str, time_limit: float | None = None, *, textures: bool = True) -> Any:
    """A new dm-control suite environment (``dm_control.rl.control.Environment``) of ``domain``/``task``.

    Args:
        domain: a suite domain (``"reacher"``, ``"manipulator"``, ...).
        task: one of the domain's tasks.
        time_limit: episode length in seconds (None: the task's default).
        textures: False builds the env headless (domains in :data:`SUITE_XML` only).

    Raises:
        ValueError: ``textures=False`` for a domain that cannot be built headless.
    """
    import numpy as np
    from dm_control.rl import control

    key = (domain, task, time_limit, bool(textures))
    template = _TEMPLATES.get(key)
    if template is None:
        template = _TEMPLATES[key] = _template(domain, task, time_limit, textures)
    physics = template.physics.copy(share_model=False)
    # The task's RandomState is replaced by a fresh one (new entropy, as suite.load gives): passing it in the
    # memo skips pickling the template's generator state, which was most of the copy.
    template_random = template.task._random
    new_task = copy.deepcopy(template.task, {id(template_random): np.random.RandomState()})
    assert new_task._random is not template_random
    return control.Environment(
        physics,
        new_task,
        time_limit=template.time_limit,
        n_sub_steps=template.n_sub_steps,
        flat_observation=template.flat_observation,
    )


def _template(domain: str, task: str, time_limit: float | None, textures: bool) -> _Template:
    from dm_control import suite
    from dm_control.mujoco import wrapper
    from dm_control.mujoco.index import make_axis_indexers

    env = suite.load(domain, task, task_kwargs=None if time_limit is None else {"time_limit": time_limit})
    base: type = type(env.physics)
    new_task = env.task
    if domain == "reacher":
        base = fast_reacher_physics()
        new_task.__class__ = fast_reacher_task()
    elif domain == "manipulator":
        from sim2real.tasks.fast_manipulator import fast_bring

        new_task.__class__ = fast_bring()
    if textures:
        model = env.physics.model
    else:
        if domain not in SUITE_XML:
            raise ValueError(
                f"`textures` must be True for dm-control domain {domain!r} (headless builds: {sorted(SUITE_XML)}). "
                "Received False."
            )
        from sim2real.tasks.models import compiled_model

        model = wrapper.MjModel(compiled_model(*SUITE_XML[domain](task), textures=False))
    cls = lazy_named_physics(base, make_axis_indexers(model))
    if textures:
        physics = env.physics
        physics.__class__ = cls  # its own named indexers stay (built by dm-control); its copies build them lazily
    else:
        physics = cls.from_model(model)  # type: ignore[attr-defined]
    return _Template(
        physics,
        new_task,
        env._step_limit * env.control_timestep(),
        env._n_sub_steps,
        env._flat_observation,
    )


class _LazyStruct:
    """``physics.named.model`` / ``.data`` as dm-control's ``struct_indexer`` gives them, each field's
    ``FieldIndexer`` built on first use (then a plain attribute)."""

    def __init__(self, struct: Any, struct_name: str, axes: Any) -> None:
        from dm_control.mujoco.wrapper.mjbindings import sizes

        self.__dict__["_struct"] = struct
        self.__dict__["_sizes"] = sizes.array_sizes[struct_name]
        self.__dict__["_axes"] = axes

    def _indexer(self, name: str) -> Any:
        """dm-control's ``struct_indexer`` loop body for one field (None: not an indexed field)."""
        import numpy as np
        from dm_control.mujoco import index

        size_names = self._sizes.get(name)
        if size_names is None:
            return None
        attr = getattr(self._struct, name, None)
        if not isinstance(attr, np.ndarray) or attr.dtype.fields:
            return None
        for column, fields in index._COLUMN_ID_TO_FIELDS.items():
            if name in fields:
                size_names = (size_names[0], column)
                break
        return index.FieldIndexer(
            parent_struct=self._struct, field_name=name, axis_indexers=[self._axes[s] for s in size_names]
        )

    def __getattr__(self, name: str) -> Any:
        indexer = None if name.startswith("__") else self._indexer(name)
        if indexer is None:
            raise AttributeError(f"'StructIndexer' object has no attribute {name!r}")
        self.__dict__[name] = indexer
        return indexer

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"'StructIndexer' object attribute {name!r} is read-only")

    def _asdict(self) -> dict[str, Any]:
        out = {}
        for name in self._sizes:
            indexer = self.__dict__[name] if name in self.__dict__ else self._indexer(name)
            if indexer is not None:
                out[name] = indexer
        return out

    def __dir__(self) -> list[str]:
        return sorted(set(super().__dir__()) | set(self._asdict()))


_LAZY: dict[tuple[type, int], type] = {}


def lazy_named_physics(base: type, axes: Any) -> type:
    """A subclass of the dm-control ``Physics`` class ``base`` whose instances (and copies) build their named
    indexers per field on first use, over the name ``axes`` (``index.make_axis_indexers`` of a model with the
    same element names). One class per ``(base, axes)``."""
    key = (base, id(axes))
    cls = _LAZY.get(key)
    if cls is not None:
        return cls
    import numpy as np
    from dm_control.mujoco import engine, wrapper
    from dm_control.rl import control

    def _reload_from_data(self: Any, data: Any) -> None:
        # dm-control's Physics._reload_from_data (1.0.50) but for the last step: the named indexers.
        if not isinstance(data, wrapper.MjData):
            raise TypeError(f"Expected wrapper.MjData. Got: {type(data)}.")
        self._data = data
        self._warnings = self.data.warning.number
        self._warnings_before = np.empty_like(self._warnings)
        self._new_warnings = np.empty(dtype=bool, shape=(len(self._warnings),))
        with self._contexts_lock:
            if self._contexts:
                self._free_rendering_contexts()
        try:
            self.after_reset()
        except control.PhysicsError as e:
            logging.warning(e)
        self._named = engine.NamedIndexStructs(
            model=_LazyStruct(self.model, "mjmodel", axes), data=_LazyStruct(self.data, "mjdata", axes)
        )

    cls = type(base.__name__, (base,), {"_reload_from_data": _reload_from_data, "__module__": base.__module__})
    cls.__qualname__ = base.__qualname__
    _LAZY[key] = cls
    return cls


class _FastReacherPhysics(Protocol):
    """What FastReacher's reward reads from the physics class :func:`fast_reacher_physics` builds."""

    model: Any

    def _geom_ids(self) -> tuple[int, int]: ...

    def finger_to_target_dist(self) -> np.floating[Any]: ...


# Built on first use (dm-control imports lazily); one class each, so instances share it.
_FAST_REACHER_PHYSICS: list[type[_FastReacherPhysics]] = []
_FAST_REACHER_TASK: list[type] = []


def fast_reacher_physics() -> type[_FastReacherPhysics]:
    """dm-control's reacher Physics with ``finger_to_target`` reading the geoms by cached index instead of by
    name: the named indexer parses its key on every call, and reward plus observation call it twice per step
    (a quarter of the step's time). The values are the same arrays, bitwise (tested)."""
    if not _FAST_REACHER_PHYSICS:
        import numpy as np
        from dm_control.suite import reacher

        class FastReacherPhysics(reacher.Physics):
            def _geom_ids(self) -> tuple[int, int]:
                ids = self.__dict__.get("_sim2real_geom_ids")
                if ids is None:
                    ids = (self.model.name2id("target", "geom"), self.model.name2id("finger", "geom"))
                    self.__dict__["_sim2real_geom_ids"] = ids
                return ids

            def finger_to_target(self) -> np.ndarray:
                target, finger = self._geom_ids()
                xpos = self.data.geom_xpos
                return xpos[target, :2] - xpos[finger, :2]

            def finger_to_target_dist(self) -> np.floating[Any]:
                return np.linalg.norm(self.finger_to_target())

        _FAST_REACHER_PHYSICS.append(FastReacherPhysics)
    return _FAST_REACHER_PHYSICS[0]


def fast_reacher_task() -> type:
    """dm-control's Reacher task with the reward's radii read by cached geom index (the named indexer parses
    ``['target', 'finger']`` every step); the same sum of the same two floats, so the reward is bitwise equal."""
    if not _FAST_REACHER_TASK:
        from dm_control.suite import reacher
        from dm_control.utils import rewards

        physics_cls = fast_reacher_physics()

        class FastReacher(reacher.Reacher):
            def get_reward(self, physics: Any) -> float:
                if not isinstance(physics, physics_cls):
                    return super().get_reward(physics)
                target, finger = physics._geom_ids()
                size = physics.model.geom_size
                radii = size[target, 0] + size[finger, 0]
                return rewards.tolerance(physics.finger_to_target_dist(), (0, radii))

        _FAST_REACHER_TASK.append(FastReacher)
    return _FAST_REACHER_TASK[0]
