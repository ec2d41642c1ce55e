"""``sim2real train``: train a PPO or SAC policy on a task and write a checkpoint.

``cli_train(argv)`` is the whole command, so ``sim2real.cli`` can dispatch ``train`` to it.

Example:
    >>> import contextlib, io
    >>> err = io.StringIO()
    >>> with contextlib.redirect_stderr(err):
    ...     cli_train(["--task", "sim2real/arm-reach", "--frames", "0", "--out", "x.pt"])
    2
    >>> "--frames" in err.getvalue()
    True
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

__all__ = ["build_parser", "cli_train"]


def build_parser(prog: str = "sim2real train") -> argparse.ArgumentParser:
    """The argument parser of ``sim2real train``."""
    from sim2real.cli._common import OneLineParser, add_source_arguments

    parser = OneLineParser(
        prog=prog,
        description="Train a PPO or SAC policy with TorchRL (optionally under randomisation) and save a checkpoint.",
    )
    add_source_arguments(parser, task_help="task id, e.g. sim2real/arm-reach (see `sim2real tasks`)")
    parser.add_argument("--algo", choices=("ppo", "sac"), default="ppo", help="algorithm (default ppo)")
    parser.add_argument("--frames", type=int, default=None, help="environment steps (overrides the agent config)")
    parser.add_argument(
        "--config",
        default=None,
        help="effects YAML (`effects:` physics randomisation and `signals:` noise/latency); default: none",
    )
    parser.add_argument(
        "--adr",
        default=None,
        help="automatic domain randomisation YAML (effects with hard limits, delta, t_low, t_high, ...); the "
        "ranges grow from the nominal point and their final state is saved in the checkpoint",
    )
    parser.add_argument(
        "--adr-export",
        default=None,
        metavar="EFFECTS.yaml",
        help="with --adr: write the ranges ADR chose (its effects at their final ranges) as an effects YAML for "
        "`train --config` or an evaluation's `randomized:`; written atomically after the checkpoint",
    )
    parser.add_argument("--agent-config", default=None, help="PPO/SAC hyperparameters YAML (its `algo` must match)")
    parser.add_argument("--seed", type=int, default=0, help="seed of weights, exploration, env and effects")
    parser.add_argument(
        "--out",
        required=True,
        help="checkpoint file to write atomically (e.g. ckpt.pt); the path is checked before training starts",
    )
    parser.add_argument("--log-dir", default=None, help="CSV logger root (default ./sim2real_runs)")
    parser.add_argument("--no-log", action="store_true", help="do not write logger files")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _fail(parser: argparse.ArgumentParser, message: str) -> int:
    print(f"{parser.prog}: error: {message}", file=sys.stderr)  # one line, like every sim2real command
    return 2


def _check_paths(args: argparse.Namespace) -> str | None:
    """The checkpoint file and the logger folder, checked before training (see :mod:`sim2real.output_paths`);
    returns the error message, or None."""
    from sim2real.cli._common import source_inputs
    from sim2real.output_paths import OutputPathError, check_distinct, check_file, check_folder, check_not_inputs

    try:
        check_file(args.out, "--out")
        inputs = {
            **source_inputs(args),
            "--config": args.config,
            "--adr": args.adr,
            "--agent-config": args.agent_config,
        }
        outputs = {"--out": args.out}
        if args.adr_export is not None:
            check_file(args.adr_export, "--adr-export")
            outputs["--adr-export"] = args.adr_export
            check_distinct(outputs)
        check_not_inputs(outputs, inputs)
        if not args.no_log:  # the logger's root, ./sim2real_runs by default
            log_dir = args.log_dir if args.log_dir is not None else "sim2real_runs"
            check_folder(log_dir, "--log-dir")
            # The logger makes that folder as training starts; a checkpoint of the same name failed only at the end.
            check_distinct({**outputs, "--log-dir": log_dir})
    except OutputPathError as err:
        return str(err)
    return None


def _check_effects(
    env: Any, effects: list[Any], config: Any, args: argparse.Namespace, label: str, task: str
) -> str | None:
    """Wraps ``env`` once with the run's effects and its ADR and resets it, then builds (and closes) the TorchRL env
    PPO collects from or SAC steps when it is not the gymnasium env itself, so effects that do not fit the env (a
    joint it does not have, an observation key it lacks, here or in TorchRL's view of it) are one line before
    training instead of a traceback from inside it; returns the message, or None. Closes ``env``."""
    import sim2real
    from sim2real.agents.adr_training import with_adr
    from sim2real.agents.collect import choose_collection, make_collection_env

    flags = " and ".join(f for f, v in (("--config", args.config), ("--adr", args.adr)) if v is not None)
    try:
        plain, adr = with_adr(effects, config)
        if adr is not None:  # e.g. metric 'success' on an arm that reports none: now, not after a batch
            from sim2real.batched.adr import check_task_metric

            check_task_metric(adr, task)
        if plain or adr is not None:
            env = sim2real.wrap(env, *plain, adr=adr, seed=args.seed)
            env.reset(seed=args.seed)
    except (TypeError, ValueError) as err:
        return f"the effects of {flags or '--config'} do not fit {label!r}: {err}"
    finally:
        env.close()
    if not (plain or adr is not None) or config.algo != "ppo":
        return None  # SAC steps a task id through gymnasium, as checked above
    run_effects = [*plain, adr] if adr is not None else plain
    try:  # what train collects from: the batched worlds or GymWrapper + sim2real's TorchRL transforms
        make_collection_env(task, run_effects, args.seed, choose_collection(task, run_effects, config)).close()
    except (TypeError, ValueError) as err:
        return f"the effects of {flags} do not fit {label!r} as TorchRL sees it (PPO's collection env): {err}"
    return None


def _adr_parameter_ranges(adr: Any, source: Any) -> str:
    """``dof_damping[lift] [0.24, 6], body_mass[tool] [0.15, 0.45], ...``: the final ADR ranges as the values they
    write into the model (:meth:`randomizers.ADR.parameter_ranges`), or ``""`` when the env has no MuJoCo model."""
    from sim2real.physics import find_physics

    env = source.make()
    try:
        handle = find_physics(env)
        if handle is None:
            return ""
        found = adr.parameter_ranges(handle.model)
    finally:
        env.close()
    return ", ".join(f"{address} [{lo:.4g}, {hi:.4g}]" for address, (lo, hi) in found.items())


def _remark(result: Any, **changes: Any) -> tuple[Path, Any] | None:
    """Rewrites the ``run.json`` that :func:`~sim2real.agents.train` left in ``result``'s log folder with
    ``changes`` (the checkpoint written, or how saving it ended the command); returns ``(folder, status)``, or None
    without a log folder or status, or when it cannot be written (the command's own outcome comes first)."""
    import dataclasses

    from sim2real.agents.run_status import read_run_status, write_run_status

    if result is None or result.log_dir is None:
        return None
    try:
        run = read_run_status(result.log_dir)
        if run is None:
            return None
        run = dataclasses.replace(run, **changes)
        write_run_status(result.log_dir, run)
    except (OSError, ValueError):
        return None
    return result.log_dir, run


def cli_train(argv: Sequence[str] | None = None, out: TextIO | None = None) -> int:
    """Runs ``sim2real train``; returns the exit code (0 ok, 2 usage error, 128 + the signal's number when interrupted).

    Args:
        argv: the arguments after ``train``.
        out: where the summary goes (default stdout).
    """
    from sim2real.agents.config import config_class, load_agent_config, replace

    out = sys.stdout if out is None else out
    parser = build_parser()
    try:
        args = parser.parse_args(list(argv) if argv is not None else None)
    except SystemExit as exc:
        return int(exc.code) if isinstance(exc.code, int) else 2
    if args.frames is not None and args.frames <= 0:
        return _fail(parser, f"--frames must be a positive int. Received {args.frames}.")
    if args.seed < 0:
        return _fail(parser, f"--seed must be >= 0. Received {args.seed}.")
    if args.adr_export is not None and args.adr is None:
        return _fail(
            parser,
            f"--adr-export needs --adr (the ranges it writes are ADR's). Received --adr-export {args.adr_export!r} alone.",
        )
    try:
        config: Any = load_agent_config(Path(args.agent_config)) if args.agent_config else config_class(args.algo)()
    except (OSError, ValueError) as err:
        return _fail(parser, f"--agent-config: {err}")
    if config.algo != args.algo:
        return _fail(parser, f"--agent-config is for {config.algo!r} but --algo is {args.algo!r}.")
    if args.frames is not None:
        try:
            config = replace(config, frames=args.frames)
        except ValueError as err:
            return _fail(parser, f"--frames: {err}")
    if args.adr is not None:
        try:
            config = replace(config, adr=Path(args.adr).read_text(encoding="utf-8"))
        except OSError as err:
            return _fail(parser, f"--adr: cannot read {args.adr!r}: {err.strerror or err}.")
        except ValueError as err:
            return _fail(parser, f"--adr: {str(err).removeprefix('`adr`: ')}")
    effects: list[Any] = []
    if args.config is not None:
        import sim2real

        try:
            effects = list(sim2real.load_config(Path(args.config)))
        except (OSError, ValueError) as err:
            return _fail(parser, f"--config: {err}")
    import sim2real

    path_error = _check_paths(args)
    if path_error is not None:
        return _fail(parser, path_error)
    from sim2real.sources import SourceError, resolve_source

    try:  # --task, --model robot.xml or --env module:factory (sim2real.sources); the env is built once to check it
        source = resolve_source(args.task, args.model, args.env)
        env = source.make()
    except SourceError as err:
        return _fail(parser, str(err))
    except (TypeError, ValueError) as err:
        return _fail(parser, f"--task: {err}")
    problem = _check_effects(env, effects, config, args, source.label, source.id)
    if problem is not None:
        return _fail(parser, problem)

    from sim2real.agents.run_status import marked_run, status_for
    from sim2real.agents.training import TrainResult, train

    result: TrainResult | None = None
    try:
        result = train(
            source.id,
            config,
            effects=effects,
            seed=args.seed,
            progress=not args.quiet and sys.stderr.isatty(),
            logger=None if args.no_log else "csv",
            log_dir=args.log_dir,
        )
        result.save(args.out)
    except KeyboardInterrupt as err:  # as every other command says it (SIGTERM too); the checkpoint is atomic
        from sim2real.cli._common import interrupted_exit, interrupted_line

        # train marked its log folder; cut short while saving, the run trained to its end but has no checkpoint
        status, signal, _ = status_for(err)
        marked = marked_run(err) or _remark(result, status=status, signal=signal)
        what = f"no checkpoint was written to {args.out!r}"
        if marked is not None:
            folder, run = marked
            what += f"; {run.where(folder)}"
        print(interrupted_line(parser.prog, err, what), file=sys.stderr)
        return interrupted_exit(err)
    except OSError as err:  # the atomic writer has removed its temporary file
        if result is None:  # while training (its own logs: a full disk, a removed folder); train marked the run
            what = f" {err.filename!r}" if err.filename is not None else ""
            problem = f"training stopped: cannot write{what}: {err.strerror or err}"
            marked = marked_run(err)
            if marked is not None:
                problem += f"; {marked[1].where(marked[0])}"
            return _fail(parser, f"{problem}; no checkpoint was written to {args.out!r}.")
        if result is not None:  # trained, but the checkpoint could not be written: the run did not end as asked
            _remark(result, status="failed", error=f"cannot write the checkpoint {args.out!r}: {err.strerror or err}")
        return _fail(parser, f"cannot write {args.out!r}: {err.strerror or err}.")
    _remark(result, checkpoint=str(Path(args.out).resolve()))
    if args.adr_export is not None and result.adr is not None:
        from randomizers import ADR, dump_config
        from randomizers.files import atomic_write

        try:  # the ranges ADR chose, as effects a next run trains or is evaluated under
            atomic_write(args.adr_export, dump_config(list(ADR.from_state(result.adr).effects_at_ranges())))
        except OSError as err:
            return _fail(
                parser,
                f"cannot write {args.adr_export!r}: {err.strerror or err} (the checkpoint {args.out!r} is written).",
            )
    returns = [r for r in result.metrics.get("episode_return", ()) if r == r]
    first = f"{returns[0]:.3f}" if returns else "n/a"
    last = f"{returns[-1]:.3f}" if returns else "n/a"
    print(
        f"sim2real train: {args.algo} on {source.label}, {result.frames} frames in {result.wall_time:.1f} s, "
        f"seed {args.seed}, {len(effects)} effect(s)"
        + ("" if result.adr is None else f" + ADR over {len(json.loads(result.adr)['config']['effects'])}"),
        file=out,
    )
    print(f"episode return (batch mean): first {first}, last {last}", file=out)
    if result.frames != config.frames:  # PPO collects whole batches (TorchRL's collector rounds up)
        print(
            f"note: PPO collects whole batches of {config.frames_per_batch} frames: {result.frames} frames for "
            f"{config.frames} asked (frames_per_batch in --agent-config sets the batch)",
            file=out,
        )
    if result.collection is not None:
        print(f"collection: {result.collection}", file=out)
    if result.adr is not None:
        from randomizers import ADR

        adr = ADR.from_state(result.adr)
        ranges = ", ".join(f"{key} [{lo:g}, {hi:g}]" for key, (lo, hi) in adr.ranges.items())
        print(f"adr: entropy {adr.entropy():.3f} nats/dim; {ranges}", file=out)
        units = _adr_parameter_ranges(adr, source)
        if units:
            print(f"adr ranges in the model's units: {units}", file=out)
        if adr.frames == 0:  # ADR learns only from finished episodes: a budget shorter than one per world moves nothing
            collection = result.collection
            worlds = f" in each of its {collection.num_envs} worlds" if collection and collection.num_envs > 1 else ""
            print(
                f"note: no episode ended{worlds} within {result.frames} frames, so ADR had no results and its ranges "
                "stayed where they started; give more --frames (or fewer num_envs in --agent-config)",
                file=out,
            )
    print(f"run id: {result.run_id}", file=out)
    if result.log_dir is not None:
        print(f"log: {result.log_dir}", file=out)
    print(f"checkpoint: {args.out}", file=out)
    if args.adr_export is not None:
        print(f"adr ranges (effects for --config): {args.adr_export}", file=out)
    return 0
