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

import copy
import difflib
import os
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym

__all__ = ["TASKS", "Task", "headless_options", "make", "task_ids"]


@dataclass(frozen=True)
class Task:
    """A registered task: id, one-line description, the factory behind it and whether it takes ``textures``."""

    id: str
    description: str
    factory: Callable[..., gym.Env]
    headless: bool = False


_DM_OPTIONS = ("flatten", "render_mode", "width", "height", "camera", "time_limit", "textures")
_COMPOSER_OPTIONS = ("flatten", "render_mode", "width", "height", "camera")


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


def _suite(domain: str, task: str) -> Callable[..., gym.Env]:
    def factory(task_id: str, **options: Any) -> gym.Env:
        from sim2real.adapters import DmEnvToGym
        from sim2real.tasks.models import check_textures
        from sim2real.tasks.suite import suite_env

        _check_options(task_id, options, _DM_OPTIONS)
        textures = check_textures(options.pop("textures", True), options.get("render_mode"))
        adapter, env_kwargs = _split(options)
        return DmEnvToGym(suite_env(domain, task, env_kwargs.get("time_limit"), textures=textures), **adapter)

    return factory


def _composer(name: str) -> Callable[..., gym.Env]:
    def factory(task_id: str, **options: Any) -> gym.Env:
        from dm_control import manipulation

        from sim2real.adapters import DmEnvToGym

        _check_options(task_id, options, _COMPOSER_OPTIONS)
        adapter, _ = _split(options)
        return DmEnvToGym(manipulation.load(name), **adapter)

    return factory


def _arm_reach(task_id: str, **options: Any) -> gym.Env:
    from sim2real.tasks.arm_reach import ArmReachEnv

    _check_options(
        task_id, options, ("render_mode", "width", "height", "max_episode_steps", "success_threshold", "textures")
    )
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
            "dmc/reacher-easy",
            "dm-control suite: 2-link planar arm reaches a large target.",
            _suite("reacher", "easy"),
            True,
        ),
        Task(
            "dmc/reacher-hard",
            "dm-control suite: 2-link planar arm reaches a small target.",
            _suite("reacher", "hard"),
            True,
        ),
        Task(
            "dmc/manipulator-bring_ball",
            "dm-control suite: planar manipulator brings a ball to a target.",
            _suite("manipulator", "bring_ball"),
            True,
        ),
        Task(
            "dmc/manipulator-bring_peg",
            "dm-control suite: planar manipulator brings a peg to a target pose.",
            _suite("manipulator", "bring_peg"),
            True,
        ),
        Task(
            "dmc/manipulator-insert_ball",
            "dm-control suite: planar manipulator drops a ball into a basket.",
            _suite("manipulator", "insert_ball"),
            True,
        ),
        Task(
            "dmc/manipulator-insert_peg",
            "dm-control suite: planar manipulator inserts a peg into a slot.",
            _suite("manipulator", "insert_peg"),
            True,
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
            True,
        ),
        Task("gym/Reacher-v5", "gymnasium MuJoCo: 2-link planar reacher (any other gym/<id> works too).", _gym),
        Task("gym/Pusher-v5", "gymnasium MuJoCo: 7-DoF arm pushes an object to a goal.", _gym),
    )
}


def task_ids() -> list[str]:
    """Every registered task id (``gym/<id>`` accepts any gymnasium id besides those listed)."""
    return list(TASKS)


