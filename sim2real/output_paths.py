"""Output paths, checked before any work starts: the one place that decides whether a command may write there.

Every command that writes (``record``, ``sysid fit``, ``train``, ``visualize``, ``evaluate``, ``study``) and
:func:`sim2real.study.run_study` call :func:`check_file` / :func:`check_folder` on each of their outputs *before*
recording, fitting, training or evaluating, so a bad path costs nothing and leaves nothing behind. The checks
create nothing: missing parent folders are created later, by the writer (:func:`randomizers.files.atomic_write`).

What is checked:

- the path is not empty, and a file output does not name a folder (``.``, ``..``, a trailing ``/``, an existing
  folder), nor a folder output an existing file;
- the nearest existing folder above it is a folder (not a file: ``afile/r.json`` can never be created) and is
  writable, as is an existing output folder;
- with ``new=True`` (the study), an existing folder must be empty: a folder that holds anything is never
  overwritten, emptied or deleted (the error names a free sibling to use instead).

Example:
    >>> import tempfile
    >>> from pathlib import Path
    >>> root = Path(tempfile.mkdtemp())
    >>> check_file(root / "logs" / "run.npz", "--out") == root / "logs" / "run.npz"
    True
    >>> (root / "note.txt").write_text("mine")
    4
    >>> check_file(root / "note.txt" / "run.npz", "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    sim2real.output_paths.OutputPathError: --out must be in a folder that exists or can be created; '.../note.txt' is a file. Received '.../note.txt/run.npz'.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

__all__ = [
    "OutputPathError",
    "check_distinct",
    "check_file",
    "check_folder",
    "check_not_inputs",
    "free_folder",
    "held_signals",
    "publish_folder",
    "signal_handlers",
    "staging_folder",
]


#: How the staging folder inside an existing empty output folder is named: ``.sim2real-study.<random>.partial``.
STAGING_PREFIX, STAGING_SUFFIX = ".sim2real-study.", ".partial"


class OutputPathError(ValueError):
    """An output path that cannot be written, or that would overwrite a folder; raised before any work."""


def _text(path: str | os.PathLike[str]) -> str:
    return os.fspath(path)


def _writable(folder: Path) -> bool:
    return os.access(folder, os.W_OK | os.X_OK)


def _check_above(path: Path, text: str, argument: str) -> None:
    """The nearest existing folder above ``path`` is a folder and writable (what is missing can be created)."""
    for probe in path.parents:  # lexical: 'a/b/c' -> 'a/b', 'a', '.'; the OS resolves '..' and links
        try:
            if not probe.exists():  # False also when a file is on the way ('afile/x')
                continue
        except OSError:  # a folder on the way that cannot be searched
            raise OutputPathError(
                f"{argument} must be in a writable folder; {str(probe)!r} cannot be read. Received {text!r}."
            ) from None
        if not probe.is_dir():
            raise OutputPathError(
                f"{argument} must be in a folder that exists or can be created; {str(probe)!r} is a file. "
                f"Received {text!r}."
            )
        if not _writable(probe):
            raise OutputPathError(
                f"{argument} must be in a writable folder; {str(probe)!r} is not writable. Received {text!r}."
            )
        return


def check_file(path: str | os.PathLike[str], argument: str = "`out`") -> Path:
    """Checks that a file can be written (atomically, by a rename in its folder) at ``path``.

    An existing file is allowed: the writer replaces it in one rename.

    Args:
        path: the output file.
        argument: how the caller names the argument in messages (``"--out"``, ``"`out`"``).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OutputPathError: ``path`` is empty or names a folder, or its folder cannot be created or written.
    """
    text = _text(path)
    if not text:
        raise OutputPathError(f"{argument} must be a file path. Received ''.")
    target = Path(text)
    if target.name in ("", ".", "..") or text.endswith(("/", os.sep)) or target.is_dir():
        raise OutputPathError(f"{argument} must name a file, not a folder. Received {text!r}.")
    _check_above(target, text, argument)
    return target


def check_folder(path: str | os.PathLike[str], argument: str = "`out`", *, new: bool = False) -> Path:
    """Checks that a folder of outputs can be written at ``path`` (staged beside it, then moved into place).

    Args:
        path: the output folder.
        argument: how the caller names the argument in messages.
        new: the folder must not exist or be empty (a folder that holds anything is never overwritten).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OutputPathError: ``path`` is empty or an existing file, its parent cannot be created or written, it is
            an existing folder that is not writable, or (``new``) an existing folder that is not empty.
    """
    text = _text(path)
    if not text:
        raise OutputPathError(f"{argument} must be a folder path. Received ''.")
    target = Path(text)
    if target.exists() and not target.is_dir():
        raise OutputPathError(f"{argument} must name a folder, not an existing file. Received {text!r}.")
    if target.is_dir():
        if new:
            names = [entry.name for entry in target.iterdir()]
            if names:
                entries = len(names)
                left = [n for n in names if n.startswith(STAGING_PREFIX) and n.endswith(STAGING_SUFFIX)]
                why = (
                    f" ({left[0]!r} is the staging folder of a study that was killed before it could remove it "
                    "(SIGKILL, a crash): delete it to use this folder)"
                    if left
                    else ""
                )
                raise OutputPathError(
                    f"{argument} must be a new or empty folder (an existing folder is never overwritten). Received "
                    f"{text!r}, which holds {entries} {'entry' if entries == 1 else 'entries'}{why}; choose "
                    f"another {argument}, e.g. {str(free_folder(target))!r}."
                )
        if not _writable(target):
            raise OutputPathError(f"{argument} must be a writable folder. Received {text!r}, which is not writable.")
        if new:  # an existing empty folder is written in place (staged inside it), its parent is not needed
            return target
    _check_above(target, text, argument)
    return target


def _entry(path: str | os.PathLike[str]) -> str:
    """The directory entry a write of ``path`` replaces (by a rename in its folder): its folder resolved as the OS
    resolves it (another spelling, a linked folder, ``link/..`` is the parent of the link's *target*), and its
    last component as it is (renaming onto a symlink or a hard link replaces that entry, not the target).

    Example:
        >>> _entry("a/./b/../r.json") == os.path.join(os.path.realpath("a"), "r.json")
        True
    """
    folder, name = os.path.split(_text(path))
    return os.path.join(os.path.realpath(folder or os.curdir), name)


def check_distinct(outputs: Mapping[str, str | os.PathLike[str]]) -> None:
    """Checks that the outputs of one command (argument -> path) are different files.

    Raises:
        OutputPathError: two arguments name the same path.
    """
    seen: dict[str, str] = {}
    for argument, path in outputs.items():
        key = _entry(path)
        if key in seen:
            raise OutputPathError(f"{argument} must differ from {seen[key]}. Received {_text(path)!r} for both.")
        seen[key] = argument


def check_not_inputs(
    outputs: Mapping[str, str | os.PathLike[str]], inputs: Mapping[str, str | os.PathLike[str] | None]
) -> None:
    """Checks that no output of a command is one of its input files (argument -> path), which the command would
    overwrite: ``sysid fit log.npz --out log.npz`` replaced the log with the fit's JSON, ``--export robot.xml`` the
    MJCF.

    Example:
        >>> check_not_inputs({"--out": "a/../log.npz"}, {"`log`": "log.npz", "--model": None})
        Traceback (most recent call last):
        ...
        sim2real.output_paths.OutputPathError: --out must not be the input `log`, which it would overwrite. Received 'a/../log.npz' for both.
    """

    for argument, path in outputs.items():
        for source, given in inputs.items():
            if given is not None and _entry(path) == _entry(given):
                raise OutputPathError(
                    f"{argument} must not be the input {source}, which it would overwrite. Received {_text(path)!r} for "
                    "both."
                )


def free_folder(path: str | os.PathLike[str]) -> Path:
    """``path`` if it is free (missing or an empty folder), else the first free ``path-2``, ``path-3``, ...

    A path without a usable name (``.``, ``..``) gets a free ``sim2real-study`` folder inside it.

    Example:
        >>> import tempfile
        >>> root = Path(tempfile.mkdtemp())
        >>> (root / "study").mkdir(); (root / "study" / "a.txt").write_text("x")
        1
        >>> free_folder(root / "study").name, free_folder(root / "other").name
        ('study-2', 'other')
    """
    base = Path(_text(path))
    if base.name in ("", ".", ".."):
        base = base / "sim2real-study"

    def free(candidate: Path) -> bool:
        try:
            return not candidate.exists() or (candidate.is_dir() and not any(candidate.iterdir()))
        except OSError:
            return False

    if free(base):
        return base
    number = 2
    while not free(base.with_name(f"{base.name}-{number}")):
        number += 1
    return base.with_name(f"{base.name}-{number}")


@contextlib.contextmanager
def held_signals() -> Iterator[None]:
    """Holds Ctrl-C (SIGINT) and the kills (SIGTERM, SIGHUP) until the block ends, then delivers the first one
    that came: the renames that move finished outputs into an existing folder run to the end, so an interruption
    leaves the old outputs or the new ones, never a mix (a new ``report.md`` beside the old ``report.html``).

    Only for a few renames: the signal waits, it is not lost. Outside the main thread (where Python runs signal
    handlers) it does nothing. A signal the process ignores stays ignored.

    Example:
        >>> import signal
        >>> before = signal.signal(signal.SIGINT, signal.default_int_handler)  # (Ctrl-C as in a terminal)
        >>> try:
        ...     with held_signals():
        ...         signal.raise_signal(signal.SIGINT)
        ...         print("the block ran to its end")
        ... except KeyboardInterrupt:
        ...     print("then Ctrl-C")
        the block ran to its end
        then Ctrl-C
        >>> _ = signal.signal(signal.SIGINT, before)
    """
    caught: list[int] = []

    def hold(signum: int, frame: Any) -> None:
        caught.append(signum)

    try:
        with signal_handlers(hold):
            yield
    finally:
        if caught:
            signal.raise_signal(caught[0])  # to the handler it was meant for, now that the outputs are whole


#: The signals that end a command: Ctrl-C (SIGINT) and the kills SIGTERM and SIGHUP (where the OS has them).
INTERRUPT_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextlib.contextmanager
def signal_handlers(handler: Callable[[int, Any], None]) -> Iterator[None]:
    """Runs the block with ``handler`` on every :data:`INTERRUPT_SIGNALS` the process does not ignore, then puts
    the previous handlers back. Outside the main thread (where Python runs no signal handler) it does nothing. One
    owner for :func:`held_signals` and the command line's ``kills_interrupt``."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, handler) for s in INTERRUPT_SIGNALS if signal.getsignal(s) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, signal.SIG_DFL if old is None else old)


def staging_folder(target: Path) -> Path:
    """A hidden staging folder for the outputs that go to the folder ``target`` (checked with ``new=True``),
    with the usual permissions (``0o777`` minus the umask, not ``mkdtemp``'s ``0o700``).

    It is made beside a new ``target`` (moved into place with one rename), or inside an existing empty one (its
    entries are moved up, so the user's folder itself stays, with its permissions; this also makes ``"."`` work
    and needs no write access to the parent).
    """
    from randomizers.files import make_temp_dir

    if target.is_dir():
        return make_temp_dir(target, prefix=STAGING_PREFIX, suffix=STAGING_SUFFIX)
    target.parent.mkdir(parents=True, exist_ok=True)
    return make_temp_dir(target.parent, prefix=f".{target.name}.", suffix=STAGING_SUFFIX)


def publish_folder(staging: Path, target: Path) -> Path:
    """Moves the finished outputs in ``staging`` (from :func:`staging_folder`) into ``target``; returns where
    they went.

    Nothing that exists is ever overwritten: ``target`` must still be missing or empty (it was checked before the
    work, but a user may have written to it since); otherwise the outputs go to :func:`free_folder` of ``target``.
    """
    if staging.parent == target:  # an existing empty folder: move the entries up, the report last
        entries = sorted(staging.iterdir(), key=lambda p: p.name.startswith("report."))
        if any((target / p.name).exists() for p in entries):
            final = free_folder(target)
            staging.rename(final)
            return final
        moved: list[str] = []
        with held_signals():  # all the entries or none: never a study without its report in the user's folder
            try:
                for entry in entries:
                    entry.rename(target / entry.name)
                    moved.append(entry.name)
            except OSError:
                for name in reversed(moved):  # back into the staging folder, which the caller removes
                    (target / name).rename(staging / name)
                raise
            staging.rmdir()
        return target
    try:
        staging.rename(target)  # fails (and changes nothing) unless target is missing or an empty folder
    except OSError:
        final = free_folder(target)
        staging.rename(final)
        return final
    return target
