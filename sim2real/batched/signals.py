"""Observation/action noise and observation latency for all batched worlds at once: :class:`BatchedSignals`.

Each world keeps its own :class:`noise_models.SignalCorruptor` (inside its single env's ``CorruptSignals``), so
its draws come from its own keyed streams, by the corruptor's own code: the episode's draws at reset, and every
block of ``BLOCK`` pre-drawn noise rows when a world's block runs out. Per step, one numpy operation per
pipeline serves all worlds: ``x * G + F[world, row]`` over preallocated ``(N, BLOCK, size)`` blocks (a world
without gain multiplies by 1.0, which is exact), then the pipeline's clip; observation latency reads a
preallocated ``(N, R, size)`` ring at each world's own lag. What is supported (:func:`signals_reason`): noise
pipelines of additive and multiplicative processes (fused by ``noise_models`` into one affine stage) and
``ObservationLatency`` with a fixed per-episode lag; sample-and-hold, jitter, action latency and the
element-wise processes (quantise, dropout, ...) keep the per-env path.

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

from collections.abc import Sequence
from typing import Any

import numpy as np

from noise_models.corruptor import ActionNoise, NoiseBlock, ObservationNoise
from noise_models.processes import BLOCK, Bias, Drift, Gaussian, Outlier, Scale, UniformNoise
from noise_models.timing import ObservationLatency

__all__ = ["BatchedSignals", "signals_reason"]

#: Processes ``noise_models`` fuses into one affine stage (``x * G + F``): the ones batched here.
AFFINE_PROCESSES = (Gaussian, UniformNoise, Bias, Scale, Drift, Outlier)


def signals_reason(models: Sequence[Any]) -> str | None:
    """Why the batched engine cannot run the signal ``models`` (None when it can)."""
    for model in models:
        if isinstance(model, (ObservationNoise, ActionNoise)):
            for process in model.processes:
                if not isinstance(process, AFFINE_PROCESSES):
                    return f"{type(process).__name__} is not batched (only {[c.__name__ for c in AFFINE_PROCESSES]})"
        elif isinstance(model, ObservationLatency):
            if model.jitter is not None:
                return "ObservationLatency with jitter is not batched"
        else:
            return f"{type(model).__name__} is not batched"
    return None


class _Pipes:
    """One pipeline position (the k-th observation or action pipeline) across all worlds."""

    def __init__(self, n: int, side: str, k: int, size: int, dtype: np.dtype) -> None:
        self.side, self.k = side, k
        self.corruptors: list[Any] = [None] * n
        self.F = np.zeros((n, BLOCK, size), dtype=dtype)
        self.G = np.ones((n, size), dtype=dtype)
        self.unit = np.ones(n, bool)  # worlds without gain: x + F (x * 1.0 is x, so skipping it is exact)
        self.rows = np.arange(n)
        self.r = np.zeros(n, np.int64)
        self.block: NoiseBlock | None = None  # clip bounds: the same for every world (the same signal layout)

    def take(self, i: int, corruptor: Any, block: NoiseBlock) -> None:
        """World ``i``'s pipeline after its reset (or after a refill): its current block and position."""
        self.corruptors[i] = corruptor
        self.F[i] = block.offsets
        self.G[i] = 1.0 if block.gain is None else block.gain
        self.unit[i] = block.gain is None
        self.r[i] = block.row
        self.block = block

    def __call__(self, x: np.ndarray, active: np.ndarray) -> np.ndarray:
        """The noisy signal of every world; only the ``active`` worlds' noise advances."""
        idx = np.flatnonzero(active & (self.r == BLOCK))
        for i in idx.tolist():
            corruptor = self.corruptors[i]  # the world's own next block, from its own stream
            self.take(i, corruptor, corruptor.next_noise_block(self.side, self.k))
        everyone = bool(active.all())
        noise = self.F[self.rows, self.r if everyone else np.minimum(self.r, BLOCK - 1)]
        w = x + noise if self.unit.all() else x * self.G + noise
        self.r += active
        if self.block is not None:
            self.block.clip(x, w)
        return w if everyone else np.where(active[:, None], w, x)


class BatchedSignals:
    """The worlds' noise pipelines and observation latency, vectorised (see the module docstring).

    Args:
        num_envs: worlds N.
        envs: each world's single env (its outermost wrapper is ``CorruptSignals``).
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
        self.action_dtype = first.action_dtype
        self._latency = ObservationLatency in first.timing
        self._lag = np.zeros(num_envs, np.int64)
        self._k = np.zeros(num_envs, np.int64)
        self._ring = np.zeros((num_envs, 1, 0), dtype=first.obs_dtype or np.float32)

    def reset_world(self, i: int, env: Any, first_obs: np.ndarray) -> None:
        """Takes world ``i``'s state after its single env's reset (draws made, reset observation delivered)."""
        c = env.corruptor
        for pipes, block in zip(self._obs, c.noise_blocks("observation"), strict=True):
            pipes.take(i, c, block)
        for pipes, block in zip(self._act, c.noise_blocks("action"), strict=True):
            pipes.take(i, c, block)
        if self._latency:
            lag = c.observation_lag
            if lag is None:
                raise ValueError("`effects`: an observation latency without a fixed lag is not batched.")
            if lag + 1 > self._ring.shape[1] or self._ring.shape[2] != first_obs.size:
                self._grow(lag + 1, first_obs)
            self._ring[i] = first_obs  # every slot holds the reset sample, as the single env's ring does
            self._lag[i] = lag
            self._k[i] = 0

    def _grow(self, size: int, first_obs: np.ndarray) -> None:
        """A ring of ``size`` slots; every world's last samples move to the slots their step counts map to."""
        old = self._ring
        ring = np.zeros((self.num_envs, size, first_obs.size), dtype=first_obs.dtype)
        if old.shape[2] == first_obs.size:
            rows = np.arange(self.num_envs)
            for d in range(old.shape[1]):  # at a reset only; the ring grows at most to the largest lag drawn
                ring[rows, (self._k - d) % size] = old[rows, (self._k - d) % old.shape[1]]
        self._ring = ring

    def act(self, actions: np.ndarray, active: np.ndarray) -> np.ndarray:
        """The actions the worlds' envs get (the policy's, through each world's action noise)."""
        if not self._act:
            return actions
        if type(actions) is not np.ndarray:
            actions = np.asarray(actions, dtype=self.action_dtype)
        for pipes in self._act:
            actions = pipes(actions, active)
        return actions

    def observe(self, obs: np.ndarray, active: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """What the policy sees: each world's fresh observation through its noise and latency (the
        ``previous`` output stays for worlds not stepped)."""
        sample = obs
        for pipes in self._obs:
            sample = pipes(sample, active)
        if not self._latency:
            return np.where(active[:, None], sample, previous)
        size = self._ring.shape[1]
        k = self._k + active
        self._k = k
        rows = np.arange(self.num_envs)
        current = self._ring[rows, k % size]
        self._ring[rows, k % size] = np.where(active[:, None], sample, current)
        # The sample of ``lag`` control steps ago; before that, the reset sample (still in its slot).
        delayed = self._ring[rows, (k - self._lag) % size]
        return np.where(active[:, None], delayed, previous)
