"""Task ids and :func:`make`: dm-control suite and composer arm tasks, gymnasium MuJoCo envs, and
the package's own ``sim2real/arm-reach``, all as gymnasium environments.

Example:
    >>> import sim2real
    >>> env = sim2real.make("dmc/reacher-easy")
    >>> env.observation_space.shape
    (6,)
    >>> sim2real.make("dmc/reacher-eazy")
    Traceback (most recent call last):
    ...
    ValueError: `task_id` must be one of the ids listed by `sim2real tasks` or 'gym/<gymnasium id>'. \
Received 'dmc/reacher-eazy'. Close matches: 'dmc/reacher-easy', 'dmc/reacher-hard', 'gym/Reacher-v5'.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import gymnasium as gym

if TYPE_CHECKING:
    import numpy as np

__all__ = ["TASKS", "Task", "make", "task_ids"]


@dataclass(frozen=True)
class Task:
    """A registered task: id, one-line description and the factory behind it."""

    id: str
    description: str
    factory: Callable[..., gym.Env]


_DM_OPTIONS = ("flatten", "render_mode", "width", "height", "camera", "time_limit")


def _check_options(task_id: str, options: dict[str, Any], allowed: tuple[str, ...]) -> None:
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise TypeError(f"`options` for {task_id!r} must be among {list(allowed)}. Received unknown {unknown}.")


def _split(options: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    adapter: dict[str, Any] = {
        k: options[k] for k in ("flatten", "render_mode", "width", "height", "camera") if k in options
    }
    env_kwargs = {}
    if "time_limit" in options:
        env_kwargs["time_limit"] = options["time_limit"]
    return adapter, env_kwargs


#: Pristine suite environments, one per (domain, task, time limit), that new instances are copied from.
_SUITE_TEMPLATES: dict[tuple[str, str, Any], Any] = {}


def _suite_env(domain: str, task: str, env_kwargs: dict[str, Any]) -> Any:
    """A new suite environment. The first one of a kind is loaded from XML and kept as a template; later
    ones copy its compiled model (about 10x faster than compiling: reacher's procedural skybox alone costs
    a quarter of a second) and deep-copy its task, with fresh entropy in the task's ``RandomState``.
    The copies step bitwise like ``suite.load`` (tested)."""
    import copy

    import numpy as np
    from dm_control import suite
    from dm_control.rl import control

    key = (domain, task, env_kwargs.get("time_limit"))
    template = _SUITE_TEMPLATES.get(key)
    if template is None:
        template = _SUITE_TEMPLATES[key] = suite.load(domain, task, task_kwargs=env_kwargs or None)
    physics = template.physics.copy(share_model=False)
    if domain == "reacher":
        physics.__class__ = _fast_reacher_physics()  # same state, cached geom ids (bitwise-identical values)
    new_task = copy.deepcopy(template.task)
    if domain == "reacher":
        new_task.__class__ = _fast_reacher_task()
    new_task._random = np.random.RandomState()
    return control.Environment(
        physics,
        new_task,
        time_limit=template._step_limit * template.control_timestep(),
        n_sub_steps=template._n_sub_steps,
        flat_observation=template._flat_observation,
    )


class _FastReacherPhysics(Protocol):
    """What FastReacher's reward reads from the physics class :func:`_fast_reacher_physics` builds."""

    model: Any

    def _geom_ids(self) -> tuple[int, int]: ...

    def finger_to_target_dist(self) -> np.floating[Any]: ...


# Built on first use (dm-control imports lazily); one class each, so instances share it.
_FAST_REACHER_PHYSICS: list[type[_FastReacherPhysics]] = []
_FAST_REACHER_TASK: list[type] = []


def _fast_reacher_physics() -> type[_FastReacherPhysics]:
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


def _fast_reacher_task() -> type:
    """dm-control's Reacher task with the reward's radii read by cached geom index (the named indexer parses
    ``['target', 'finger']`` every step); the same sum of the same two floats, so the reward is bitwise equal."""
    if not _FAST_REACHER_TASK:
        from dm_control.suite import reacher
        from dm_control.utils import rewards

        physics_cls = _fast_reacher_physics()

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


def _suite(domain: str, task: str) -> Callable[..., gym.Env]:
    def factory(task_id: str, **options: Any) -> gym.Env:
        from sim2real.adapters import DmEnvToGym

        _check_options(task_id, options, _DM_OPTIONS)
        adapter, env_kwargs = _split(options)
        return DmEnvToGym(_suite_env(domain, task, env_kwargs), **adapter)

    return factory


def _composer(name: str) -> Callable[..., gym.Env]:
    def factory(task_id: str, **options: Any) -> gym.Env:
        from dm_control import manipulation

        from sim2real.adapters import DmEnvToGym

        _check_options(task_id, options, _DM_OPTIONS[:-1])
        adapter, _ = _split(options)
        return DmEnvToGym(manipulation.load(name), **adapter)

    return factory


def _arm_reach(task_id: str, **options: Any) -> gym.Env:
    from sim2real.tasks.arm_reach import ArmReachEnv

    _check_options(task_id, options, ("render_mode", "width", "height", "max_episode_steps", "success_threshold"))
    return ArmReachEnv(**options)


def _gym(task_id: str, **options: Any) -> gym.Env:
    gym_id = task_id[len("gym/") :]
    try:
        return gym.make(gym_id, **options)
    except gym.error.Error as err:
        raise ValueError(f"`task_id` {task_id!r}: gymnasium cannot make {gym_id!r}: {err}") from err


