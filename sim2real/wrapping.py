"""``sim2real.wrap``: one call that applies effects to a gymnasium, dm_env or TorchRL environment.

Physics effects (:mod:`randomizers`) and signal models (:mod:`noise_models`) mix freely; physics is
randomised innermost, signals are corrupted outside it.

Example:
    >>> import sim2real
    >>> from randomizers import Friction, Mass, Uniform
    >>> env = sim2real.wrap(sim2real.make("dmc/reacher-easy"),
    ...                     Friction(scale=Uniform(0.5, 1.5)), Mass(scale=Uniform(0.8, 1.2), bodies="arm*"),
    ...                     seed=0)
    >>> obs, info = env.reset(seed=0)
    >>> round(info["sim2real"]["params"]["body_mass[arm]"], 6)
    0.042376

    The issue's example, noise and latency at physics rate around a dm-control task:

    >>> from noise_models import ActionLatency, Bias, Gaussian, ObservationLatency, ObservationNoise
    >>> from randomizers import Uniform
    >>> env = sim2real.wrap(sim2real.make("dmc/reacher-easy"),
    ...                     ObservationNoise(Gaussian(std=0.01), Bias(Uniform(-0.02, 0.02))),
    ...                     ObservationLatency(steps=3), ActionLatency(seconds=0.02), seed=0)
    >>> obs, info = env.reset(seed=0)
    >>> info["sim2real"]["params"]["obs_latency"], info["sim2real"]["params"]["action_latency_steps"]
    (0.06, 1)
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any

import gymnasium as gym

from noise_models.corruptor import ActionNoise, ObservationNoise
from noise_models.timing import TimeModel
from randomizers import ADR, EFFECT_TYPES, Effect, Texture
from randomizers.seeding import SeedLike, normalize_seed
from sim2real.wrappers.gym import RandomizePhysics, merge_report

__all__ = ["make_vec", "wrap"]


_SIGNAL_TYPES = (ObservationNoise, ActionNoise, TimeModel)


def _flatten(effects: Iterable[Any]) -> list[Any]:
    out: list[Any] = []
    for item in effects:
        if isinstance(item, (list, tuple)):
            out.extend(_flatten(item))
        elif isinstance(item, (Effect, ADR, *_SIGNAL_TYPES)):
            out.append(item)
        else:
            raise TypeError(
                f"`effects` must be effects from `randomizers` ({', '.join(EFFECT_TYPES)}), models from `noise_models` "
                "(ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold, ControlJitter) or "
                "lists of them. "
                f"Received {item!r} of type {type(item).__name__}."
            )
    return out


def _is_torchrl_env(env: Any) -> bool:
    if "torchrl" not in sys.modules:  # never import torch just to check
        return False
    from torchrl.envs import EnvBase

    return isinstance(env, EnvBase)


def wrap(env: Any, *effects: Any, adr: ADR | None = None, seed: SeedLike = None) -> Any:
    """Applies ``effects`` to ``env`` and returns the same kind of environment.

    Args:
        env: a ``gymnasium.Env``, a ``dm_env.Environment`` (dm-control) or a TorchRL ``EnvBase``.
        *effects: physics effects from :mod:`randomizers` and signal models from :mod:`noise_models`
            (lists are flattened). An :class:`~randomizers.ADR` among them is taken as ``adr``.
        adr: automatic domain randomisation: the controller's effects draw from its live ranges and every
            finished episode is reported to it (:mod:`sim2real.wrappers.adr`); share one controller between
            the envs of a process freely.
        seed: root seed of every stream (int, tuple of ints or None for fresh entropy). Each effect
            and model draws from its own stream keyed by (seed, name, episode).

    Returns:
        gymnasium -> :class:`~sim2real.wrappers.RandomizePhysics` (physics only),
        :class:`~sim2real.wrappers.CorruptSignals` (signals only) or, with both, one
        :class:`~sim2real.wrappers.RandomizeAndCorrupt` layer that behaves bitwise as the second around the first
        (:mod:`sim2real.wrappers.fused`); dm_env -> the ``*DmEnv`` twins; TorchRL -> ``TransformedEnv`` with
        :class:`~sim2real.wrappers.RandomizePhysicsTransform`, :class:`~sim2real.wrappers.CorruptSignalsTransform`
        or, with both, :class:`~sim2real.wrappers.RandomizeAndCorruptTransform` appended. With ``adr``, physics and
        signals stay two layers. Wrapping a wrapped env again adds layers (``wrap(wrap(env, *physics), *signals)``
        is the two-layer composition).

    Raises:
        TypeError: unsupported env kind, or physics effects on an env without MuJoCo.
        ValueError: more than one ADR controller.
    """
    return _wrap(env, effects, adr, seed)


def _wrap(env: Any, effects: Iterable[Any], adr: ADR | None, seed: SeedLike, physics: type | None = None) -> Any:
    """:func:`wrap`; ``physics``: the class of a gymnasium env's physics-only layer (None: ``RandomizePhysics``)."""
    items = _flatten(effects)
    controllers = [e for e in items if isinstance(e, ADR)] + ([] if adr is None else [adr])
    if adr is not None and not isinstance(adr, ADR):
        raise TypeError(f"`adr` must be an ADR controller (sim2real.ADR) or None. Received {adr!r}.")
    if len(controllers) > 1:
        raise ValueError(
            f"`adr` must be one ADR controller; merge their effects into one. Received {len(controllers)}."
        )
    adr = controllers[0] if controllers else None
    items = [e for e in items if not isinstance(e, ADR)]
    flat = [e for e in items if isinstance(e, Effect)]
    signals = [e for e in items if not isinstance(e, Effect)]
    normalize_seed(seed)
    if any(isinstance(e, Texture) for e in (*flat, *(adr.effects if adr else ()))):
        # Texture edits must reach every live render context, also of envs not built by make().
        from sim2real.pixels import track_render_contexts

        track_render_contexts(env)
    if isinstance(env, gym.vector.VectorEnv):
        raise TypeError(
            "`env` is a gymnasium VectorEnv: wrap each sub-environment instead (e.g. "
            "`gymnasium.vector.SyncVectorEnv([lambda: sim2real.wrap(make(), ...), ...])`) or use "
            "`sim2real.make_vec(task_id, num_envs, *effects, seed=...)`."
        )
    if isinstance(env, gym.Env):
        from sim2real.wrappers.signals import CorruptSignals

        if adr is not None:
            from sim2real.wrappers.adr import AutoRandomizePhysics

            env = AutoRandomizePhysics(env, flat, adr, seed)
        elif flat and signals:  # one fused layer on the hot path instead of two
            from sim2real.wrappers.fused import RandomizeAndCorrupt

            return RandomizeAndCorrupt(env, flat, signals, seed)
        elif flat or not signals:
            env = (physics or RandomizePhysics)(env, flat, seed)
        return CorruptSignals(env, signals, seed) if signals else env
    if _is_torchrl_env(env):
        from torchrl.envs import Compose, TransformedEnv
        from torchrl.envs.batched_envs import BatchedEnvBase

        base = env.base_env if isinstance(env, TransformedEnv) else env
        if isinstance(base, BatchedEnvBase):
            # Its MuJoCo models live in its workers, and its observations carry a batch dimension.
            raise TypeError(
                f"`env` is a batched TorchRL env ({type(base).__name__}, batch_size {list(env.batch_size)}): wrap "
                "each sub-environment in its factory instead, e.g. `SerialEnv(2, [lambda i=i: sim2real.wrap("
                "GymEnv(...), *effects, seed=(seed, i)) for i in range(2)])`."
            )

        from sim2real.wrappers.torchrl import CorruptSignalsTransform, RandomizePhysicsTransform

        transforms: list[Any] = []
        if adr is not None:
            from sim2real.wrappers.adr import make_adr_transform

            transforms.append(make_adr_transform(flat, adr, seed))
        elif flat and signals:  # one fused transform instead of two
            from sim2real.wrappers.fused_torchrl import RandomizeAndCorruptTransform

            transforms.append(RandomizeAndCorruptTransform(flat, signals, seed))
        elif flat or not signals:
            transforms.append(RandomizePhysicsTransform(flat, seed))
        if signals and not (flat and adr is None):
            transforms.append(CorruptSignalsTransform(signals, seed))
        if not isinstance(env, TransformedEnv):
            # One transform stays reachable as ``env.transform`` itself (several become a Compose).
            env = TransformedEnv(env, transforms[0] if len(transforms) == 1 else Compose(*transforms))
        else:
            for transform in transforms:
                env.append_transform(transform)
        # The transforms bind when the specs are asked for: asked here, an env they cannot serve is refused by wrap,
        # not at the first reset.
        env.full_observation_spec  # noqa: B018
        return env
    import dm_env

    if isinstance(env, dm_env.Environment):
        from sim2real.wrappers.dm import RandomizePhysicsDmEnv
        from sim2real.wrappers.signals import CorruptSignalsDmEnv

        if adr is not None:
            from sim2real.wrappers.adr import AutoRandomizePhysicsDmEnv

            env = AutoRandomizePhysicsDmEnv(env, flat, adr, seed)
        elif flat and signals:  # one fused layer instead of two
            from sim2real.wrappers.fused import RandomizeAndCorruptDmEnv

            return RandomizeAndCorruptDmEnv(env, flat, signals, seed)
        elif flat or not signals:
            env = RandomizePhysicsDmEnv(env, flat, seed)
        return CorruptSignalsDmEnv(env, signals, seed) if signals else env
    raise TypeError(
        "`env` must be a gymnasium.Env, a dm_env.Environment (dm-control) or a TorchRL EnvBase. "
        f"Received {type(env).__module__}.{type(env).__qualname__}."
    )


