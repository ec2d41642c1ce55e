"""Batched worlds: many MuJoCo worlds of one task, each its own model copy with its own draws, stepped together
below Python, with observations and rewards computed for all worlds in one numpy operation.

* :func:`make_batched` / :class:`BatchedEnv`: the engine (:mod:`sim2real.batched.engine`);
* :mod:`sim2real.batched.worlds`: the worlds' physics on MuJoCo's thread-pooled ``mujoco.batch`` (one C call a step);
* :mod:`sim2real.batched.kernels`: per-task observation and reward kernels (which tasks are supported: the built-in
  ones in ``KERNELS`` and any MJCF file as ``"model:<path>"``; an env with its own Python step is not);
* :mod:`sim2real.batched.signals`: observation/action noise and observation latency for all worlds at once;
* :class:`BatchedVectorEnv`: the engine as a gymnasium ``VectorEnv`` (next-step autoreset);
* :class:`sim2real.batched.torchrl_env.BatchedTorchRLEnv`: the engine as one TorchRL ``EnvBase`` with
  ``batch_size=[N]`` (imported from its module, so that ``import sim2real`` never imports torch).

:func:`sim2real.evaluation.evaluate` uses the engine for every condition it supports (``Evaluation.engines``).

Example:
    >>> import sim2real as s2r
    >>> from sim2real.batched import supports
    >>> supports("dmc/reacher-easy", s2r.Damping(scale=s2r.Uniform(0.5, 2.0))) is None
    True
"""

from __future__ import annotations

from sim2real.batched.engine import BatchedEnv, make_batched, supports
from sim2real.batched.kernels import KERNELS, Kernel, kernel_for
from sim2real.batched.vector import BatchedVectorEnv

__all__ = ["KERNELS", "BatchedEnv", "BatchedVectorEnv", "Kernel", "kernel_for", "make_batched", "supports"]
