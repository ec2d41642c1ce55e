"""The ``sim2real`` command line: ``tasks``, ``demo``, ``visualize``, ``record``, ``train``, ``sysid fit``,
``evaluate`` and ``study``.

Every command that runs an env takes ``--task NAME``, ``--model robot.xml`` (an MJCF file) or ``--env
package.module:factory`` (a callable returning a gymnasium env or a dm_env), resolved by :mod:`sim2real.sources`.
Exit codes: 0 on success, 2 on a usage error or bad input (unknown task, missing or invalid model file, a factory
that does not import, bad config, an output path that cannot be written), with one line on stderr and no
traceback. Output paths are checked (:mod:`sim2real.output_paths`) before any work starts, and every file is
written atomically, so a failure leaves nothing half-written. An interruption (Ctrl-C / SIGINT, SIGTERM, SIGHUP)
ends a command with one line on stderr and exit 128 + the signal's number (130, 143, 129), after its temporary
files, staging folders and worker processes are removed; what was in an existing output folder stays as it was.

The commands live in one module per role: :mod:`~sim2real.cli.parser` (the arguments),
:mod:`~sim2real.cli.demo` (``tasks``, ``demo``, ``visualize``), :mod:`~sim2real.cli.sysid_commands`
(``record``, ``sysid fit``), :mod:`~sim2real.cli.evaluate` (``evaluate``, ``study``) and
:mod:`sim2real.agents.cli` (``train``).

Example:
    >>> from sim2real.cli import main
    >>> main(["tasks"])  # doctest: +ELLIPSIS
    dmc/reacher-easy ...
    0
"""

from __future__ import annotations

import os
import sys

from sim2real.cli._common import UsageError, interrupted_exit, interrupted_line, kills_interrupt
from sim2real.cli.demo import ARM_REACH_POLICY, cmd_demo, cmd_tasks, cmd_visualize, default_effects
from sim2real.cli.evaluate import cmd_evaluate, cmd_study
from sim2real.cli.parser import build_parser, join_negative_values
from sim2real.cli.sysid_commands import cmd_record, cmd_sysid

__all__ = ["ARM_REACH_POLICY", "default_effects", "main"]


def main(argv: list[str] | None = None) -> int:
    """Runs the ``sim2real`` command line.

    Args:
        argv: arguments without the program name (default ``sys.argv[1:]``).

    Returns:
        The exit code: 0 on success, 2 on a usage error or bad input, 3 when ``evaluate --safety`` finds a
        declared safety limit exceeded (the report is written; one line per violation on stderr), 4 when
        ``sysid fit`` finds that the fitted model cannot reproduce the log (the fit is written but not exported;
        one line with the reasons on stderr), 128 + the signal's number when interrupted (130 on Ctrl-C /
        SIGINT, 143 on SIGTERM, 129 on SIGHUP; one line on stderr, no partial output).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    with kills_interrupt():  # SIGTERM/SIGHUP clean up as Ctrl-C does (staging folders, temporary files, workers)
        try:
            return _run(argv)
        except KeyboardInterrupt as err:  # any command, at any point after start-up (train says it itself)
            command = argv[0] if argv and not argv[0].startswith("-") else ""
            print(interrupted_line(f"sim2real {command}".rstrip(), err), file=sys.stderr)
            return interrupted_exit(err)


def _run(argv: list[str]) -> int:
    if argv[:1] == ["train"]:
        from sim2real.agents.cli import cli_train

        return cli_train(argv[1:])
    parser = build_parser()
    try:
        args = parser.parse_args(join_negative_values(argv))
    except SystemExit as exit_:  # --help, --version and argparse's own usage errors
        return exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 2)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    commands = {
        "tasks": lambda: cmd_tasks(sys.stdout),
        "visualize": lambda: cmd_visualize(args, sys.stdout),
        "record": lambda: cmd_record(args, sys.stdout),
        "sysid": lambda: cmd_sysid(args, sys.stdout),
        "evaluate": lambda: cmd_evaluate(args, sys.stdout),
        "study": lambda: cmd_study(args, sys.stdout),
    }
    try:
        return commands.get(args.command, lambda: cmd_demo(args, sys.stdout))()
    except UsageError as err:
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
