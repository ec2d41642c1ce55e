"""Batched closed-loop evaluation: policies scored on sim, randomised sim, a "real" target and sweeps.

A *condition* is one way of building the environment: the nominal sim, a randomised sim (a config), the
"real" target (a twin with held-out parameters, noise and latency, or measured real-robot returns from
a CSV), a point of a one-parameter sweep or of a two-parameter grid. :func:`evaluate` runs every policy
on every condition for the same ``episodes``; many envs (one parameter sample each) are stepped
together with one batched policy call per control step.

Seeding: episode ``e`` is reset with :func:`episode_seed` ``(seed, e)`` in *every* condition and for
*every* policy, and each effect draws from streams keyed by that seed. So row ``e`` of every result is
the same initial state (common random numbers): gaps between simulated conditions and differences
between policies are paired, and any single (policy, condition, episode) can be replayed alone.
Results do not depend on the batch size, the backend or the number of workers.

The conditions and their builders live in :mod:`sim2real.conditions` and the result object in
:mod:`sim2real.evaluation_results`; both are re-exported here, so ``sim2real.evaluation.Condition`` and
``from sim2real.evaluation import nominal, Evaluation`` keep working.

Example:
    >>> import sim2real as s2r
    >>> from sim2real.evaluation import evaluate, nominal, randomized, sweep
    >>> from sim2real.agents import ReachController
    >>> conditions = [nominal(), randomized([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))]),
    ...               *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 1.0])]
    >>> result = evaluate({"reach": ReachController()}, "sim2real/arm-reach", conditions,
    ...                   episodes=2, seed=0, max_steps=20)
    >>> [c.name for c in result.conditions]
    ['sim', 'randomized', 'ActuatorGain.scale=0.5', 'ActuatorGain.scale=1']
    >>> result.returns["reach"]["sim"].shape
    (2,)
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim2real.conditions import CONDITION_KINDS, Condition, _freeze, grid, measured, nominal, randomized, real, sweep

# Names that moved to sim2real.conditions and are still imported from here (sim2real.spec, sim2real.study).
from sim2real.conditions import FrozenMap as FrozenMap
from sim2real.conditions import _default_nominal as _default_nominal
from sim2real.conditions import axis_values as axis_values
from sim2real.evaluation_results import Evaluation, _nested

__all__ = [
    "CONDITION_KINDS",
    "Condition",
    "Evaluation",
    "episode_seed",
    "evaluate",
    "grid",
    "measured",
    "nominal",
    "randomized",
    "real",
    "sweep",
]


# ----------------------------------------------------------------------------------------------- engine


def episode_seed(seed: int, episode: int) -> int:
    """The reset seed of episode ``episode`` (a uint32), the same in every condition and for every policy.

    Example:
        >>> episode_seed(0, 0) == episode_seed(0, 0) != episode_seed(0, 1)
        True
    """
    return int(np.random.SeedSequence([int(seed), int(episode)]).generate_state(1)[0])


@dataclass(frozen=True)
class _Job:
    task: str
    options: Mapping[str, Any]
    conditions: tuple[Condition, ...]  # all with the same calibration params: they share the base envs
    policies: tuple[tuple[str, Any], ...]
    first: int
    count: int
    seed: int
    max_steps: int | None
    engine: str = "auto"
    safety: Any = None  # a sim2real.safety.SafetyLimits: measure the envelope quantities of every episode
    chunks: int = 1  # runs of `count` episodes each: first, first + count, ... (a one-condition group's are paired)


@dataclass(frozen=True)
class _JobResult:
    condition: str
    first: int
    returns: dict[str, np.ndarray]
    lengths: dict[str, np.ndarray]
    successes: dict[str, np.ndarray]
    draws: dict[str, np.ndarray]
    steps: int
    engine: str = "per-env"
    safety: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # policy -> quantity -> (count,)
    reason: str | None = None  # why a per-env run did not use the batched engine


#: Conditions per job: a job builds its envs once and reuses them for each of its conditions.
_CONDITIONS_PER_JOB = 6
#: Batched conditions a job steps side by side (one policy call acts for all of them). Wider is not faster: MuJoCo's
#: stepping of a 32-world reacher batch costs 1.0x / 1.2x / 1.5x its time alone with 2 / 3 / 6 batches interleaved
#: (the worlds' data no longer stay in the caches), which eats what the fewer policy calls save.
_LOCKSTEP = 2


def _observation(obs: Any, task: str) -> np.ndarray:
    arr = np.asarray(obs)
    if arr.dtype == object or arr.ndim != 1:
        raise TypeError(
            f"evaluation needs flat vector observations; task {task!r} gives {type(obs).__name__} "
            f"of shape {getattr(arr, 'shape', None)} (use flatten=True)."
        )
    return arr


def _release(env: Any, base: Any) -> None:
    """Peels sim2real's wrappers off ``env`` down to ``base``, restoring its nominal model."""
    while env is not base and hasattr(env, "release"):
        env = env.release()


