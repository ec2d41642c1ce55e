"""``sim2real study``: the whole sim-to-real loop on an embedded default, in one command.

Stages (each prints its progress and time):

1. **twin** - the "real" robot: a twin of the task with held-out parameters, sensor noise and actuator
   latency from the bundled profile (``sim2real/data/study/<task>/study.yaml``). The report reveals it
   only in an appendix.
2. **sysid** - excitation logs recorded on the twin, fitted with :func:`sysid.fit` (independent
   multi-starts run on the backend, the lowest cost wins), turned into a *calibrated, randomised*
   simulator: each fitted value rounded to ``digits`` significant digits and randomised by
   ``max(relative_width, 2 stderr / estimate)`` around it, the fitted action latency and sensor noise,
   plus the profile's ``keep`` randomisation (what the fit does not cover).
3. **policies** - a nominal, a randomised and a calibrated PPO policy, loaded from the checkpoints the
   package ships when they were trained under exactly the same configuration (``manifest.json`` holds the
   ``sim2real train`` command that reproduces each), trained otherwise; plus the task's scripted baseline.
4. **evaluate** - every policy on the nominal sim, the randomised sim, the calibrated sim, the twin, and
   one-parameter sweeps and a two-parameter grid (:func:`sim2real.evaluation.evaluate`).
5. **report** - :class:`sim2real.report.GapReport` written to ``OUT/report.html``, ``report.md``,
   ``report.json`` and ``figures/``, next to the fit (``sysid/fit.json``) and the calibrated config.

Everything goes to a staging folder first and is moved into place at the end, so Ctrl-C or an error leaves
no half-written study. ``out`` is checked before any work: it must be a new or empty folder, because an existing
folder that holds anything is never overwritten, emptied or deleted (without ``out``, the first free
``sim2real-study``, ``sim2real-study-2``, ... is used). The same seed reproduces ``report.json`` bitwise (wall-clock times are kept out of
it), on either backend.

Example (the CI-sized budget, in a temporary folder):

    >>> from sim2real.study import BUDGETS
    >>> BUDGETS["quick"].episodes, BUDGETS["standard"].episodes
    (4, 32)
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TextIO

import yaml

__all__ = [
    "BUDGETS",
    "DEFAULT_OUT",
    "DEFAULT_TASK",
    "Budget",
    "StudyProfile",
    "StudyResult",
    "calibrated_effects",
    "load_profile",
    "run_study",
    "study_summary",
    "study_tasks",
]

DEFAULT_TASK = "dmc/reacher-easy"
#: The study folder when none is given (or the first free ``sim2real-study-2``, ``-3``, ... when it is taken).
DEFAULT_OUT = "sim2real-study"
PROFILES = Path(__file__).resolve().parent / "data" / "study"
ROLES = ("nominal", "randomized", "calibrated")


@dataclass(frozen=True)
class Budget:
    """How much work a study does.

    Attributes:
        name: ``quick``, ``standard`` or ``full``.
        episodes: episodes per (policy, condition).
        max_steps: cap on episode length (None: the task's own limit).
        sweep_points: points kept per sweep (None: all; otherwise both bounds and the nominal first).
        grid_points: points kept per grid axis (None: all).
        log_episodes, log_steps: excitation episodes and control steps recorded on the twin.
        fit_starts: independent sysid multi-starts (seeds), run on the backend.
        train_frames: frames for policies that must be trained (None: the profile's PPO frames).
        retrain: train every policy even when a shipped checkpoint matches.
        num_resamples: bootstrap resamples of every interval.
    """

    name: str
    episodes: int
    max_steps: int | None
    sweep_points: int | None
    grid_points: int | None
    log_episodes: int
    log_steps: int
    fit_starts: int
    train_frames: int | None
    retrain: bool
    num_resamples: int


BUDGETS: dict[str, Budget] = {
    "quick": Budget("quick", 4, 200, 3, 2, 4, 200, 2, 2_000, False, 500),
    "standard": Budget("standard", 32, None, None, None, 4, 200, 2, None, False, 2_000),
    "full": Budget("full", 100, None, None, None, 8, 200, 4, None, True, 5_000),
}


# ------------------------------------------------------------------------------------------------- profile


@dataclass(frozen=True)
class StudyProfile:
    """A task's study configuration (``sim2real/data/study/<task>/study.yaml``)."""

    task: str
    twin_params: Mapping[str, float]
    twin_signals: tuple[Any, ...]
    randomized: tuple[Any, ...]
    calibration_params: tuple[str, ...]
    excitation: str
    relative_width: float
    digits: int
    keep: tuple[Any, ...]
    sweeps: tuple[Mapping[str, Any], ...]
    grid: Mapping[str, Any] | None
    agent: Any
    folder: Path

    @property
    def recording(self) -> tuple[float, int]:
        """(sensor noise std, action latency steps) of the twin, as :func:`sim2real.recording.record` takes them."""
        import noise_models

        std, latency = 0.0, 0
        for model in self.twin_signals:
            if isinstance(model, noise_models.ObservationNoise) and isinstance(model.processes[0], noise_models.Gaussian):
                std = float(model.processes[0].std)
            elif isinstance(model, noise_models.ActionLatency):
                latency = int(model.steps)
        return std, latency


def _slug(task: str) -> str:
    return task.replace("/", "-")


def study_tasks() -> list[str]:
    """Task ids with a bundled study profile."""
    out = []
    for path in sorted(PROFILES.glob("*/study.yaml")):
        out.append(str(yaml.safe_load(path.read_text())["task"]))
    return out


def load_profile(task: str = DEFAULT_TASK) -> StudyProfile:
    """The bundled study profile of ``task``.

    Raises:
        ValueError: no profile for ``task`` (the tasks with one are listed), or an invalid profile.
    """
    import noise_models
    from randomizers import load_config
    from sim2real.agents import load_agent_config

    path = PROFILES / _slug(task) / "study.yaml"
    if not path.is_file():
        raise ValueError(f"`task` must be one of {study_tasks()} (tasks with a bundled study). Received {task!r}.")
    data = yaml.safe_load(path.read_text())
    twin = data["twin"]
    twin_signals = tuple(load_config({"signals": twin.get("signals", [])}))
    for model in twin_signals:
        ok = (
            isinstance(model, noise_models.ObservationNoise)
            and len(model.processes) == 1
            and isinstance(model.processes[0], noise_models.Gaussian)
            and model.select is None
        ) or (
            isinstance(model, noise_models.ActionLatency)
            and isinstance(model.steps, (int, float))
            and float(model.steps).is_integer()
        )
        if not ok:
            raise ValueError(
                f"{path}: twin.signals may hold one ObservationNoise(Gaussian) on every channel and an "
                f"ActionLatency(steps=k) (what the excitation recorder can reproduce). Received {model!r}."
            )
    calib = data["calibration"]
    agent = load_agent_config(dict(data["agent"]))
    return StudyProfile(
        task=str(data["task"]),
        twin_params={str(k): float(v) for k, v in twin["params"].items()},
        twin_signals=twin_signals,
        randomized=tuple(load_config(data["randomized"])),
        calibration_params=tuple(calib["params"]),
        excitation=str(calib.get("excitation", "multisine")),
        relative_width=float(calib.get("relative_width", 0.1)),
        digits=int(calib.get("digits", 2)),
        keep=tuple(load_config(calib["keep"])) if calib.get("keep") else (),
        sweeps=tuple(data.get("sweeps", [])),
        grid=data.get("grid"),
        agent=agent,
        folder=path.parent,
    )


# ------------------------------------------------------------------------------------------------- sysid


def calibrated_effects(fit: Any, *, relative_width: float = 0.1, digits: int = 2, keep: Sequence[Any] = ()) -> list:
    """The calibrated, randomised simulator of a fit: :meth:`sysid.FitResult.to_effects` with the profile's
    ``relative_width`` and ``digits`` (each estimate drawn uniformly from ``estimate +- max(relative_width *
    |estimate|, 2 stderr)``, the fitted latencies in seconds, the fitted sensor noise), then ``keep``.

    Example:
        >>> from sysid import FitResult
        >>> fit = FitResult.from_estimates({"dof_damping[shoulder]": (0.0299, 0.0001)})
        >>> calibrated_effects(fit)
        [Damping(set=Uniform(low=0.027, high=0.033), joints='shoulder')]
    """
    return [*fit.to_effects(min_relative_width=relative_width, digits=digits), *keep]


@dataclass(frozen=True)
class _FitJob:
    task: str
    log_path: str
    params: tuple[str, ...]
    seed: int


def _fit_one(job: _FitJob) -> Any:
    import sysid
    from sim2real.tasks import make

    env = make(job.task)
    from sim2real.physics import find_physics

    handle = find_physics(env)
    assert handle is not None
    log = sysid.load_log(job.log_path, model=handle.model)
    result = sysid.fit(log, handle.model, list(job.params), latency=True, seed=job.seed, progress=False, nthread=1)
    env.close()
    return result


def _record_twin(profile: StudyProfile, budget: Budget, seed: int) -> Any:
    """Excitation logs recorded on the twin (its held-out parameters, sensor noise and action latency)."""
    import noise_models
    from randomizers.parameters import Address, effect_for
    from sim2real.recording import record

    std, _ = profile.recording
    effects: list[Any] = [effect_for(Address.parse(a), "set", v) for a, v in profile.twin_params.items()]
    effects += [m for m in profile.twin_signals if isinstance(m, noise_models.ActionLatency)]
    return record(
        profile.task,
        effects=effects,
        policy=profile.excitation,
        episodes=budget.log_episodes,
        steps=budget.log_steps,
        seed=seed,
        obs_noise=std,
    )


def _best_fit(
    profile: StudyProfile, log_path: Path, budget: Budget, seed: int, backend: str, workers: int | None
) -> Any:
    """``budget.fit_starts`` independent fits (seeds ``1000 seed + k``) on the backend; the lowest cost wins
    (ties: the first)."""
    jobs = [
        _FitJob(profile.task, str(log_path), profile.calibration_params, seed * 1000 + k)
        for k in range(budget.fit_starts)
    ]
    results = _dispatch(_fit_one, jobs, backend, workers, "sysid")
    return min(results, key=lambda r: (r.cost, results.index(r)))


# ------------------------------------------------------------------------------------------------- policies


@dataclass(frozen=True)
class _TrainJob:
    task: str
    role: str
    agent: Any
    effects_yaml: str | None
    seed: int
    out: str


def _train_one(job: _TrainJob) -> str:
    from randomizers import load_config
    from sim2real.agents import train

    effects = load_config(job.effects_yaml) if job.effects_yaml else []
    result = train(job.task, job.agent, effects=effects, seed=job.seed, progress=False, logger=None)
    result.save(job.out)
    return job.out


def _manifest(profile: StudyProfile) -> list[dict[str, Any]]:
    path = profile.folder / "checkpoints" / "manifest.json"
    if not path.is_file():
        return []
    return list(json.loads(path.read_text()).get("checkpoints", []))


def _shipped(profile: StudyProfile, role: str, effects_yaml: str | None) -> Path | None:
    for entry in _manifest(profile):
        if (
            entry.get("role") == role
            and entry.get("task") == profile.task
            and entry.get("effects") == effects_yaml
            and entry.get("agent") == profile.agent.to_dict()
        ):
            path = profile.folder / "checkpoints" / entry["file"]
            if path.is_file():
                return path
    return None


def _effects_yaml(effects: Sequence[Any]) -> str | None:
    from randomizers import dump_config

    return dump_config(list(effects)) if effects else None


# ------------------------------------------------------------------------------------------------- conditions


def _thin(values: Sequence[float], nominal: float, keep: int | None) -> list[float]:
    values = [float(v) for v in values]
    if keep is None or len(values) <= keep:
        return values
    chosen = {values[0], values[-1]}
    if any(math.isclose(v, nominal) for v in values):
        chosen.add(nominal)
    rest = [v for v in values if v not in chosen]
    while len(chosen) < keep and rest:
        chosen.add(rest.pop(len(rest) // 2))
    return sorted(chosen)


def _conditions(profile: StudyProfile, calibrated: Sequence[Any], budget: Budget) -> list[Any]:
    from sim2real.evaluation import _default_nominal, grid, nominal, randomized, real, sweep

    conds = [
        nominal(),
        randomized(list(profile.randomized), description="randomised sim (chosen without data)"),
        randomized(list(calibrated), name="calibrated", description="calibrated, randomised sim (from the fit)"),
        real(list(profile.twin_signals), params=profile.twin_params, description="the real twin (held out)"),
    ]
    for item in profile.sweeps:
        spec = dict(item)
        path = spec["field"]
        nom = spec.get("nominal", _default_nominal(path))
        spec["values"] = _thin(spec["values"], nom, budget.sweep_points)
        conds.extend(sweep(spec, path, spec["values"], nominal=spec.get("nominal")))
    if profile.grid is not None:
        axes = {}
        for key in ("x", "y"):
            spec = dict(profile.grid[key])
            nom = spec.get("nominal", _default_nominal(spec["field"]))
            spec["values"] = _thin(spec["values"], nom, budget.grid_points)
            axes[key] = spec
        conds.extend(grid(axes["x"], axes["y"]))
    return conds


# ------------------------------------------------------------------------------------------------- the study


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
    import sysid
    from randomizers.files import atomic_write
    from sim2real.agents import baseline_for
    from sim2real.evaluation import evaluate
    from sim2real.report import GapReport

    stages = _Stages(log, 5)
    trajectory = stages.run(
        "twin",
        f"recording {budget.log_episodes} {profile.excitation} episodes on the real twin",
        lambda: _record_twin(profile, budget, seed),
    )
    (staging / "sysid").mkdir()
    log_path = staging / "sysid" / "twin_log.npz"
    sysid.save_log(trajectory, log_path)

    def fit() -> Any:
        return _best_fit(profile, log_path, budget, seed, backend, workers)

    result = stages.run("sysid", f"fitting {', '.join(profile.calibration_params)} and the latency", fit)
    atomic_write(staging / "sysid" / "fit.json", result.to_json())
    calibrated = calibrated_effects(
        result, relative_width=profile.relative_width, digits=profile.digits, keep=profile.keep
    )
    calibrated_yaml = _effects_yaml(calibrated)
    atomic_write(staging / "sysid" / "calibrated.yaml", calibrated_yaml or "effects: []\n")

    role_effects = {"nominal": (), "randomized": profile.randomized, "calibrated": tuple(calibrated)}
    sources: dict[str, str] = {}
    policies: dict[str, Any] = {}

    def policies_stage() -> None:
        jobs = []
        for role in ROLES:
            text = _effects_yaml(role_effects[role])
            shipped = None if budget.retrain else _shipped(profile, role, text)
            if shipped is not None:
                policies[role] = str(shipped)
                sources[role] = f"shipped checkpoint {shipped.name}"
                continue
            agent = profile.agent
            if budget.train_frames is not None:
                agent = replace(agent, frames=budget.train_frames)
            (staging / "checkpoints").mkdir(exist_ok=True)
            path = staging / "checkpoints" / f"{role}.pt"
            jobs.append(_TrainJob(profile.task, role, agent, text, seed, str(path)))
            sources[role] = f"trained here ({agent.frames} frames, seed {seed})"
        for job, path in zip(jobs, _dispatch(_train_one, jobs, backend, workers, "train"), strict=True):
            policies[job.role] = path
        policies["scripted"] = baseline_for(profile.task)
        sources["scripted"] = repr(policies["scripted"])

    stages.run("policies", "nominal, randomised and calibrated PPO policies and the scripted baseline", policies_stage)
    conditions = _conditions(profile, calibrated, budget)
    named = {role: policies[role] for role in (*ROLES, "scripted")}

    def evaluate_stage() -> Any:
        return evaluate(
            named,
            profile.task,
            conditions,
            episodes=budget.episodes,
            seed=seed,
            max_steps=budget.max_steps,
            batch=budget.episodes,
            backend=backend,
            workers=workers,
            progress=progress,
        )

    evaluation = stages.run(
        "evaluate",
        f"{len(named)} policies x {len(conditions)} conditions x {budget.episodes} episodes ({backend})",
        evaluate_stage,
    )

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
        )
        report.write(staging)
        return report

    report = stages.run("report", "statistics, figures, HTML/Markdown/JSON", report_stage)
    return StudyResult(
        out=staging,
        report=staging / "report.html",
        summary=study_summary(report, evaluation),
        seconds=dict(stages.seconds),
        policies=dict(sources),
        evaluation=evaluation,
        fit=result,
    )


def _fmt(e: Any, percent: bool = False) -> str:
    if percent:
        return f"{100 * e.value:.0f}% [{100 * e.low:.0f}%, {100 * e.high:.0f}%]"
    return f"{e.value:.0f} [{e.low:.0f}, {e.high:.0f}]"


def study_summary(report: Any, evaluation: Any = None) -> str:
    """The study's one-paragraph summary: the sim-to-real gap before calibration (the nominal and the randomised
    policy, from the nominal sim) and after it (the calibrated policy, whose own sim is the calibrated one; needs
    the ``evaluation``), with intervals."""
    try:
        parts = []
        conf = report.stats_for("nominal", "sim").mean.confidence
        nominal_sim, nominal_real = report.stats_for("nominal", "sim").mean, report.stats_for("nominal", "real").mean
        parts.append(
            f"Before calibration, the nominal policy returns {_fmt(nominal_sim)} in sim and {_fmt(nominal_real)} on the "
            f"real twin: it loses {_fmt(report.gap('nominal').relative, True)} of its sim return."
        )
        randomized_real = report.stats_for("randomized", "real").mean
        parts.append(
            f"Domain randomisation chosen without data gives {_fmt(randomized_real)} on the twin "
            f"(loss {_fmt(report.gap('randomized').relative, True)})."
        )
        calibrated_real = report.stats_for("calibrated", "real").mean
        text = (
            f"After system identification, the policy trained on the calibrated, randomised sim returns "
            f"{_fmt(calibrated_real)} on the twin"
        )
        if evaluation is not None:
            from sim2real import metrics

            with warnings.catch_warnings():  # the report lists the few-samples warnings already
                warnings.simplefilter("ignore", metrics.FewSamplesWarning)
                own = metrics.gap(
                    evaluation.table("calibrated", ["calibrated", "real"]),
                    paired=True,
                    rng=report.rng_seed,
                    num_resamples=report.num_resamples,
                )
            text += (
                f" and {_fmt(report.stats_for('calibrated', 'calibrated').mean)} in the calibrated sim it was trained "
                f"on, so it loses {_fmt(own.relative, True)} from its own sim to the twin"
            )
        parts.append(text + ".")
        scripted = report.stats_for("scripted", "real").mean
        parts.append(f"The scripted baseline returns {_fmt(scripted)} on the twin.")
        parts.append(f"Intervals: {100 * conf:.0f}% stratified bootstrap over {nominal_sim.n} episodes per condition.")
        return " ".join(parts)
    except KeyError:
        return report.summary()


# ------------------------------------------------------------------------------------------------- shipping


def prepare_checkpoints(task: str = DEFAULT_TASK, *, seed: int = 0, budget: str = "standard") -> list[str]:
    """Maintainers: writes the training configs of the shipped checkpoints into the profile's ``checkpoints/``
    folder (the calibrated one from the twin logs and fit of ``seed`` at ``budget``) and returns the
    ``sim2real train`` commands that produce them; run those, then :func:`write_manifest`."""
    from randomizers.files import atomic_write

    profile = load_profile(task)
    spec = BUDGETS[budget]
    folder = profile.folder / "checkpoints"
    folder.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        import sysid

        log_path = Path(tmp) / "log.npz"
        sysid.save_log(_record_twin(profile, spec, seed), log_path)
        fit = _best_fit(profile, log_path, spec, seed, "serial", None)
    calibrated = calibrated_effects(
        fit, relative_width=profile.relative_width, digits=profile.digits, keep=profile.keep
    )
    atomic_write(folder / "agent.yaml", profile.agent.to_yaml())
    commands = []
    for role, effects in (("nominal", ()), ("randomized", profile.randomized), ("calibrated", tuple(calibrated))):
        text = _effects_yaml(effects)
        config = ""
        if text is not None:
            atomic_write(folder / f"{role}.yaml", text)
            config = f" --config {role}.yaml"
        commands.append(
            f"sim2real train --task {profile.task} --agent-config agent.yaml{config} --seed 0 --out {role}.pt --no-log"
        )
    return commands


def write_manifest(task: str = DEFAULT_TASK, commands: Sequence[str] = ()) -> Path:
    """Maintainers: records the shipped checkpoints of ``task`` (role, file, effects YAML, agent config and the
    command) in ``checkpoints/manifest.json``; a checkpoint is used only when all of these match."""
    from randomizers.files import atomic_write
    from sim2real.agents import load_checkpoint

    profile = load_profile(task)
    folder = profile.folder / "checkpoints"
    entries = []
    for role in ROLES:
        path = folder / f"{role}.pt"
        if not path.is_file():
            continue
        ckpt = load_checkpoint(path, task=profile.task)
        config_file = folder / f"{role}.yaml"
        effects = config_file.read_text() if config_file.is_file() else None
        if ckpt.effects != effects:
            raise ValueError(f"{path} was trained under other effects than {config_file}.")
        entries.append(
            {
                "role": role,
                "file": path.name,
                "task": profile.task,
                "effects": effects,
                "agent": ckpt.config.to_dict(),
                "seed": ckpt.seed,
                "run_id": ckpt.run_id,
                "command": next((c for c in commands if f"--out {role}.pt" in c), ""),
            }
        )
    path = folder / "manifest.json"
    atomic_write(path, json.dumps({"checkpoints": entries}, indent=1, sort_keys=True) + "\n")
    return path