TASKS: dict[str, Task] = {
    t.id: t
    for t in (
        Task(
            "dmc/reacher-easy", "dm-control suite: 2-link planar arm reaches a large target.", _suite("reacher", "easy")
        ),
        Task(
            "dmc/reacher-hard", "dm-control suite: 2-link planar arm reaches a small target.", _suite("reacher", "hard")
        ),
        Task(
            "dmc/manipulator-bring_ball",
            "dm-control suite: planar manipulator brings a ball to a target.",
            _suite("manipulator", "bring_ball"),
        ),
        Task(
            "dmc/manipulator-bring_peg",
            "dm-control suite: planar manipulator brings a peg to a target pose.",
            _suite("manipulator", "bring_peg"),
        ),
        Task(
            "dmc/manipulator-insert_ball",
            "dm-control suite: planar manipulator drops a ball into a basket.",
            _suite("manipulator", "insert_ball"),
        ),
        Task(
            "dmc/manipulator-insert_peg",
            "dm-control suite: planar manipulator inserts a peg into a slot.",
            _suite("manipulator", "insert_peg"),
        ),
        Task(
            "dmc/jaco-reach_site",
            "dm-control composer: Kinova Jaco arm moves its hand to a target site (features).",
            _composer("reach_site_features"),
        ),
        Task(
            "dmc/jaco-lift_brick",
            "dm-control composer: Kinova Jaco arm lifts a Duplo brick (features).",
            _composer("lift_brick_features"),
        ),
        Task(
            "sim2real/arm-reach",
            "sim2real: 5-joint arm, end-effector delta-xyz actions through damped-least-squares IK.",
            _arm_reach,
        ),
        Task("gym/Reacher-v5", "gymnasium MuJoCo: 2-link planar reacher (any other gym/<id> works too).", _gym),
        Task("gym/Pusher-v5", "gymnasium MuJoCo: 7-DoF arm pushes an object to a goal.", _gym),
    )
}


def task_ids() -> list[str]:
    """Every registered task id (``gym/<id>`` accepts any gymnasium id besides those listed)."""
    return list(TASKS)


def make(task_id: str, *, pixels: bool = False, params: Any = None, **options: Any) -> gym.Env:
    """Creates a task as a ``gymnasium.Env``.

    Args:
        task_id: an id from :data:`TASKS` (``sim2real tasks`` lists them) or ``gym/<gymnasium id>``.
        pixels: image observations: the env is wrapped in :class:`~sim2real.pixels.PixelObservation`,
            which then takes the options ``size`` (``(height, width)``, default ``(84, 84)``),
            ``camera`` (name or id; default the model's first camera) and ``pixels_only`` (default
            True; False gives a dict of ``"state"`` and ``"pixels"``).
        params: a calibration: a :class:`sysid.FitResult` or ``{address: value}``, written into the model
            (it becomes the nominal model that later randomisation is relative to).
        **options: for ``dmc/*``: ``flatten`` (default True), ``render_mode``, ``width``, ``height``,
            ``camera`` and (suite only) ``time_limit`` in seconds; for ``gym/*``: anything
            ``gymnasium.make`` takes; for ``sim2real/arm-reach``: the
            :class:`~sim2real.tasks.arm_reach.ArmReachEnv` arguments.

    Raises:
        ValueError: unknown task id (close matches listed).
        TypeError: an option the task does not take.

    Example:
        >>> import sim2real
        >>> sim2real.make("sim2real/arm-reach", pixels=True, size=(64, 48)).observation_space.shape
        (64, 48, 3)
    """
    from sim2real.pixels import PixelObservation, track_render_contexts

    if not isinstance(pixels, bool):
        raise TypeError(f"`pixels` must be a bool. Received {pixels!r}.")
    if not pixels:
        if "size" in options or "pixels_only" in options:
            raise TypeError(f"`size` and `pixels_only` apply with pixels=True only. Received {sorted(options)}.")
        env = _make(task_id, **options)
        track_render_contexts(env)  # texture resamples reach the env's own renderers
    else:
        view = {k: options.pop(k) for k in ("size", "camera", "pixels_only") if k in options}
        env = PixelObservation(_make(task_id, **options), **view)
    if params is not None:
        from sim2real.calibration import calibrate

        calibrate(env, params)
    return env


def _make(task_id: str, **options: Any) -> gym.Env:
    if not isinstance(task_id, str):
        raise TypeError(f"`task_id` must be a string such as 'dmc/reacher-easy'. Received {task_id!r}.")
    if task_id.startswith("gym/") and len(task_id) > 4:
        return _gym(task_id, **options)
    if task_id.startswith(("model:", "env:")):  # an MJCF file or an env factory (sim2real.sources)
        from sim2real.user_envs import make_user_env

        return make_user_env(task_id, **options)
    task = TASKS.get(task_id)
    if task is None:
        close = difflib.get_close_matches(task_id, list(TASKS), n=3, cutoff=0.6)
        hint = f" Close matches: {', '.join(repr(c) for c in close)}." if close else ""
        raise ValueError(
            "`task_id` must be one of the ids listed by `sim2real tasks` or 'gym/<gymnasium id>'. "
            f"Received {task_id!r}.{hint}"
        )
    return task.factory(task_id, **options)