def _run_job(job: _Job) -> list[_JobResult]:
    """Runs ``job.count`` episodes of every policy on each of the job's conditions. The conditions the batched
    engine supports run together, in lockstep (:func:`_lockstep_episodes`); the others one after another on
    shared envs stepped one by one."""
    from sim2real.agents.policy import as_policy
    from sim2real.tasks import headless_options

    n = job.count
    # Nothing here renders: build headless where the physics is the same (reacher's skybox was most of a build).
    options = headless_options(job.task, job.options, [cond.effects for cond in job.conditions])
    firsts = [job.first + c * n for c in range(job.chunks)]
    seeds = {f: [episode_seed(job.seed, f + i) for i in range(n)] for f in firsts}
    policies = [(name, as_policy(source, task=job.task)) for name, source in job.policies]
    # (condition, first episode) of every run on the batched engine
    batched = [(cond, f) for cond in job.conditions if _batched_reason(job, cond) is None for f in firsts]
    results: dict[tuple[str, int], _JobResult] = {}
    restore_threads = _single_torch_thread()
    # Each batched run of a lockstep chunk has its own worlds; the per-env conditions share the first set.
    width = min(len(batched), _LOCKSTEP) or 1
    bases = [[job.conditions[0].base_env(job.task, **options) for _ in range(n)] for _ in range(width)]
    try:
        meter = None if job.safety is None else job.safety.meter(_physics(bases[0][0]).model, n)
        for start in range(0, len(batched), _LOCKSTEP):
            from sim2real.batched import BatchedEnv

            chunk = batched[start : start + _LOCKSTEP]
            worlds: list[Any] = []
            try:
                # The same single envs, reset seeds and streams, stepped together (bitwise the per-env results).
                # Side by side, each batch runs on this thread: several MuJoCo thread pools in one process fight over
                # the cores (a 6-condition job: 2.4x the C stepping time with 2 threads each on the 2-core box).
                threads = 1 if len(chunk) > 1 else None
                for (cond, _), base in zip(chunk, bases, strict=False):
                    worlds.append(
                        BatchedEnv(
                            job.task, n, cond.effects, envs=base, stream_seeds=[job.seed] * n,
                            end_diverged=bool(cond.effects), threads=threads,
                        )
                    )  # fmt: skip
                meters = [None if meter is None else job.safety.meter(w.models[0], n) for w in worlds]
                runs = [_Run(cond, f, w, m, seeds[f]) for (cond, f), w, m in zip(chunk, worlds, meters, strict=True)]
                for res in _lockstep_episodes(job, runs, policies, _mergeable(job)):
                    results[res.condition, res.first] = res
            finally:
                for w in worlds:
                    w.close()
        for cond in job.conditions:
            for f in firsts:
                if (cond.name, f) in results:
                    continue
                envs = [cond.wrap(b, seed=job.seed) for b in bases[0]]
                try:
                    res = _episodes(job, cond, envs, seeds[f], policies, meter)
                    results[cond.name, f] = dataclasses.replace(res, first=f, reason=_batched_reason(job, cond))
                finally:
                    for env, b in zip(envs, bases[0], strict=True):
                        _release(env, b)
    finally:
        restore_threads()
        for base in bases:
            for env in base:
                env.close()
    return [results[cond.name, f] for cond in job.conditions for f in firsts]


