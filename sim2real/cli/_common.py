"""What every ``sim2real`` command shares: the usage error, output checks, argument types and env sources.

Example:
    >>> import argparse
    >>> parser = argparse.ArgumentParser()
    >>> add_source_arguments(parser, default_task="sim2real/arm-reach")
    >>> source_of(parser.parse_args([])).id
    'sim2real/arm-reach'
    >>> source_of(parser.parse_args(["--env", "nowhere:make"]))
    Traceback (most recent call last):
    ...
    sim2real.cli._common.UsageError: `--env` 'nowhere:make': cannot import module 'nowhere': No module named 'nowhere'.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
from collections.abc import Callable, Iterator
from typing import Any, NoReturn

from sim2real.sources import Source, SourceError, resolve_source

__all__ = [
    "Interrupted",
    "OneLineParser",
    "UsageError",
    "add_source_arguments",
    "check_outputs",
    "int_at_least",
    "interrupted_exit",
    "interrupted_line",
    "kills_interrupt",
    "source_inputs",
    "source_of",
    "writing",
]


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr and exit 2, like every other failure of a
    ``sim2real`` command (argparse prints the whole usage block first); ``--help`` still prints it.

    Example:
        >>> import contextlib, io
        >>> parser = OneLineParser(prog="sim2real record")
        >>> _ = parser.add_argument("--steps", type=int)
        >>> err = io.StringIO()
        >>> with contextlib.redirect_stderr(err):
        ...     try:
        ...         parser.parse_args(["--steps", "x"])
        ...     except SystemExit as exit_:
        ...         print(exit_.code)
        2
        >>> err.getvalue()
        "sim2real record: error: argument --steps: invalid int value: 'x'. See `sim2real record --help`.\\n"
    """

    def error(self, message: str) -> NoReturn:
        text = message if message.endswith(".") else f"{message}."
        self.exit(2, f"{self.prog}: error: {text} See `{self.prog} --help`.\n")


class UsageError(Exception):
    """Bad input found after parsing; ``main`` prints it and returns 2."""


class Interrupted(KeyboardInterrupt):
    """A kill (``SIGTERM``, ``SIGHUP``) raised in the main thread as Ctrl-C is, so that what runs on Ctrl-C runs
    on a kill too: temporary files and staging folders are removed, worker processes are stopped. Without it
    the process died at once and left its staging folder (inside an empty ``--out`` folder, which the next
    ``study`` then refused as not empty) and its pool workers running, holding the terminal's pipes open.

    Attributes:
        signum: the signal's number.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def interrupted_exit(err: BaseException) -> int:
    """The exit code of a command ended by ``err`` (a ``KeyboardInterrupt``): 128 + the signal's number, as a
    shell reports a process the signal ended (130 for Ctrl-C / SIGINT, 143 for SIGTERM, 129 for SIGHUP).

    Example:
        >>> interrupted_exit(KeyboardInterrupt()), interrupted_exit(Interrupted(signal.SIGTERM))
        (130, 143)
    """
    return 128 + int(getattr(err, "signum", signal.SIGINT))


def interrupted_line(command: str, err: BaseException, what: str = "no partial output was left behind") -> str:
    """The one line an interrupted command prints on stderr.

    Example:
        >>> interrupted_line("sim2real study", KeyboardInterrupt())
        'sim2real study: interrupted; no partial output was left behind'
        >>> interrupted_line("sim2real study", Interrupted(signal.SIGTERM))
        'sim2real study: interrupted by SIGTERM; no partial output was left behind'
    """
    by = f" by {signal.Signals(err.signum).name}" if isinstance(err, Interrupted) else ""
    return f"{command}: interrupted{by}; {what}"


@contextlib.contextmanager
def kills_interrupt() -> Iterator[None]:
    """While the block runs (in the main thread), ``SIGTERM`` and ``SIGHUP`` raise :class:`Interrupted` and
    Ctrl-C its ``KeyboardInterrupt``, once: a second signal while the first one's clean-up runs (a second Ctrl-C
    in a hurry) is ignored, so it cannot cut the clean-up short (workers left running, a staging folder half
    removed, a traceback). A signal the caller ignores (``nohup`` ignores SIGHUP) stays ignored. The previous
    handlers are restored after."""
    from sim2real.output_paths import signal_handlers

    fired: list[int] = []

    def interrupt(signum: int, frame: Any) -> None:
        if fired:  # already interrupting: let the clean-up finish
            return
        fired.append(signum)
        raise KeyboardInterrupt if signum == signal.SIGINT else Interrupted(signum)

    with signal_handlers(interrupt):
        yield


def check_outputs(
    files: dict[str, str | None],
    folder: tuple[str, str, bool] | None = None,
    inputs: dict[str, str | None] | None = None,
) -> None:
    """Checks every output of a command (``{"--out": path, "--report": path}``, files; ``folder`` is
    ``(argument, path, new)``) before any work, so a bad path fails at once and creates nothing; no output file
    may be one of the command's ``inputs`` (``{"--model": path, ...}``), which it would overwrite."""
    from sim2real.output_paths import OutputPathError, check_distinct, check_file, check_folder, check_not_inputs

    given = {argument: path for argument, path in files.items() if path is not None}
    try:
        for argument, path in given.items():
            check_file(path, argument)
        check_distinct(given)
        check_not_inputs(given, inputs or {})
        if folder is not None:
            check_folder(folder[1], folder[0], new=folder[2])
    except OutputPathError as err:
        raise UsageError(str(err)) from err


