"""The SAC training loop: steps the env directly (one transition at a time, no collector, no TensorDict for a
gymnasium env), fills :class:`~sim2real.agents.sac.ReplayBuffer` and runs :class:`~sim2real.agents.sac.SACUpdate`.

A task id or a gymnasium env is stepped through gymnasium (``sim2real.wrap`` applies the effects there), which
costs ~20 us a step instead of ~0.4 ms through a TorchRL env; a TorchRL env given by the user is stepped through
TorchRL. Random actions of the warm-up are drawn as one tensor from torch's seeded generator (TorchRL's
``rand_step`` asks ``importlib.util.find_spec("pandas")`` on every call, inside ``TensorDict.from_any``).

Example:
    >>> from sim2real.agents import SACConfig
    >>> cfg = SACConfig(frames=200, frames_per_batch=100, init_random_frames=100, batch_size=32,
    ...                 hidden_sizes=(16,), obs_norm_frames=50)
    >>> actor, rows, frames = train_sac("sim2real/arm-reach", cfg, effects=(), seed=0, progress=False, log=None)
    >>> frames, [int(r["frames"]) for r in rows], "loss_qvalue" in rows[-1]
    (200, [100, 200], True)
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from sim2real.agents.config import SACConfig
from sim2real.agents.loop_utils import env_bounds, progress_bar, record_row
from sim2real.agents.sac import LOSS_KEYS, NStepWriter, ReplayBuffer, SACUpdate

__all__ = ["train_sac"]


class _GymSteps:
    """A gymnasium env seen as ``reset() -> obs`` and ``step(action) -> (obs, reward, terminated, truncated)``."""

    def __init__(self, env: Any, seed: int) -> None:
        import gymnasium as gym

        self.env = env
        self._seed: int | None = seed
        obs_space, act_space = env.observation_space, env.action_space
        if not isinstance(obs_space, gym.spaces.Box) or len(obs_space.shape) != 1:
            raise TypeError(
                "`task_or_env` must give one flat `observation` vector (use flatten=True for dm-control). "
                f"Received observation space {obs_space}."
            )
        if (
            not isinstance(act_space, gym.spaces.Box)
            or not np.all(np.isfinite(act_space.low))
            or not np.all(np.isfinite(act_space.high))
        ):
            raise TypeError(f"the env's action space must be a bounded Box. Received {act_space}.")
        self.obs_dim = int(obs_space.shape[0])
        self.low = [float(v) for v in np.ravel(act_space.low)]
        self.high = [float(v) for v in np.ravel(act_space.high)]
        self._dtype = act_space.dtype

    def reset(self) -> np.ndarray:
        obs, _ = self.env.reset(seed=self._seed) if self._seed is not None else self.env.reset()
        self._seed = None  # seeded once; later resets continue the env's own generator
        return np.asarray(obs, dtype=np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        obs, reward, terminated, truncated, _ = self.env.step(action.astype(self._dtype, copy=False))
        return np.asarray(obs, dtype=np.float32), float(reward), bool(terminated), bool(truncated)

    def close(self) -> None:
        self.env.close()


class _TorchRLSteps:
    """The same interface over a TorchRL env (built by :func:`~sim2real.agents.collect.make_train_env`)."""

    def __init__(self, env: Any) -> None:
        self.env = env
        self.obs_dim, _, self.low, self.high = env_bounds(env)
        self._td: Any = None

    def reset(self) -> np.ndarray:
        self._td = self.env.reset()
        return self._td["observation"].numpy().astype(np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        from torchrl.envs.utils import step_mdp

        self._td.set("action", torch.as_tensor(action, dtype=torch.float32))
        out = self.env.step(self._td)
        nxt = out["next"]
        done = bool(nxt["done"].any())
        terminated = bool(nxt.get("terminated", nxt["done"]).any())
        obs = nxt["observation"].numpy().astype(np.float32)
        reward = float(nxt["reward"].sum())
        self._td = step_mdp(out)
        return obs, reward, terminated, done and not terminated

    def close(self) -> None:
        self.env.close()


def steps_directly(task_or_env: Any) -> bool:
    """Whether :func:`train_sac` steps ``task_or_env`` through gymnasium (a task id or a gymnasium env)."""
    import gymnasium as gym

    return isinstance(task_or_env, (str, gym.Env))


def _steps(task_or_env: Any, effects: Sequence[Any], seed: int) -> _GymSteps | _TorchRLSteps:
    import sim2real

    if steps_directly(task_or_env):
        env = sim2real.make(task_or_env) if isinstance(task_or_env, str) else task_or_env
        if effects:
            env = sim2real.wrap(env, *effects, seed=seed)
        return _GymSteps(env, seed)
    return _TorchRLSteps(task_or_env)


def train_sac(
    task_or_env: Any,
    cfg: SACConfig,
    *,
    effects: Sequence[Any],
    seed: int,
    progress: bool,
    log: Any,
    rows: list[dict[str, float]] | None = None,
) -> tuple[Any, list[dict[str, float]], int]:
    """Trains a SAC actor; returns ``(actor, metric rows, frames)`` (see :func:`~sim2real.agents.train`). The rows
    are appended to ``rows`` when given, batch by batch, so a caller knows how far an interrupted run got.

    ``task_or_env`` is a task id or gymnasium env (``effects`` are applied here with ``sim2real.wrap``) or a TorchRL
    env already built by :func:`~sim2real.agents.make_train_env` (effects applied; ``effects`` is then ignored).

    Each row covers ``cfg.frames_per_batch`` env steps followed by ``round(utd_ratio * frames_per_batch)`` updates
    (once ``init_random_frames`` steps and one batch are stored).
    """
    from sim2real.agents.nets import actor_normalizer, build_actor, build_qvalue

    steps = _steps(task_or_env, effects, seed)
    try:
        act_dim = len(steps.low)
        actor = build_actor("sac", steps.obs_dim, steps.low, steps.high, cfg.hidden_sizes, cfg.activation,
                            cfg.init_log_std, cfg.angle_obs)  # fmt: skip
        norm = actor_normalizer(actor)
        from sim2real.batched.adr import adr_of

        adr = adr_of(effects)
        with adr.paused() if adr is not None else contextlib.nullcontext():  # random actions: not the policy's
            _fit_normalizer(steps, norm, cfg.obs_norm_frames, act_dim)
        qvalues = [build_qvalue(steps.obs_dim, act_dim, cfg.hidden_sizes, cfg.activation, norm) for _ in range(2)]
        update = SACUpdate(actor, qvalues, lr=cfg.lr, gamma=cfg.gamma, tau=cfg.tau, alpha_init=cfg.alpha_init,
                           target_entropy=cfg.target_entropy)  # fmt: skip
        buffer = ReplayBuffer(min(cfg.buffer_size, cfg.frames), steps.obs_dim, act_dim, seed)
        writer = NStepWriter(buffer, cfg.n_step, cfg.gamma)
        explore = _explorer(update, act_dim)
        mean_action = _mean_actor(update)
        every = cfg.mean_action_every
        episode = 0  # index of the episode being collected (0-based, warm-up episodes included)
        mid = (np.asarray(steps.high) + np.asarray(steps.low)) / 2
        half = (np.asarray(steps.high) - np.asarray(steps.low)) / 2
        updates = max(1, round(cfg.utd_ratio * cfg.frames_per_batch))
        rows = [] if rows is None else rows
        frames = 0
        obs = steps.reset()
        episode_return = 0.0
        held = 0  # environment steps left on the current decision (cfg.action_repeat)
        a_np = env_action = decision_obs = np.zeros(0)
        decision_reward = 0.0
        with progress_bar(cfg.frames, progress, "sac") as bar:
            while frames < cfg.frames:
                n = min(cfg.frames_per_batch, cfg.frames - frames)
                rewards = np.empty(n)
                finished: list[float] = []
                for i in range(n):
                    if held == 0:  # a new decision: held for cfg.action_repeat steps
                        if frames + i < cfg.init_random_frames:
                            a_n = torch.rand(act_dim) * 2.0 - 1.0
                        elif every and episode % every == every - 1:
                            a_n = mean_action(obs)
                        else:
                            a_n = explore(obs)
                        a_np = a_n.numpy()
                        env_action = mid + half * a_np
                        decision_obs, decision_reward, held = obs, 0.0, cfg.action_repeat
                    next_obs, reward, terminated, truncated = steps.step(env_action)
                    decision_reward += reward * cfg.reward_scale
                    held -= 1
                    if held == 0 or terminated or truncated:
                        writer.add(decision_obs, a_np, decision_reward, next_obs, terminated, truncated)
                        held = 0
                    rewards[i] = reward
                    episode_return += reward
                    if terminated or truncated:
                        finished.append(episode_return)
                        episode_return = 0.0
                        episode += 1
                        obs = steps.reset()
                    else:
                        obs = next_obs
                frames += n
                row = {
                    "frames": float(frames),
                    "reward": float(rewards.mean()),
                    "episode_return": float(np.mean(finished)) if finished else math.nan,
                    "episodes": float(len(finished)),
                }
                if frames >= cfg.init_random_frames and len(buffer) >= cfg.batch_size:
                    total = torch.zeros(len(LOSS_KEYS))
                    for _ in range(updates):
                        total += update.step(*buffer.sample(cfg.batch_size))
                    row.update(zip(LOSS_KEYS, (total / updates).tolist(), strict=True))
                record_row(rows, log, row, frames)
                bar.update(n)
                if finished:
                    bar.set_postfix(ret=f"{row['episode_return']:.2f}")
    finally:
        steps.close()
    return actor, rows, frames


def _explorer(update: SACUpdate, act_dim: int) -> Callable[[np.ndarray], torch.Tensor]:
    """A sample of the current policy in the normalised box for one observation."""

    def act(obs: np.ndarray) -> torch.Tensor:
        with torch.no_grad():
            loc, scale = update.extractor(update.mlp(update.norm(torch.from_numpy(obs))))
            return torch.tanh(loc + scale * torch.randn(act_dim))

    return act


def _mean_actor(update: SACUpdate) -> Callable[[np.ndarray], torch.Tensor]:
    """The current policy's mean action (what a deterministic evaluation plays) in the normalised box."""

    def act(obs: np.ndarray) -> torch.Tensor:
        with torch.no_grad():
            loc, _ = update.extractor(update.mlp(update.norm(torch.from_numpy(obs))))
            return torch.tanh(loc)

    return act


def _fit_normalizer(steps: _GymSteps | _TorchRLSteps, norm: Any, frames: int, act_dim: int) -> None:
    """Sets the input normaliser from ``frames`` uniform-random steps (not counted as training frames)."""
    if frames <= 0:
        return
    mid = (np.asarray(steps.high) + np.asarray(steps.low)) / 2
    half = (np.asarray(steps.high) - np.asarray(steps.low)) / 2
    actions = (torch.rand(frames, act_dim) * 2.0 - 1.0).numpy()
    seen = np.empty((frames, steps.obs_dim), dtype=np.float32)
    obs = steps.reset()
    for i in range(frames):
        seen[i] = obs
        obs, _, terminated, truncated = steps.step(mid + half * actions[i])
        if terminated or truncated:
            obs = steps.reset()
    data = torch.from_numpy(seen)
    norm.set_stats(data.mean(0), data.std(0).clamp_min(0.01))