def _mergeable(job: _Job) -> list[bool]:
    """Per policy: whether one call may act for the worlds of all the job's conditions at once. Only a network
    loaded from a checkpoint (stateless; a user's callable may keep state between calls, and a scripted baseline
    is cheap anyway), and only for runs of at least 4 worlds: its batched forward then computes every row on its
    own, so the rows of a condition come out of the joint call bitwise as out of a call of their own (which
    :func:`_rows_alike` checks on probe batches). With 1 or 2 rows the study's SAC actors gave other last bits in
    a quarter to a half of the probes on the 2-core box (another matrix kernel), with 4 to 128 rows never."""
    return [isinstance(source, (str, os.PathLike)) and job.count >= 4 for _, source in job.policies]


def _rows_alike(policy: Any, n: int, k: int, width: int) -> bool:
    """Whether ``policy`` gives each block of ``n`` rows of a ``k * n``-row batch bitwise what it gives that block
    alone, on four probe batches (a BLAS may compute a tiny batch through another kernel: one or two rows of a
    torch MLP differ in the last bits of some actions on the 2-core box, four or more never did)."""
    rng = np.random.default_rng(0)
    for _ in range(4):
        probe = rng.normal(size=(k * n, width)).astype(np.float32)
        whole = policy(probe)
        for j in range(k):
            if not np.array_equal(policy(probe[j * n : (j + 1) * n]), whole[j * n : (j + 1) * n]):
                return False
    return True


def _lockstep_episodes(
    job: _Job, runs: list[_Run], policies: list[tuple[str, Any]], mergeable: list[bool]
) -> list[_JobResult]:
    """:func:`_episodes` on the batched engine, for every condition at once: policy by policy, all conditions'
    worlds step control step by control step side by side, each condition in its own
    :class:`~sim2real.batched.BatchedEnv` with its own safety meter, and a mergeable policy acts for all of them in
    one call (a torch forward costs ~250 us whether it has 32 rows or 192). Each condition's resets, steps and sums
    are those of the per-env loop, in the same order: a done world's reward is 0.0 and its sums stay untouched. With
    a safety meter, every stepped world is measured after every step from the batch's arrays
    (:meth:`~sim2real.safety_probe.SafetyMeter.observe_batch`: the quantities the single env's ``MjData`` gives)."""
    c, n = len(runs), runs[0].worlds.num_envs
    for run in runs:
        if run.meter is not None:
            run.meter.bind_batch(run.worlds.physics.batch)  # before the resets: a field bound between calls is 0
    for p, (name, policy) in enumerate(policies):
        merge = c > 1 and mergeable[p] and _rows_alike(policy, n, c, runs[0].worlds.observation_dim)
        for run in runs:
            run.start(first=p == 0)
        t = 0
        while job.max_steps is None or t < job.max_steps:
            going = [run for run in runs if not run.finished]
            if not going:
                break
            if merge:  # rows of a finished condition are computed and not used, as a finished world's are
                actions = policy(np.concatenate([run.obs for run in runs]))
                for k, run in enumerate(runs):
                    if not run.finished:
                        run.step(actions[k * n : (k + 1) * n])
            else:
                for run in going:
                    run.step(policy(run.obs))
            t += 1
        for run in runs:
            run.finish(name)
    return [run.result(job) for run in runs]


