"""``sim2real record`` and ``sim2real sysid fit``: excitation logs and fits, on a task, an MJCF file or an env factory.

``sysid fit`` reads a ``.npz`` log or a driver's CSV: the format is found from the file's first bytes (a ``.npz``
is a zip archive), never guessed from a failed load, and a CSV needs ``--columns MAP.yaml`` (the column mapping,
units, scale and offset of :func:`sysid.load_csv`; ``timestep``/``control_timestep`` default to the model's).

Example:
    >>> import contextlib, io, os, tempfile
    >>> from sim2real.cli import main
    >>> path = os.path.join(tempfile.mkdtemp(), "robot.csv")
    >>> _ = open(path, "w").write("t,q,dq,u\\n0,0,0,0\\n0.01,0,0,0\\n")
    >>> err = io.StringIO()
    >>> with contextlib.redirect_stderr(err):
    ...     main(["sysid", "fit", path, "--task", "dmc/reacher-easy", "--params", "dof_damping[*]"])
    2
    >>> "is a CSV file; give --columns MAP.yaml" in err.getvalue()
    True
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import re
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

from sim2real.cli._common import UsageError, check_outputs, source_inputs, source_of, writing
from sim2real.sources import Source, SourceError, open_source

__all__ = ["EXIT_FIT_NOT_OK", "cmd_record", "cmd_sysid"]

#: Exit code of ``sysid fit`` when the fit is not ok (``FitResult.ok`` is False) and nothing was exported; distinct
#: from ``evaluate --safety``'s 3 (a safety limit exceeded), so a pipeline running both knows which gate failed.
EXIT_FIT_NOT_OK = 4


def cmd_record(args: argparse.Namespace, out: TextIO) -> int:
    import sysid
    from sim2real.home import parse_home
    from sim2real.recording import record

    check_outputs({"--out": args.out}, inputs=source_inputs(args))
    try:
        sysid.check_log_path(args.out, "--out")  # before the recording, not after it
    except ValueError as err:
        raise UsageError(str(err)) from err
    source = source_of(args)
    try:
        home = parse_home(args.home)
        log = record(
            source,
            sets=args.sets,
            policy=args.policy,
            episodes=args.episodes,
            steps=args.steps,
            seed=args.seed,
            obs_noise=args.obs_noise,
            latency=args.latency,
            obs_latency=args.obs_latency,
            amplitude=args.amplitude,
            home=home,
            gravity_comp=args.gravity_comp,
            progress=False if args.quiet else None,
        )
    except (TypeError, ValueError) as err:  # SourceError is a ValueError
        raise UsageError(str(err)) from err
    writing(args.out, lambda: sysid.save_log(log, args.out))
    excitation = log.meta.get("excitation", {})
    where = "the env's reset state" if excitation.get("home") == "current" else "the home pose"
    print(
        f"wrote {args.out}: {log.num_steps} rows ({args.episodes} episode(s) of {source.label}, policy {args.policy} "
        f"around {where}, amplitude {excitation.get('amplitude', args.amplitude):g}); "
        f"true params {log.meta.get('true_params', {})}",
        file=out,
    )
    latency = {k: v for k, v in log.meta.get("true_latency_seconds", {}).items() if v}
    if latency:  # --latency/--obs-latency are ground truth too: the fit's latency is checked against them
        print("true latency (s): " + ", ".join(f"{k}={v:g}" for k, v in sorted(latency.items())), file=out)
    for note in excitation.get("notes", ()):
        print(f"note: {note}", file=out)
    return 0


def _model_of(source: Source) -> Any:
    """The MjModel (and the env to close) of a source."""
    try:
        env, handle = open_source(source)
    except SourceError as err:
        raise UsageError(str(err)) from err
    return env, handle


def _load(path: str, columns: str | None, model: Any, substeps: int | None) -> Any:
    import sysid

    kind = sysid.log_format(path)
    if kind == "unknown":  # before: an empty CSV was "a .npz log" to --columns and failed as one without it
        what = "is empty" if Path(path).stat().st_size == 0 else "starts with neither a zip header nor a CSV header row"
        raise UsageError(
            f"`log` {path!r} must be a .npz log from `sim2real record` or a driver's CSV (a header row with ',', ';' "
            f"or tabs). Received a file that {what}."
        )
    if kind == "csv":
        if columns is None:
            raise UsageError(
                f"{path!r} is a CSV file; give --columns MAP.yaml (column mapping, units, scale/offset; see "
                "sysid.load_csv) to read it."
            )
        mapping = sysid.load_column_map(Path(columns))
        meta = dict(mapping.get("meta", {}))
        meta.setdefault("timestep", float(model.opt.timestep))
        meta.setdefault("control_timestep", float(model.opt.timestep) * (substeps or 1))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", sysid.CsvWarning)
            try:
                log = sysid.load_csv(
                    path,
                    mapping["columns"],
                    meta=meta,
                    model=model,
                    units=mapping.get("units"),
                    scale=mapping.get("scale"),
                    offset=mapping.get("offset"),
                    delimiter=mapping.get("delimiter", ","),
                )
            except sysid.LogError as err:
                told = "meta['control_timestep']" in str(err) and "It looks like" not in str(err)  # not a unit
                if "control_timestep" in mapping.get("meta", {}) or not told:
                    raise
                # The period came from the model, not from the user: say where it came from and where to set it.
                raise UsageError(
                    f"{err} That {meta['control_timestep']:g} s is the model's control period (a --model MJCF runs at 50 Hz "
                    'unless it declares <custom><numeric name="sim2real_control_timestep" data="..."/></custom>): '
                    f"declare the driver's period there, or give meta: {{control_timestep: ...}} in {columns}."
                ) from err
        for item in caught:
            print(f"sim2real sysid fit: warning: {item.message}", file=sys.stderr)
        return log
    if columns is not None:
        raise UsageError(f"--columns applies to CSV logs; {path!r} is a .npz log. Received --columns {columns!r}.")
    return sysid.load_log(path, model=model)


class _Unstable(logging.Filter):
    """Counts (and holds back) MuJoCo's "simulation is unstable" warnings, which dm-control routes to absl's
    logger: a search trying parameters far from the log diverges on purpose and those rollouts are rejected, but
    each wrote a line (about 1900 for one fit of a 7-DoF arm from a CSV in the wrong units)."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if "simulation is unstable" in record.getMessage():
            self.count += 1
            return False
        return True