def headless_options(task_id: str, options: Mapping[str, Any], effects: Iterable[Any] = ()) -> dict[str, Any]:
    """``options`` with ``textures=False`` added where that builds the same physics faster: the task can be built
    headless, ``options`` neither render nor choose ``textures`` themselves, and no effect among ``effects``
    (lists and ADR controllers included) edits textures. For envs that are never rendered (evaluation).

    Example:
        >>> headless_options("dmc/reacher-easy", {"time_limit": 2.0})
        {'time_limit': 2.0, 'textures': False}
        >>> headless_options("gym/Reacher-v5", {})
        {}
    """
    from randomizers import ADR, Texture

    out = dict(options)
    task = TASKS.get(task_id)
    if task is None or not task.headless or {"textures", "render_mode", "pixels"} & set(out):
        return out
    stack = list(effects)
    while stack:
        item = stack.pop()
        if isinstance(item, (list, tuple)):
            stack.extend(item)
        elif isinstance(item, ADR):
            stack.extend(item.effects)
        elif isinstance(item, Texture):
            return out
    out["textures"] = False
    return out


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
            ``camera`` and (suite only) ``time_limit`` in seconds and ``textures``; for ``gym/*``: anything
            ``gymnasium.make`` takes; for ``sim2real/arm-reach``: the
            :class:`~sim2real.tasks.arm_reach.ArmReachEnv` arguments. ``textures=False`` (``dmc/reacher-*``,
            ``dmc/manipulator-*``, ``sim2real/arm-reach``) builds a headless env for one that is never
            rendered: the model is compiled without textures, the physics is bitwise the same, and building
            it is several times faster (:mod:`sim2real.tasks.models`). Every env owns its model copy (each
            task's model is compiled once per process).

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
    # What gymnasium.make(env.spec) passes back here to build the same env again; a model file by its absolute path
    # (a relative one would name another file, or none, from another working folder).
    kind, _, path = task_id.partition(":") if isinstance(task_id, str) else ("", "", "")
    again = f"model:{os.path.abspath(path)}" if kind == "model" and path and not os.path.isabs(path) else task_id
    recreate = {"task_id": again, **({"pixels": True} if pixels else {}), **options}
    if params is not None:
        recreate["params"] = params
    if pixels and options.get("textures", True) is not True:
        raise ValueError(f"`textures` must be True with pixels=True. Received {options['textures']!r}.")
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
    _give_spec(env, task_id, recreate)
    return env


def _give_spec(env: gym.Env, task_id: str, kwargs: dict[str, Any]) -> None:
    """Gives the env of ``task_id`` the ``EnvSpec`` that recreates it (``gymnasium.make(env.spec)``, and so the
    spec of every wrapper recording its arguments around it): entry point :func:`make`, ``kwargs`` its arguments.
    Its flags are those ``gymnasium.make`` stamps on the env it builds from the spec (no checker, order or
    time-limit wrapper added), so the remade env's spec equals this one. The id is the task id, or for a user
    model or factory (whose id is a path) ``sim2real/model-<file stem>`` / ``sim2real/env-<factory>``. An env that
    has a spec already (``gym/*``, a factory calling ``gymnasium.make``) keeps it, with a ``params`` calibration
    added to it (:func:`calibrated_gym`)."""
    base = env.unwrapped
    if base.spec is not None:
        if "params" not in kwargs:
            return
        spec = copy.copy(base.spec)
        spec.kwargs = {"entry_point": spec.entry_point, "params": kwargs["params"], **spec.kwargs}
        spec.entry_point = "sim2real.tasks:calibrated_gym"
        base.spec = spec
        layer = env
        while isinstance(layer, gym.Wrapper):  # gymnasium's own layers cache the spec they derive
            layer._cached_spec = None
            layer = layer.env
        return
    env.unwrapped.spec = gym.envs.registration.EnvSpec(
        id=_spec_id(task_id),
        entry_point="sim2real.tasks:make",
        max_episode_steps=None,
        order_enforce=False,
        disable_env_checker=True,
        kwargs=kwargs,
    )


def _spec_id(task_id: str) -> str:
    """A gymnasium id for ``task_id``: itself for a registered task; for ``model:<path>`` and
    ``env:<module>:<factory>`` (not gymnasium ids) ``sim2real/model-<stem>`` and ``sim2real/env-<factory>``.

    Example:
        >>> _spec_id("model:/robots/my arm-v2.xml"), _spec_id("env:pkg.envs:make_arm")
        ('sim2real/model-my_arm_v2', 'sim2real/env-make_arm')
    """
    if task_id in TASKS:
        return task_id
    kind, _, rest = task_id.partition(":")
    name = os.path.splitext(os.path.basename(rest))[0] if kind == "model" else rest.rsplit(":", 1)[-1]
    return f"sim2real/{kind}-{re.sub(r'[^A-Za-z0-9_.]', '_', name) or kind}"


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
        if task_id in gym.registry:  # the user's own gym.register'ed env, named as gymnasium names it
            hint = f" {task_id!r} is registered with gymnasium: use 'gym/{task_id}'."
        elif task_id.lower().endswith((".xml", ".mjcf")) or os.path.isfile(task_id):  # a bare model path
            hint = f" An MJCF file is 'model:<path>': use 'model:{task_id}'."
        raise ValueError(
            "`task_id` must be one of the ids listed by `sim2real tasks` or 'gym/<gymnasium id>'. "
            f"Received {task_id!r}.{hint}"
        )
    return task.factory(task_id, **options)


def calibrated_gym(entry_point: Any, params: Any, **kwargs: Any) -> gym.Env:
    """The bare gymnasium env of ``entry_point`` (a gymnasium entry point) built with ``kwargs`` and calibrated
    with ``params``: the spec entry point of ``make("gym/<id>", params=...)``, so ``gymnasium.make(env.spec)``
    rebuilds the calibration under gymnasium's own checker, order and time-limit layers."""
    from gymnasium.envs.registration import load_env_creator

    from sim2real.calibration import calibrate

    creator = entry_point if callable(entry_point) else load_env_creator(entry_point)
    env = creator(**kwargs)
    if not isinstance(env, gym.Env):
        raise TypeError(f"`entry_point` must build a gymnasium.Env. Received {type(env).__name__}.")
    calibrate(env, params)
    return env