class _Run:
    """One condition's episodes ``first``, ``first + 1``, ... in :func:`_lockstep_episodes`: its worlds (one per
    episode, reset with ``seeds``), meter and sums."""

    def __init__(self, cond: Condition, first: int, worlds: Any, meter: Any, seeds: list[int]) -> None:
        self.cond, self.first, self.worlds, self.meter, self.seeds = cond, first, worlds, meter, seeds
        n = worlds.num_envs
        self.returns: dict[str, np.ndarray] = {}
        self.lengths: dict[str, np.ndarray] = {}
        self.successes: dict[str, np.ndarray] = {}
        self.draws: dict[str, np.ndarray] = {}
        self.safety: dict[str, dict[str, np.ndarray]] = {}
        self.steps = 0
        self.done = np.zeros(n, dtype=bool)
        self.everyone = True  # no world's episode has ended: every world is stepped (and measured)
        self.finished = False  # every world's episode has ended

    def start(self, first: bool) -> None:
        n = self.worlds.num_envs
        self.obs, params = self.worlds.reset(seed=self.seeds)
        if first:
            self.draws = {k: params[k] for k in sorted(params)}
        self.total = np.zeros(n)
        self.length = np.zeros(n, dtype=np.int64)
        self.done = np.zeros(n, dtype=bool)
        self.success = np.zeros(n, dtype=bool)
        self.diverged = np.zeros(n, dtype=bool)
        self.everyone, self.finished = True, False
        if self.meter is not None:
            self.meter.reset()

    def step(self, actions: np.ndarray) -> None:
        worlds = self.worlds
        if self.everyone:  # no mask to build, copy or look through: the engine's and the meter's all-worlds paths
            self.obs, reward, terminated, truncated, bad = worlds.step(actions)
            if self.meter is not None:
                self.diverged |= bad
                self.meter.observe_batch(None, worlds.models, worlds.physics.data)
            self.total += reward
            self.length += 1
            self.success = terminated.copy()  # a task's is_success is its termination
        else:
            active = ~self.done
            self.obs, reward, terminated, truncated, bad = worlds.step(actions, mask=active)
            if self.meter is not None:
                self.diverged |= bad
                self.meter.observe_batch(np.flatnonzero(active), worlds.models, worlds.physics.data)
            self.total += reward  # 0.0 where a world is done, as the per-env loop leaves those sums untouched
            self.length += active
            self.success = np.where(active, terminated, self.success)
        ended = terminated | truncated
        if ended.any():
            self.done |= ended
            self.everyone = False
            self.finished = bool(self.done.all())

    def finish(self, name: str) -> None:
        self.steps += int(self.length.sum())
        self.returns[name] = self.total
        self.lengths[name] = self.length
        if self.worlds.kernel.reports_success:
            self.successes[name] = self.success
        if self.meter is not None:
            self.safety[name] = self.meter.episodes(self.diverged)

    def result(self, job: _Job) -> _JobResult:
        return _JobResult(
            self.cond.name, self.first, self.returns, self.lengths, self.successes, self.draws, self.steps,
            "batched", self.safety,
        )  # fmt: skip


def _physics(env: Any) -> Any:
    """The MuJoCo handle inside ``env`` (safety measurements need one)."""
    from sim2real.physics import find_physics

    handle = find_physics(env)
    if handle is None:
        raise ValueError(f"`safety` needs a MuJoCo model inside the env; found none in {type(env).__name__}.")
    return handle


def _diverged(info: Mapping[str, Any]) -> bool:
    return bool(info.get("diverged", False) or info.get("sim2real", {}).get("diverged", False))


def _batched_reason(job: _Job, cond: Condition) -> str | None:
    """Why ``cond`` runs per env (None: it runs on the batched engine)."""
    if job.engine == "per-env":
        return "engine='per-env' was asked for"
    from sim2real.batched import supports

    return supports(job.task, *cond.effects, options=job.options)


def _single_torch_thread() -> Callable[[], None]:
    """Torch policies run on one intra-op thread (restored by the returned function): the batches are small,
    and on a busy machine extra threads spin against other processes (an arm-reach evaluation of a PPO actor
    took 22.4 s with 2 threads and 3.4 s with 1 on the 2-core box). One thread also makes the results
    independent of the machine's core count."""
    if "torch" not in sys.modules:
        return lambda: None
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    return lambda: torch.set_num_threads(previous)


