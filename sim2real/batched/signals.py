"""Observation/action noise and observation latency for all batched worlds at once: :class:`BatchedSignals`.

Each world keeps its own :class:`noise_models.SignalCorruptor` (inside its single env's ``CorruptSignals``), so
its draws come from its own keyed streams, by the corruptor's own code: the episode's draws at reset, and every
block of ``BLOCK`` pre-drawn noise rows when a world's block runs out. Per step, one numpy operation per
pipeline serves all worlds: ``x * G + F[world, row]`` over preallocated ``(N, BLOCK, size)`` blocks (a world
without gain multiplies by 1.0, which is exact), then the pipeline's clip; observation latency reads a
preallocated ``(N, R, size)`` ring at each world's own lag. ``ActionLatency`` (fixed or drawn per episode, by
each world's corruptor from its own stream) delays either the actuator command at physics rate (``"ctrl"``: the
engine applies each world's delayed command from a preallocated ``(N, S, nu)`` ring inside its physics step,
mid control step when the latency is not whole control steps) or, where the action does not map onto ``ctrl``,
the action by whole control steps (``"action"``: a preallocated ``(N, S, act_dim)`` ring here). Worlds in lockstep
(reset together, stepped unmasked since: the usual case) sit on the same noise row and ring slot, so the step
reads ``F[:, row]`` and ``ring[:, slot]`` as views instead of gathering one row per world, and their blocks run
out together; a partial reset or a masked step drops back to per-world rows until the worlds line up again (the
same values either way; ``tests/test_batched_lockstep.py``). What is supported
(:func:`signals_reason`): noise pipelines of additive and multiplicative processes (fused by ``noise_models``
into one affine stage), ``ObservationLatency`` with a fixed per-episode lag and ``ActionLatency`` without jitter;
sample-and-hold, jitter and the element-wise processes (quantise, dropout, ...) keep the per-env path.

Example:
    >>> import sim2real as s2r
    >>> from sim2real.batched import make_batched
    >>> envs = make_batched("dmc/reacher-easy", 2, s2r.ObservationNoise(s2r.Gaussian(std=0.01)),
    ...                     s2r.ObservationLatency(steps=2), seed=0)
    >>> obs, params = envs.reset(seed=0)
    >>> params["obs_latency_steps"].tolist()
    [2.0, 2.0]
    >>> envs.close()
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from noise_models.corruptor import ActionNoise, NoiseBlock, ObservationNoise, SignalCorruptor
from noise_models.fused import next_blocks, pipeline_of
from noise_models.processes import BLOCK, Bias, Drift, Gaussian, Outlier, Scale, UniformNoise
from noise_models.timing import ActionLatency, ObservationLatency

try:  # the clip ufunc itself: np.clip's Python dispatch costs more than the clipping (as noise_models.fused)
    # numpy's stubs do not declare the `clip` ufunc in umath, though numpy 2 exports it there.
    from numpy._core.umath import clip as _clip  # type: ignore[attr-defined]
except ImportError:  # pragma: no cover - numpy < 2
    from numpy.core.umath import clip as _clip  # type: ignore[no-redef]

__all__ = ["BatchedSignals", "action_latency_bound", "signals_reason"]

#: Processes ``noise_models`` fuses into one affine stage (``x * G + F``): the ones batched here.
AFFINE_PROCESSES = (Gaussian, UniformNoise, Bias, Scale, Drift, Outlier)


def signals_reason(models: Sequence[Any]) -> str | None:
    """Why the batched engine cannot run the signal ``models`` (None when it can)."""
    for model in models:
        if isinstance(model, (ObservationNoise, ActionNoise)):
            for process in model.processes:
                if not isinstance(process, AFFINE_PROCESSES):
                    return f"{type(process).__name__} is not batched (only {[c.__name__ for c in AFFINE_PROCESSES]})"
        elif isinstance(model, (ObservationLatency, ActionLatency)):
            if model.jitter is not None:
                return f"{type(model).__name__} with jitter is not batched"
        else:
            return f"{type(model).__name__} is not batched"
    return None


def action_latency_bound(corruptor: Any) -> int:
    """The longest action latency, in physics steps, any episode of a bound ``corruptor`` can draw."""
    model = corruptor.timing[ActionLatency]
    return int(model.check_capacity(model.step_scale(corruptor.timestep)))


class _Pipes:
    """One pipeline position (the k-th observation or action pipeline) across all worlds.

    Worlds reset together and stepped unmasked sit on the same row of their blocks (``common``): the step's
    noise is then ``F[row]``, one contiguous ``(N, size)`` view (blocks are stored row-major over worlds,
    ``(BLOCK, N, size)``), instead of a per-world gather, and their blocks run out together (refilled in one pass).
    Any reset of some worlds or a masked step returns to per-world rows (``r``); the values are the same either way.
    """

    def __init__(self, n: int, side: str, k: int, size: int, dtype: np.dtype) -> None:
        self.side, self.k = side, k
        self.corruptors: list[Any] = [None] * n
        # Every world's pipeline, looked up at the first refill of every world after a reset (None: look again), so
        # a lockstep refill does not go through 64 corruptors to reach them (objects cold after the physics step).
        self._pipelines: list[Any] | None = None
        self.F = np.zeros((BLOCK, n, size), dtype=dtype)
        # Row r of every world as a view made once (refills write into F in place): the step indexes a list instead
        # of making a view of F each call.
        self.F_rows = list(self.F)
        self.G = np.ones((n, size), dtype=dtype)
        self.unit = np.ones(n, bool)  # worlds without gain: x + F (x * 1.0 is x, so skipping it is exact)
        self.rows = np.arange(n)
        self.r = np.zeros(n, np.int64)  # each world's row (stale while ``common`` is set)
        self.common: int | None = None  # the row of every world, when they line up
        self.check = False  # rows may line up again (after resets or masked steps): look at the next full step
        # The pipeline's clip (NoiseBlock.clip), None without bounds: the same for every world (one signal layout).
        self.clip: Any = None
        # A clip of the whole signal (actions): its bounds broadcast to (N, size) once, so the step's clip is one
        # ufunc loop over all worlds instead of one short loop per world (NoiseBlock.clip's arithmetic).
        self.bounds: tuple[np.ndarray, np.ndarray] | None = None
        self.all_unit = True  # every world without gain
        # Calls before any world can reach the end of its block (r grows by at most 1 a call): until then no
        # world needs a refill and the check is skipped.
        self.headroom = 0

    def _split(self) -> None:
        """Back to per-world rows."""
        if self.common is not None:
            self.r[:] = self.common
            self.common = None
            self.headroom = 0

    def take(self, i: int, corruptor: Any, block: NoiseBlock) -> None:
        """World ``i``'s pipeline after its reset (or after a refill): its current block and position."""
        self._split()
        self._hold(i, corruptor, block)
        self.all_unit = bool(self.unit.all())
        self.check = True

    def _hold(self, i: int, corruptor: Any, block: NoiseBlock) -> None:
        self.corruptors[i] = corruptor
        self._pipelines = None
        self.F[:, i] = block.offsets
        self.G[i] = 1.0 if block.gain is None else block.gain
        self.unit[i] = block.gain is None
        self.r[i] = block.row
        self.clip = None if block.low is None else block.clip
        low, high = block.low, block.high
        if low is None or high is None or block.guard:
            self.bounds = None
        elif self.bounds is None:
            shape = self.G.shape
            self.bounds = (np.broadcast_to(low, shape).copy(), np.broadcast_to(high, shape).copy())
        self.headroom = 0  # recomputed at the next call

    def _refill(self, worlds: list[int]) -> None:
        """The next block of each of ``worlds``, each from its own stream (as its single env would draw it),
        composed for all of them at once (``SignalCorruptor.next_noise_blocks``)."""
        if not worlds:
            return
        corruptors = self.corruptors
        compose = type(corruptors[0]).next_noise_blocks
        if len(worlds) == len(corruptors):  # every world, in order (lockstep): composed into the blocks
            out = (self.F.transpose(1, 0, 2), self.G, self.unit)
            if compose is SignalCorruptor.next_noise_blocks:  # next_blocks of their pipelines, looked up once
                pipelines = self._pipelines
                if pipelines is None:
                    pipelines = self._pipelines = [pipeline_of(c, self.side, self.k) for c in corruptors]
                next_blocks(pipelines, out)
            else:
                compose(corruptors, self.side, self.k, out)
            self.r[...] = 0
        else:
            corruptors = [corruptors[i] for i in worlds]
            offsets, gains, unit = compose(corruptors, self.side, self.k)
            self.F[:, worlds] = offsets.transpose(1, 0, 2)
            self.G[worlds] = gains
            self.unit[worlds] = unit
            self.r[worlds] = 0
        self.headroom = 0
        self.all_unit = bool(self.unit.all())

    def _clip(self, x: np.ndarray, w: np.ndarray) -> None:
        bounds = self.bounds
        if bounds is not None:
            _clip(w, bounds[0], bounds[1], w)
        elif self.clip is not None:
            self.clip(x, w)

    def __call__(self, x: np.ndarray, active: np.ndarray, everyone: bool, out: np.ndarray | None = None) -> np.ndarray:
        """The noisy signal of every world; only the ``active`` worlds' noise advances (``everyone``: all are).
        ``out``: an ``(N, size)`` array to write it into when every world is on one row (returned then)."""
        if everyone:
            if self.check:
                self.check = False
                first = int(self.r[0])
                if self.common is None and bool((self.r == first).all()):
                    self.common = first
            row = self.common
            if row is not None:
                if row == BLOCK:  # every world's block is spent at once
                    self._refill(list(range(len(self.corruptors))))
                    row = int(self.r[0])  # 0: a fresh block's first row, for every world
                self.common = row + 1
                noise = self.F_rows[row]
                if self.all_unit:
                    w = np.add(x, noise, out)
                else:
                    w = np.multiply(x, self.G, out)
                    w += noise
                bounds = self.bounds  # _clip, inline: this is every step's path
                if bounds is not None:
                    _clip(w, bounds[0], bounds[1], w)
                elif self.clip is not None:
                    self.clip(x, w)
                return w
        else:
            self._split()
            self.check = True
        if self.headroom <= 0:
            self._refill(np.flatnonzero(active & (self.r == BLOCK)).tolist())
            self.headroom = BLOCK - int(self.r.max())
        self.headroom -= 1
        noise = self.F[self.r if everyone else np.minimum(self.r, BLOCK - 1), self.rows]
        w = x + noise if self.all_unit else x * self.G + noise
        self.r += active
        self._clip(x, w)
        return w if everyone else np.where(active[:, None], w, x)


