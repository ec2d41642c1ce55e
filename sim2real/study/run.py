"""Running the study: stages, the staging folder, the backends."""

from __future__ import annotations

import os
import shutil
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TextIO

from sim2real.study.profile import BUDGETS, DEFAULT_TASK, Budget, StudyProfile, load_profile

__all__ = ["DEFAULT_OUT", "StudyResult", "run_study"]

#: The study folder when none is given (or the first free ``sim2real-study-2``, ``-3``, ... when it is taken).
DEFAULT_OUT = "sim2real-study"


@dataclass(frozen=True)
class StudyResult:
    """What :func:`run_study` returns.

    Attributes:
        out: the study folder.
        report: path of ``report.html``.
        summary: the one-paragraph summary (also at the top of the report).
        seconds: stage name -> wall-clock seconds.
        policies: role -> where its policy came from (a shipped or trained checkpoint, or the baseline).
        evaluation: the :class:`sim2real.evaluation.Evaluation`.
        fit: the :class:`sysid.FitResult`.
    """

    out: Path
    report: Path
    summary: str
    seconds: Mapping[str, float]
    policies: Mapping[str, str]
    evaluation: Any = field(repr=False)
    fit: Any = field(repr=False)


class _Stages:
    def __init__(self, out: TextIO | None, total: int) -> None:
        self.out = out
        self.total = total
        self.index = 0
        self.seconds: dict[str, float] = {}

    def run(self, name: str, text: str, fn: Callable[[], Any]) -> Any:
        self.index += 1
        if self.out is not None:
            print(f"[{self.index}/{self.total}] {name}: {text}", file=self.out, flush=True)
        start = time.perf_counter()
        value = fn()
        self.seconds[name] = time.perf_counter() - start
        if self.out is not None:
            print(f"      {name} done in {self.seconds[name]:.1f} s", file=self.out, flush=True)
        return value


def _check(budget: str, backend: str, seed: Any) -> Budget:
    if budget not in BUDGETS:
        raise ValueError(f"`budget` must be one of {list(BUDGETS)}. Received {budget!r}.")
    if backend not in ("local", "ray", "serial"):
        raise ValueError(f"`backend` must be one of ['local', 'ray', 'serial']. Received {backend!r}.")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"`seed` must be an int >= 0. Received {seed!r}.")
    return BUDGETS[budget]


def run_study(
    task: str = DEFAULT_TASK,
    out: str | os.PathLike[str] | None = None,
    *,
    budget: str = "standard",
    backend: str = "local",
    seed: int = 0,
    workers: int | None = None,
    progress: bool = True,
    log: TextIO | None = sys.stderr,
) -> StudyResult:
    """Runs the whole study (see the module docstring) and writes it to ``out``.

    Args:
        task: a task with a bundled profile (:func:`study_tasks`).
        out: the study folder: a new or an empty folder (a folder that holds anything is never overwritten).
            Default: the first free one of ``sim2real-study``, ``sim2real-study-2``, ...
        budget: one of :data:`BUDGETS` (``quick`` is what CI runs).
        backend: ``local`` (process pool), ``ray`` or ``serial``; the results are the same.
        seed: seeds the recording, the fit, the evaluation and the bootstrap (and training when it happens).
        workers: processes for the backend (default: CPU count).
        progress: progress bars inside stages.
        log: where stage lines go (None: silent).

    Raises:
        ValueError: an unknown task, budget or backend, or a bad seed.
        sim2real.output_paths.OutputPathError: (a ``ValueError``) ``out`` is an existing file or a folder that
            is not empty, or it cannot be created or written; raised before any work.
    """
    from sim2real.output_paths import check_folder, free_folder, publish_folder, staging_folder

    spec = _check(budget, backend, seed)
    profile = load_profile(task)
    target = check_folder(free_folder(DEFAULT_OUT) if out is None else out, "`out`", new=True)
    staging = staging_folder(target)
    try:
        result = _run(profile, spec, staging, backend, seed, workers, progress, log)
        final = publish_folder(staging, target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)  # only our own hidden staging folder
        raise
    if final != target and log is not None:
        print(f"{str(target)!r} was taken while the study ran; the study is in {str(final)!r}", file=log)
    return replace(result, out=final, report=final / "report.html")