def _episodes(
    job: _Job,
    cond: Condition,
    envs: list[Any],
    seeds: list[int],
    policies: list[tuple[str, Any]],
    meter: Any = None,
) -> _JobResult:
    n = len(envs)
    returns: dict[str, np.ndarray] = {}
    lengths: dict[str, np.ndarray] = {}
    successes: dict[str, np.ndarray] = {}
    draws: dict[str, np.ndarray] = {}
    safety: dict[str, dict[str, np.ndarray]] = {}
    steps = 0
    for p, (name, policy) in enumerate(policies):
        first = [env.reset(seed=s) for env, s in zip(envs, seeds, strict=True)]
        obs = np.stack([_observation(o, job.task) for o, _ in first])
        if p == 0:
            keys = sorted({k for _, info in first for k in info.get("sim2real", {}).get("params", {})})
            for key in keys:
                draws[key] = np.array([float(info["sim2real"]["params"].get(key, math.nan)) for _, info in first])
        total = np.zeros(n)
        length = np.zeros(n, dtype=np.int64)
        done = np.zeros(n, dtype=bool)
        success = np.zeros(n, dtype=bool)
        reports_success = False
        if meter is not None:  # found after the reset: a composer env's physics is a new one every episode
            meter.reset()
            handles = [_physics(env) for env in envs]
            diverged = np.array([_diverged(info) for _, info in first])
        t = 0
        while not done.all() and (job.max_steps is None or t < job.max_steps):
            actions = policy(obs)
            for i in np.flatnonzero(~done):
                o, r, terminated, truncated, info = envs[i].step(actions[i])
                if meter is not None:
                    meter.observe(i, handles[i].model, handles[i].data)
                    diverged[i] |= _diverged(info)
                obs[i] = o
                total[i] += float(r)
                length[i] += 1
                if "is_success" in info:
                    reports_success = True
                    success[i] = bool(info["is_success"])
                if terminated or truncated:
                    done[i] = True
            t += 1
        steps += int(length.sum())
        returns[name] = total
        lengths[name] = length
        if reports_success:
            successes[name] = success
        if meter is not None:
            safety[name] = meter.episodes(diverged)
    return _JobResult(cond.name, job.first, returns, lengths, successes, draws, steps, safety=safety)


def _policies(policies: Any) -> tuple[tuple[str, Any], ...]:
    from sim2real.agents.policy import BatchedPolicy, as_policy

    if isinstance(policies, Mapping):
        items = [(str(k), v) for k, v in policies.items()]
    else:
        seq = list(policies) if isinstance(policies, (list, tuple)) else [policies]
        items = [(as_policy(p).name, p) for p in seq]
    if not items:
        raise ValueError("`policies` must name at least one policy. Received none.")
    names = [n for n, _ in items]
    if len(set(names)) != len(names):
        raise ValueError(f"`policies` must have unique names. Received {names}.")
    # Workers rebuild the policy from its source (a checkpoint path, a module, a baseline...).
    return tuple((n, p.source if isinstance(p, BatchedPolicy) and p.source is not None else p) for n, p in items)