class BatchedSignals:
    """The worlds' noise pipelines and observation latency, vectorised (see the module docstring).

    Args:
        num_envs: worlds N.
        envs: each world's single env (its outermost wrapper holds the ``corruptor``: the fused
            ``RandomizeAndCorrupt`` or ``CorruptSignals``).
    """

    def __init__(self, num_envs: int, envs: Sequence[Any]) -> None:
        self.num_envs = num_envs
        first = envs[0].corruptor
        self._obs = [
            _Pipes(num_envs, "observation", k, size, first.obs_dtype)
            for k, size in enumerate(first.pipeline_sizes("observation"))
        ]
        self._act = [
            _Pipes(num_envs, "action", k, size, first.action_dtype)
            for k, size in enumerate(first.pipeline_sizes("action"))
        ]
        self._obs_inner, self._obs_last = self._obs[:-1], (self._obs[-1] if self._obs else None)
        self.action_dtype = first.action_dtype
        self._latency = ObservationLatency in first.timing
        self._lag = np.zeros(num_envs, np.int64)
        self._k = np.zeros(num_envs, np.int64)  # each world's observations this episode (stale while _kc is set)
        self._kc: int | None = None  # the count of every world, when they line up (see _Pipes)
        self._lagc: int | None = None  # the lag of every world, when they are the same
        self._line_up = False  # counts may line up again (after resets or masked steps): look at the next full step
        # (slots, N, size): slot k of every world is one contiguous (N, size) array.
        self._ring = np.zeros((1, num_envs, 0), dtype=first.obs_dtype or np.float32)
        self._slots = list(self._ring)  # the ring's slots as views made once (the lockstep step picks two a step)
        self._rows = np.arange(num_envs)
        # ActionLatency. On the "action" path (the action does not map onto ctrl: arm-reach's IK targets) each
        # world's action waits ``lag`` whole control steps in a float64 ring, zeros until the first arrives, as
        # in the corruptor's command buffer. On the "ctrl" path the engine applies each world's delayed actuator
        # command inside its physics step from ``command_ring`` (see BatchedEnv._advance).
        #: ``"ctrl"``, ``"action"`` or None (no ActionLatency): what the worlds delay.
        self.action_path: str | None = envs[0].action_latency_path
        longest = action_latency_bound(first) if self.action_path is not None else 0
        n_sub = max(int(first.nominal_substeps), 1)
        act_size = first.action_layout.size if self.action_path == "action" else 0
        self._act_lag = np.zeros(num_envs, np.int64)
        self._act_t = np.zeros(num_envs, np.int64)
        self._act_ring = np.zeros((num_envs, math.floor(longest / n_sub + 0.5) + 1, act_size))
        #: ``(N, S, nu)`` commands sent in each world's episode (slot ``k % S`` for control step ``k``): S is the
        #: longest whole-control-step lag + 2, so a slot not yet written this episode holds the reset command.
        self.command_ring = np.zeros((num_envs, longest // n_sub + 2, 0))
        #: Each world's latency as (whole control steps, remaining physics steps) of this episode.
        self.command_lag = np.zeros(num_envs, np.int64)
        self.command_rest = np.zeros(num_envs, np.int64)
        #: The ``(lag, rest)`` of every world when they are the same and the worlds' commands line up (all reset
        #: together, all stepped since); None: per world. ``command_check``: look again at the next full step.
        self.command_common: tuple[int, int] | None = None
        self.command_check = False
        self._n_sub = n_sub
        # The step's usual shapes, for act/observe's short paths: one action pipeline and nothing else on the action
        # side; observation latency after one noise pipeline.
        self._one_act = len(self._act) == 1 and self.action_path != "action"
        self._one_obs = self._latency and len(self._obs) == 1

    def reset_world(self, i: int, env: Any, first_obs: np.ndarray, ctrl: np.ndarray | None = None) -> None:
        """Takes world ``i``'s state after its single env's reset (draws made, reset observation delivered;
        ``ctrl``: the world's actuator command at reset, which a delayed command replaces when it arrives)."""
        c = env.corruptor
        if self.action_path == "action":
            self._act_lag[i] = int(c.current_params["action_latency_control_steps"])
            self._act_ring[i] = 0.0
            self._act_t[i] = 0
        elif self.action_path == "ctrl":
            if ctrl is None:
                raise ValueError(
                    "`ctrl` must be the world's actuator command at reset with ActionLatency. Received None."
                )
            if self.command_ring.shape[2] != ctrl.size:
                self.command_ring = np.zeros((self.num_envs, self.command_ring.shape[1], ctrl.size))
            self.command_ring[i] = ctrl  # every slot: the reset command, until the first delayed command arrives
            self.command_lag[i], self.command_rest[i] = divmod(
                int(c.current_params["action_latency_steps"]), self._n_sub
            )
            self.command_common = None
            self.command_check = True
        for pipes, block in zip(self._obs, c.noise_blocks("observation"), strict=True):
            pipes.take(i, c, block)
        for pipes, block in zip(self._act, c.noise_blocks("action"), strict=True):
            pipes.take(i, c, block)
        if self._latency:
            self._counts()
            self._line_up = True
            lag = c.observation_lag
            if lag is None:
                raise ValueError("`effects`: an observation latency without a fixed lag is not batched.")
            if lag + 1 > self._ring.shape[0] or self._ring.shape[2] != first_obs.size:
                self._grow(lag + 1, first_obs)
            self._ring[:, i] = first_obs  # every slot holds the reset sample, as the single env's ring does
            self._lag[i] = lag
            self._k[i] = 0

    def _grow(self, size: int, first_obs: np.ndarray) -> None:
        """A ring of ``size`` slots; every world's last samples move to the slots their step counts map to."""
        old = self._ring
        ring = np.zeros((size, self.num_envs, first_obs.size), dtype=first_obs.dtype)
        if old.shape[2] == first_obs.size:
            rows = np.arange(self.num_envs)
            for d in range(old.shape[0]):  # at a reset only; the ring grows at most to the largest lag drawn
                ring[(self._k - d) % size, rows] = old[(self._k - d) % old.shape[0], rows]
        self._ring = ring
        self._slots = list(ring)

    def act(self, actions: np.ndarray, active: np.ndarray, everyone: bool | None = None) -> np.ndarray:
        """The actions the worlds' envs get (the policy's, through each world's action noise and, on the
        ``"action"`` path, its action latency); ``everyone``: whether every world is ``active`` (None: look)."""
        if everyone is True and self._one_act and type(actions) is np.ndarray:  # the usual step: one add and clip
            pipes = self._act[0]
            row = pipes.common
            bounds = pipes.bounds
            if row is not None and row != BLOCK and not pipes.check and pipes.all_unit and bounds is not None:
                pipes.common = row + 1  # _Pipes.__call__'s lockstep path, inline
                w = np.add(actions, pipes.F_rows[row])
                _clip(w, bounds[0], bounds[1], w)
                return w
            return pipes(actions, active, True)
        if not self._act and self.action_path != "action":
            return actions
        if everyone is None:
            everyone = bool(active.all())
        if type(actions) is not np.ndarray:
            actions = np.asarray(actions, dtype=self.action_dtype)
        for pipes in self._act:
            actions = pipes(actions, active, everyone)
        if self.action_path == "action":
            ring, t, rows = self._act_ring, self._act_t, self._rows
            size = ring.shape[1]
            slot = t % size
            ring[rows, slot] = np.where(active[:, None], actions, ring[rows, slot])
            # The action of ``lag`` control steps ago; before the first arrives, the zeros of a slot not yet written.
            actions = ring[rows, (t - self._act_lag) % size].astype(self.action_dtype)
            self._act_t = t + active
        return actions

    def observe(
        self, obs: np.ndarray, active: np.ndarray, previous: np.ndarray, everyone: bool | None = None
    ) -> np.ndarray:
        """What the policy sees: each world's fresh observation through its noise and latency (the
        ``previous`` output stays for worlds not stepped; ``everyone``: whether every world is ``active``, None:
        look). The result may be ``previous`` itself, overwritten."""
        if everyone is True and self._one_obs and not self._line_up:
            kc, lag = self._kc, self._lagc
            if kc is not None and lag is not None:  # the usual step (below, inline): lockstep, one lag, one pipeline
                kc += 1
                self._kc = kc
                slots = self._slots
                size = len(slots)
                slot = slots[kc % size]
                pipes = self._obs[0]
                row = pipes.common
                if row is not None and row != BLOCK and not pipes.check and pipes.all_unit and pipes.clip is None:
                    pipes.common = row + 1  # _Pipes.__call__'s lockstep path without a clip, inline
                    np.add(obs, pipes.F_rows[row], slot)
                else:
                    sample = pipes(obs, active, True, slot)
                    if sample is not slot:
                        np.copyto(slot, sample)
                # The slot's copy by assignment: the same values and dtype, half of np.copyto's call cost.
                previous[...] = slots[(kc - lag) % size]
                return previous
        if everyone is None:
            everyone = bool(active.all())
        if not self._latency:
            if everyone:
                sample = self._noisy(obs, active, True, previous)
                if sample is not previous:
                    np.copyto(previous, sample)
                return previous
            return np.where(active[:, None], self._noisy(obs, active, False), previous)
        ring = self._ring
        size = ring.shape[0]
        if everyone:
            if self._line_up:
                self._line_up = False
                self._kc = int(self._k[0]) if bool((self._k == self._k[0]).all()) else None
                self._lagc = int(self._lag[0]) if bool((self._lag == self._lag[0]).all()) else None
            kc = self._kc
            if kc is not None:  # every world at the same step of its episode: slots are views
                kc += 1
                self._kc = kc
                slots = self._slots
                slot = slots[kc % size]
                last = self._obs_last
                if last is not None and not self._obs_inner:  # one pipeline (_noisy, inline): into the slot
                    sample = last(obs, active, True, slot)
                else:
                    sample = self._noisy(obs, active, True, slot)  # straight into the slot when the noise can
                if sample is not slot:
                    np.copyto(slot, sample)
                if self._lagc is not None:
                    # The sample of ``lag`` control steps ago; before that, the reset sample (still in its slot).
                    np.copyto(previous, slots[(kc - self._lagc) % size])
                    return previous
                return ring[(kc - self._lag) % size, self._rows]
        else:
            self._counts()
            self._line_up = True
        sample = self._noisy(obs, active, everyone)
        k = self._k + active
        self._k = k
        rows = self._rows
        slot_k = k % size
        if everyone:
            ring[slot_k, rows] = sample
            return ring[(k - self._lag) % size, rows]
        ring[slot_k, rows] = np.where(active[:, None], sample, ring[slot_k, rows])
        delayed = ring[(k - self._lag) % size, rows]
        return np.where(active[:, None], delayed, previous)

    def _noisy(self, obs: np.ndarray, active: np.ndarray, everyone: bool, out: np.ndarray | None = None) -> np.ndarray:
        """The observations through the noise pipelines (``obs`` itself without any); the last pipeline writes
        into ``out`` when it can (every world on one row)."""
        sample = obs
        for pipes in self._obs_inner:
            sample = pipes(sample, active, everyone)
        last = self._obs_last
        return sample if last is None else last(sample, active, everyone, out)

    def _counts(self) -> None:
        """Back to per-world step counts of the observation ring."""
        if self._kc is not None:
            self._k[:] = self._kc
            self._kc = None