def make_vec(
    task_id: str,
    num_envs: int,
    *effects: Any,
    adr: ADR | None = None,
    seed: int | None = None,
    vectorization: str = "sync",
    **options: Any,
) -> gym.vector.VectorEnv:
    """A gymnasium vector env of ``num_envs`` wrapped copies of a task; env ``i`` draws from the
    streams rooted at ``(seed, i)``, so every sub-env gets independent draws even with
    ``reset(seed=None)``.

    Draws are reported when they are made: ``info["sim2real"]`` (address -> ``(num_envs,)`` values, as gymnasium
    merges sub-env infos) comes with ``reset`` and with every step in which a sub-env autoresets (its new
    episode's draws), and with any step in which a sub-env's physics diverged; other steps carry no
    ``"sim2real"`` key. Gymnasium merges every sub-env's nested info dict on every step it is present, which cost
    a quarter of a vector step. Effects that change the model during an episode (``Push``, ``Interval``
    schedules) and ``ControlJitter`` (substeps drawn per step) keep the report on every step.

    With ``adr``, every sub-env draws from the one controller's ranges and pins its own boundaries (its boundary
    stream is rooted at ``(seed, i)`` too); finished episodes reach the controller in the order they end, which
    for ``"sync"`` is: step by step, sub-env 0 first. ``"async"`` would give each process a copy of the
    controller, so it is refused with ``adr``.

    Example:
        >>> import sim2real
        >>> from randomizers import Damping, Uniform
        >>> envs = sim2real.make_vec("dmc/reacher-easy", 2, Damping(scale=Uniform(0.5, 2.0)), seed=0)
        >>> obs, info = envs.reset()
        >>> a, b = info["sim2real"]["params"]["dof_damping[shoulder]"]
        >>> bool(a != b)
        True
        >>> envs.close()
    """
    from sim2real.tasks import make

    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"`num_envs` must be an int >= 1. Received {num_envs!r}.")
    if vectorization not in ("sync", "async"):
        raise ValueError(f"`vectorization` must be one of ['sync', 'async']. Received {vectorization!r}.")
    if adr is not None and vectorization != "sync":
        raise ValueError(
            "`vectorization` must be 'sync' with `adr` (one controller shared in this process; 'async' would copy "
            f"it into every worker). Received {vectorization!r}."
        )
    root = 0 if seed is None else seed
    every_step = _reports_every_step([*effects, *(adr.effects if adr is not None else ())])
    # Physics effects only (or none): their one layer reports at reset itself, no second layer on every step.
    physics_only = adr is None and all(isinstance(e, Effect) for e in _flatten(effects))

    def build(i: int) -> gym.Env:
        if every_step:
            return wrap(make(task_id, **options), *effects, adr=adr, seed=(root, i))
        if physics_only:
            return _wrap(make(task_id, **options), effects, None, (root, i), _PhysicsReportedAtReset)
        return _ReportAtReset(wrap(make(task_id, **options), *effects, adr=adr, seed=(root, i)))

    fns = [(lambda i=i: build(i)) for i in range(num_envs)]
    if vectorization == "sync":
        return gym.vector.SyncVectorEnv(fns)
    return gym.vector.AsyncVectorEnv(fns)


