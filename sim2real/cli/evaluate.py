"""``sim2real evaluate`` and ``sim2real study``.

``evaluate`` reads a spec (:func:`sim2real.spec.load_spec`; its env is ``task:``, ``model:`` or ``env:``), and
``--task``/``--model``/``--env`` on the command line override it.

Example:
    >>> import contextlib, io
    >>> from sim2real.cli import main
    >>> err = io.StringIO()
    >>> with contextlib.redirect_stderr(err):
    ...     main(["evaluate", "--config", "missing.yaml", "--out", "report"])
    2
    >>> "missing.yaml" in err.getvalue()
    True
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any, TextIO

from sim2real.cli._common import UsageError, check_outputs, source_of, writing

__all__ = ["cmd_evaluate", "cmd_study"]


def cmd_evaluate(args: argparse.Namespace, out: TextIO) -> int:
    from sim2real._gl import RenderingUnavailable
    from sim2real.report import GapReport
    from sim2real.spec import SpecError, load_spec
    from sysid import FitResult

    # The command line's source replaces the spec's (which it then need not name), before its policies are read.
    override = source_of(args).id if (args.task, args.model, args.env) != (None, None, None) else None
    try:
        spec = load_spec(Path(args.config), task=override)
        options = dict(spec.report)
        fit_path = options.pop("fit", None)
        fit = FitResult.from_json(Path(fit_path)) if fit_path is not None else None
    except FileNotFoundError as err:
        raise UsageError(str(err)) from err
    except (SpecError, ValueError) as err:
        raise UsageError(str(err)) from err
    limits = _limits(args.safety)
    _check_out(args.out, {"--config": args.config, "--safety": args.safety, "the spec's fit": fit_path})
    try:  # effects that do not fit the model, a constant action of the wrong size: one line, before any episode
        spec.check()
    except SpecError as err:
        raise UsageError(str(err)) from err
    from sim2real.agents.checkpoint import CheckpointError
    from sim2real.safety import LimitsError, SafetyTable

    try:  # checkpoints and the safety names are checked here, before any worker starts
        evaluation = spec.run(backend=args.backend, workers=args.workers, progress=not args.quiet, safety=limits)
    except CheckpointError as err:
        raise UsageError(str(err)) from err
    except LimitsError as err:
        raise UsageError(f"--safety: {err}") from err
    notes = options.pop("notes", ())
    notes = [notes] if isinstance(notes, str) else list(notes)
    try:
        sheet = spec.contact_sheet()
    except RenderingUnavailable as err:  # the report still has every number; say why the images are missing
        sheet = None
        notes.append(f"no contact sheet of the visual effects: {err}")
    control_timestep, substeps, units, unit = _clock(spec.task)
    options.setdefault("control_timestep", control_timestep)  # a timing sweep's steps are shown in ms
    options.setdefault("substeps", substeps)
    for key, value in units.items():  # slide joints and tendons in their own units (N·s/m and m, not N·m·s/rad)
        options.setdefault(key, value)
    if unit is not None:  # a sensor-noise sweep in rad / rad/s, not "observation units"
        options.setdefault("observation_unit", unit)
    report = GapReport.build(evaluation, fit=fit, contact_sheet=sheet, rng=spec.seed, notes=tuple(notes), **options)
    if limits is None:
        table = None
    else:  # the model names the joint at a joint speed peak
        substeps, model = _substeps(spec.task)
        table = SafetyTable.build(evaluation, limits, substeps=substeps, model=model)
    if table is not None:
        report = dataclasses.replace(report, safety=table)
    files = writing(args.out, lambda: report.write(Path(args.out)))
    print(report.summary(), file=out)
    engines = evaluation.engine_summary()
    if engines is not None:  # how each condition ran (the batched engine, or per env and why)
        print(engines, file=out)
    print(f"wrote {files.html}", file=out)
    if table is None:
        return 0
    if table.passed:
        bounds = [(r.over_rate.high, r.episodes) for r in table.rows if r.over_rate is not None]
        tail = ""
        if bounds:  # passing on few episodes is weak evidence: say how weak
            high, episodes = max(bounds)
            tail = f" (at 95%, up to {100 * high:.3g}% of episodes may still cross a limit: {episodes} episodes)"
        print(f"safety: every policy within {args.safety} on every condition{tail}", file=out)
        return 0
    for violation in table.violations:  # one line each, for a CI log; exit 3 gates the pipeline
        print(f"sim2real evaluate: safety: {violation.message}", file=sys.stderr)
    return 3


def _check_out(out: str, inputs: dict[str, str | None]) -> None:
    """``--out``, before any episode: a folder whose report files can be replaced (none of them is a folder, nor
    ``figures`` a file: found after the evaluation, that stopped the write midway, with the old ``report.json``
    gone and some new files beside old ones), and none of them one of the command's input files."""
    from sim2real.output_paths import OutputPathError, check_not_inputs
    from sim2real.report.files import REPORT_FILES, check_out

    try:
        check_out(out, "--out")
        check_not_inputs({f"--out's {name}": Path(out) / name for name in REPORT_FILES}, inputs)
    except OutputPathError as err:
        raise UsageError(str(err)) from err


