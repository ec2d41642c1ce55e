"""The batched engine as a gymnasium ``VectorEnv``: :class:`BatchedVectorEnv`.

Autoreset follows gymnasium 1.x's default ``next-step`` mode: a world whose episode ended in step ``t``
returns its final observation there, and is reset in step ``t + 1`` (that world's action is ignored, its
reward is 0 and ``terminated``/``truncated`` are False). Draws are reported when they change, at reset and
in the step that autoresets, as ``info["sim2real"]["params"]`` (address -> ``(N,)`` values) with the mask of
the worlds that were reset (``info["sim2real"]["reset"]``), never merged on every step.

Example:
    >>> import numpy as np
    >>> import sim2real as s2r
    >>> from sim2real.batched import BatchedVectorEnv
    >>> envs = BatchedVectorEnv("dmc/reacher-easy", 2, s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), seed=0)
    >>> obs, info = envs.reset(seed=0)
    >>> obs.shape, info["sim2real"]["params"]["dof_damping[shoulder]"].shape
    ((2, 6), (2,))
    >>> obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    >>> reward.dtype, truncated.shape
    (dtype('float64'), (2,))
    >>> envs.close()
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from sim2real.batched.engine import BatchedEnv

__all__ = ["BatchedVectorEnv"]


class BatchedVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` batched worlds of ``task`` behind gymnasium's ``VectorEnv`` API (next-step autoreset).

    Args:
        task: a task id with a batched kernel, or ``"model:<path>"`` (an MJCF file).
        num_envs: worlds N.
        *effects: physics effects drawn per episode.
        seed: root seed; world ``i`` is the single env ``wrap(make(task), *effects, seed=(seed, i))``.
        **options: keyword arguments for :func:`sim2real.make`.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}  # noqa: RUF012 - gymnasium API

    def __init__(self, task: str, num_envs: int, *effects: Any, seed: int = 0, **options: Any) -> None:
        self.engine = BatchedEnv(task, num_envs, effects, seed=seed, **options)
        single = self.engine.envs[0]
        self.num_envs = self.engine.num_envs
        self.single_observation_space = single.observation_space
        self.single_action_space = single.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._autoreset = np.zeros(self.num_envs, bool)
        self._started = False

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Resets every world; ``seed`` is None, an int (world ``i`` gets ``seed + i``) or one per world."""
        if options:
            raise ValueError(f"`options` is not supported by BatchedVectorEnv. Received {options!r}.")
        obs, params = self.engine.reset(seed=seed)
        self._autoreset[:] = False
        self._started = True
        return obs, {"sim2real": {"params": params, "reset": np.ones(self.num_envs, bool)}}

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One step of every world; worlds that ended in the previous step are reset instead."""
        if not self._started:
            raise RuntimeError("BatchedVectorEnv.step() called before reset().")
        reset = self._autoreset.copy()
        obs, reward, terminated, truncated, diverged = self.engine.step(actions, mask=~reset)
        info: dict[str, Any] = {}
        if reset.any():
            obs, params = self.engine.reset(indices=np.flatnonzero(reset))
            info["sim2real"] = {"params": params, "reset": reset}
        if diverged.any():
            info.setdefault("sim2real", {})["diverged"] = diverged
        self._autoreset = terminated | truncated
        return obs, reward, terminated, truncated, info

    def close_extras(self, **kwargs: Any) -> None:
        self.engine.close()