def _reports_every_step(effects: Iterable[Any]) -> bool:
    """Whether the env's report changes during an episode (pushes, interval schedules, per-step jitter)."""
    from noise_models.timing import ControlJitter
    from randomizers import Interval, Push

    return any(
        isinstance(e, (Push, ControlJitter)) or isinstance(getattr(e, "schedule", None), Interval)
        for e in _flatten(effects)
    )


class _ReportAtReset(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """A :func:`make_vec` sub-env whose ``info["sim2real"]`` comes with resets and with steps whose physics
    diverged only (its draws are fixed for the episode; see :func:`make_vec`). It records its (no) arguments so
    the sub-env's spec recreates it, as every other sim2real layer does."""

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(env)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        report = info.get("sim2real")
        if report is not None and not report["diverged"]:
            del info["sim2real"]
        return obs, reward, terminated, truncated, info


class _PhysicsReportedAtReset(RandomizePhysics):
    """A :func:`make_vec` sub-env's physics layer when it is the only one: ``RandomizePhysics`` whose
    ``info["sim2real"]`` comes with resets and with steps whose physics diverged only (as :class:`_ReportAtReset`
    around it, without building a report on every step for the layer above to delete, nor that layer's step).
    Its step is ``RandomizePhysics.step`` without the report: a make_vec env without step effects (pushes, interval
    schedules; see :func:`_reports_every_step`) has none to run."""

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        if self._reset_diverged or self._step_effects:
            obs, reward, terminated, truncated, info = super().step(action)
            if not info["sim2real"]["diverged"]:
                del info["sim2real"]
            return obs, reward, terminated, truncated, info
        obs, reward, terminated, truncated, info = self.env.step(action)
        obs, truncated, diverged = self._settle_step(obs, truncated, info)
        if diverged:
            merge_report(info, self._info())
        return obs, reward, terminated, truncated, info
