"""The engine that runs signal pipelines: :class:`SignalCorruptor` (the pipelines themselves,
:class:`ObservationNoise` and :class:`ActionNoise`, are values in :mod:`noise_models.pipelines`).

A pipeline applies its processes in order to one signal. Consecutive additive and multiplicative
processes (Gaussian, UniformNoise, Bias, Drift, Outlier, Scale) are fused into one affine map per
step whose noise is pre-drawn in blocks, so a typical pipeline costs one numpy add per step.

:class:`SignalCorruptor` is environment-agnostic: ``sim2real`` feeds it flat observation and action
vectors and the physics step count, and it returns what the policy sees and what the actuators get.

Example:
    >>> import numpy as np
    >>> from noise_models import Bias, Gaussian, ObservationLatency, ObservationNoise
    >>> from noise_models.values import Layout
    >>> c = SignalCorruptor([ObservationNoise(Gaussian(std=0.1), Bias(0.5)), ObservationLatency(steps=2)], seed=0)
    >>> c.bind(obs=Layout(3), action=None, timestep=0.01, substeps=1)
    >>> c.begin_episode()
    >>> c.current_params["obs_bias"], c.current_params["obs_latency_steps"]
    (0.5, 2)
    >>> first = c.first_observation(np.zeros(3))
    >>> later = [c.observe(np.full(3, 100.0 * t), now=t) for t in (1, 2, 3)]
    >>> [round(float(o.mean()) / 100) for o in later]   # steps 1 and 2 see the reset sample, step 3 sees step 1
    [0, 0, 1]
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from noise_models import compiled
from noise_models.fused import NoiseBlock, Pipeline, hot_pipe, next_blocks
from noise_models.pipelines import ActionNoise, ObservationNoise
from noise_models.processes import BLOCK
from noise_models.seeding import SeedLike, StreamFactory, normalize_seed, reseeded_root
from noise_models.timing import (
    ActionLatency,
    CommandDelay,
    ControlJitter,
    ObservationDelay,
    ObservationLatency,
    SampleAndHold,
    TimeModel,
    convert_time,
    sample_and_hold_updates,
)
from noise_models.values import Layout, draw, selection_repr

__all__ = ["ActionNoise", "NoiseBlock", "ObservationNoise", "SignalCorruptor", "SignalModel"]

SignalModel = ObservationNoise | ActionNoise | ObservationLatency | ActionLatency | SampleAndHold | ControlJitter
_MODEL_NAMES = "ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold, ControlJitter"


class SignalCorruptor:
    """Runs observation/action pipelines and timing models for one environment.

    Lifecycle: :meth:`bind` once (signal layouts and time base), :meth:`begin_episode` before each
    reset, then :meth:`first_observation` on the reset observation, and per control step
    :meth:`act`, :meth:`substeps` / :meth:`command_segments` (physics-rate action latency, from
    inside the env's physics step) and :meth:`observe`.

    Seeding follows ``randomizers``: every model has its own keyed stream (per-episode draws at
    resample 0, per-step noise blocks at resample 1, 2, ...), ``begin_episode(seed=s)`` re-roots at
    ``(seed, SEPARATOR, s)``.

    A process's stream is named by its own content, never by its position: ``<side>_<name>`` for a
    process on the whole signal (``obs_noise``), ``<side>_<name>[<selection>]`` otherwise
    (``obs_noise[velocity]``), so adding a model never shifts another's draws. Reports always use the
    plain ``<side>_<name>`` prefix (``obs_noise_std[3]``). Two processes with the same name and
    selection, or the same name on overlapping entries, are refused: pass ``name=`` to one of them.

    Args:
        models: ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold and
            ControlJitter instances (at most one of each timing model).
        seed: root seed (int, tuple of ints, or None for fresh entropy).

    Attributes:
        current_params: name -> value drawn for this episode (a new dict each episode).
        episode: index of the current episode since the last seeding (-1 before the first).
        hot_act: this episode's :meth:`act` without the shape check, for callers that checked it (set by
            :meth:`begin_episode`).
        hot_observe: this episode's :meth:`observe` (set by :meth:`first_observation`); both are specialised once
            per episode for the common cases and give what the general code gives, bitwise.
    """

    def __init__(self, models: Iterable[SignalModel], seed: SeedLike = None) -> None:
        models = tuple(models)
        self.obs_noise: list[ObservationNoise] = []
        self.action_noise: list[ActionNoise] = []
        self.timing: dict[type, TimeModel] = {}
        for i, m in enumerate(models):
            if isinstance(m, ObservationNoise):
                self.obs_noise.append(m)
            elif isinstance(m, ActionNoise):
                self.action_noise.append(m)
            elif isinstance(m, (ObservationLatency, ActionLatency, SampleAndHold, ControlJitter)):
                if type(m) in self.timing:
                    raise ValueError(
                        f"`models[{i}]` is a second {type(m).__name__}; give at most one of each timing model. "
                        f"Received {self.timing[type(m)]!r} and {m!r}."
                    )
                self.timing[type(m)] = m
            else:
                raise TypeError(
                    f"`models[{i}]` must be one of {_MODEL_NAMES}. Received {m!r} of type {type(m).__name__}."
                )
        self.models = models
        self._wrap_seed = normalize_seed(seed)
        self._streams = StreamFactory(self._wrap_seed)
        self._owners: dict[str, int] = {}
        self.obs_names = self._names("obs", self.obs_noise)
        self.action_names = self._names("action", self.action_noise)
        self._timing_gens = {cls: self._streams.generator(m.stream) for cls, m in self.timing.items()}
        self.episode = -1
        self.current_params: dict[str, float] = {}
        self._bound = False
        self.delays_actions = False

    def _names(self, side: str, pipelines: Sequence[ObservationNoise | ActionNoise]) -> list[list[str]]:
        # A process's stream is named by its own content: side, name and selection (``obs_noise``,
        # ``obs_noise[velocity]``), never by its position, so adding a model never shifts another's draws.
        # Its report keys keep the plain prefix (``obs_noise_std[3]``).
        out = []
        for pipe in pipelines:
            k = next(i for i, m in enumerate(self.models) if m is pipe)
            names = []
            for p in pipe.processes:
                select = p.select if p.select is not None else pipe.select
                base = f"{side}_{p.name}"
                name = base if select is None else f"{base}[{selection_repr(select)}]"
                if name in self._owners:
                    raise ValueError(
                        f"`models[{k}]` and `models[{self._owners[name]}]` would share the "
                        f"random stream {name!r} (same process name and selection); pass a distinct `name=` to "
                        f"one of the processes, e.g. {type(p).__name__}(..., name='{p.name}2')."
                    )
                self._owners[name] = k
                names.append(name)
            out.append(names)
        return out

    # -- properties ---------------------------------------------------------------------------
    @property
    def stream_names(self) -> tuple[str, ...]:
        """Stream name of every process and timing model (what :func:`noise_models.stream` needs)."""
        names = [n for group in (*self.obs_names, *self.action_names) for n in group]
        return (*names, *(m.stream for m in self.timing.values()))

    @property
    def root_seed(self) -> tuple[int, ...]:
        return self._streams.root

    @property
    def has_observation(self) -> bool:
        """Whether observations change (noise, latency or sample-and-hold)."""
        return bool(self.obs_noise) or ObservationLatency in self.timing or SampleAndHold in self.timing

    @property
    def has_action(self) -> bool:
        return bool(self.action_noise) or ActionLatency in self.timing

    @property
    def needs_physics_hook(self) -> bool:
        """Whether the env's physics stepping must be intercepted (physics-rate action latency, jitter)."""
        return self.physics_time and (
            (ActionLatency in self.timing and not self.delays_actions) or ControlJitter in self.timing
        )

    # -- binding ------------------------------------------------------------------------------
    def bind(
        self,
        *,
        obs: Layout | None,
        action: Layout | None,
        timestep: float | None,
        substeps: int = 1,
        physics: bool = True,
        obs_dtype: Any = np.float64,
        action_dtype: Any = np.float64,
        action_delay: str = "ctrl",
    ) -> None:
        """Resolves selections and the time base.

        Args:
            obs: layout of the flat observation (None if the env's observations are not a vector/dict).
            action: layout of the flat action.
            timestep: seconds per time step (the physics timestep with MuJoCo, else the control period).
            substeps: physics steps per control step (1 without MuJoCo).
            physics: whether time counts physics steps (MuJoCo found).
            action_delay: where ActionLatency acts with MuJoCo: ``"ctrl"`` delays the actuator command
                at physics rate (from inside the physics step); ``"action"`` delays the policy's action
                by whole control steps before the env sees it, for envs whose action does not map onto
                ``ctrl`` (mocap-driven hands). Without MuJoCo the action is always what is delayed.

        Raises:
            ValueError: a selection names unknown keys/indices, a latency is longer than its buffer, or
                a timing model needs a timestep or MuJoCo the environment does not have.
        """
        if (self.obs_noise or ObservationLatency in self.timing or SampleAndHold in self.timing) and obs is None:
            raise TypeError("observation models need a Box or Dict observation space of numbers.")
        if (self.action_noise or ActionLatency in self.timing) and action is None:
            raise TypeError("action models need a Box action space.")
        # An empty signal (an env without actuators, a Box of shape (0,)) has nothing to corrupt or delay: refused
        # rather than reported as applied (noise on it failed at the first reset with an IndexError).
        for kinds, layout, what in (
            ((ObservationNoise, ObservationLatency, SampleAndHold), obs, "observation"),
            ((ActionNoise, ActionLatency), action, "action"),
        ):
            names = sorted({type(m).__name__ for m in self.models if isinstance(m, kinds)})
            if names and layout is not None and layout.size == 0:
                raise ValueError(
                    f"{' and '.join(names)} need a non-empty {what}: this env's {what} has no entries, so nothing "
                    f"would be corrupted or delayed. Received an {what} of size 0."
                )
        if ControlJitter in self.timing and not physics:
            raise ValueError(
                "ControlJitter changes the number of physics substeps, so it needs an env with MuJoCo inside."
            )
        if action_delay not in ("ctrl", "action"):
            raise ValueError(f"`action_delay` must be one of ['ctrl', 'action']. Received {action_delay!r}.")
        self.physics_time = physics
        # Whether act() delays the action itself (control steps) rather than the env's ctrl (physics steps).
        self.delays_actions = ActionLatency in self.timing and (not physics or action_delay == "action")
        self.timestep = timestep
        self.nominal_substeps = int(substeps) if physics else 1
        self.obs_layout, self.action_layout = obs, action
        self._action_flat = (action.size,) if action is not None else None
        self.obs_dtype, self.action_dtype = np.dtype(obs_dtype), np.dtype(action_dtype)
        self._obs_pipes = [
            Pipeline(n, names, obs, self.obs_dtype, self)  # type: ignore[arg-type]
            for n, names in zip(self.obs_noise, self.obs_names, strict=True)
        ]
        self._action_pipes = [
            Pipeline(n, names, action, self.action_dtype, self)  # type: ignore[arg-type]
            for n, names in zip(self.action_noise, self.action_names, strict=True)
        ]
        self._check_reports()
        jitter = self.timing.get(ControlJitter)
        min_substeps = self.nominal_substeps
        if jitter is not None:
            lo = getattr(jitter.delta, "support", (jitter.delta, jitter.delta))[0]  # type: ignore[attr-defined]
            min_substeps = max(1, self.nominal_substeps + math.floor(float(lo) + 0.5))
        self._scales: dict[type, float] = {}
        self._capacity: dict[type, int] = {}
        for cls in (ObservationLatency, ActionLatency):
            model = self.timing.get(cls)
            if model is None:
                continue
            scale = model.step_scale(timestep)  # type: ignore[attr-defined]
            longest = model.check_capacity(scale)  # type: ignore[attr-defined]
            self._scales[cls] = scale
            self._capacity[cls] = longest // min_substeps + 3
        sah = self.timing.get(SampleAndHold)
        if sah is not None:
            self._scales[SampleAndHold] = sah.step_scale(timestep)  # type: ignore[attr-defined]
            self._sah_idx = obs.resolve(sah.select, "select")  # type: ignore[union-attr, attr-defined]
        self._obs_delay = (
            ObservationDelay(self._capacity[ObservationLatency]) if ObservationLatency in self.timing else None
        )
        self._cmd_delay: CommandDelay | None = None
        if ActionLatency in self.timing:
            assert action is not None  # ActionLatency without an action layout was refused above
            size = action.size if self.delays_actions else 0  # physics-level size is set by reset_commands
            self._cmd_delay = CommandDelay(self._capacity[ActionLatency], max(size, 1))
        self._bound = True

    def _check_reports(self) -> None:
        """Refuses two same-named processes on overlapping entries: their reports would share keys."""
        seen: dict[str, tuple[str, np.ndarray]] = {}
        for pipe in (*self._obs_pipes, *self._action_pipes):
            for name, idx in zip(pipe.names, pipe.indices, strict=True):
                prefix = name.partition("[")[0]
                if prefix in seen and np.intersect1d(seen[prefix][1], idx).size:
                    raise ValueError(
                        f"The processes of streams {seen[prefix][0]!r} and {name!r} act on overlapping entries, so "
                        f"both would report {prefix!r} for them; pass a distinct `name=` to one of the processes."
                    )
                seen[prefix] = (name, np.union1d(seen[prefix][1], idx) if prefix in seen else np.asarray(idx))

    # -- episodes -----------------------------------------------------------------------------
    def begin_episode(self, seed: SeedLike = None) -> None:
        """Draws this episode's values and clears every buffer and state."""
        if not self._bound:
            raise RuntimeError("SignalCorruptor.begin_episode() called before bind().")
        reset_seed = normalize_seed(seed, "seed")
        if reset_seed is not None:
            self._streams = StreamFactory(reseeded_root(self._wrap_seed, reset_seed))
            self._timing_gens = {cls: self._streams.generator(m.stream) for cls, m in self.timing.items()}
            for pipe in (*self._obs_pipes, *self._action_pipes):
                pipe.regenerate()
            self.episode = -1
        self.episode += 1
        report: dict[str, float] = {}
        for pipe in (*self._obs_pipes, *self._action_pipes):
            pipe.begin(self.episode, report)
        self._begin_timing(report)
        self.current_params = report
        self._sah = SampleAndHold in self.timing
        self._plain = not self.observation_needs_time
        self._obs_jitter = ObservationLatency in self._jitter_blocks
        self._act_jitter = ActionLatency in self._jitter_blocks
        # With a fixed latency and a fixed control period, samples arrive in order at fixed lags.
        n = self.nominal_substeps
        regular = ControlJitter not in self.timing
        self._obs_lag = (
            -(-self._obs_latency // n)
            if ObservationLatency in self.timing and regular and not self._obs_jitter
            else None
        )
        self.command_lag = (
            self._action_latency // n
            if ActionLatency in self.timing
            and regular
            and not self._act_jitter
            and self.physics_time
            and not self.delays_actions
            and self._action_latency % n == 0
            else None
        )
        self._control_step = 0
        self._substep_draws = 0
        self._last_obs_time = 0
        self._last_out: Any = None
        self.hot_act = self._hot_act()
        self.hot_observe: Callable[[np.ndarray, int], np.ndarray] = self._observe_any  # until first_observation

    def _pipes(self, side: str) -> list[Pipeline]:
        if side not in ("observation", "action"):
            raise ValueError(f"`side` must be one of ['observation', 'action']. Received {side!r}.")
        return self._obs_pipes if side == "observation" else self._action_pipes

    def noise_blocks(self, side: str) -> tuple[NoiseBlock, ...]:
        """Each ``side`` (``"observation"`` or ``"action"``) pipeline's :class:`NoiseBlock`, in order.

        Raises:
            ValueError: a pipeline that is not one affine stage (e.g. Quantize, Dropout; see NoiseBlock).
        """
        return tuple(pipe.noise_block() for pipe in self._pipes(side))

    def next_noise_block(self, side: str, k: int) -> NoiseBlock:
        """Draws the next block of the ``k``-th ``side`` pipeline from its own stream (as its step would when
        its block is spent) and returns it."""
        pipe = self._pipes(side)[k]
        pipe.refill(rows=False)  # the reader takes the offsets whole: no per-row views (half a refill's cost)
        block = pipe.noise_block()
        pipe.r = BLOCK  # the reader steps the block: this pipeline's own next step draws the block after it
        return block

    @staticmethod
    def next_noise_blocks(
        corruptors: Sequence[SignalCorruptor],
        side: str,
        k: int,
        out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`next_noise_block` of the ``k``-th ``side`` pipeline of many corruptors with the same models (the
        worlds of one batched engine), each from its own stream, composed at once: ``(offsets, gains, unit)``,
        ``(P, BLOCK, size)``, ``(P, size)`` and ``(P,)`` (True: no gain), bitwise those blocks' values
        (:func:`noise_models.fused.next_blocks`, into ``out`` when given)."""
        return next_blocks([c._pipes(side)[k] for c in corruptors], out)

    def pipeline_sizes(self, side: str) -> tuple[int, ...]:
        """Signal length of each ``side`` pipeline (after :meth:`bind`)."""
        return tuple(pipe.layout.size for pipe in self._pipes(side))

    @property
    def observation_lag(self) -> int | None:
        """This episode's observation latency in control steps when it is one fixed lag (None otherwise)."""
        return getattr(self, "_obs_lag", None)

    def _timing_rng(self, cls: type, resample: int) -> np.random.Generator:
        gen = self._timing_gens[cls]
        self._streams.start(gen, self.timing[cls].stream, self.episode, resample)
        return gen

    def _begin_timing(self, report: dict[str, float]) -> None:
        self._obs_latency = self._action_latency = 0
        self._jitter_blocks: dict[type, tuple[int, np.ndarray | None]] = {}
        for cls, prefix in ((ObservationLatency, "obs_latency"), (ActionLatency, "action_latency")):
            model = self.timing.get(cls)
            if model is None:
                continue
            steps = model.draw_steps(self._timing_rng(cls, 0), self._scales[cls])  # type: ignore[attr-defined]
            report[f"{prefix}_steps"] = steps
            if self.timestep is not None:
                unit = "physics_steps" if self.physics_time else "control_steps"
                report[prefix] = convert_time(steps, unit, "seconds", timestep=self.timestep)
            if cls is ObservationLatency:
                self._obs_latency = steps
            elif self.physics_time and self.delays_actions and self.timestep is not None:
                # The action reaches the env once per control step: whole control steps of the nominal
                # period, and the report says what is applied.
                n = self.nominal_substeps
                k = math.floor(steps / n + 0.5)
                self._action_latency = k
                report["action_latency_steps"] = k * n
                report["action_latency"] = convert_time(
                    k, "control_steps", "seconds", timestep=self.timestep, substeps=n
                )
                report["action_latency_control_steps"] = k
            else:
                self._action_latency = steps
            if model.jitter is not None:  # type: ignore[attr-defined]
                self._jitter_blocks[cls] = (-1, None)
        sah = self.timing.get(SampleAndHold)
        if sah is not None:
            rng = self._timing_rng(SampleAndHold, 0)
            scale = self._scales[SampleAndHold]
            period_value = sah.steps if sah.steps is not None else sah.seconds  # type: ignore[attr-defined]
            self._sah_period = max(float(draw(period_value, rng, 1)[0]) * scale, 1e-9)
            self._sah_phase = float(draw(sah.phase, rng, 1)[0]) * scale  # type: ignore[attr-defined]
            report["obs_update_period_steps"] = self._sah_period
            report["obs_update_phase_steps"] = self._sah_phase
        if ControlJitter in self.timing:
            self._jitter_blocks[ControlJitter] = (-1, None)
            report["control_substeps_nominal"] = self.nominal_substeps

    def _jitter(self, cls: type, k: int) -> int:
        """The per-step extra delay (or substep change) number ``k`` of the episode."""
        block, values = self._jitter_blocks[cls]
        b, r = divmod(k, BLOCK)
        if b != block:
            rng = self._timing_rng(cls, 1 + b)
            model = self.timing[cls]
            if cls is ControlJitter:
                values = model.block(rng, BLOCK)  # type: ignore[attr-defined]
            else:
                values = model.jitter_block(rng, BLOCK, self._scales[cls])  # type: ignore[attr-defined]
            self._jitter_blocks[cls] = (b, values)
        return 0 if values is None else int(values[r])

    @property
    def observation_needs_time(self) -> bool:
        """Whether :meth:`observe` uses ``now`` (latency or sample-and-hold); if not, callers may pass 0."""
        return ObservationLatency in self.timing or SampleAndHold in self.timing

    @property
    def episode_reads_time(self) -> bool:
        """Whether :meth:`observe` reads ``now`` this episode: only sample-and-hold and a latency that is not one
        fixed lag do (a fixed lag delivers from a ring by control step); if not, callers may pass 0. Valid after
        :meth:`begin_episode`."""
        return self.observation_needs_time and (SampleAndHold in self.timing or self.observation_lag is None)

    # -- observations -------------------------------------------------------------------------
    def _corrupt(self, obs: np.ndarray) -> np.ndarray:
        for pipe in self._obs_pipes:
            obs = pipe(obs)
        return obs

    def first_observation(self, obs: np.ndarray) -> np.ndarray:
        """Corrupts the reset observation (delivered at once, whatever the latency)."""
        sample = self._corrupt(obs)
        if SampleAndHold in self.timing:
            sample = np.array(sample, dtype=self.obs_dtype)
            self._held = sample.copy()
        self._obs_samples = 0
        if self._obs_delay is not None:
            if sample is obs:  # kept for later steps: the caller's array may be a buffer its env writes again
                sample = obs.copy()
            self._obs_delay.reset(sample, 0)
            if self._obs_lag is not None:
                self._obs_ring = [sample] * (self._obs_lag + 1)
        self._last_out = sample
        self.hot_observe = self._hot_observe()
        return sample

    def observe(self, obs: np.ndarray, now: int = 0) -> np.ndarray:
        """The observation the policy gets at time ``now`` (physics steps since reset) given the env's
        fresh observation ``obs``."""
        return self.hot_observe(obs, now)

    def _hot_observe(self) -> Callable[[np.ndarray, int], np.ndarray]:
        """This episode's :meth:`observe`, specialised once per episode for the common cases (no pipeline or one
        additive pipeline, then no time model or one fixed lag): the same arithmetic on the same state as
        :meth:`_observe_any`, without its per-step dispatch (the hot path; tests/test_hot_path.py pins it)."""
        pipes = self._obs_pipes
        lag = self._obs_lag
        if len(pipes) > 1 or self._sah or (lag is None and not self._plain):
            return self._observe_any
        noise = hot_pipe(pipes[0]) if pipes else None
        if lag is None:  # noise only (self._plain)
            if noise is None:
                return self._observe_any
            fast = compiled.pipe(pipes[0], noise)
            if fast is not noise:  # (called as (obs, now))
                return fast

            def noisy(obs: np.ndarray, now: int = 0) -> np.ndarray:
                return noise(obs)

            return noisy
        ring = self._obs_ring
        size = lag + 1
        if noise is not None and pipes[0].simple == 1:
            return self._hot_noisy_lag(pipes[0], ring, lag)

        def observe(obs: np.ndarray, now: int = 0) -> np.ndarray:
            # Kept in the ring: without noise (whose output is new) a copy, as the env may write its buffer again.
            sample = obs.copy() if noise is None else noise(obs)
            # Fixed latency, fixed control period: the sample of ``lag`` control steps ago, from a ring of
            # references (the same answer as the arrival-ordered delay line, with less work).
            k = self._obs_samples + 1
            self._obs_samples = k
            ring[k % size] = sample
            if k > lag:
                return ring[(k - lag) % size]
            return ring[(k - lag) % size].copy()  # the reset sample, delivered again

        return observe

    def _hot_noisy_lag(
        self, pipe: Pipeline, ring: list[np.ndarray], lag: int
    ) -> Callable[[np.ndarray, int], np.ndarray]:
        """The most common observation stack, one additive pipeline without a clip (``pipe.simple == 1``, known
        after the reset observation's first block) and a fixed lag, as one function: what ``hot_pipe(pipe)``
        and the ring do, with one Python call per step instead of two."""
        fast = compiled.noisy_lag(pipe, ring, lag, self._obs_samples)
        if fast is not None:
            return fast
        size = lag + 1
        k = self._obs_samples  # counted here for the episode (nothing else reads it while this path runs)

        def observe(obs: np.ndarray, now: int = 0) -> np.ndarray:
            nonlocal k
            r = pipe.r
            if r == BLOCK:
                sample = pipe(obs)  # draws the next block (simple stays 1: the gain is per episode)
            else:
                pipe.r = r + 1
                sample = obs + pipe.rows[r]
            k += 1
            ring[k % size] = sample
            if k > lag:
                return ring[(k - lag) % size]
            return ring[(k - lag) % size].copy()  # the reset sample, delivered again

        return observe

    def _observe_any(self, obs: np.ndarray, now: int = 0) -> np.ndarray:
        """What :meth:`observe` does, for every combination of models."""
        sample = obs
        for pipe in self._obs_pipes:
            sample = pipe(sample)
        if self._plain:
            return sample
        if self._sah:
            if sample is obs:
                sample = np.array(obs, dtype=self.obs_dtype)
            if sample_and_hold_updates(self._last_obs_time, now, self._sah_period, self._sah_phase):
                self._held = sample.copy()
            else:
                sample[self._sah_idx] = self._held[self._sah_idx]
            self._last_obs_time = now
        lag = self._obs_lag
        if sample is obs and self._obs_delay is not None:
            sample = obs.copy()  # kept for later steps: the caller's array may be a buffer its env writes again
        if lag is not None:
            # Fixed latency, fixed control period: the sample of ``lag`` control steps ago, from a ring
            # of references (the same answer as the arrival-ordered delay line, with less work).
            k = self._obs_samples + 1
            self._obs_samples = k
            ring = self._obs_ring
            size = lag + 1
            ring[k % size] = sample
            if k > lag:
                return ring[(k - lag) % size]
            return ring[(k - lag) % size].copy()  # the reset sample, delivered again
        delay = self._obs_delay
        if delay is not None:
            self._obs_samples += 1
            arrival = now + self._obs_latency
            if self._obs_jitter:
                arrival += self._jitter(ObservationLatency, self._obs_samples)
            delay.push(sample, arrival)
            sample = delay.read(now)
            if sample is self._last_out:
                sample = sample.copy()
            self._last_out = sample
        return sample

    # -- actions --------------------------------------------------------------------------------
    def act(self, action: np.ndarray) -> np.ndarray:
        """The action the env gets for the policy's ``action`` (noise; and latency when time counts
        control steps)."""
        flat = self._action_flat
        if action.shape != flat and flat is not None:
            raise ValueError(
                f"`action` must be a flat array of shape {self._action_flat} (the action layout). "
                f"Received an array of shape {action.shape}."
            )
        return self.hot_act(action)

    def _hot_act(self) -> Callable[[np.ndarray], np.ndarray]:
        """This episode's :meth:`act` without the shape check (callers that checked the shape call it directly),
        specialised for no pipeline or one additive pipeline, without a control-step delay or with a fixed one."""
        if len(self._action_pipes) > 1:
            return self._act_any
        if self.delays_actions:
            return self._hot_delayed_act()
        # Without a control-step delay nothing reads the control step count (_act_any keeps it for the delay).
        if not self._action_pipes:
            return lambda action: action
        pipe = self._action_pipes[0]
        return compiled.pipe(pipe, hot_pipe(pipe))

    def _hot_delayed_act(self) -> Callable[[np.ndarray], np.ndarray]:
        """This episode's :meth:`act` when it delays the actions by a fixed number of control steps (no latency
        jitter; at most one pipeline): the command of ``lag`` control steps ago from a ring of ``lag + 1``, zeros
        before the first arrives: what :meth:`_act_any`'s command buffer gives in that case (its float64 slot then
        ``astype(action_dtype)`` is this ``astype``: a float dtype's round trip through float64 is exact), without its
        arrival bookkeeping per step. Anything else (jitter, a latency the buffer would refuse) takes
        :meth:`_act_any`."""
        lag = self._action_latency
        delay = self._cmd_delay
        if self._act_jitter or delay is None or lag + 1 > delay.capacity:
            return self._act_any
        dtype = self.action_dtype
        if dtype.kind != "f":
            return self._act_any
        pipes = self._action_pipes
        noise = compiled.pipe(pipes[0], hot_pipe(pipes[0])) if pipes else None
        size = lag + 1
        zero = np.zeros(self.action_layout.size).astype(dtype)  # type: ignore[union-attr]
        ring = [zero] * size

        def act(action: np.ndarray) -> np.ndarray:
            sent = action if noise is None else noise(action)
            t = self._control_step
            self._control_step = t + 1
            # A fresh array in the action's dtype, kept until it is handed out (lag steps later, then overwritten).
            # Through float64 as the buffer casts, unless the noise's arithmetic made it in the dtype already (the
            # round trip is then exact; the caller's own array may hold a signalling NaN the round trip quiets).
            noisy = noise is not None and sent.dtype == dtype
            ring[t % size] = sent.astype(dtype) if noisy else sent.astype(np.float64).astype(dtype)
            if t >= lag:
                return ring[(t - lag) % size]
            return zero.copy()  # nothing has arrived yet: the buffer's reset command

        return act

    def _act_any(self, action: np.ndarray) -> np.ndarray:
        """What :meth:`act` does after its shape check, for every combination of models."""
        for pipe in self._action_pipes:
            action = pipe(action)
        if self.delays_actions:
            t = self._control_step
            jitter = self._jitter(ActionLatency, t) if ActionLatency in self._jitter_blocks else 0
            if jitter and self.physics_time:
                jitter = math.floor(jitter / self.nominal_substeps + 0.5)
            # delays_actions implies ActionLatency, for which bind() built the command delay.
            assert self._cmd_delay is not None
            if t == 0:
                self._cmd_delay.reset(np.zeros(self.action_layout.size))  # type: ignore[union-attr]
            self._cmd_delay.push(action, t + self._action_latency + jitter)
            (command, _), *_ = self._cmd_delay.segments(t, 1)
            action = command.astype(self.action_dtype)
        self._control_step += 1
        return action

    def reset_commands(self, ctrl: np.ndarray) -> None:
        """Starts the physics-rate command buffer with the actuators' command at reset."""
        if self._cmd_delay is not None and not self.delays_actions:
            if self._cmd_delay._values.shape[1] != ctrl.size:
                self._cmd_delay = CommandDelay(self._cmd_delay.capacity, ctrl.size)
            self._cmd_delay.reset(ctrl)
            if self.command_lag is not None:
                # Fixed whole-control-step latency: a ring of lag + 1 commands, all the reset command at first.
                self.command_ring = np.tile(np.asarray(ctrl, dtype=np.float64), (self.command_lag + 1, 1))
        self._commands_sent = 0

    def substeps(self, nominal: int) -> int:
        """Physics substeps of the control step about to run (ControlJitter), at least 1."""
        if ControlJitter not in self.timing:
            return nominal
        k = self._substep_draws
        self._substep_draws = k + 1
        return max(1, nominal + self._jitter(ControlJitter, k))

    def command_segments(self, ctrl: np.ndarray, start: int, n: int) -> list[tuple[np.ndarray, int]]:
        """Sends ``ctrl`` at physics step ``start`` and returns the ``(command, steps)`` pieces that
        cover physics steps ``start .. start + n - 1``."""
        delay = self._cmd_delay
        if delay is None:
            return [(ctrl, n)]
        k = self._commands_sent
        self._commands_sent = k + 1
        arrival = start + self._action_latency
        if self._act_jitter:
            arrival += self._jitter(ActionLatency, k)
        delay.push(ctrl, arrival)
        return delay.segments(start, n)

    def continue_segments(self, start: int, n: int) -> list[tuple[np.ndarray, int]]:
        """Pieces for further physics steps of the same control step (envs that step one substep at a time)."""
        if self._cmd_delay is None:
            raise RuntimeError("no action latency")
        return self._cmd_delay.segments(start, n)