def evaluate(
    policies: Any,
    task: str,
    conditions: Sequence[Condition],
    *,
    episodes: int = 10,
    seed: int = 0,
    max_steps: int | None = None,
    batch: int = 64,
    task_options: Mapping[str, Any] | None = None,
    backend: str = "serial",
    workers: int | None = None,
    progress: bool = False,
    engine: str = "auto",
    safety: Any = None,
    start: int = 0,
) -> Evaluation:
    """Scores every policy on every condition with batched closed-loop episodes.

    Args:
        policies: ``{name: policy}`` or a list of policies (named by :func:`sim2real.agents.as_policy`); a
            policy is a TorchRL module, a checkpoint (path), a scripted baseline or a callable obs -> action.
        task: the task id (see ``sim2real tasks``).
        conditions: from :func:`nominal`, :func:`randomized`, :func:`real`, :func:`measured`,
            :func:`sweep` and :func:`grid`; names must be unique.
        episodes: episodes per (policy, simulated condition).
        seed: root seed; episode ``e`` is reset with :func:`episode_seed` ``(seed, e)`` everywhere.
        max_steps: cap on episode length (default: the task's own limit).
        batch: envs stepped together (one batched policy call per control step).
        task_options: keyword arguments for :func:`sim2real.make`.
        backend: ``"serial"`` (in this process), ``"local"`` (process pool) or ``"ray"``; results are the same.
        workers: processes for the ``local``/``ray`` backends (default: CPU count).
        progress: show a progress bar.
        engine: ``"auto"`` steps a condition's envs on the batched engine (:mod:`sim2real.batched`) when the
            task and its effects are supported and one by one otherwise; ``"per-env"`` always steps them one by
            one. Both give bitwise the same results; ``Evaluation.engines`` says which ran each condition and
            ``Evaluation.fallbacks`` why a condition ran per env.
        safety: a :class:`sim2real.safety.SafetyLimits`: also measure every episode's safety quantities (joint
            limit hits, effort ratio, contact force, end-effector speed, joint speed ratio, divergence;
            :mod:`sim2real.safety_probe`)
            into ``Evaluation.safety``, on either engine. Its names are resolved against the task's model before
            any episode runs. None (the default) measures nothing and costs nothing.
        start: the index of the first episode: ``start`` continues an evaluation of ``start`` episodes with the next
            ``episodes`` (episode ``e`` is reset with ``episode_seed(seed, e)``; with ``start`` a multiple of
            ``batch`` it runs in the same batches as in a run from 0, so its rows are bitwise that run's rows
            ``start``, ...).

    Raises:
        ValueError: bad counts, duplicate names, an unknown backend.
        sim2real.agents.CheckpointError: (a ``ValueError``) a checkpoint path that is broken, tampered with or
            trained on another task; raised before any episode runs.
    """
    for argument, value, low in (("episodes", episodes, 1), ("batch", batch, 1), ("start", start, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"`{argument}` must be an int >= {low}. Received {value!r}.")
    if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1):
        raise ValueError(f"`max_steps` must be None or an int >= 1. Received {max_steps!r}.")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"`seed` must be an int >= 0. Received {seed!r}.")
    if engine not in ("auto", "per-env"):
        raise ValueError(f"`engine` must be one of ['auto', 'per-env']. Received {engine!r}.")
    conditions = tuple(conditions)
    if safety is not None:
        _check_safety(safety, task, conditions, dict(task_options or {}))
    if not conditions or not all(isinstance(c, Condition) for c in conditions):
        raise TypeError(
            "`conditions` must be a non-empty list of Condition (from nominal(), randomized(), real(), measured(), "
            f"sweep(), grid()). Received {conditions!r}."
        )
    names = [c.name for c in conditions]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"`conditions` must have unique names. Received duplicates {duplicates}.")
    named = _policies(policies)
    paths = [source for _, source in named if isinstance(source, (str, os.PathLike))]
    if paths:  # a broken, tampered or foreign checkpoint fails here, before any worker starts
        from sim2real.agents.checkpoint import check_checkpoints

        check_checkpoints(paths, task, dict(task_options or {}))
    policy_names = tuple(n for n, _ in named)
    options = _freeze(dict(task_options or {}))
    groups: dict[Any, list[Condition]] = {}
    for cond in conditions:
        if cond.simulated:
            key = None if cond.params is None else tuple(sorted(cond.params.items()))
            groups.setdefault(key, []).append(cond)
    end = start + episodes
    jobs = []
    for group in groups.values():
        for i in range(0, len(group), _CONDITIONS_PER_JOB):
            conds = tuple(group[i : i + _CONDITIONS_PER_JOB])
            firsts = list(range(start, end, batch))
            while firsts:
                # A lone condition (the twin) steps two runs of `batch` episodes side by side, as conditions are.
                count = min(batch, end - firsts[0])
                chunks = 1
                while len(conds) == 1 and chunks < min(_LOCKSTEP, len(firsts)) and end - firsts[chunks] >= count:
                    chunks += 1
                job = _Job(task, options, conds, named, firsts[0], count, int(seed), max_steps, engine, safety, chunks)
                jobs.append(job)
                firsts = firsts[chunks:]
    clock = time.perf_counter()
    results = _dispatch(jobs, backend, workers, progress)
    seconds = time.perf_counter() - clock
    return _collect(task, int(seed), episodes, max_steps, policy_names, conditions, results, seconds)


