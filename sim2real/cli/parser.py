"""The ``sim2real`` argument parser (``train`` parses its own arguments in :mod:`sim2real.agents.cli`).

Example:
    >>> args = build_parser().parse_args(["record", "--model", "robot.xml", "--home", "keyframe", "--out", "a.npz"])
    >>> args.task, args.model, args.env, args.home, args.gravity_comp
    (None, 'robot.xml', None, 'keyframe', False)
"""

from __future__ import annotations

import argparse

import sim2real
from sim2real.cli._common import OneLineParser, add_source_arguments, int_at_least
from sim2real.cli.sysid_commands import EXIT_FIT_NOT_OK

__all__ = ["ARM_REACH", "build_parser", "join_negative_values"]

#: Options whose value may start with a minus sign (a home pose of negative joint angles).
NEGATIVE_VALUES = ("--home",)


def _horizon(text: str) -> str | int | None:
    """``--horizon``: ``auto``, ``episode`` (None: whole episodes) or a number of control steps >= 1.

    Example:
        >>> _horizon("auto"), _horizon("episode"), _horizon("40")
        ('auto', None, 40)
    """
    if text in ("auto", "episode"):
        return "auto" if text == "auto" else None
    try:
        steps = int(text)
    except ValueError:
        steps = 0
    if steps < 1:
        raise argparse.ArgumentTypeError(
            f"must be 'auto', 'episode' or a number of control steps >= 1. Received {text!r}"
        )
    return steps


