"""dm_env wrapper that randomises physics: :class:`RandomizePhysicsDmEnv`.

dm_env timesteps carry no info dict, so the draws are on ``current_params`` (and ``diverged``).

Example:
    >>> from dm_control import suite
    >>> from randomizers import Damping, Uniform
    >>> env = RandomizePhysicsDmEnv(suite.load("reacher", "easy"), [Damping(scale=Uniform(0.5, 2.0))], seed=0)
    >>> timestep = env.reset()
    >>> sorted(env.current_params)
    ['dof_damping[shoulder]', 'dof_damping[wrist]']
    >>> env.close()
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import dm_env

from randomizers import Effect, PhysicsRandomizer
from randomizers.seeding import SeedLike
from sim2real.wrappers.gym import require_physics, settle_draws

__all__ = ["RandomizePhysicsDmEnv"]


class DmEnvWrapper(dm_env.Environment):
    """Base of sim2real's dm_env wrappers: the wrapped env is ``self._env``; specs and any attribute the
    wrapper does not define (``task``, ``control_timestep``, ``physics``...) come from it."""

    _env: dm_env.Environment

    def observation_spec(self) -> Any:
        return self._env.observation_spec()

    def action_spec(self) -> Any:
        return self._env.action_spec()

    def reward_spec(self) -> Any:
        return self._env.reward_spec()

    def discount_spec(self) -> Any:
        return self._env.discount_spec()

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name == "_env":
            raise AttributeError(name)
        return getattr(self._env, name)


class PhysicsDmSteps:
    """The reset and step of a dm_env layer that randomises physics, shared by :class:`RandomizePhysicsDmEnv` and
    the fused :class:`~sim2real.wrappers.fused.RandomizeAndCorruptDmEnv` (one owner of the divergence and
    re-application rules). The class using it sets the attributes below."""

    _env: dm_env.Environment
    randomizer: PhysicsRandomizer
    _handle: Any
    _hook: Any
    _step_effects: bool
    _last_obs: Any
    _physics_reset_next: bool
    diverged: bool
    reapplied: tuple[str, ...]

    @property
    def physics(self) -> Any:
        return self._env.physics

    def restore_nominal(self) -> None:
        """Writes every touched model field back to its nominal value (bitwise)."""
        self.randomizer.restore_nominal()

    def _physics_reset(self) -> dm_env.TimeStep:
        """Draws the episode's effects and resets the wrapped env (see :class:`RandomizePhysicsDmEnv`)."""
        self.randomizer.begin_episode()
        if self._hook is None:
            self.randomizer.apply()
        from dm_control.rl.control import PhysicsError

        try:
            timestep = self._env.reset()
        except PhysicsError:
            # Flagged, not raised (the draws are on current_params); the next step is a truncation.
            from sim2real.adapters import suite_observation

            try:
                observation = suite_observation(self._env)
            except Exception:  # a diverged physics may fail anywhere; the fallback covers it
                observation = None
            self._last_obs = observation
            self._physics_reset_next = False
            self.diverged = True
            return dm_env.restart(observation)
        # The task's reset may overwrite a draw (finger's hinge damping): write it again, keep the state the
        # task chose, recompute what derives from it (and the observation, for suite tasks).
        self.reapplied, moved = settle_draws(self._handle, self.randomizer)
        if moved:
            from sim2real.adapters import suite_observation

            observation = suite_observation(self._env)
            if observation is not None:
                timestep = timestep._replace(observation=observation)
        self._last_obs = timestep.observation
        self._physics_reset_next = False
        self.diverged = False
        return timestep

    def _physics_step(self, action: Any) -> dm_env.TimeStep:
        """Steps the wrapped env, ending the episode with a truncation on a divergence."""
        from dm_control.rl.control import PhysicsError

        if self._physics_reset_next:
            return self._physics_reset()
        if self.diverged:  # the reset diverged: end the episode without stepping
            self._physics_reset_next = True
            return dm_env.truncation(0.0, self._last_obs)
        if self._step_effects:
            self.randomizer.step()
        try:
            timestep = self._env.step(action)
            failed = self._handle.diverged()
        except PhysicsError:
            failed = True
        if failed:
            self.diverged = True
            self._physics_reset_next = True
            return dm_env.truncation(0.0, self._last_obs)
        self._last_obs = timestep.observation
        self._physics_reset_next = timestep.last()
        return timestep


class RandomizePhysicsDmEnv(PhysicsDmSteps, DmEnvWrapper):
    """Draws physics effects at each ``reset()`` of a dm-control environment.

    A physics divergence ends the episode with a truncation timestep (``discount=1``, reward 0,
    the last finite observation) and ``diverged = True``; a reset that diverges returns a first
    timestep (the observation of the state MuJoCo fell back to) with ``diverged = True``, and the next
    step is that truncation. Draws a task's own reset overwrote are
    written again after it (addresses in ``reapplied``), as :class:`~sim2real.wrappers.RandomizePhysics` does.

    Args:
        env: a dm-control suite or composer environment.
        effects: physics effects from :mod:`randomizers`.
        seed: root seed of the effect streams (dm_env has no per-reset seed).
    """

    def __init__(self, env: dm_env.Environment, effects: Sequence[Effect], seed: SeedLike = None) -> None:
        if not isinstance(env, dm_env.Environment):
            raise TypeError(f"`env` must be a dm_env.Environment. Received {type(env).__name__}.")
        self._env = env
        self.randomizer = PhysicsRandomizer(effects, seed)
        self._handle = require_physics(env, self.randomizer.effects)
        self._hook = self._handle.attach(self.randomizer)
        self._step_effects = self.randomizer.has_step_effects
        self._last_obs: Any = None
        self._physics_reset_next = True
        self.diverged = False
        self.reapplied: tuple[str, ...] = ()
        self._closed = False

    @property
    def current_params(self) -> dict[str, float]:
        """Address -> value in use this episode."""
        return self.randomizer.current_params

    def reset(self) -> dm_env.TimeStep:
        return self._physics_reset()

    def step(self, action: Any) -> dm_env.TimeStep:
        return self._physics_step(action)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._handle.detach(self.randomizer, self._hook)
        self._env.close()