def _check_safety(safety: Any, task: str, conditions: tuple[Condition, ...], options: dict[str, Any]) -> None:
    """A bad ``safety`` (its geom, site or body names) fails here, before any worker starts."""
    from sim2real.physics import find_physics
    from sim2real.safety import LimitsError, SafetyLimits

    if not isinstance(safety, SafetyLimits):
        raise TypeError(
            f"`safety` must be None or a sim2real.safety.SafetyLimits (load_limits). Received {type(safety).__name__}."
        )
    simulated = [c for c in conditions if isinstance(c, Condition) and c.simulated]
    if not simulated:
        return
    env = simulated[0].base_env(task, **options)
    try:
        handle = find_physics(env)
        if handle is None:
            raise LimitsError(
                f"{safety.source}: the limits need a MuJoCo model inside the env; found none in {type(env).__name__}."
            )
        safety.meter(handle.model, 1)
    finally:
        env.close()


def _dispatch(jobs: list[_Job], backend: str, workers: int | None, progress: bool) -> list[_JobResult]:
    if backend == "serial":
        from tqdm.auto import tqdm

        runs = [_run_job(job) for job in tqdm(jobs, desc="evaluate", disable=not progress, leave=False)]
    else:
        from sim2real.parallel import run_tasks

        runs = list(run_tasks(_run_job, jobs, backend=backend, workers=workers, progress=progress, desc="evaluate"))
    return [res for run in runs for res in run]


def _collect(
    task: str,
    seed: int,
    episodes: int,
    max_steps: int | None,
    policies: tuple[str, ...],
    conditions: tuple[Condition, ...],
    results: Sequence[_JobResult],
    seconds: float,
) -> Evaluation:
    returns: dict[str, dict[str, np.ndarray]] = {p: {} for p in policies}
    lengths: dict[str, dict[str, np.ndarray]] = {p: {} for p in policies}
    successes: dict[str, dict[str, np.ndarray]] = {p: {} for p in policies}
    draws: dict[str, dict[str, np.ndarray]] = {}
    safety: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    by_condition: dict[str, list[_JobResult]] = {}
    for res in results:
        by_condition.setdefault(res.condition, []).append(res)
    steps = 0
    engines: dict[str, str] = {}
    fallbacks: dict[str, str] = {}
    for cond in conditions:
        if not cond.simulated:
            assert cond.returns is not None and cond.successes is not None
            for p in policies:
                if p in cond.returns:
                    returns[p][cond.name] = np.asarray(cond.returns[p])
                if p in cond.successes:
                    successes[p][cond.name] = np.asarray(cond.successes[p])
            continue
        parts = sorted(by_condition[cond.name], key=lambda r: r.first)
        steps += sum(r.steps for r in parts)
        engines[cond.name] = parts[0].engine
        if parts[0].reason is not None:
            fallbacks[cond.name] = parts[0].reason
        for p in policies:
            returns[p][cond.name] = np.concatenate([r.returns[p] for r in parts])
            lengths[p][cond.name] = np.concatenate([r.lengths[p] for r in parts])
            if all(p in r.successes for r in parts):
                successes[p][cond.name] = np.concatenate([r.successes[p] for r in parts])
            if all(p in r.safety for r in parts):
                measured = {q: np.concatenate([r.safety[p][q] for r in parts]) for q in parts[0].safety[p]}
                safety.setdefault(p, {})[cond.name] = measured
        keys = sorted({k for r in parts for k in r.draws})
        if keys:
            draws[cond.name] = {
                k: np.concatenate([r.draws.get(k, np.full(len(r.returns[policies[0]]), math.nan)) for r in parts])
                for k in keys
            }
    return Evaluation(
        task=task,
        seed=seed,
        episodes=episodes,
        max_steps=max_steps,
        policies=policies,
        conditions=conditions,
        returns=_nested(returns, np.float64),
        successes=_nested(successes, bool),
        lengths=_nested(lengths, np.int64),
        draws=_nested(draws, np.float64),
        env_steps=steps,
        seconds=seconds,
        engines=engines,
        safety=_safety_view(safety),
        fallbacks=fallbacks,
    )


def _safety_view(safety: dict[str, dict[str, dict[str, np.ndarray]]]) -> Mapping[str, Any]:
    from sim2real.evaluation_results import _readonly

    return _freeze({p: _freeze({c: _freeze({q: _readonly(v) for q, v in m.items()}) for c, m in d.items()})
                    for p, d in safety.items()})  # fmt: skip
