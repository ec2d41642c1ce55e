"""gymnasium wrapper that randomises physics: :class:`RandomizePhysics`.

Example:
    >>> import sim2real
    >>> from randomizers import Friction, Mass, Uniform
    >>> env = RandomizePhysics(sim2real.make("dmc/reacher-easy"),
    ...                        [Friction(scale=Uniform(0.5, 1.5)), Mass(scale=Uniform(0.8, 1.2), bodies="arm")],
    ...                        seed=0)
    >>> obs, info = env.reset(seed=1)
    >>> sorted(info["sim2real"]["params"])[:2]
    ['body_mass[arm]', 'geom_friction[arm][0]']
    >>> env.close()  # restores the nominal model bitwise
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from randomizers import Effect, PhysicsRandomizer
from randomizers.seeding import SeedLike
from sim2real.physics import PhysicsHandle, find_physics

__all__ = ["RandomizePhysics", "merge_report", "observe_again", "require_physics", "settle_draws"]

# Wrappers that hand the inner observation through unchanged, so it may be recomputed underneath them.
_PASS_THROUGH = (
    gym.wrappers.TimeLimit,
    gym.wrappers.OrderEnforcing,
    gym.wrappers.PassiveEnvChecker,
)


def observe_again(env: gym.Env) -> Any:
    """The observation of the env's current physics state, computed again, or None where that cannot be
    done faithfully (a wrapper that changes observations in between, an env that does not say how)."""
    inner = env
    while isinstance(inner, gym.Wrapper):
        if not isinstance(inner, _PASS_THROUGH):
            return None
        inner = inner.env
    observe = getattr(inner, "observe", None)  # sim2real's dm-control adapter
    if callable(observe):
        return observe()
    get_obs = getattr(inner, "_get_obs", None)  # gymnasium's MuJoCo envs
    return get_obs() if callable(get_obs) else None


def require_physics(env: Any, effects: Sequence[Effect]) -> PhysicsHandle:
    """The physics handle of ``env``, or a TypeError naming the env type when there is none."""
    handle = find_physics(env)
    if handle is None:
        names = ", ".join(sorted({type(e).__name__ for e in effects})) or "physics effects"
        raise TypeError(
            f"`env` of type {type(env).__module__}.{type(env).__qualname__} has no MuJoCo model, so the "
            f"physics effects ({names}) cannot reach it. Physics effects need a dm-control suite/composer env, "
            "a gymnasium env with `unwrapped.model`/`unwrapped.data`, or a TorchRL DMControlEnv/GymEnv."
        )
    return handle


def settle_draws(handle: PhysicsHandle, randomizer: PhysicsRandomizer) -> tuple[tuple[str, ...], bool]:
    """After the env's own reset, makes the model hold the episode's draws: an env that compiled a new model in
    its reset (a procedural scene) gets them written into that one (its reset ran on the new nominal model), and
    draws the task's reset overwrote (dm-control ``finger`` resets its hinge damping) are written again. The state
    the env chose is kept; ``mj_forward`` recomputes what derives from it.

    Returns:
        The addresses written again, and whether the model changed under the env's reset state (then its
        reset observation should be computed again, see :func:`observe_again`).
    """
    rebuilt = handle.rebuilt()
    if rebuilt:
        # The model left behind gets its nominal back first: an env that picks among models it keeps would
        # otherwise come back to one holding old draws and snapshot them as its nominal.
        randomizer.restore_nominal()
        randomizer.bind(handle.model, handle.data)
        randomizer.apply()
    reapplied = randomizer.reapply_overwritten()
    moved = rebuilt or bool(reapplied)
    if moved:
        mujoco.mj_forward(handle.model, handle.data)
    return reapplied, moved


_SCALARS = (str, bytes, int, float, complex, type(None), np.number, np.bool_)


def _immutable(value: Any) -> bool:
    """Whether ``value`` is an immutable value all the way down: scalars, strings, tuples and frozensets of such,
    frozen dataclasses (distributions, ``Interval``) and frozen effects holding only such. A deep copy of it would
    be an equal object that nobody can change, so recording it need not copy it.

    Example:
        >>> from randomizers import Mass, Uniform
        >>> _immutable((Mass(scale=Uniform(0.8, 1.2), bodies=["arm", "hand"]), (0, 3)))
        True
        >>> _immutable([0, 3]), _immutable(np.zeros(2))
        (False, False)
    """
    if isinstance(value, _SCALARS):
        return True
    if type(value) in (tuple, frozenset):
        return all(_immutable(v) for v in value)
    if isinstance(value, Effect):
        frozen = bool(getattr(value, "_frozen", False))
    else:
        frozen = dataclasses.is_dataclass(value) and not isinstance(value, type) and value.__dataclass_params__.frozen  # type: ignore[attr-defined]
    state = getattr(value, "__dict__", None)
    if not frozen or state is None or hasattr(type(value), "__slots__"):
        return False
    return all(_immutable(v) for v in state.values())


def merge_report(info: dict[str, Any], report: dict[str, Any]) -> None:
    """Puts ``report`` under ``info["sim2real"]``, merging with a report an inner wrapper left there."""
    inner = info.get("sim2real")
    if inner is None:
        info["sim2real"] = report
        return
    merged = {**inner, **report}
    merged["params"] = {**inner.get("params", {}), **report.get("params", {})}
    merged["diverged"] = bool(inner.get("diverged")) or bool(report.get("diverged"))
    info["sim2real"] = merged


class RandomizePhysics(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Draws the effects' values at every reset (or on their schedule) and writes them into the
    env's MuJoCo model; reports them in ``info["sim2real"]``.

    ``info["sim2real"]`` holds ``params`` (address -> value in use), ``events`` (pushes so far, as
    :class:`randomizers.effects.PushEvent` tuples), ``episode``, ``diverged`` and ``reapplied``; every
    call returns fresh dicts, so stored infos stay true.

    Draws are written before the inner reset (so the task's reset runs on the randomised model) and
    checked after it: a task whose own reset writes a randomised field (dm-control ``finger`` resets its
    hinge damping) gets the draws written again, the addresses listed in ``reapplied``. The state the
    task chose is kept; ``mj_forward`` recomputes what derives from it, and the reset observation is
    recomputed where that is faithful (dm-control suite tasks and gymnasium MuJoCo envs under
    pass-through wrappers); elsewhere it is the task's own, which differs only in force- or
    acceleration-derived sensors. What is reported is always what the model holds.
    A diverged simulation ends the episode with ``truncated=True``, ``diverged=True`` and the last
    finite observation. A reset that diverges (e.g. a task that settles its physics under
    ``Stiffness(set=1e9)``) returns ``diverged=True`` with the draws that caused it in ``params`` and
    the observation of the state MuJoCo fell back to; the next step ends the episode (``truncated=True``)
    without stepping.

    Args:
        env: a gymnasium env with MuJoCo inside (see :func:`sim2real.find_physics`).
        effects: physics effects from :mod:`randomizers`.
        seed: root seed of the effect streams; ``reset(seed=s)`` re-roots them at ``(seed, s)``.
    """

    def __init__(self, env: gym.Env, effects: Sequence[Effect], seed: SeedLike = None) -> None:
        # Recorded so a spec'd env can be recreated (``env.spec.make()``, gymnasium's checker). Effects are immutable
        # values: gymnasium's deep copy of them (~35 us of a batched world's wrap) is skipped when nothing in them or
        # in the seed could change.
        effects = tuple(effects)
        gym.utils.RecordConstructorArgs.__init__(
            self, effects=effects, seed=seed, _disable_deepcopy=_immutable(effects) and _immutable(seed)
        )
        super().__init__(env)
        self.randomizer = PhysicsRandomizer(effects, seed)
        self._handle = require_physics(env, self.randomizer.effects)
        self._hook = self._handle.attach(self.randomizer)
        self._step_effects = self.randomizer.has_step_effects
        # dm-control raises on divergence and the adapter reports it in info; only plain MuJoCo
        # envs need the warning counters read every step.
        self._read_warnings = self._handle.source == "gymnasium"
        self._diverged = False
        self._reapplied: tuple[str, ...] = ()
        self._reset_diverged = False
        self._last_obs: Any = None
        self._closed = False

    @property
    def current_params(self) -> dict[str, float]:
        """Address -> value in use this episode."""
        return self.randomizer.current_params

    def _info(self) -> dict[str, Any]:
        # Fresh dicts on every call: users keep infos, and gymnasium's checker rejects shared objects.
        r = self.randomizer
        return {
            "params": r.current_params.copy(),
            "events": r.events,
            "episode": r.episode,
            "diverged": self._diverged,
            "reapplied": self._reapplied,
        }

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        self.randomizer.begin_episode(seed)
        if self._hook is None:
            self.randomizer.apply()
        obs, info = self.env.reset(seed=seed, options=options)
        # The env's own reset may have written a randomised field (dm-control finger resets its hinge damping) or
        # compiled a new model: the draws go (again) into the model it holds, the state it chose is kept.
        self._reapplied, moved = settle_draws(self._handle, self.randomizer)
        if moved:
            fresh = observe_again(self.env)
            if fresh is not None:
                obs = fresh
        self._last_obs = obs
        # A reset that diverges (a task settling its physics under an extreme draw) is flagged, not raised:
        # the report names the draws, and the next step ends the episode with truncated=True.
        self._diverged = self._reset_diverged = bool(info.pop("diverged", False)) or (
            self._read_warnings and self._handle.diverged()
        )
        merge_report(info, self._info())
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        if self._reset_diverged:  # nothing to step: the reset diverged
            return self._last_obs, 0.0, False, True, {"sim2real": self._info()}
        if self._step_effects:
            self.randomizer.step()
        obs, reward, terminated, truncated, info = self.env.step(action)
        obs, truncated, _ = self._settle_step(obs, truncated, info)
        if "sim2real" in info:
            merge_report(info, self._info())
        else:
            info["sim2real"] = self._info()
        return obs, reward, terminated, truncated, info

    def _settle_step(self, obs: Any, truncated: bool, info: dict[str, Any]) -> tuple[Any, bool, bool]:
        """The inner step's divergence (the adapters say it in ``info``, MjcfEnv says False; plain MuJoCo envs are
        read from the warning counters): ``(obs, truncated, diverged)``, on divergence the last good observation
        and ``truncated=True``. Every physics layer's step settles its divergence here."""
        diverged = bool(info.get("diverged", False)) or (self._read_warnings and self._handle.diverged())
        if diverged:
            obs, truncated, self._diverged = self._last_obs, True, True
        self._last_obs = obs
        return obs, truncated, diverged

    def restore_nominal(self) -> None:
        """Writes every touched model field back to its nominal value (bitwise)."""
        self.randomizer.restore_nominal()

    def release(self) -> gym.Env:
        """Detaches from the wrapped env and returns it, still open, for reuse: the nominal model is
        restored bitwise and the recompile hook removed. The wrapper is closed afterwards."""
        if not self._closed:
            self._closed = True
            self._handle.detach(self.randomizer, self._hook)
        return self.env

    def close(self) -> None:
        self.release()
        super().close()