def writing(path: str | os.PathLike[str], write: Callable[[], Any]) -> Any:
    """Runs ``write`` (an atomic write of ``path``); a failure of the file system (disk full, a folder removed
    meanwhile) becomes one line and exit 2. The atomic writer has already removed its temporary file."""
    try:
        return write()
    except OSError as err:
        reason = err.strerror or str(err)
        raise UsageError(f"cannot write {os.fspath(path)!r}: {reason}.") from err


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an int ``>= minimum``."""

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


def add_source_arguments(
    parser: argparse.ArgumentParser, *, default_task: str | None = None, task_help: str = "task id (`sim2real tasks`)"
) -> None:
    """Adds the mutually exclusive ``--task``/``--model``/``--env`` (resolved by :func:`source_of`)."""
    group = parser.add_argument_group("env source (one of)").add_mutually_exclusive_group()
    default = f" (default: {default_task})" if default_task else ""
    group.add_argument("--task", default=None, help=f"{task_help}{default}")
    group.add_argument(
        "--model", metavar="ROBOT.xml", help="your own robot: an MJCF file (see README 'Your own robot')"
    )
    group.add_argument(
        "--env",
        metavar="PACKAGE.MODULE:FACTORY",
        help="your own env: a callable returning a gymnasium env or a dm_env.Environment",
    )
    parser.set_defaults(_default_task=default_task)


def source_inputs(args: argparse.Namespace) -> dict[str, str | None]:
    """The input files the env source names, for :func:`check_outputs`: ``--model``'s MJCF file and the file of
    ``--env``'s module (an output path over either would overwrite the user's robot)."""
    from sim2real.user_envs import module_file

    env = getattr(args, "env", None)
    return {"--model": getattr(args, "model", None), "--env module": module_file(env) if env is not None else None}


def source_of(args: argparse.Namespace, *, task: str | None = None) -> Source:
    """The :class:`Source` of ``--task``/``--model``/``--env`` (``task`` is a positional task id, if any)."""
    given_task = args.task if task is None else task
    if task is not None and args.task is not None:
        raise UsageError(f"give the task once (positional or --task). Received {task!r} and --task {args.task!r}.")
    try:
        source = resolve_source(given_task, args.model, args.env, default_task=getattr(args, "_default_task", None))
    except SourceError as err:
        raise UsageError(str(err)) from err
    return source