def _dispatch(fn: Callable[[Any], Any], items: list[Any], backend: str, workers: int | None, desc: str) -> list:
    if backend == "serial" or len(items) == 1:
        return [fn(item) for item in items]
    from sim2real.parallel import run_tasks

    return list(run_tasks(fn, items, backend=backend, workers=workers, progress=False, desc=desc))


def _run(
    profile: StudyProfile,
    budget: Budget,
    staging: Path,
    backend: str,
    seed: int,
    workers: int | None,
    progress: bool,
    log: TextIO | None,
) -> StudyResult:
    import yaml

    import sysid
    from randomizers.files import atomic_write
    from sim2real.agents import baseline_for
    from sim2real.physics import find_physics
    from sim2real.report import GapReport
    from sim2real.report.labels import model_units, observation_unit
    from sim2real.safety import SafetyTable, physics_substeps
    from sim2real.spec import load_spec
    from sim2real.study.fitting import best_fit, calibrated_effects, record_twin
    from sim2real.study.policies import (
        TrainJob,
        adr_simulator,
        effects_yaml,
        role_agent,
        shipped,
        study_roles,
        train_one,
    )
    from sim2real.study.precision import extend, plan_target, replan_rounds, run_target
    from sim2real.study.summary import DISPLAY_CONDITIONS, DISPLAY_POLICIES, TRAINING, study_summary
    from sim2real.tasks import make

    def dispatch(fn: Callable[[Any], Any], items: list[Any], desc: str) -> list:
        return _dispatch(fn, items, backend, workers, desc)

    stages = _Stages(log, 6)
    trajectory = stages.run(
        "twin",
        f"recording {budget.log_episodes} {profile.excitation} episodes on the real twin",
        lambda: record_twin(profile, budget, seed),
    )
    (staging / "sysid").mkdir()
    log_path = staging / "sysid" / "twin_log.npz"
    sysid.save_log(trajectory, log_path)
    result = stages.run(
        "sysid",
        f"fitting {', '.join(profile.calibration_params)} and the latency",
        # In this process: a fit takes ~1 s, a process pool's start (workers importing torch and dm-control) 3-5 s
        # (standard budget, 2 fits: 1.5-2.2 s here vs 5.5-6.7 s through the local pool, the same fit).
        lambda: best_fit(profile, log_path, budget, seed, lambda fn, items, desc: [fn(item) for item in items]),
    )
    atomic_write(staging / "sysid" / "fit.json", result.to_json())
    calibrated = calibrated_effects(
        result, relative_width=profile.relative_width, digits=profile.digits, keep=profile.keep
    )
    calibrated_path = staging / "sysid" / "calibrated.yaml"
    atomic_write(calibrated_path, effects_yaml(calibrated) or "effects: []\n")

    roles = study_roles(profile)
    role_effects = {"nominal": (), "randomized": profile.randomized, "calibrated": tuple(calibrated)}
    role_effects["adr"] = profile.adr_signals  # plus the ADR ranges of its agent config (role_agent)
    sources: dict[str, str] = {}
    checkpoints: dict[str, str] = {}

    def policies_stage() -> None:
        jobs = []
        for role in roles:
            text = effects_yaml(role_effects[role])
            found = None if budget.retrain else shipped(profile, role, text)
            if found is not None:
                checkpoints[role] = str(found)
                sources[role] = f"shipped checkpoint {found.name}"
                continue
            agent = role_agent(profile, role)
            if budget.train_frames is not None:
                agent = replace(agent, frames=budget.train_frames)
            (staging / "checkpoints").mkdir(exist_ok=True)
            path = staging / "checkpoints" / f"{role}.pt"
            jobs.append(TrainJob(profile.task, role, agent, text, seed, str(path)))
            sources[role] = f"trained here ({agent.frames} frames, seed {seed})"
        for job, path in zip(jobs, dispatch(train_one, jobs, "train"), strict=True):
            checkpoints[job.role] = path
        sources["scripted"] = repr(baseline_for(profile.task))

    label = f"{', '.join(roles)} {profile.agent.algo.upper()} policies and the scripted baseline"
    stages.run("policies", label, policies_stage)
    # The conditions are an ordinary evaluation spec: the same parser as `sim2real evaluate --config`.
    policies: dict[str, Any] = {role: {"checkpoint": checkpoints[role]} for role in roles}
    policies["scripted"] = "baseline"
    simulators: dict[str, Any] = {"calibrated": str(calibrated_path)}
    if "adr" in checkpoints:  # the sim the ADR policy ended its training in: its final ranges
        simulators["adr"] = yaml.safe_load(effects_yaml(adr_simulator(checkpoints["adr"], profile.adr_signals)) or "")
    spec = load_spec(profile.spec_config(budget, seed=seed, policies=policies, simulators=simulators))
    safety = profile.safety  # the arm's envelope, measured on every simulated condition (the Safety section)
    evaluation = stages.run(
        "evaluate",
        f"{len(spec.policies)} policies x {len(spec.conditions)} conditions x {budget.episodes} episodes ({backend})",
        lambda: spec.run(backend=backend, workers=workers, progress=progress, safety=safety),
    )
    engines = evaluation.engine_summary()
    if log is not None and engines is not None:  # which conditions the batched engine ran, and why any ran per env
        print(f"      {engines}", file=log)
    # Enough episodes to decide: the evaluation above is the pilot of the headline's precision goal on the twin.
    batch = spec.batch  # whole batches: each round of the target stage continues the last one

    def plan(current: Any) -> Any:
        return plan_target(current, fraction=budget.precision, cap=budget.max_target_episodes, batch=batch)

    target = plan(evaluation)
    if target.episodes > evaluation.episodes:
        pilot = evaluation

        def target_stage() -> tuple[Any, Any]:
            # Each run continues the last (run_target with its result as the pilot; whole batches, so bitwise the
            # run from episode 0); see replan_rounds.
            last = pilot

            def run_to(episodes: int) -> Any:
                nonlocal last
                last = run_target(spec, "real", episodes, pilot=last, backend=backend, workers=workers,
                                  progress=progress, safety=safety)  # fmt: skip
                return extend(pilot, last, "real")

            return replan_rounds(
                target, run_to, plan, note=None if log is None else (lambda text: print(f"      {text}", file=log))
            )

        evaluation, target = stages.run(
            "target",
            f"{target.episodes} episodes of every policy on the real twin (the pilot asks for {target.needed} to "
            f"reach +-{target.goal:.3g}; cap {target.cap})",
            target_stage,
        )
    else:
        stages.run("target", f"the pilot's {evaluation.episodes} episodes reach the precision goal", lambda: None)
    env = make(profile.task)
    try:  # what the report's units and the safety sampling note are read from
        obs_unit, substeps = observation_unit(env), physics_substeps(env)
        handle = find_physics(env)
        units = {} if handle is None else model_units(handle.model)  # slide joints and tendons in their own units
    finally:
        env.close()

    def report_stage() -> Any:
        report = GapReport.build(
            evaluation,
            fit=result,
            reference="sim",
            randomized="randomized",
            target="real",
            num_resamples=budget.num_resamples,
            rng=seed,
            title=f"sim2real study: {profile.task}",
            notes=(*(f"{role} policy: {text}" for role, text in sources.items()), f"budget {budget.name}, seed {seed}"),
            # each policy's robustness radii keep a fraction of its return in its own sim
            training={k: v for k, v in TRAINING.items() if k in spec.policies},
            control_timestep=float(trajectory.meta["control_timestep"]),  # latencies shown in ms
            policy_labels={k: v for k, v in DISPLAY_POLICIES.items() if k in spec.policies},
            condition_labels={k: v for k, v in DISPLAY_CONDITIONS.items() if k in {c.name for c in spec.conditions}},
            observation_unit=obs_unit,  # the sensor-noise sweep in rad / m / rad/s
            **units,
        )
        if safety is not None:
            model = None if handle is None else handle.model  # names the joint at a joint speed peak
            report = replace(report, safety=SafetyTable.build(evaluation, safety, substeps=substeps, model=model))
        report = report.with_episode_target(target)  # the half-width reached, from the report's own interval
        report = report.with_lead(study_summary(report))  # the paragraph is part of report.md/html/json
        report.write(staging)
        return report

    report = stages.run("report", "statistics, figures, HTML/Markdown/JSON", report_stage)
    return StudyResult(
        out=staging,
        report=staging / "report.html",
        summary=report.summary(),  # the lead paragraph, the headline and the small-budget warnings
        seconds=dict(stages.seconds),
        policies=dict(sources),
        evaluation=evaluation,
        fit=result,
    )