def join_negative_values(argv: list[str]) -> list[str]:
    """``--home -0.4,1.2`` as ``--home=-0.4,1.2``: argparse takes a value that starts with ``-`` and is not a plain
    number for an option, so an arm's home pose of negative angles could only be given with ``=``.

    Example:
        >>> join_negative_values(["record", "--home", "-0.4,1.2", "--out", "a.npz"])
        ['record', '--home=-0.4,1.2', '--out', 'a.npz']
    """
    out: list[str] = []
    i = 0
    while i < len(argv):
        value = argv[i + 1] if i + 1 < len(argv) else ""
        if argv[i] in NEGATIVE_VALUES and value[:1] == "-" and value[1:2] in tuple("0123456789."):
            out.append(f"{argv[i]}={value}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


#: The task with a scripted controller; every other task gets the zero action.
ARM_REACH = "sim2real/arm-reach"


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
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
            "reaching controller; other tasks, --model ROBOT.xml and --env MODULE:FACTORY use the zero action."
        ),
    )
    add_source_arguments(demo, default_task=ARM_REACH)
    demo.add_argument(
        "--episodes", type=int_at_least(1), default=20, help="episodes per condition (default: %(default)s)"
    )
    demo.add_argument(
        "--seed",
        type=int_at_least(0),
        default=0,
        help="root seed; episode i resets with seed+i in both conditions (default: %(default)s)",
    )
    demo.add_argument(
        "--config",
        metavar="EFFECTS.yaml",
        help=(
            "YAML file of effects and signal models (see randomizers.load_config, e.g. `sysid fit --export`); "
            "default: Mass x U(0.5, 2), "
            "Damping x LogU(0.5, 4), ActuatorGain x U(0.3, 1), Friction x U(0.5, 1.5)"
        ),
    )
    demo.add_argument("--quiet", action="store_true", help="no progress bar")

    visualize = sub.add_parser(
        "visualize",
        help="render N randomised frames of a task into one PNG contact sheet",
        description=(
            "Render the first frame of N episodes of TASK (or --model ROBOT.xml, --env MODULE:FACTORY; reset seeds SEED..SEED+N-1) with the effects of "
            "--config applied, as a grid in one PNG (written atomically). Without --config the nominal task is shown."
        ),
    )
    visualize.add_argument(
        "task_positional",
        metavar="TASK",
        nargs="?",
        default=None,
        help="task id (see `sim2real tasks`), or give --model/--env",
    )
    add_source_arguments(visualize, task_help="task id, as the positional")
    visualize.add_argument("--config", metavar="EFFECTS.yaml", help="YAML file of effects (randomizers.load_effects)")
    visualize.add_argument("--n", type=int_at_least(1), default=16, help="number of frames (default: %(default)s)")
    visualize.add_argument("--out", default="sheet.png", help="output PNG path (default: %(default)s)")
    visualize.add_argument("--seed", type=int_at_least(0), default=0, help="root seed (default: %(default)s)")
    visualize.add_argument(
        "--size", type=int_at_least(8), default=84, help="frame side in pixels (default: %(default)s)"
    )
    visualize.add_argument("--camera", help="camera name or id (default: the model's first camera)")

    record = sub.add_parser(
        "record",
        help="record an excitation log (.npz) for system identification",
        description=(
            "Run an excitation signal on TASK's model (or --model ROBOT.xml, --env MODULE:FACTORY) (perturbed by --set, with action latency and sensor "
            "noise) and write a trajectory log (.npz, written atomically) that `sim2real sysid fit` reads. The true "
            "values of the perturbed parameters and the latencies are stored in the log's meta."
        ),
    )
    add_source_arguments(record, default_task=ARM_REACH)
    record.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="ADDRESS=VALUE",
        help="perturbation: 'dof_damping[*]=*1.3' (scale), '+0.1' (add) or '=0.5' (set); repeatable",
    )
    record.add_argument("--policy", default="multisine", help="random, multisine, chirp or prbs (default: %(default)s)")
    record.add_argument("--episodes", type=int_at_least(1), default=4, help="episodes (default: %(default)s)")
    record.add_argument(
        "--steps", type=int_at_least(2), default=200, help="control steps per episode (default: %(default)s)"
    )
    record.add_argument("--seed", type=int_at_least(0), default=0, help="root seed (default: %(default)s)")
    record.add_argument(
        "--obs-noise",
        default="0",
        metavar="S|CHANNEL=S,CHANNEL[JOINT]=S,...",
        help=(
            "Gaussian sensor noise std: one number for every logged qpos/qvel/sensordata entry, or comma-separated "
            "entries qpos=S, qvel=S, sensordata=S, qpos[JOINT]=S, qvel[JOINT]=S (JOINT: a hinge or slide joint's "
            "name or fnmatch pattern; rad, rad/s for hinges, m, m/s for slides), later entries overriding earlier "
            "ones, e.g. 'qpos=0.001,qpos[lift]=0.0001,qvel=0.01' (default: %(default)s); stored per entry in the "
            "log's meta['noise_std_per_entry']"
        ),
    )
    record.add_argument("--latency", type=int_at_least(0), default=0, help="action latency in control steps")
    record.add_argument("--obs-latency", type=int_at_least(0), default=0, help="sensor latency in control steps")
    record.add_argument("--amplitude", type=float, default=0.5, help="fraction of each actuator's half-range")
    record.add_argument(
        "--home",
        default=None,
        metavar="keyframe|current|q0,q1,...",
        help=(
            "start pose the excitation swings around: the model's home keyframe (default for --model/--env; else "
            "its first keyframe, else qpos0), the env's reset state (default for --task) or joint positions; with a "
            "fixed pose the amplitude is halved until every limited joint stays in range (the output says so)"
        ),
    )
    record.add_argument(
        "--gravity-comp",
        action="store_true",
        help="torque-driven arms: add the torque that holds the arm against gravity at its current pose",
    )
    record.add_argument("--out", required=True, help="output .npz path")
    record.add_argument("--quiet", action="store_true", help="no progress bar (shown on a terminal)")

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
            "Fit the addressed parameters of TASK's model (or --model ROBOT.xml, --env MODULE:FACTORY) to LOG (.npz "
            "from `sim2real record`, or a driver's CSV read through --columns MAP.yaml) and write the estimates, standard errors, 95% intervals, Cramér-Rao bounds, noise levels, "
            f"fit percentages and identifiability warnings as JSON. Exit {EXIT_FIT_NOT_OK} when the fitted model cannot reproduce the log (the "
            "JSON is still written; the reasons are printed)."
        ),
    )
    fit.add_argument("log", help="trajectory log (.npz from `sim2real record`) or a driver's CSV (with --columns)")
    add_source_arguments(fit, task_help="task id whose model is fitted")
    fit.add_argument(
        "--columns",
        metavar="MAP.yaml",
        help="for a CSV log: column mapping, units, scale/offset (see sysid.load_csv and README 'Your own robot')",
    )
    fit.add_argument(
        "--params", required=True, help="comma-separated addresses, e.g. 'dof_damping[*],geom_friction[*][0]'"
    )
    fit.add_argument(
        "--bounds",
        action="append",
        default=[],
        metavar="ADDRESS=LOW,HIGH",
        help=(
            "search range of a fitted parameter, repeatable, e.g. 'dof_frictionloss[wrist]=0,0.5' (default: its "
            "model value /10 to x10; required where that value is 0)"
        ),
    )
    fit.add_argument(
        "--latency",
        action="store_true",
        help="also estimate the action latency (and the sensor latency when the log has sensors): 0-5 control steps",
    )
    fit.add_argument(
        "--latency-max",
        type=int_at_least(1),
        metavar="N",
        help="estimate the latencies over 0-N control steps (implies --latency; the fit warns when its estimate is N)",
    )
    fit.add_argument(
        "--horizon",
        type=_horizon,
        default="auto",
        metavar="auto|episode|N",
        help=(
            "shooting-segment length: 'auto' (default: from how fast the open-loop prediction leaves the log), "
            "'episode' (whole episodes) or N control steps; each segment's initial state is fitted"
        ),
    )
    fit.add_argument("--out", default="result.json", help="JSON output (default: %(default)s)")
    fit.add_argument("--report", help="also write an HTML page with the summary and the fit figure")
    fit.add_argument(
        "--export",
        metavar="EFFECTS.yaml",
        help=(
            "also write the fit-then-randomise effects (FitResult.to_randomizers: each estimate +- the larger of 2 "
            "standard errors and 10%% of it, the fitted latencies in seconds and the sensor noise) "
            f"for `train --config` / `demo --config`; a fit that is not ok is not exported (exit {EXIT_FIT_NOT_OK}) unless --force"
        ),
    )
    fit.add_argument("--force", action="store_true", help="export a fit even when it is not ok")
    fit.add_argument("--seed", type=int_at_least(0), default=0, help="seed of the global search (default: %(default)s)")
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
    add_source_arguments(evaluate, task_help="evaluate on this task instead of the spec's `task:`/`model:`/`env:`")
    evaluate.add_argument(
        "--out",
        required=True,
        help=(
            "report folder (created with its parents); in an existing folder only report.html, report.md, "
            "report.json and figures/*.png are replaced, all or none of them (also on Ctrl-C), nothing else in it "
            "is touched"
        ),
    )
    evaluate.add_argument(
        "--safety",
        metavar="LIMITS.yaml",
        help=(
            "safety envelope (see sim2real.safety): measure joint-limit hits, effort, contact force, end-effector "
            "speed and divergences of every episode, add a Safety section to the report; exit 3 when a limit is exceeded"
        ),
    )
    evaluate.add_argument("--backend", choices=("serial", "local", "ray"), default="local", help="default: local")
    evaluate.add_argument("--workers", type=int_at_least(1), default=None, help="processes (default: CPU count)")
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
    for flag, metavar in (("--model", "ROBOT.xml"), ("--env", "MODULE:FACTORY")):
        study.add_argument(
            flag, metavar=metavar, default=None,
            help="refused with the commands that run the same loop on your robot (the study's policies ship trained)",
        )  # fmt: skip
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
    study.add_argument("--seed", type=int_at_least(0), default=0, help="default: %(default)s")
    study.add_argument("--workers", type=int_at_least(1), default=None, help="processes (default: CPU count)")
    study.add_argument("--quiet", action="store_true", help="no stage lines or progress bars")
    return parser
