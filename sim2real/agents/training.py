"""``train``: PPO and SAC with TorchRL on any task from :func:`sim2real.make`, with or without randomisation.

Determinism: every draw comes from torch's CPU generator seeded with ``seed`` inside
``torch.random.fork_rng`` (so the caller's global torch RNG state is restored afterwards), minibatch
orders from a dedicated ``torch.Generator``, the environment from ``env.set_seed(seed)`` and the
effects from ``sim2real.wrap(..., seed=seed)`` (on the batched engine world ``i`` from ``seed=(seed, i)``).
The same seed, thread count and versions give the same weights; torch does not promise identical float
reductions across thread counts or machines.

Collection: PPO collects from ``PPOConfig.num_envs`` worlds of the batched engine when it supports the task and
effects, else from one TorchRL env (:mod:`sim2real.agents.collect`); ``TrainResult.collection`` records which.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import re
import time
import uuid
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from sim2real.agents.collect import Collection, choose_collection, make_collection_env, make_train_env
from sim2real.agents.config import PPOConfig, SACConfig
from sim2real.agents.loop_utils import env_bounds, log_row, progress_bar, record_row
from sim2real.agents.run_status import RunStatus, mark, status_for, write_run_status

__all__ = ["TrainResult", "make_train_env", "train"]

_LOGGERS = ("csv", "tensorboard", None)


@dataclass(frozen=True)
class TrainResult:
    """What :func:`train` returns.

    Attributes:
        policy: the trained TorchRL actor (``ProbabilisticActor``; ``"observation"`` -> ``"action"``).
        config: the :class:`PPOConfig` or :class:`SACConfig` used.
        metrics: metric name -> one value per collected batch; ``"frames"`` holds the frame count at each
            row, ``"episode_return"`` the mean undiscounted return of episodes finished in that batch
            (NaN when none finished), plus the losses of the algorithm.
        frames: environment steps collected.
        wall_time: seconds spent in :func:`train`.
        run_id: unique id of the run (names the logger folder and is stored in checkpoints).
        seed: the seed.
        task: task id, or None when an env object was given without a gymnasium ``spec``.
        log_dir: folder of the logger's files, or None without a logger.
        effects: the randomisation trained under, as YAML (:func:`sim2real.dump_config`); None without effects.
        adr: the ADR controller's final state as JSON (:meth:`randomizers.ADR.to_json`; its ``history`` has the
            ranges and entropy vs frames), None without ADR.
        collection: how the frames were collected (batched engine and its world count, or per env and why).
    """

    policy: Any
    config: PPOConfig | SACConfig
    metrics: Mapping[str, tuple[float, ...]]
    frames: int
    wall_time: float
    run_id: str
    seed: int
    task: str | None = None
    log_dir: Path | None = field(default=None)
    effects: str | None = None
    adr: str | None = None
    collection: Collection | None = None

    def save(self, path: str | os.PathLike[str]) -> None:
        """Writes a checkpoint (see :func:`~sim2real.agents.save_checkpoint`)."""
        from sim2real.agents.checkpoint import save_checkpoint

        save_checkpoint(
            path, self.policy, self.config, self.seed, self.run_id, task=self.task, effects=self.effects, adr=self.adr
        )


def _task_id(task_or_env: Any) -> str | None:
    if isinstance(task_or_env, str):
        return task_or_env
    spec = getattr(task_or_env, "spec", None)
    return getattr(spec, "id", None) if spec is not None and not callable(spec) else None


def _make_logger(logger: str | None, log_dir: str | os.PathLike[str] | None, run_id: str) -> Any:
    if logger not in _LOGGERS:
        raise ValueError(f"`logger` must be one of {list(_LOGGERS)}. Received {logger!r}.")
    if logger is None:
        return None
    root = str(Path(log_dir) if log_dir is not None else Path("sim2real_runs"))
    if logger == "csv":
        from torchrl.record.loggers import CSVLogger

        return CSVLogger(exp_name=run_id, log_dir=root)
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        raise ValueError(
            "`logger` 'tensorboard' needs the tensorboard package, which is not installed; use 'csv' or None."
        ) from None
    from torchrl.record.loggers import TensorboardLogger

    return TensorboardLogger(exp_name=run_id, log_dir=root)


def _logger_dir(logger: Any) -> Path | None:
    if logger is None:
        return None
    path = getattr(logger, "log_dir", None)
    exp = getattr(logger, "exp_name", None)
    if path is None:
        return None
    return Path(path) / exp if exp is not None and (Path(path) / exp).exists() else Path(path)


def _run_id(algo: str, task: str | None, seed: int) -> str:
    slug = re.sub(r"[^A-Za-z0-9]+", "-", task or "env").strip("-")
    # uuid4 reads os.urandom, so the id is unique without touching any seeded generator.
    return f"{algo}_{slug}_seed{seed}_{time.strftime('%Y%m%d-%H%M%S')}_{uuid.uuid4().hex[:6]}"


def train(
    task_or_env: Any,
    config: PPOConfig | SACConfig,
    *,
    effects: Sequence[Any] = (),
    seed: int = 0,
    progress: bool = True,
    logger: str | None = "csv",
    log_dir: str | os.PathLike[str] | None = None,
    threads: int = 1,
) -> TrainResult:
    """Trains a PPO or SAC policy (chosen by the type of ``config``) with TorchRL.

    Args:
        task_or_env: a task id, a gymnasium env or a TorchRL env (see :func:`make_train_env`).
        config: :class:`PPOConfig` (TorchRL ``ClipPPOLoss`` + ``GAE``; frames collected from ``num_envs`` worlds of
            the batched engine when it supports the task and effects, see :mod:`sim2real.agents.collect`) or
            :class:`SACConfig` (the hand-written update of :mod:`sim2real.agents.sac` on a uniform replay
            buffer; a task id or gymnasium env is then stepped through gymnasium, a TorchRL env through TorchRL).
        effects: physics effects and signal models applied with :func:`sim2real.wrap` (domain randomisation).
        seed: seeds weights, exploration, minibatch order, env and effects.
        progress: show a tqdm bar on stderr.
        logger: ``"csv"`` (TorchRL ``CSVLogger``), ``"tensorboard"`` (needs tensorboard) or None.
        log_dir: root folder of the logger (default ``./sim2real_runs``); the run writes to ``log_dir/run_id``,
            with its status in ``run.json`` (:mod:`sim2real.agents.run_status`): ``"running"``, then
            ``"completed"``, or ``"interrupted"``/``"failed"`` with the frames done when Ctrl-C, a kill or an
            exception ends the run (which is then re-raised as it came, with a note saying where the run is).
        threads: torch intra-op threads while training (restored afterwards). One is the default: these MLPs
            are too small to gain from more, and on a busy machine extra threads spin against other processes
            (2,000 PPO frames took 19.9 s with 2 threads and 6.3 s with 1 on the 2-core CI-sized box).

    Returns:
        A :class:`TrainResult`.

    Raises:
        TypeError: ``config`` is not a PPO/SAC config, or an unsupported env.
        ValueError: a bad ``seed``, ``logger`` or task id.
    """
    import torch

    if not isinstance(config, (PPOConfig, SACConfig)):
        raise TypeError(f"`config` must be a PPOConfig or SACConfig. Received {type(config).__name__}.")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"`seed` must be an int >= 0. Received {seed!r}.")
    task = _task_id(task_or_env)
    run_id = _run_id(config.algo, task, seed)
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"`threads` must be an int >= 1. Received {threads!r}.")
    from sim2real.agents.adr_training import log_adr, with_adr

    plain, adr = with_adr(effects, config)  # an ADR in effects, or config.adr; logged with every batch
    effects = [*plain, adr] if adr is not None else plain
    if adr is not None:  # a success metric on a task without success: refused now, not after a batch (any engine)
        from sim2real.batched.adr import check_task_metric

        check_task_metric(adr, task_or_env)
    from sim2real.agents.sac_loop import steps_directly

    collection = (
        choose_collection(task_or_env, effects, config)
        if isinstance(config, PPOConfig)
        else Collection(
            "per-env",
            1,
            "SAC steps one env (its run is update-bound; see sim2real.agents.collect)",
            env="gymnasium" if steps_directly(task_or_env) else "TorchRL",  # what train_sac steps below
        )
    )
    log = _make_logger(logger, log_dir, run_id)
    if log is not None:
        log.log_hparams(
            {**config.to_dict(), "seed": seed, "task": task or "", "run_id": run_id,
             "collection": str(collection), "collection_engine": collection.engine,
             "collection_num_envs": collection.num_envs}
        )  # fmt: skip
    folder = _logger_dir(log)
    if folder is not None and folder.name != run_id:  # never a status in a folder other runs share
        folder = None
    # The folder's run.json says "running" until the run ends, then how it ended (see run_status).
    run = RunStatus("running", run_id, config.algo, task, seed, config.frames, 0)
    if folder is not None:
        write_run_status(folder, run)
    log = log_adr(log, adr)
    start = time.perf_counter()
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(threads)
    rows: list[dict[str, float]] = []  # filled batch by batch: what was done when the run is cut short
    try:
        with contextlib.ExitStack() as stack:
            stack.callback(torch.set_num_threads, previous_threads)
            stack.enter_context(torch.random.fork_rng(devices=[]))
            torch.manual_seed(seed)
            if isinstance(config, SACConfig):
                from sim2real.agents.sac_loop import train_sac

                # A task id or gymnasium env is stepped through gymnasium; any other env through TorchRL.
                source = task_or_env if steps_directly(task_or_env) else make_train_env(task_or_env, effects, seed)
                policy, rows, frames = train_sac(
                    source, config, effects=effects, seed=seed, progress=progress, log=log, rows=rows
                )
            else:
                env = make_collection_env(task_or_env, effects, seed, collection)
                try:
                    policy, rows, frames = _train_ppo(env, config, seed, progress, log, adr, rows=rows)
                finally:
                    env.close()
    except BaseException as err:  # Ctrl-C, a kill (the CLI's Interrupted) or an error: marked, then raised as before
        if folder is not None:
            status, signal, error = status_for(err)
            done = int(rows[-1]["frames"]) if rows else 0
            run = dataclasses.replace(run, status=status, frames=done, signal=signal, error=error)
            try:
                write_run_status(folder, run)
            except OSError as failed:  # the run's own error is the one to raise
                err.add_note(f"sim2real: could not mark the run {run.status} in {str(folder)!r}: {failed}")
            else:
                mark(err, folder, run)
        raise
    if folder is not None:
        try:
            write_run_status(folder, dataclasses.replace(run, status="completed", frames=frames))
        except OSError as failed:  # the trained policy is still returned (and saved by the caller)
            warnings.warn(f"could not mark the run completed in {str(folder)!r}: {failed}", stacklevel=2)
    wall = time.perf_counter() - start
    names = sorted({k for row in rows for k in row}, key=lambda k: (k != "frames", k))
    metrics = MappingProxyType({k: tuple(float(row.get(k, math.nan)) for row in rows) for k in names})
    return TrainResult(
        policy=policy,
        config=config,
        metrics=metrics,
        frames=frames,
        wall_time=wall,
        run_id=run_id,
        seed=seed,
        task=task,
        log_dir=_logger_dir(log),
        effects=_effects_text(plain),
        adr=None if adr is None else adr.to_json(),
        collection=collection,
    )


def _effects_text(effects: Sequence[Any]) -> str | None:
    from sim2real.wrapping import _flatten

    flat = _flatten(effects)
    if not flat:
        return None
    from randomizers import dump_config

    return dump_config(flat)


_bounds = env_bounds


def _fit_normalizer(env: Any, norm: Any, frames: int) -> None:
    import torch

    if frames <= 0:
        return
    # Uniform random actions (drawn from torch's forked, seeded generator); the env is reset again by the
    # collector afterwards, so these steps only fix the input statistics. N batched worlds take frames / N each.
    rollout = env.rollout(_steps_per_world(env, frames), break_when_any_done=False)
    obs = rollout["observation"].reshape(-1, rollout["observation"].shape[-1]).to(torch.float32)
    norm.set_stats(obs.mean(0), obs.std(0).clamp_min(0.01))


def _behaviour_cloning(env: Any, actor: Any, cfg: PPOConfig, low: list[float], high: list[float]) -> None:
    """Warm start: regresses the actor's deterministic action on a scripted baseline's actions, recorded on the
    training env (so under its randomisation, noise and latency)."""
    import numpy as np
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from sim2real.agents.baselines import BASELINES

    # Only called with bc_frames > 0, which PPOConfig refuses without a bc_baseline.
    assert cfg.bc_baseline is not None
    teacher = {cls.__name__: cls for cls in BASELINES.values()}[cfg.bc_baseline]()

    def act(td: Any) -> Any:
        obs = td["observation"].detach().cpu().numpy()
        td["action"] = torch.as_tensor(np.asarray(teacher(obs), dtype=np.float32))
        return td

    data = env.rollout(_steps_per_world(env, cfg.bc_frames), act, break_when_any_done=False)
    obs = data["observation"].reshape(-1, data["observation"].shape[-1]).to(torch.float32)
    lo, hi = torch.as_tensor(low), torch.as_tensor(high)
    mid, half = (hi + lo) / 2, (hi - lo) / 2
    # Targets kept inside the tanh's range so the regression never chases an infinite pre-activation.
    target = (mid + half * ((data["action"].reshape(obs.shape[0], -1) - mid) / half).clamp(-0.97, 0.97)).float()
    params = [p for p in actor.parameters() if p.requires_grad]
    optim = torch.optim.Adam(params, lr=1e-3)
    order_gen = torch.Generator().manual_seed(int(torch.initial_seed()) % (2**31))
    batch = 256
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(cfg.bc_epochs):
            order = torch.randperm(obs.shape[0], generator=order_gen)
            for start in range(0, obs.shape[0], batch):
                idx = order[start : start + batch]
                out = actor(_td(obs[idx]))
                loss = ((out["action"] - target[idx]) ** 2).mean()
                optim.zero_grad()
                loss.backward()
                optim.step()


def _steps_per_world(env: Any, frames: int) -> int:
    """Steps of ``env`` that give at least ``frames`` frames (one per world of a batched env)."""
    return -(-frames // max(1, int(env.batch_size.numel())))


def _td(obs: Any) -> Any:
    from tensordict import TensorDict

    return TensorDict({"observation": obs}, batch_size=[obs.shape[0]])


def _episode_stats(data: Any) -> dict[str, float]:
    import torch

    done = data["next", "done"]
    returns = data["next", "episode_reward"][done]
    row = {"reward": float(data["next", "reward"].mean())}
    row["episode_return"] = float(returns.mean()) if returns.numel() else math.nan
    row["episodes"] = float(int(torch.count_nonzero(done)))
    return row


_bar = progress_bar
_log = log_row


def _train_ppo(
    env: Any,
    cfg: PPOConfig,
    seed: int,
    progress: bool,
    log: Any,
    adr: Any = None,
    rows: list[dict[str, float]] | None = None,
) -> tuple[Any, list[dict], int]:
    """Trains a PPO actor on ``env``; returns ``(actor, metric rows, frames)``. The rows are appended to ``rows``
    when given, batch by batch, so a caller knows how far an interrupted run got."""
    import torch
    from torchrl.collectors import Collector
    from torchrl.objectives import ClipPPOLoss
    from torchrl.objectives.value import GAE

    from sim2real.agents.nets import actor_normalizer, build_actor, build_critic

    obs_dim, _, low, high = _bounds(env)
    actor = build_actor("ppo", obs_dim, low, high, cfg.hidden_sizes, cfg.activation, cfg.init_log_std)
    norm = actor_normalizer(actor)
    # Random actions and a scripted teacher are not the policy: ADR learns nothing from their episodes.
    with adr.paused() if adr is not None else contextlib.nullcontext():
        _fit_normalizer(env, norm, cfg.obs_norm_frames)
        if cfg.bc_frames > 0:
            _behaviour_cloning(env, actor, cfg, low, high)
    critic = build_critic(obs_dim, cfg.hidden_sizes, cfg.activation, norm)
    advantage = GAE(gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=critic, average_gae=False)
    loss_module = ClipPPOLoss(
        actor,
        critic,
        clip_epsilon=cfg.clip_epsilon,
        entropy_bonus=cfg.entropy_coef > 0,
        entropy_coeff=cfg.entropy_coef,
        critic_coeff=cfg.critic_coef,
        normalize_advantage=True,
    )
    optim = torch.optim.Adam(loss_module.parameters(), lr=cfg.lr)
    shuffle = torch.Generator().manual_seed(seed)
    with warnings.catch_warnings():  # whole batches: `sim2real train` says how many frames that makes, once
        warnings.filterwarnings(
            "ignore", message=r"total_frames \(\d+\) is not exactly divisible", category=UserWarning
        )
        collector = Collector(
            env,
            actor,
            frames_per_batch=cfg.frames_per_batch,
            total_frames=cfg.frames,
            auto_register_policy_transforms=False,
        )
    rows = [] if rows is None else rows
    frames = 0
    try:
        with _bar(cfg.frames, progress, "ppo") as bar:
            for data in collector:
                # A batched env gives (N, T): GAE runs along each world's own time axis, minibatches over all.
                n = data.numel()
                frames += n
                row = {"frames": float(frames), **_episode_stats(data)}
                if cfg.reward_scale != 1.0:
                    data["next", "reward"] = data["next", "reward"] * cfg.reward_scale
                sums = {"loss_objective": 0.0, "loss_critic": 0.0, "loss_entropy": 0.0}
                steps = 0
                for _ in range(cfg.epochs):
                    with torch.no_grad():
                        advantage(data)
                    flat = data.reshape(-1)
                    order = torch.randperm(n, generator=shuffle)
                    for start in range(0, n - cfg.minibatch_size + 1, cfg.minibatch_size):
                        batch = flat[order[start : start + cfg.minibatch_size]]
                        out = loss_module(batch)
                        total = out["loss_objective"] + out["loss_critic"]
                        if "loss_entropy" in out.keys():  # noqa: SIM118 - TensorDict has no `in`
                            total = total + out["loss_entropy"]
                        optim.zero_grad()
                        total.backward()
                        torch.nn.utils.clip_grad_norm_(loss_module.parameters(), cfg.max_grad_norm)
                        optim.step()
                        for key in sums:
                            if key in out.keys():  # noqa: SIM118
                                sums[key] += float(out[key].detach())
                        steps += 1
                row.update({k: v / max(steps, 1) for k, v in sums.items()})
                collector.update_policy_weights_()
                record_row(rows, log, row, frames)
                bar.update(n)
                if math.isfinite(row["episode_return"]):
                    bar.set_postfix(ret=f"{row['episode_return']:.2f}")
    finally:
        collector.shutdown()
    return actor, rows, frames