@contextlib.contextmanager
def _quiet_instability() -> Iterator[_Unstable]:
    unstable = _Unstable()
    logger = logging.getLogger("absl")
    logger.addFilter(unstable)
    try:
        yield unstable
    finally:
        logger.removeFilter(unstable)


def _latency(args: argparse.Namespace) -> int | bool | None:
    """``sysid.fit``'s ``latency``: the searched range's top from ``--latency-max``, else the default with
    ``--latency``."""
    if args.latency_max is not None:
        return int(args.latency_max)
    return True if args.latency else None


def _bounds(given: list[str]) -> dict[str, tuple[float, float]] | None:
    """``sysid.fit``'s ``bounds`` from ``--bounds ADDRESS=LOW,HIGH`` (repeatable); None when none is given.

    Example:
        >>> _bounds(["dof_frictionloss[wrist]=0,0.5"])
        {'dof_frictionloss[wrist]': (0.0, 0.5)}
    """
    out: dict[str, tuple[float, float]] = {}
    for text in given or ():
        address, _, pair = text.partition("=")
        try:
            low, high = (float(v) for v in pair.split(","))
        except ValueError:
            address = ""
        if not address.strip():
            raise UsageError(
                f"--bounds must look like 'dof_frictionloss[wrist]=0,0.5' (ADDRESS=LOW,HIGH). Received {text!r}."
            )
        out[address.strip()] = (low, high)
    return out or None


def _bounds_error(err: ValueError) -> UsageError:
    """``sysid.fit``'s message on its ``bounds`` argument, in the CLI's words (``--bounds``, with an example)."""
    text = str(err)
    needed = re.match(r"`bounds` must be given for '([^']+)': (.*) Received none\.$", text)
    if needed is not None:
        return UsageError(
            f"--bounds must be given for {needed.group(1)!r}: {needed.group(2)} Give its search range, e.g. "
            f"--bounds '{needed.group(1)}=0,1'. Received none."
        )
    if text.startswith("`bounds"):
        return UsageError(f"--bounds: {text}")
    return UsageError(text)


def _fit_report_html(result: Any, task: str, log_path: str) -> str:
    import base64
    import html

    from sim2real.report import html_page, png_bytes  # the one page shell and PNG export of every HTML report

    image = base64.b64encode(png_bytes(result.plot())).decode("ascii")
    warnings = "".join(f"<li>{html.escape(w)}</li>" for w in result.warnings) or "<li>none</li>"
    body = (
        f"<h1>System identification: {html.escape(task)}</h1><p>log: {html.escape(log_path)}</p>"
        f"<pre>{html.escape(result.summary())}</pre><h2>Warnings</h2><ul>{warnings}</ul>"
        f"<h2>Fit and residuals</h2><figure><img alt='fit' src='data:image/png;base64,{image}'></figure>"
    )
    return html_page(f"sysid fit: {task}", body)


