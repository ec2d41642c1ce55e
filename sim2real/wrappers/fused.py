"""One wrapper layer for physics randomisation and signal models together: :class:`RandomizeAndCorrupt`
(gymnasium) and :class:`RandomizeAndCorruptDmEnv` (dm_env).

:func:`sim2real.wrap` returns these when it is given both physics effects and signal models. Each behaves exactly
as the two layers it replaces, :class:`~sim2real.wrappers.CorruptSignals` around
:class:`~sim2real.wrappers.RandomizePhysics` (and the ``*DmEnv`` twins): the same draws from the same keyed
streams, observations, rewards, reset semantics and ``info["sim2real"]`` (tested bitwise against the two layers),
with one Python layer on the step path instead of two and the episode's merged report built once per episode
instead of copied and merged on every step. Stack :func:`sim2real.wrap` twice (physics, then signals) to get the
two layers.

Example:
    >>> import sim2real
    >>> from noise_models import Gaussian, ObservationLatency, ObservationNoise
    >>> from randomizers import Damping, Uniform
    >>> env = sim2real.wrap(sim2real.make("dmc/reacher-easy"), Damping(scale=Uniform(0.5, 2.0)),
    ...                     ObservationNoise(Gaussian(std=0.01)), ObservationLatency(steps=2), seed=0)
    >>> type(env).__name__
    'RandomizeAndCorrupt'
    >>> obs, info = env.reset(seed=0)
    >>> sorted(info["sim2real"]["params"])[:3]
    ['dof_damping[shoulder]', 'dof_damping[wrist]', 'obs_latency']
    >>> env.close()  # restores the nominal model bitwise
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import dm_env
import gymnasium as gym
import numpy as np

from noise_models import SignalModel, compiled
from noise_models.timing import elapsed_steps
from randomizers import Effect, PhysicsRandomizer
from randomizers.seeding import SeedLike
from sim2real.wrappers.dm import PhysicsDmSteps
from sim2real.wrappers.gym import merge_report, observe_again, require_physics, settle_draws
from sim2real.wrappers.signals import CorruptSignals, CorruptSignalsDmEnv, wrong_action_shape

try:  # the compiled hot step (optional, see noise_models.compiled)
    from sim2real.wrappers._hotstep import HotStep
except ImportError:  # pragma: no cover - built without a C compiler
    HotStep = None  # type: ignore[assignment,misc]

__all__ = ["RandomizeAndCorrupt", "RandomizeAndCorruptDmEnv"]


class RandomizeAndCorrupt(CorruptSignals):
    """Physics effects drawn at every reset (or on their schedule) and written into the env's MuJoCo model, and
    noise and timing models on its observations and actions, in one gymnasium wrapper.

    Everything :class:`~sim2real.wrappers.RandomizePhysics` and :class:`~sim2real.wrappers.CorruptSignals` say
    holds here: ``info["sim2real"]`` holds ``params`` (physics addresses, then the signal models' names),
    ``events``, ``episode`` (the physics episode), ``diverged``, ``reapplied`` and, with ControlJitter or
    ActionLatency, ``substeps`` / ``action_latency_path``; a reset or step that diverges is flagged and ends the
    episode as there. ``env`` is the wrapped env itself (:meth:`release` hands it back with the nominal model
    restored).

    Args:
        env: a gymnasium env with MuJoCo inside (see :func:`sim2real.find_physics`) and Box (or Dict of Box)
            observations and a Box action space.
        effects: physics effects from :mod:`randomizers`.
        models: ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold, ControlJitter.
        seed: root seed of every stream; ``reset(seed=s)`` re-roots them at ``(seed, s)``.
    """

    def __init__(
        self, env: gym.Env, effects: Sequence[Effect], models: Sequence[SignalModel], seed: SeedLike = None
    ) -> None:
        # Recorded first (the first record wins): a spec'd env is recreated with both lists.
        gym.utils.RecordConstructorArgs.__init__(self, effects=tuple(effects), models=tuple(models), seed=seed)
        # The physics layer's set-up comes first, as when RandomizePhysics is built inside CorruptSignals.
        self.randomizer = PhysicsRandomizer(effects, seed)
        self._handle = require_physics(env, self.randomizer.effects)
        self._hook = self._handle.attach(self.randomizer)
        self._step_effects = self.randomizer.has_step_effects
        self._read_warnings = self._handle.source == "gymnasium"
        self._diverged = False
        self._reapplied: tuple[str, ...] = ()
        self._reset_diverged = False
        self._last_obs: Any = None  # the env's own (clean) last observation
        self._physics_closed = False
        self._merged: dict[str, Any] = {}
        self._merged_from: tuple[Any, Any] = (None, None)
        self._template: dict[str, Any] | None = None  # the step report but its params, built once per episode
        super().__init__(env, models, seed)
        # Steps whose report is the episode's template plus the params (no inner report, per-step substeps or
        # events): the common case, and the hot path.
        self._templated = not (self._jitter or self._step_effects)
        # This episode's hot step (decided at reset, see _make_hot_step), or None: the general path.
        self._hot_step: Callable[[Any], tuple[Any, Any, bool, bool, dict[str, Any]]] | None = None
        # This episode's action ring when the wrapper delays the actions itself (SignalClock.ring_actions).
        self._action_ring: list[Any] | None = None
        self._actions_sent = 0

    @property
    def current_params(self) -> dict[str, float]:
        """Address or name -> value in use this episode: the physics draws, then the signal models' (a new dict)."""
        return dict(self._params())

    @property
    def physics_params(self) -> dict[str, float]:
        """Address -> physics value in use this episode (what ``RandomizePhysics.current_params`` gives)."""
        return self.randomizer.current_params

    @property
    def signal_params(self) -> dict[str, float]:
        """Name -> signal model value drawn for this episode (what ``CorruptSignals.current_params`` gives)."""
        return self.corruptor.current_params

    @property
    def reapplied(self) -> tuple[str, ...]:
        """Addresses whose draws the task's own reset overwrote and that were written again (this episode)."""
        return self._reapplied

    def _params(self) -> dict[str, Any]:
        # Merged once per pair of dicts: both are replaced (never mutated) when their values change.
        phys, signals = self.randomizer.current_params, self.corruptor.current_params
        if self._merged_from[0] is not phys or self._merged_from[1] is not signals:
            merged = phys.copy()
            merged.update(signals)
            self._merged = merged
            self._merged_from = (phys, signals)
        return self._merged

    def _physics_report(self) -> dict[str, Any]:
        r = self.randomizer
        return {
            "params": r.current_params.copy(),
            "events": r.events,
            "episode": r.episode,
            "diverged": self._diverged,
            "reapplied": self._reapplied,
        }

    def _full_report(self, info: dict[str, Any]) -> None:
        """``info["sim2real"]`` as the two layers leave it; fresh dicts on every call (users keep infos)."""
        if "sim2real" in info:  # a report of an inner wrapper: merged as the two layers merge it
            merge_report(info, self._physics_report())
            self._report(info)
            return
        r = self.randomizer
        report = {
            "params": self._params().copy(),
            "events": r.events,
            "episode": r.episode,
            "diverged": self._diverged,
            "reapplied": self._reapplied,
        }
        if self._jitter:
            report["substeps"] = self.clock._target
        if self.clock.action_path is not None:
            report["action_latency_path"] = self.clock.action_path
        info["sim2real"] = report

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        c = self.corruptor
        self.clock._in_step = False  # in case the last step raised
        c.begin_episode(seed)
        randomizer = self.randomizer
        randomizer.begin_episode(seed)
        if self._hook is None:
            randomizer.apply()
        obs, info = self.env.reset(seed=seed, options=options)
        # As RandomizePhysics: the draws go (again) into the model the env holds, the state it chose kept.
        self._reapplied, moved = settle_draws(self._handle, randomizer)
        if moved:
            fresh = observe_again(self.env)
            if fresh is not None:
                obs = fresh
        self._last_obs = obs
        self._diverged = self._reset_diverged = bool(info.pop("diverged", False)) or (
            self._read_warnings and self._handle.diverged()
        )
        self.clock.begin_episode()
        self._action_ring = self.clock.ring_actions(self.env)
        self._actions_sent = 0
        if self._action_ring is not None:
            # A suite env steps its physics through the hook's owner (the first-step check has nothing to find).
            self.__dict__.pop("step", None)
        self._needs_now = c.episode_reads_time
        if self._has_obs:
            obs = self._obs_out(c.first_observation(self._obs_in(obs)), obs)
        self._full_report(info)
        self._template = None
        self._hot = False
        if self._templated and not self._reset_diverged:
            self._template = self._report_template()
            if (
                self._has_action
                and self._has_obs
                and self._act_codec is None
                and self._obs_codec is None
                and not self._needs_now
            ):
                self._hot_step = self._make_hot_step()
                if "step" not in self.__dict__:  # (the first-step check, while pending, runs the class's step)
                    self.step = self._hot_step  # type: ignore[method-assign,assignment]  # env.step calls it
        return obs, info

    def __copy__(self) -> Any:
        twin = super().__copy__()
        if self._hot_step is not None:  # the hot step is bound to this wrapper: the copy takes the general path
            if twin.__dict__.get("step") is self._hot_step:
                del twin.__dict__["step"]
            twin.__dict__["_hot_step"] = None
        return twin

    @property
    def _hot(self) -> bool:
        """Whether this episode steps through its hot step; set False to leave it (the general path then)."""
        return self._hot_step is not None

    @_hot.setter
    def _hot(self, value: bool) -> None:
        if value:
            raise ValueError("`_hot` can only be turned off; reset decides when an episode has a hot step.")
        if self._hot_step is not None and self.__dict__.get("step") is self._hot_step:
            del self.step
        self._hot_step = None

    def _make_hot_step(self) -> Callable[[Any], tuple[Any, Any, bool, bool, dict[str, Any]]]:
        """This episode's step for the common case (decided at reset): a flat Box action and observation, the
        corruptor's per-episode hot paths (act, observe), no clock read, the report from the episode's template.
        What the general path does, with the episode's constants bound once (tests/test_hot_path.py pins it);
        installed as the instance's ``step`` so that ``env.step`` calls it directly. A physics step that diverges
        leaves it (``_step_end``)."""
        clock, env, ring = self.clock, self.env, self._action_ring
        act, observe = self.corruptor.hot_act, self.corruptor.hot_observe
        template, shape, dtype = self._template, self._act_shape, self.corruptor.action_dtype
        randomizer, corruptor, step_end = self.randomizer, self.corruptor, self._step_end
        diverged = self._handle.diverged if self._read_warnings else None
        size = len(ring) if ring is not None else 0
        ndarray, asarray = np.ndarray, np.asarray
        assert template is not None
        # The episode's draws: both dicts are replaced, never mutated, when a value changes (a call to the
        # randomizer's apply/restore_nominal mid-episode), so two identity checks tell when to merge again.
        phys, signals, merged = randomizer.current_params, corruptor.current_params, self._params()
        if HotStep is not None and compiled.enabled():  # the step below, compiled (sim2real/wrappers/_hotstep.c)
            return HotStep(
                self,
                clock,
                env.step,
                ring,
                act,
                observe,
                template,
                shape,
                dtype,
                randomizer,
                corruptor,
                phys,
                signals,
                merged,
                step_end,
                diverged,
                asarray,
                wrong_action_shape,
            )

        def step(action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
            if type(action) is not ndarray:
                action = asarray(action, dtype=dtype)
            if action.shape != shape:
                raise ValueError(wrong_action_shape(action.shape, shape))
            sent = act(action)
            # (clock._control only counts for envs without MuJoCo: this layer always has it.)
            if ring is None:
                clock._passed = 0
                clock._in_step = True
                obs, reward, terminated, truncated, info = env.step(sent)
                clock._in_step = False
            else:  # the episode's whole-step latency, delayed here (see SignalClock.ring_actions)
                k = self._actions_sent
                self._actions_sent = k + 1
                ring[k % size] = sent.copy() if sent is action else sent  # the caller may reuse its buffer
                obs, reward, terminated, truncated, info = env.step(ring[(k + 1) % size])
            if (info and ("diverged" in info or "sim2real" in info)) or (diverged is not None and diverged()):
                return step_end(obs, reward, terminated, truncated, info, True)
            self._last_obs = obs
            report = template.copy()
            if randomizer.current_params is phys and corruptor.current_params is signals:
                report["params"] = merged.copy()
            else:
                report["params"] = self._params().copy()
            info["sim2real"] = report
            return observe(obs, 0), reward, terminated, truncated, info

        return step

    def _report_template(self) -> dict[str, Any]:
        """The step report of this episode with ``params`` still to fill (valid until the next reset or
        divergence; only used without per-step substeps or events, see ``_templated``)."""
        r = self.randomizer
        template: dict[str, Any] = {
            "params": None,
            "events": r.events,
            "episode": r.episode,
            "diverged": self._diverged,
            "reapplied": self._reapplied,
        }
        if self.clock.action_path is not None:
            template["action_latency_path"] = self.clock.action_path
        return template

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        hot = self._hot_step
        if hot is not None:  # (installed as the instance's step unless the first-step check is pending)
            return hot(action)
        clock = self.clock
        c = self.corruptor
        given = action
        if self._has_action:
            if type(action) is not np.ndarray:
                action = np.asarray(action, dtype=c.action_dtype)
            if action.shape != self._act_shape:
                raise ValueError(wrong_action_shape(action.shape, self._act_shape))
            codec = self._act_codec
            action = c.hot_act(action) if codec is None else c.hot_act(action.reshape(-1)).reshape(codec)
        clock._passed = 0  # (clock._control counts only for envs without MuJoCo: this layer always has it)
        if self._reset_diverged:  # nothing to step: the reset diverged
            return self._step_end(self._last_obs, 0.0, False, True, {}, False)
        if self._step_effects:
            self.randomizer.step()
        ring = self._action_ring
        if ring is not None:  # the episode's whole-step latency, delayed here (see SignalClock.ring_actions)
            k = self._actions_sent
            self._actions_sent = k + 1
            size = len(ring)
            # A copy where the action is (a view of) the caller's, which the caller may write again.
            ring[k % size] = np.array(action) if np.may_share_memory(action, given) else action
            obs, reward, terminated, truncated, info = self.env.step(ring[(k + 1) % size])
            return self._step_end(obs, reward, terminated, truncated, info, True)
        clock._in_step = True
        obs, reward, terminated, truncated, info = self.env.step(action)
        clock._in_step = False
        return self._step_end(obs, reward, terminated, truncated, info, True)

    def _step_end(
        self, obs: Any, reward: Any, terminated: bool, truncated: bool, info: dict[str, Any], stepped: bool
    ) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        """The rest of a step after the env's own (``stepped`` False: the reset diverged, nothing was stepped):
        divergence, the observation models, the report."""
        c = self.corruptor
        clock = self.clock
        if stepped:
            if info.get("diverged", False) or (self._read_warnings and self._handle.diverged()):
                obs, truncated, self._diverged = self._last_obs, True, True
                self._template = None
                self._hot = False
            self._last_obs = obs
        if self._has_obs:
            now = 0
            if self._needs_now:
                handle = clock.handle
                now = clock._control if handle is None else elapsed_steps(clock._t0, handle.data.time, clock.physics_dt)
            if self._obs_codec is None:
                obs = c.hot_observe(obs, now)
            else:
                obs = self._obs_out(c.hot_observe(self._obs_in(obs), now), obs)
        if "sim2real" in info or not self._templated:
            self._full_report(info)
            return obs, reward, terminated, truncated, info
        # _full_report's common case: the episode's template, fresh dicts every step.
        template = self._template
        if template is None:
            template = self._template = self._report_template()
        report = template.copy()
        report["params"] = self._params().copy()
        info["sim2real"] = report
        return obs, reward, terminated, truncated, info

    def restore_nominal(self) -> None:
        """Writes every touched model field back to its nominal value (bitwise)."""
        self.randomizer.restore_nominal()

    def release(self) -> gym.Env:
        """Detaches from the wrapped env and returns it, still open, for reuse: physics stepping is no longer
        intercepted, the nominal model is restored bitwise and the recompile hook removed."""
        env = super().release()  # the signal clock first, as the outer of the two layers lets go first
        if not self._physics_closed:
            self._physics_closed = True
            self._handle.detach(self.randomizer, self._hook)
        return env


class RandomizeAndCorruptDmEnv(PhysicsDmSteps, CorruptSignalsDmEnv):
    """:class:`RandomizeAndCorrupt` for dm_env environments (dm-control suite and composer): one layer doing what
    :class:`~sim2real.wrappers.CorruptSignalsDmEnv` around :class:`~sim2real.wrappers.RandomizePhysicsDmEnv`
    does. The draws are on :attr:`current_params` (physics, then signals), ``diverged`` and ``reapplied`` as on
    ``RandomizePhysicsDmEnv``.

    Args:
        env: a dm-control suite or composer environment.
        effects: physics effects from :mod:`randomizers`.
        models: ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold, ControlJitter.
        seed: root seed of every stream (dm_env has no per-reset seed).

    Example:
        >>> from dm_control import suite
        >>> from noise_models import Gaussian, ObservationNoise
        >>> from randomizers import Damping, Uniform
        >>> env = RandomizeAndCorruptDmEnv(suite.load("reacher", "easy"), [Damping(scale=Uniform(0.5, 2.0))],
        ...                                [ObservationNoise(Gaussian(std=0.01), select="velocity")], seed=0)
        >>> timestep = env.reset()
        >>> sorted(env.current_params)[:3]
        ['dof_damping[shoulder]', 'dof_damping[wrist]', 'obs_noise_std[velocity]']
        >>> env.close()
    """

    def __init__(
        self, env: dm_env.Environment, effects: Sequence[Effect], models: Sequence[SignalModel], seed: SeedLike = None
    ) -> None:
        if not isinstance(env, dm_env.Environment):
            raise TypeError(f"`env` must be a dm_env.Environment. Received {type(env).__name__}.")
        self.randomizer = PhysicsRandomizer(effects, seed)
        self._handle = require_physics(env, self.randomizer.effects)
        self._hook = self._handle.attach(self.randomizer)
        self._step_effects = self.randomizer.has_step_effects
        self._last_obs: Any = None
        self._physics_reset_next = True  # RandomizePhysicsDmEnv's own flag
        self.diverged = False
        self.reapplied: tuple[str, ...] = ()
        self._physics_closed = False
        super().__init__(env, models, seed)

    @property
    def current_params(self) -> dict[str, float]:
        """Address or name -> value in use this episode: the physics draws, then the signal models'."""
        merged = dict(self.randomizer.current_params)
        merged.update(self.corruptor.current_params)
        return merged

    def _inner_reset(self) -> dm_env.TimeStep:
        return self._physics_reset()

    def _inner_step(self, action: Any) -> dm_env.TimeStep:
        return self._physics_step(action)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.clock.close()
        if not self._physics_closed:
            self._physics_closed = True
            self._handle.detach(self.randomizer, self._hook)
        self._env.close()