def _substeps(task: Any) -> tuple[int | None, Any]:
    """Physics steps per control step of the spec's task: what the Safety section's once-per-control-step sampling
    sees (the same reading the study makes); and its model (None without one), which names joints."""
    from sim2real.physics import find_physics
    from sim2real.safety import physics_substeps
    from sim2real.tasks import make

    env = make(task)
    try:
        handle = find_physics(env)
        return physics_substeps(env), None if handle is None else handle.model
    finally:
        env.close()


def _clock(task: Any) -> tuple[float | None, int | None, dict[str, Any], str | None]:
    """Seconds per control step and physics steps per control step of the spec's task: what the Safety section's
    once-per-control-step sampling sees (the same reading the study makes), and what a latency sweep's ``steps``
    (physics steps) are in milliseconds. Before, a frame_skip=4 env's sweep over ActionLatency.steps 0, 4, 8 was
    labelled 'action latency (control steps)': four times the latency applied."""
    from sim2real.physics import find_physics
    from sim2real.report.labels import model_units, observation_unit
    from sim2real.safety import physics_substeps
    from sim2real.tasks import make

    env = make(task)
    try:
        substeps = physics_substeps(env)
        handle = find_physics(env)
        unit = observation_unit(env)
        if handle is None:
            return None, substeps, {}, unit
        units = model_units(handle.model)
        timestep = float(handle.model.opt.timestep)
        period = getattr(env.unwrapped, "dt", None)  # a gymnasium MujocoEnv: timestep x frame_skip
        if substeps is None and isinstance(period, (int, float)) and period > 0:
            return float(period), max(1, round(float(period) / timestep)), units, unit
        return (None, None, units, unit) if substeps is None else (timestep * substeps, substeps, units, unit)
    finally:
        env.close()


def _limits(path: str | None) -> Any:
    """The ``--safety`` limits (a bad file is a usage error: exit 2, one line)."""
    if path is None:
        return None
    from sim2real.safety import LimitsError, load_limits

    if not Path(path).is_file():
        raise UsageError(f"--safety: file {path!r} does not exist.")
    try:
        return load_limits(Path(path))
    except LimitsError as err:
        raise UsageError(f"--safety: {err}") from err


def cmd_study(args: argparse.Namespace, stdout: TextIO) -> int:
    from sim2real.output_paths import free_folder
    from sim2real.study import DEFAULT_OUT, run_study

    given = [f"{flag} {value}" for flag, value in (("--model", args.model), ("--env", args.env)) if value is not None]
    if given:  # every command that takes --task takes --model/--env; the study needs what ships for its tasks
        import shlex

        from sim2real.study.profile import study_tasks

        # The user's own words, quoted for a shell: `record --env pkg:make`, not an MJCF they may not have.
        own = f"--model {shlex.quote(args.model)}" if args.model is not None else f"--env {shlex.quote(args.env)}"
        raise UsageError(
            f"the study runs on tasks with a bundled profile and trained policies ({study_tasks()}); on your robot run "
            f"its loop with `sim2real record {own}`, `sim2real sysid fit LOG {own} --export EFFECTS.yaml`, `sim2real "
            f"train {own} --config EFFECTS.yaml` and `sim2real evaluate --config SPEC.yaml` (README, 'Your own "
            f"robot'). Received {' and '.join(given)}."
        )
    out = args.out if args.out is not None else str(free_folder(DEFAULT_OUT))
    check_outputs({}, ("--out", out, True))
    try:
        result = run_study(
            args.task,
            out,
            budget=args.budget,
            backend=args.backend,
            seed=args.seed,
            workers=args.workers,
            progress=not args.quiet,
            log=None if args.quiet else sys.stderr,
        )
    except ValueError as err:
        raise UsageError(str(err)) from err
    except OSError as err:
        raise UsageError(f"cannot write {out!r}: {err.strerror or err}.") from err
    print(result.summary, file=stdout)
    print(f"report: {result.report}", file=stdout)
    return 0