def _has_noise(result: Any, group: str) -> bool:
    """Whether the fit estimated a sensor-noise level for ``group`` (``"qpos"``, ``"qvel"``)."""
    try:
        result.noise_level(group)
    except ValueError:
        return False
    return True


def cmd_sysid(args: argparse.Namespace, out: TextIO) -> int:
    import sysid
    from randomizers.files import atomic_write, check_suffix

    if args.sysid_command != "fit":
        raise UsageError("choose a sysid command: `sim2real sysid fit LOG --task TASK --params ...`")
    if args.task is None and args.model is None and args.env is None:
        raise UsageError("give the model to fit: --task TASK, --model ROBOT.xml or --env MODULE:FACTORY.")
    check_outputs(
        {"--out": args.out, "--report": args.report, "--export": args.export},
        inputs={"`log`": args.log, **source_inputs(args), "--columns": args.columns},
    )
    if args.report is not None:
        try:
            check_suffix(args.report, "--report", (".html", ".htm"), "an HTML page")
        except ValueError as err:
            raise UsageError(str(err)) from err
    source = source_of(args)
    if not Path(args.log).is_file():
        raise UsageError(f"cannot read the log: `log` {args.log!r} does not exist.")
    env, handle = _model_of(source)
    select = None
    try:
        if args.export:
            from sim2real.calibration import noise_select

            # Where the fitted qpos and qvel noise levels go in the env's observation (an MJCF robot: qpos then
            # qvel); None: one level over the whole observation, as before.
            select = noise_select(env)
        log = _load(args.log, args.columns, handle.model, handle.substeps)
        params = [p.strip() for p in args.params.split(",") if p.strip()]
        with _quiet_instability() as unstable:
            result = sysid.fit(
                log,
                handle.model,
                params,
                bounds=_bounds(getattr(args, "bounds", [])),
                latency=_latency(args),
                seed=args.seed,
                progress=not args.quiet,
                horizon=getattr(args, "horizon", "auto"),
            )
        if unstable.count:
            print(
                f"sim2real sysid fit: note: MuJoCo reported an unstable simulation {unstable.count} time(s) during "
                "the search (its warnings are counted here, not printed: parameter candidates far from the log "
                "diverge)",
                file=sys.stderr,
            )
    except FileNotFoundError as err:
        raise UsageError(f"cannot read {err}") from err
    except (TypeError, ValueError) as err:  # LogError is a ValueError
        raise _bounds_error(err) if isinstance(err, ValueError) else UsageError(str(err)) from err
    finally:
        close = getattr(env, "close", None)
        if callable(close):
            close()
    # The page is rendered before anything is written, so a failure while drawing it leaves no JSON behind.
    page = _fit_report_html(result, source.label, args.log) if args.report else None
    ok = bool(getattr(result, "ok", True))
    effects = None
    if args.export and (ok or args.force):
        if select is not None:  # the groups this fit has a noise level for (none: one level, or no noise at all)
            select = {group: where for group, where in select.items() if _has_noise(result, group)} or None
        try:
            effects = result.to_randomizers(noise_select=select, force=bool(args.force))
        except ValueError as err:
            raise UsageError(f"--export: {err}") from err
    writing(args.out, lambda: result.to_json(args.out))
    written = [args.out]
    if page is not None:
        writing(args.report, lambda: atomic_write(args.report, page))
        written.append(args.report)
    if effects is not None:
        writing(args.export, lambda: atomic_write(args.export, effects))
        written.append(args.export)
    print(result.summary(), file=out)
    print(f"wrote {' and '.join(written)}", file=out)
    if not ok:
        reasons = "; ".join(getattr(getattr(result, "quality", None), "reasons", ())) or "see the warnings"
        forced = (
            " (exported anyway: --force)"
            if effects is not None
            else (f"; {args.export} was not written (pass --force to export it anyway)" if args.export else "")
        )
        print(f"sim2real sysid fit: the fit is not ok: {reasons}{forced}", file=sys.stderr)
        short = int(getattr(getattr(result, "quality", None), "horizon", 0) or 0)
        if getattr(args, "horizon", "auto") == "auto" and short:
            # A stiff servo amplifies the sensor noise of a logged start state, so the automatic length is often
            # the shortest; coupled joints (a tendon-driven gripper) then leave short segments' residuals coloured.
            print(
                f"sim2real sysid fit: hint: the fit used shooting segments of {short} control steps (--horizon auto); "
                "if the model is right, refit with --horizon episode or a longer --horizon N",
                file=sys.stderr,
            )
        return 0 if effects is not None else EXIT_FIT_NOT_OK
    return 0
