"""ADR on every env API: the physics wrappers with an :class:`~randomizers.ADR` controller behind them.

Each wrapper is its API's physics wrapper (same reports, divergence handling and restore) whose randomizer is a
:class:`randomizers.adr_randomizer.ADRRandomizer`; on top it sums the episode's reward and, when the episode
ends (terminated, truncated, diverged, or ``last()`` on dm_env), hands the finished :class:`~randomizers.Episode`
to the controller. An episode cut short by a ``reset()`` before it ended is not reported. Many wrappers may share
one controller in a process (``sim2real.make_vec``): results reach it in the order the episodes end. The batched
engine resets its worlds through these wrappers but steps below them, so it sums and reports the episodes itself
(:mod:`sim2real.batched.adr`).

Example:
    >>> import sim2real
    >>> from randomizers import ADR, Damping, Uniform
    >>> adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, t_low=-1e9, t_high=-1e8, m=1, p_boundary=1.0)
    >>> env = sim2real.wrap(sim2real.make("dmc/reacher-easy"), adr=adr, seed=0)
    >>> obs, info = env.reset(seed=0)
    >>> info["sim2real"]["adr"]["pin"]
    ('Damping[joints=*]', 'low', 1.0)
    >>> done = False
    >>> while not done:
    ...     obs, reward, terminated, truncated, info = env.step(env.action_space.sample() * 0)
    ...     done = terminated or truncated
    >>> adr.ranges["Damping[joints=*]"]  # a return >= t_high widened the pinned boundary
    (0.5, 1.0)
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import dm_env
import gymnasium as gym

from randomizers import ADR, Effect, Episode
from randomizers.adr_randomizer import ADRRandomizer
from randomizers.seeding import SeedLike
from sim2real.wrappers.dm import RandomizePhysicsDmEnv
from sim2real.wrappers.gym import RandomizePhysics

__all__ = ["AutoRandomizePhysics", "AutoRandomizePhysicsDmEnv", "adr_report", "make_adr_transform"]


def adr_report(randomizer: ADRRandomizer) -> dict[str, Any]:
    """What ``info["sim2real"]["adr"]`` holds: this episode's pin ``(key, side, value)`` or None."""
    pin = randomizer.pin
    return {"pin": None if pin is None else (pin.key, pin.side, pin.value)}


def _success(info: dict[str, Any]) -> bool | None:
    for key in ("success", "is_success"):
        if key in info:
            return bool(info[key])
    return None


class AutoRandomizePhysics(RandomizePhysics):
    """gymnasium: :class:`~sim2real.wrappers.RandomizePhysics` with ADR effects drawn from ``adr``'s ranges.

    ``info["sim2real"]["adr"]`` (at reset and on the step that ends the episode) holds the episode's pin; the
    pinned value is in ``params`` like every draw. Success is read from ``info["success"]`` or
    ``info["is_success"]`` on the last step when the task sets one.

    Args:
        env: a gymnasium env with MuJoCo inside.
        effects: physics effects outside ADR.
        adr: the controller (shared freely between wrappers of one process).
        seed: root seed of every stream, the boundary choice included.
    """

    def __init__(self, env: gym.Env, effects: Sequence[Effect], adr: ADR, seed: SeedLike = None) -> None:
        # The controller is recorded by reference: it is shared on purpose, and gymnasium's default deep copy of it
        # cost ~1.7 ms per env (20 of them per batched training run). Effects are immutable values.
        gym.utils.RecordConstructorArgs.__init__(
            self, effects=tuple(effects), adr=adr, seed=copy.deepcopy(seed), _disable_deepcopy=True
        )
        super().__init__(env, (), seed)
        randomizer = ADRRandomizer(effects, adr, seed)
        self._handle.detach(self.randomizer, self._hook)
        self.randomizer = randomizer
        self._hook = self._handle.attach(randomizer)
        self._step_effects = randomizer.has_step_effects
        self.adr = adr
        self._return = 0.0
        self._length = 0
        self._running = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = super().reset(seed=seed, options=options)
        self._return, self._length, self._running = 0.0, 0, True
        info["sim2real"]["adr"] = adr_report(self.randomizer)  # type: ignore[arg-type]
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        self._return += float(reward)
        self._length += 1
        if (terminated or truncated) and self._running:
            self._running = False
            randomizer: ADRRandomizer = self.randomizer  # type: ignore[assignment]
            randomizer.end_episode(Episode(self._return, self._length, _success(info)))
            info["sim2real"]["adr"] = adr_report(randomizer)
        return obs, reward, terminated, truncated, info


class AutoRandomizePhysicsDmEnv(RandomizePhysicsDmEnv):
    """dm_env: :class:`~sim2real.wrappers.RandomizePhysicsDmEnv` with ADR; the episode ends at ``last()``.

    dm_env has no info dict: the pin is on ``pin`` (and its value in ``current_params``).

    Args:
        env: a dm-control suite or composer environment.
        effects: physics effects outside ADR.
        adr: the controller.
        seed: root seed of every stream.
    """

    def __init__(self, env: dm_env.Environment, effects: Sequence[Effect], adr: ADR, seed: SeedLike = None) -> None:
        super().__init__(env, (), seed)
        randomizer = ADRRandomizer(effects, adr, seed)
        self._handle.detach(self.randomizer, self._hook)
        self.randomizer = randomizer
        self._hook = self._handle.attach(randomizer)
        self._step_effects = randomizer.has_step_effects
        self.adr = adr
        self._return = 0.0
        self._length = 0
        self._running = False

    @property
    def pin(self) -> Any:
        """This episode's :class:`~randomizers.adr.Pin` or None."""
        return self.randomizer.pin  # type: ignore[attr-defined]

    def reset(self) -> dm_env.TimeStep:
        timestep = super().reset()
        self._return, self._length, self._running = 0.0, 0, True
        return timestep

    def step(self, action: Any) -> dm_env.TimeStep:
        timestep = super().step(action)
        if timestep.first():  # the step was an automatic reset
            return timestep
        self._return += float(timestep.reward or 0.0)
        self._length += 1
        if timestep.last() and self._running:
            self._running = False
            self.randomizer.end_episode(Episode(self._return, self._length))  # type: ignore[attr-defined]
        return timestep


def make_adr_transform(effects: Sequence[Effect], adr: ADR, seed: SeedLike = None) -> Any:
    """TorchRL: a :class:`~sim2real.wrappers.RandomizePhysicsTransform` with ADR (imports torch lazily)."""
    from sim2real.wrappers.adr_torchrl import AutoRandomizePhysicsTransform

    return AutoRandomizePhysicsTransform(effects, adr, seed)
