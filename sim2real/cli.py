"""The ``sim2real`` command line: ``sim2real tasks``, ``sim2real demo`` and ``sim2real visualize``.

Exit codes: 0 on success, 2 on a usage error or bad input (unknown task, bad config), with the
message on stderr and no traceback.

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
    return parser


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
    from tqdm import tqdm  # type: ignore[import-untyped]

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
    effects = _load_demo_effects(args.config) if args.config is not None else []
    camera: int | str | None = args.camera
    if isinstance(camera, str) and camera.lstrip("-").isdigit():
        camera = int(camera)
    try:
        sheet = sim2real.contact_sheet(
            args.task, effects, n=args.n, seed=args.seed, size=(args.size, args.size), camera=camera, out=args.out
        )
    except (TypeError, ValueError, FileNotFoundError) as err:
        raise _UsageError(str(err)) from err
    h, w = sheet.image.shape[:2]
    print(f"wrote {sheet.path} ({args.n} frames of {args.task}, {len(effects)} effect(s), {w}x{h} px)", file=out)
    return 0


# ---------------------------------------------------------------------------------- entry point


def main(argv: list[str] | None = None) -> int:
    """Runs the ``sim2real`` command line.

    Args:
        argv: arguments without the program name (default ``sys.argv[1:]``).

    Returns:
        The exit code: 0 on success, 2 on a usage error or bad input.
    """
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
        return _cmd_demo(args, sys.stdout)
    except _UsageError as err:
        print(f"sim2real {args.command}: error: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader went away (`sim2real tasks | head -1`): stop quietly, and point stdout at devnull so
        # the interpreter's final flush does not raise a second time.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1


if __name__ == "__main__":
    sys.exit(main())
