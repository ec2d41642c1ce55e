"""The ``sim2real`` command line: ``tasks``, ``demo``, ``visualize``, ``record`` and ``sysid fit``.

Exit codes: 0 on success, 2 on a usage error or bad input (unknown task, bad config, an output path that cannot
be written), with one line on stderr and no traceback. Output paths are checked (:mod:`sim2real.output_paths`)
before any work starts, and every file is written atomically, so a failure leaves nothing half-written.

Example:
    >>> from sim2real.cli import main
    >>> main(["tasks"])  # doctest: +ELLIPSIS
    dmc/reacher-easy ...
    0
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

import sim2real
from randomizers import Effect

__all__ = ["ARM_REACH_POLICY", "default_effects", "main"]

#: The task with a scripted controller; every other task gets the zero action.
ARM_REACH = "sim2real/arm-reach"
#: One-line description of the scripted arm-reach controller, printed by ``sim2real demo``.
ARM_REACH_POLICY = "scripted reach: action = clip(target - end_effector, -0.05, 0.05)"

Policy = Callable[[np.ndarray], np.ndarray]


class _UsageError(Exception):
    """Bad input found after parsing; ``main`` prints it and returns 2."""


def _check_outputs(files: dict[str, str | None], folder: tuple[str, str, bool] | None = None) -> None:
    """Checks every output of a command (``{"--out": path, "--report": path}``, files; ``folder`` is
    ``(argument, path, new)``) before any work, so a bad path fails at once and creates nothing."""
    from sim2real.output_paths import OutputPathError, check_distinct, check_file, check_folder

    given = {argument: path for argument, path in files.items() if path is not None}
    try:
        for argument, path in given.items():
            check_file(path, argument)
        check_distinct(given)
        if folder is not None:
            check_folder(folder[1], folder[0], new=folder[2])
    except OutputPathError as err:
        raise _UsageError(str(err)) from err


def _writing(path: str | os.PathLike[str], write: Callable[[], Any]) -> Any:
    """Runs ``write`` (an atomic write of ``path``); a failure of the file system (disk full, a folder removed
    meanwhile) becomes one line and exit 2. The atomic writer has already removed its temporary file."""
    try:
        return write()
    except OSError as err:
        reason = err.strerror or str(err)
        raise _UsageError(f"cannot write {os.fspath(path)!r}: {reason}.") from err


def default_effects() -> list[Effect]:
    """The physics randomisation ``sim2real demo`` applies when no ``--config`` is given.

    The ranges are wide enough that the scripted arm-reach controller visibly suffers: slower
    servos (lower actuator gain), heavier links and more joint damping make it reach later or
    not at all within the 200-step episode.
    """
    return [
        sim2real.Mass(scale=sim2real.Uniform(0.5, 2.0)),
        sim2real.Damping(scale=sim2real.LogUniform(0.5, 4.0)),
        sim2real.ActuatorGain(scale=sim2real.Uniform(0.3, 1.0)),
        sim2real.Friction(scale=sim2real.Uniform(0.5, 1.5)),
    ]


# ---------------------------------------------------------------------------------- argument types


def _int_at_least(minimum: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"must be an int >= {minimum}. Received {text!r}.")
        return value

    parse.__name__ = f"int >= {minimum}"
    return parse


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sim2real",
        description=(
            "sim2real: make robot policies survive the jump from MuJoCo simulation to the real world "
            "(physics randomisation, noise, system identification, gap evaluation)."
        ),
        epilog="Run `sim2real <command> --help` for the options of one command.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {sim2real.__version__}")
    sub = parser.add_subparsers(dest="command", title="commands")

    sub.add_parser(
        "tasks",
        help="list the task ids `sim2real.make` accepts, with a one-line description each",
        description="List the task ids `sim2real.make` accepts. Any gymnasium id also works as gym/<id>.",
    )

    demo = sub.add_parser(
        "demo",
        help="run a controller on the nominal and on the physics-randomised env and compare",
        description=(
            "Run a controller on the nominal task and on the same task with randomised physics "
            "(same reset seeds, so the same targets), and print mean return, its std, success rate "
            "and the parameters sampled in the first episodes. sim2real/arm-reach uses a scripted "
            "reaching controller; other tasks use the zero action."
        ),
    )
    demo.add_argument("--task", default=ARM_REACH, help="task id (see `sim2real tasks`; default: %(default)s)")
    demo.add_argument(
        "--episodes", type=_int_at_least(1), default=20, help="episodes per condition (default: %(default)s)"
    )
    demo.add_argument(
        "--seed",
        type=_int_at_least(0),
        default=0,
        help="root seed; episode i resets with seed+i in both conditions (default: %(default)s)",
    )
    demo.add_argument(
        "--config",
        metavar="EFFECTS.yaml",
        help=(
            "YAML file of effects (see randomizers.load_effects); default: Mass x U(0.5, 2), "
            "Damping x LogU(0.5, 4), ActuatorGain x U(0.3, 1), Friction x U(0.5, 1.5)"
        ),
    )
    demo.add_argument("--quiet", action="store_true", help="no progress bar")

    visualize = sub.add_parser(
        "visualize",
        help="render N randomised frames of a task into one PNG contact sheet",
        description=(
            "Render the first frame of N episodes of TASK (reset seeds SEED..SEED+N-1) with the effects of "
            "--config applied, as a grid in one PNG (written atomically). Without --config the nominal task is shown."
        ),
    )
    visualize.add_argument("task", help="task id (see `sim2real tasks`)")
    visualize.add_argument("--config", metavar="EFFECTS.yaml", help="YAML file of effects (randomizers.load_effects)")
    visualize.add_argument("--n", type=_int_at_least(1), default=16, help="number of frames (default: %(default)s)")
    visualize.add_argument("--out", default="sheet.png", help="output PNG path (default: %(default)s)")
    visualize.add_argument("--seed", type=_int_at_least(0), default=0, help="root seed (default: %(default)s)")
    visualize.add_argument(
        "--size", type=_int_at_least(8), default=84, help="frame side in pixels (default: %(default)s)"
    )
    visualize.add_argument("--camera", help="camera name or id (default: the model's first camera)")

    record = sub.add_parser(
        "record",
        help="record an excitation log (.npz) for system identification",
        description=(
            "Run an excitation signal open loop on TASK's model (perturbed by --set, with action latency and sensor "
            "noise) and write a trajectory log (.npz, written atomically) that `sim2real sysid fit` reads. The true "
            "values of the perturbed parameters and the latencies are stored in the log's meta."
        ),
    )
    record.add_argument("--task", default=ARM_REACH, help="task id (default: %(default)s)")
    record.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="ADDRESS=VALUE",
        help="perturbation: 'dof_damping[*]=*1.3' (scale), '+0.1' (add) or '=0.5' (set); repeatable",
    )
    record.add_argument("--policy", default="multisine", help="random, multisine, chirp or prbs (default: %(default)s)")
    record.add_argument("--episodes", type=_int_at_least(1), default=4, help="episodes (default: %(default)s)")
    record.add_argument(
        "--steps", type=_int_at_least(2), default=200, help="control steps per episode (default: %(default)s)"
    )
    record.add_argument("--seed", type=_int_at_least(0), default=0, help="root seed (default: %(default)s)")
    record.add_argument("--obs-noise", type=float, default=0.0, help="sensor noise std on qpos/qvel/sensordata")
    record.add_argument("--latency", type=_int_at_least(0), default=0, help="action latency in control steps")
    record.add_argument("--obs-latency", type=_int_at_least(0), default=0, help="sensor latency in control steps")
    record.add_argument("--amplitude", type=float, default=0.5, help="fraction of each actuator's half-range")
    record.add_argument("--out", required=True, help="output .npz path")

    train = sub.add_parser(
        "train",
        help="train a PPO or SAC policy with TorchRL and save a checkpoint",
        description="Train a policy (`sim2real train --task T --algo ppo --frames N [--config effects.yaml] --out ckpt.pt`).",
        add_help=False,
    )
    del train  # its arguments are parsed by sim2real.agents.cli (torch loads only for this command)

    sysid_parser = sub.add_parser("sysid", help="system identification (`sim2real sysid fit LOG ...`)")
    sysid_sub = sysid_parser.add_subparsers(dest="sysid_command", title="sysid commands")
    fit = sysid_sub.add_parser(
        "fit",
        help="fit parameters (and latency) of a task's model to a trajectory log",
        description=(
            "Fit the addressed parameters of TASK's model to LOG (.npz from `sim2real record`, or a CSV converted with "
            "sysid.load_csv) and write the estimates, standard errors, 95%% intervals, Cramér-Rao bounds, noise levels, "
            "fit percentages and identifiability warnings as JSON."
        ),
    )
    fit.add_argument("log", help="trajectory log (.npz)")
    fit.add_argument("--task", required=True, help="task id whose model is fitted")
    fit.add_argument(
        "--params", required=True, help="comma-separated addresses, e.g. 'dof_damping[*],geom_friction[*][0]'"
    )
    fit.add_argument("--latency", action="store_true", help="also estimate the action latency")
    fit.add_argument("--out", default="result.json", help="JSON output (default: %(default)s)")
    fit.add_argument("--report", help="also write an HTML page with the summary and the fit figure")
    fit.add_argument(
        "--seed", type=_int_at_least(0), default=0, help="seed of the global search (default: %(default)s)"
    )
    fit.add_argument("--quiet", action="store_true", help="no progress bar")

    evaluate = sub.add_parser(
        "evaluate",
        help="score policies on sim, randomised sim, a real target and sweeps; write the gap report",
        description=(
            "Evaluate the policies of a spec (YAML, see sim2real.spec) on the nominal sim, a randomised sim, the real "
            "target (a twin or measured returns) and sweeps, then write DIR/report.html, report.md, report.json and "
            "figures/*.png."
        ),
    )
    evaluate.add_argument("--config", required=True, help="evaluation spec (YAML)")
    evaluate.add_argument(
        "--out",
        required=True,
        help=(
            "report folder (created with its parents); in an existing folder only report.html, report.md, "
            "report.json and figures/*.png are replaced, nothing else in it is touched"
        ),
    )
    evaluate.add_argument("--backend", choices=("serial", "local", "ray"), default="local", help="default: local")
    evaluate.add_argument("--workers", type=_int_at_least(1), default=None, help="processes (default: CPU count)")
    evaluate.add_argument("--quiet", action="store_true", help="no progress bar")

    study = sub.add_parser(
        "study",
        help="the main job: twin, sysid, policies, evaluation and the gap report on an embedded default",
        description=(
            "Run the whole sim-to-real loop: record logs on a 'real' twin, fit them with system identification, "
            "build the calibrated randomised simulator, evaluate nominal, randomised, calibrated and scripted "
            "policies on sim, randomised sim, the twin and sweeps, and write the gap report."
        ),
    )
    study.add_argument("--task", default="dmc/reacher-easy", help="task with a bundled study (default: %(default)s)")
    study.add_argument(
        "--out",
        default=None,
        help=(
            "study folder: a new or empty folder (created with its parents). An existing folder that holds anything "
            "is never overwritten: the command refuses with exit 2 before any work. Default: sim2real-study, or the "
            "first free sim2real-study-2, -3, ... when it is taken, so a second run never touches the first"
        ),
    )
    study.add_argument("--budget", choices=("quick", "standard", "full"), default="standard", help="default: standard")
    study.add_argument("--backend", choices=("local", "ray", "serial"), default="local", help="default: local")
    study.add_argument("--seed", type=_int_at_least(0), default=0, help="default: %(default)s")
    study.add_argument("--workers", type=_int_at_least(1), default=None, help="processes (default: CPU count)")
    study.add_argument("--quiet", action="store_true", help="no stage lines or progress bars")
    return parser


def _cmd_evaluate(args: argparse.Namespace, out: TextIO) -> int:
    from sim2real._gl import RenderingUnavailable
    from sim2real.report import GapReport
    from sim2real.spec import SpecError, load_spec
    from sysid import FitResult

    try:
        spec = load_spec(Path(args.config))
        options = dict(spec.report)
        fit = FitResult.from_json(Path(options.pop("fit"))) if "fit" in options else None
    except FileNotFoundError as err:
        raise _UsageError(str(err)) from err
    except (SpecError, ValueError) as err:
        raise _UsageError(str(err)) from err
    _check_outputs({}, ("--out", args.out, False))
    from sim2real.agents.checkpoint import CheckpointError

    try:  # checkpoints are loaded and checked here, before any worker starts
        evaluation = spec.run(backend=args.backend, workers=args.workers, progress=not args.quiet)
    except CheckpointError as err:
        raise _UsageError(str(err)) from err
    notes = options.pop("notes", ())
    notes = [notes] if isinstance(notes, str) else list(notes)
    try:
        sheet = spec.contact_sheet()
    except RenderingUnavailable as err:  # the report still has every number; say why the images are missing
        sheet = None
        notes.append(f"no contact sheet of the visual effects: {err}")
    report = GapReport.build(evaluation, fit=fit, contact_sheet=sheet, rng=spec.seed, notes=tuple(notes), **options)
    files = _writing(args.out, lambda: report.write(Path(args.out)))
    print(report.summary(), file=out)
    print(f"wrote {files.html}", file=out)
    return 0


def _cmd_study(args: argparse.Namespace, stdout: TextIO) -> int:
    from sim2real.output_paths import free_folder
    from sim2real.study import DEFAULT_OUT, run_study

    out = args.out if args.out is not None else str(free_folder(DEFAULT_OUT))
    _check_outputs({}, ("--out", out, True))
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
        raise _UsageError(str(err)) from err
    except OSError as err:
        raise _UsageError(f"cannot write {out!r}: {err.strerror or err}.") from err
    print(result.summary, file=stdout)
    print(f"report: {result.report}", file=stdout)
    return 0


# ---------------------------------------------------------------------------------- tasks


def _cmd_tasks(out: TextIO) -> int:
    width = max(len(task_id) for task_id in sim2real.TASKS)
    for task_id, task in sim2real.TASKS.items():
        print(f"{task_id:<{width}}  {task.description}", file=out)
    print(f"\n{'gym/<id>':<{width}}  any gymnasium id works too, e.g. gym/Hopper-v5.", file=out)
    return 0


# ---------------------------------------------------------------------------------- demo


@dataclass(frozen=True)
class _Episode:
    ret: float
    length: int
    success: bool | None  # None when the task reports no "is_success"
    diverged: bool
    params: dict[str, float]


def _arm_reach_policy(obs: np.ndarray) -> np.ndarray:
    return np.clip(obs[3:6] - obs[0:3], -0.05, 0.05).astype(np.float32)


def _zero_policy(env: Any) -> Policy:
    zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    return lambda obs: zero


def _run_episode(env: Any, policy: Policy, seed: int) -> _Episode:
    obs, info = env.reset(seed=seed)
    params = dict(info.get("sim2real", {}).get("params", {}))
    total, length, done = 0.0, 0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        total += float(reward)
        length += 1
        done = bool(terminated or truncated)
    success = bool(info["is_success"]) if "is_success" in info else None
    diverged = bool(info.get("sim2real", {}).get("diverged", False) or info.get("diverged", False))
    return _Episode(total, length, success, diverged, params)


def _load_demo_effects(config: str | None) -> list[Effect]:
    if config is None:
        return default_effects()
    try:
        # A Path makes load_effects read the file whatever its suffix (a str could be taken for YAML text).
        return list(sim2real.load_effects(Path(config)))
    except (OSError, ValueError) as err:
        raise _UsageError(f"--config: {err}") from err


def _make_envs(task: str, effects: Sequence[Effect], seed: int) -> tuple[Any, Any]:
    try:
        nominal = sim2real.make(task)
    except ValueError as err:
        raise _UsageError(str(err)) from err
    try:
        randomised = sim2real.wrap(sim2real.make(task), *effects, seed=seed)
    except (TypeError, ValueError) as err:
        nominal.close()
        raise _UsageError(f"the effects do not fit task {task!r}: {err}") from err
    return nominal, randomised


def _summary_row(name: str, episodes: list[_Episode]) -> str:
    returns = np.array([e.ret for e in episodes])
    successes = [e.success for e in episodes if e.success is not None]
    success = f"{100.0 * np.mean(successes):6.1f}%" if successes else f"{'n/a':>7}"
    length = np.mean([e.length for e in episodes])
    diverged = sum(e.diverged for e in episodes)
    return (
        f"{name:<12}{returns.mean():>12.2f}{returns.std():>10.2f}{success:>10}{length:>10.1f}"
        f"{diverged:>7d}/{len(episodes)}"
    )


def _print_params(episodes: list[_Episode], nominal: dict[str, float], seed: int, out: TextIO) -> None:
    shown = episodes[:3]
    addresses = sorted({a for e in shown for a in e.params})
    if not addresses:
        print("(the effects sampled no parameters)", file=out)
        return
    width = max(len(a) for a in addresses)
    heads = f"{'nominal':>14}" + "".join(f"{f'ep {i} (seed {seed + i})':>18}" for i in range(len(shown)))
    print(f"{'parameter':<{width}}{heads}", file=out)

    def cell(values: dict[str, float], address: str, size: int) -> str:
        return f"{values[address]:>{size}.6g}" if address in values else f"{'-':>{size}}"

    for address in addresses:
        cells = cell(nominal, address, 14) + "".join(cell(e.params, address, 18) for e in shown)
        print(f"{address:<{width}}{cells}", file=out)


def _cmd_demo(args: argparse.Namespace, out: TextIO) -> int:
    from tqdm import tqdm

    effects = _load_demo_effects(args.config)
    nominal, randomised = _make_envs(args.task, effects, args.seed)
    policy: Policy
    if args.task == ARM_REACH:
        policy_name, policy = ARM_REACH_POLICY, _arm_reach_policy
    else:
        policy_name = f"zero action (no scripted controller for {args.task}; only {ARM_REACH} has one)"
        policy = _zero_policy(nominal)

    # Read before close(): the wrapper knows the nominal value of every address it perturbs.
    randomizer = getattr(randomised, "randomizer", None)
    nominal_params = randomizer.nominal_params() if randomizer is not None else {}
    n = args.episodes
    results: dict[str, list[_Episode]] = {}
    show_bar = not args.quiet and sys.stderr.isatty()
    try:
        with tqdm(total=2 * n, desc="demo", unit="ep", file=sys.stderr, disable=not show_bar) as bar:
            for name, env in (("nominal", nominal), ("randomised", randomised)):
                bar.set_postfix_str(name)
                episodes = []
                for i in range(n):
                    episodes.append(_run_episode(env, policy, args.seed + i))
                    bar.update(1)
                results[name] = episodes
    finally:
        nominal.close()
        randomised.close()

    print(
        f"sim2real demo: {args.task}, {n} episode(s) per condition, reset seeds {args.seed}..{args.seed + n - 1}",
        file=out,
    )
    print(f"policy: {policy_name}", file=out)
    source = args.config if args.config is not None else "defaults"
    print(
        f"randomised condition: sim2real.wrap(make({args.task!r}), *effects, seed={args.seed}), effects from {source}:",
        file=out,
    )
    for effect in effects:
        print(f"  {effect!r}", file=out)
    print(file=out)
    print(f"{'condition':<12}{'mean return':>12}{'std':>10}{'success':>10}{'mean len':>10}{'diverged':>10}", file=out)
    for name, episodes in results.items():
        print(_summary_row(name, episodes), file=out)
    gap = np.mean([e.ret for e in results["randomised"]]) - np.mean([e.ret for e in results["nominal"]])
    print(f"return gap (randomised - nominal): {gap:+.2f}", file=out)
    if results["nominal"][0].success is None:
        print("(this task reports no success flag; compare returns)", file=out)
    print(file=out)
    print(f"sampled parameters of the randomised condition, first {min(3, n)} episode(s):", file=out)
    _print_params(results["randomised"], nominal_params, args.seed, out)
    return 0


# ---------------------------------------------------------------------------------- visualize


def _cmd_visualize(args: argparse.Namespace, out: TextIO) -> int:
    _check_outputs({"--out": args.out})
    effects = _load_demo_effects(args.config) if args.config is not None else []
    camera: int | str | None = args.camera
    if isinstance(camera, str) and camera.lstrip("-").isdigit():
        camera = int(camera)
    try:
        sheet = _writing(
            args.out,
            lambda: sim2real.contact_sheet(
                args.task, effects, n=args.n, seed=args.seed, size=(args.size, args.size), camera=camera, out=args.out
            ),
        )
    except (TypeError, ValueError, FileNotFoundError) as err:
        raise _UsageError(str(err)) from err
    h, w = sheet.image.shape[:2]
    print(f"wrote {sheet.path} ({args.n} frames of {args.task}, {len(effects)} effect(s), {w}x{h} px)", file=out)
    return 0


# ---------------------------------------------------------------------------------- record / sysid


def _cmd_record(args: argparse.Namespace, out: TextIO) -> int:
    import sysid
    from sim2real.recording import record

    _check_outputs({"--out": args.out})
    try:
        log = record(
            args.task,
            sets=args.sets,
            policy=args.policy,
            episodes=args.episodes,
            steps=args.steps,
            seed=args.seed,
            obs_noise=args.obs_noise,
            latency=args.latency,
            obs_latency=args.obs_latency,
            amplitude=args.amplitude,
        )
    except (TypeError, ValueError) as err:
        raise _UsageError(str(err)) from err
    _writing(args.out, lambda: sysid.save_log(log, args.out))
    print(
        f"wrote {args.out}: {log.num_steps} rows ({args.episodes} episode(s) of {args.task}, policy {args.policy}); "
        f"true params {log.meta.get('true_params', {})}",
        file=out,
    )
    return 0


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


def _cmd_sysid(args: argparse.Namespace, out: TextIO) -> int:
    import sysid
    from randomizers.files import atomic_write
    from sim2real.tasks import make

    if args.sysid_command != "fit":
        raise _UsageError("choose a sysid command: `sim2real sysid fit LOG --task TASK --params ...`")
    _check_outputs({"--out": args.out, "--report": args.report})
    try:
        env = make(args.task)
        handle = sim2real.find_physics(env)
        if handle is None:
            raise ValueError(f"task {args.task!r} has no MuJoCo model")
        log = sysid.load_log(args.log, model=handle.model)
        params = [p.strip() for p in args.params.split(",") if p.strip()]
        result = sysid.fit(
            log, handle.model, params, latency=True if args.latency else None, seed=args.seed, progress=not args.quiet
        )
        env.close()
    except FileNotFoundError as err:
        raise _UsageError(f"cannot read the log: {err}") from err
    except (TypeError, ValueError) as err:  # LogError is a ValueError
        raise _UsageError(str(err)) from err
    # The page is rendered before anything is written, so a failure while drawing it leaves no JSON behind.
    page = _fit_report_html(result, args.task, args.log) if args.report else None
    _writing(args.out, lambda: result.to_json(args.out))
    if page is not None:
        _writing(args.report, lambda: atomic_write(args.report, page))
    print(result.summary(), file=out)
    print(f"wrote {args.out}" + (f" and {args.report}" if args.report else ""), file=out)
    return 0


# ---------------------------------------------------------------------------------- entry point


def main(argv: list[str] | None = None) -> int:
    """Runs the ``sim2real`` command line.

    Args:
        argv: arguments without the program name (default ``sys.argv[1:]``).

    Returns:
        The exit code: 0 on success, 2 on a usage error or bad input.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["train"]:
        from sim2real.agents.cli import cli_train

        return cli_train(argv[1:])
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # --help, --version and argparse's own usage errors
        return exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 2)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        if args.command == "tasks":
            return _cmd_tasks(sys.stdout)
        if args.command == "visualize":
            return _cmd_visualize(args, sys.stdout)
        if args.command == "record":
            return _cmd_record(args, sys.stdout)
        if args.command == "sysid":
            return _cmd_sysid(args, sys.stdout)
        if args.command == "evaluate":
            return _cmd_evaluate(args, sys.stdout)
        if args.command == "study":
            return _cmd_study(args, sys.stdout)
        return _cmd_demo(args, sys.stdout)
    except _UsageError as err:
        print(f"sim2real {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"sim2real {args.command}: interrupted; no partial output was left behind", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`sim2real tasks | head -1`): stop quietly, and point stdout at devnull so
        # the interpreter's final flush does not raise a second time.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1


if __name__ == "__main__":
    sys.exit(main())
