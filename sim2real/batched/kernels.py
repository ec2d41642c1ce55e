"""Per-task observation and reward kernels of the batched engine: what a task computes from its physics, for all
worlds in one numpy operation per step.

A kernel names the per-world MjData arrays it reads (:attr:`Kernel.fields`); the engine copies them, once per
step and world, into preallocated ``(N, ...)`` buffers, and the kernel turns those buffers into the observation,
reward and termination of every world at once. Each kernel repeats its task's arithmetic operation for operation
(same operands, same order, float64 until the adapter's float32 cast), so a world's values are bitwise those of
the single env; ``tests/test_batched.py`` checks it episode by episode.

Example:
    >>> from sim2real.batched.kernels import KERNELS, kernel_for
    >>> sorted(KERNELS)
    ['dmc/reacher-easy', 'dmc/reacher-hard']
    >>> kernel_for("dmc/reacher-easy").obs_dim
    6
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import mujoco
import numpy as np

__all__ = ["KERNELS", "Kernel", "ReacherKernel", "kernel_for"]


class Kernel:
    """What the engine needs from a task: which arrays to gather, and the vectorised observation and reward.

    Attributes:
        obs_dim: length of the flat float32 observation.
        fields: MjData attribute names gathered per world after every step (``(N, *shape)`` buffers).
    """

    obs_dim: int = 0
    fields: tuple[str, ...] = ()

    def bind(self, models: Sequence[mujoco.MjModel], envs: Sequence[Any]) -> None:
        """Reads what stays fixed over an episode (called after every reset of any world)."""

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> np.ndarray:
        """``(N, obs_dim)`` float32 observations from the gathered ``(N, ...)`` arrays."""
        raise NotImplementedError

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> np.ndarray:
        """``(N,)`` float64 rewards."""
        raise NotImplementedError


class ReacherKernel(Kernel):
    """dm-control ``reacher``: observation ``[position, to_target, velocity]`` and the sparse reward
    ``1.0 if |finger - target| <= r_target + r_finger else 0.0``.

    ``to_target`` is ``geom_xpos[target, :2] - geom_xpos[finger, :2]``; the distance is
    ``sqrt(dx*dx + dy*dy)``, the arithmetic ``np.linalg.norm`` does on a 2-vector (no fused multiply-add;
    checked bitwise on 2e4 random vectors), and the radii sum is re-read at every reset (the task writes the
    target's size in its ``initialize_episode``).
    """

    obs_dim = 6
    fields = ("geom_xpos",)

    def __init__(self) -> None:
        self._target = self._finger = -1
        self._radii = np.zeros(0)

    def bind(self, models: Sequence[mujoco.MjModel], envs: Sequence[Any]) -> None:
        m0 = models[0]
        self._target = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_GEOM, "target")
        self._finger = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_GEOM, "finger")
        sizes = np.stack([m.geom_size for m in models])
        self._radii = sizes[:, self._target, 0] + sizes[:, self._finger, 0]

    def _to_target(self, gathered: dict[str, np.ndarray]) -> np.ndarray:
        xpos = gathered["geom_xpos"]
        return xpos[:, self._target, :2] - xpos[:, self._finger, :2]

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([qpos, self._to_target(gathered), qvel], axis=1, dtype=np.float32)

    def reward(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> np.ndarray:
        d = self._to_target(gathered)
        dist = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])
        return np.where((dist >= 0.0) & (dist <= self._radii), 1.0, 0.0)


#: Task id -> kernel factory: the tasks the batched engine runs (others fall back to per-env stepping).
KERNELS: dict[str, Callable[[], Kernel]] = {
    "dmc/reacher-easy": ReacherKernel,
    "dmc/reacher-hard": ReacherKernel,
}


def kernel_for(task_id: str) -> Kernel:
    """A fresh kernel for ``task_id``.

    Raises:
        ValueError: a task without a batched kernel (the message lists those that have one).
    """
    factory = KERNELS.get(task_id) if isinstance(task_id, str) else None
    if factory is None:
        raise ValueError(f"`task` must be one of {sorted(KERNELS)} for the batched engine. Received {task_id!r}.")
    return factory()
