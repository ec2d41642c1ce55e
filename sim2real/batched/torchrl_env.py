"""The batched engine as a TorchRL environment: :class:`BatchedTorchRLEnv` (``batch_size=[N]``).

One ``EnvBase`` holds all N worlds: a step is one engine step (no per-env TorchRL plumbing), a partial reset
(``"_reset"``) resets only the worlds asked for. Keys: ``"observation"`` (float32, the single env's values),
``"reward"`` (float32; reacher's 0/1 rewards are exact), ``"done"``/``"terminated"``/``"truncated"``, and the
episode's draws under ``"sim2real_params"`` (float64, one entry per :attr:`BatchedTorchRLEnv.param_names`) and
``"sim2real_diverged"``, as :class:`~sim2real.wrappers.RandomizePhysicsTransform` reports them.

Example:
    >>> import sim2real as s2r
    >>> from torchrl.envs.utils import check_env_specs
    >>> env = BatchedTorchRLEnv("dmc/reacher-easy", 4, s2r.Mass(scale=s2r.Uniform(0.8, 1.2)), seed=0)
    >>> check_env_specs(env, seed=0)
    >>> td = env.rollout(5)
    >>> td.batch_size, td["next", "reward"].shape, env.param_names[0]
    (torch.Size([4, 5]), torch.Size([4, 5, 1]), 'body_mass[arm]')
    >>> env.close()
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from sim2real.batched.engine import BatchedEnv, _is_seed

__all__ = ["BatchedTorchRLEnv"]

PARAMS_KEY = "sim2real_params"
DIVERGED_KEY = "sim2real_diverged"


class BatchedTorchRLEnv(EnvBase):
    """``num_envs`` batched worlds of ``task`` as one TorchRL env with ``batch_size=[num_envs]``.

    Args:
        task: a task id with a batched kernel, or ``"model:<path>"`` (an MJCF file).
        num_envs: worlds N.
        *effects: physics effects drawn per episode.
        seed: root seed; world ``i`` is the single env ``wrap(make(task), *effects, seed=(seed, i))``.
        device: the TensorDicts' device.
        **options: keyword arguments for :func:`sim2real.make`.
    """

    def __init__(
        self, task: str, num_envs: int, *effects: Any, seed: int = 0, device: Any = "cpu", **options: Any
    ) -> None:
        self.engine = BatchedEnv(task, num_envs, effects, seed=seed, **options)
        n = self.engine.num_envs
        super().__init__(device=device, batch_size=torch.Size([n]))
        single = self.engine.envs[0]
        space = single.action_space
        self.param_names: tuple[str, ...] = self._param_names(single)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(n, self.engine.observation_dim), dtype=torch.float32, device=self.device),
            **{
                PARAMS_KEY: Unbounded(shape=(n, len(self.param_names)), dtype=torch.float64, device=self.device),
                DIVERGED_KEY: Categorical(2, shape=(n, 1), dtype=torch.bool, device=self.device),
            },
            shape=(n,),
            device=self.device,
        )
        self.action_spec = Bounded(
            low=torch.as_tensor(np.broadcast_to(space.low, (n, *space.shape)).copy()),
            high=torch.as_tensor(np.broadcast_to(space.high, (n, *space.shape)).copy()),
            shape=(n, *space.shape),
            dtype=torch.float32,
            device=self.device,
        )
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32, device=self.device)
        self.done_spec = Composite(
            done=Categorical(2, shape=(n, 1), dtype=torch.bool, device=self.device),
            terminated=Categorical(2, shape=(n, 1), dtype=torch.bool, device=self.device),
            truncated=Categorical(2, shape=(n, 1), dtype=torch.bool, device=self.device),
            shape=(n,),
            device=self.device,
        )
        self._reset_seed: int | None = None
        self._diverged = np.zeros(n, bool)
        self._on_cpu = self.device is None or torch.device(self.device).type == "cpu"
        self._params_tensor = self._params({})  # the draws in use: rebuilt at every reset, shared by the steps

    @staticmethod
    def _param_names(single: Any) -> tuple[str, ...]:
        """Every address and signal parameter a world reports, known before the first reset: the physics ones from
        the nominal model, the signal ones from a throwaway draw of a copy of world 0's corruptor (the worlds'
        own streams are not touched)."""
        corruptor = getattr(single, "corruptor", None)
        # Two layers (CorruptSignals around the physics layer) or one fused layer that has both.
        physics = single if corruptor is None or hasattr(single, "randomizer") else single.env
        randomizer = getattr(physics, "randomizer", None)  # None: signal models alone, no physics addresses
        names = list(randomizer.nominal_params()) if randomizer is not None else []
        if corruptor is not None:
            probe = copy.deepcopy(corruptor)
            probe.begin_episode(seed=0)
            names += [name for name in probe.current_params if name not in names]
        return tuple(names)

    def _params(self, params: dict[str, np.ndarray]) -> torch.Tensor:
        n = self.engine.num_envs
        columns = [params.get(name, np.full(n, np.nan)) for name in self.param_names]
        values = np.stack(columns, axis=1) if columns else np.zeros((n, 0))
        return torch.as_tensor(values, dtype=torch.float64, device=self.device)

    def _tensor(self, array: np.ndarray) -> torch.Tensor:
        """A fresh numpy array as a tensor on the env's device (shared memory on the CPU: no copy)."""
        tensor = torch.from_numpy(array)
        return tensor if self._on_cpu else tensor.to(self.device)

    def _out(
        self, obs: np.ndarray, terminated: np.ndarray, truncated: np.ndarray, reward: np.ndarray | None
    ) -> TensorDictBase:
        # Every array here is fresh (the engine returns copies), so the tensors share its memory; the shapes are
        # the specs' already, so nothing is reshaped (EnvBase's per-step spec lookups are skipped, _step_proc_data).
        n = self.engine.num_envs
        out = {
            "observation": self._tensor(obs),
            "terminated": self._tensor(terminated.reshape(n, 1)),
            "truncated": self._tensor(truncated.reshape(n, 1)),
            "done": self._tensor((terminated | truncated).reshape(n, 1)),
            PARAMS_KEY: self._params_tensor,
            DIVERGED_KEY: self._tensor(self._diverged.reshape(n, 1).copy()),
        }
        if reward is not None:
            out["reward"] = self._tensor(reward.astype(np.float32).reshape(n, 1))
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _step_proc_data(self, next_tensordict_out: TensorDictBase) -> TensorDictBase:
        # EnvBase reshapes rewards to the spec and fills missing done keys here, looking specs up on every step;
        # _out emits every done key and the reward in their spec shapes, so only the optional type checks remain.
        if self.run_type_checks:
            return super()._step_proc_data(next_tensordict_out)
        return next_tensordict_out

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        n = self.engine.num_envs
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is not None and not bool(mask.all()):
            indices = np.flatnonzero(mask.reshape(n).cpu().numpy())
            obs, _ = self.engine.reset(indices=indices)
            self._diverged[indices] = False
        else:
            seed, self._reset_seed = self._reset_seed, None
            obs, _ = self.engine.reset(seed=seed)
            self._diverged[:] = False
        self._params_tensor = self._params(self.engine.params)
        none = np.zeros(n, bool)
        return self._out(obs, none, none, None)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get("action").detach().cpu().numpy()
        obs, reward, terminated, truncated, diverged = self.engine.step(actions)
        np.logical_or(self._diverged, diverged, out=self._diverged)  # in place: EnvBase.__setattr__ costs ~10 us
        return self._out(obs, terminated, truncated, reward)

    def _set_seed(self, seed: int | None) -> None:
        # The next full reset seeds world i with seed + i (gymnasium's vector convention, as BatchedEnv.reset).
        if seed is not None and not _is_seed(seed):
            raise ValueError(f"`seed` must be None or an int >= 0. Received {seed!r} ({type(seed).__name__}).")
        self._reset_seed = None if seed is None else int(seed)

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Closes the worlds (their models are restored to nominal)."""
        self.engine.close()
        super().close(raise_if_closed=raise_if_closed)
