"""Atomic file writes shared by every package that saves results (configs, logs, reports, figures).

A write goes to a temporary file in the destination folder, which is then renamed over the target, so a
crash or Ctrl-C never leaves a half-written file. The file gets the usual permissions (``0o666`` minus the
umask), not ``mkstemp``'s private ``0o600``; :func:`make_temp_dir` is the same for a folder (``0o777`` minus the
umask, not ``mkdtemp``'s ``0o700``).

The process umask is never read or changed: the temporary file or folder is created with ``0o666`` / ``0o777``
and the kernel applies the umask itself, as for any ``open()``. (Reading it with ``os.umask`` means setting it,
and another thread creating a file in that moment would get world-writable permissions.)

Example:
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "out", "a.txt")
    >>> atomic_write(path, "hello")
    >>> open(path).read()
    'hello'
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

__all__ = ["atomic_write", "check_suffix", "make_temp_dir"]

_T = TypeVar("_T")
_ATTEMPTS = 100


def _unique(folder: Path, prefix: str, suffix: str, create: Callable[[Path], _T]) -> tuple[Path, _T]:
    """Creates a new entry ``<prefix><random><suffix>`` in ``folder`` with ``create`` (which must fail with
    ``FileExistsError`` on a taken name), as ``tempfile`` does, and returns its path and what ``create`` returned."""
    for _ in range(_ATTEMPTS):
        path = folder / f"{prefix}{secrets.token_hex(6)}{suffix}"
        try:
            return path, create(path)
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name in {str(folder)!r} after {_ATTEMPTS} attempts.")


def check_suffix(path: str | os.PathLike[str], argument: str, suffixes: tuple[str, ...], what: str) -> Path:
    """``path``, checked to end in one of ``suffixes`` (case-insensitive): the file a writer produces is of one
    format (``what`` says which), and a name that promises another would hold the wrong bytes.

    Example:
        >>> check_suffix("fit.pdf", "--report", (".html", ".htm"), "an HTML page")
        Traceback (most recent call last):
        ...
        ValueError: --report must end in '.html' or '.htm' (an HTML page). Received 'fit.pdf'.
    """
    target = Path(path)
    if target.suffix.lower() not in suffixes:
        allowed = " or ".join(repr(s) for s in suffixes)
        raise ValueError(f"{argument} must end in {allowed} ({what}). Received {os.fspath(path)!r}.")
    return target


def make_temp_dir(parent: str | os.PathLike[str], *, prefix: str = ".", suffix: str = ".tmp") -> Path:
    """A new, empty folder in ``parent`` with a unique name and the usual permissions (``0o777`` minus the umask).

    Use it to stage files that are then moved into place with one rename; unlike ``tempfile.mkdtemp`` the folder is
    not private (``0o700``), so it can become the final folder as it is.

    Example:
        >>> import tempfile
        >>> folder = make_temp_dir(tempfile.mkdtemp(), prefix=".report.", suffix=".tmp")
        >>> folder.is_dir(), folder.name.startswith(".report."), list(folder.iterdir())
        (True, True, [])
    """
    path, _ = _unique(Path(parent), prefix, suffix, lambda p: os.mkdir(p, 0o777))
    return path


def atomic_write(
    path: str | os.PathLike[str],
    content: str | bytes | Callable[[str], None],
    *,
    make_parents: bool = True,
) -> None:
    """Writes ``content`` (text, bytes, or a function that writes to the temporary path it is given) to
    ``path`` atomically.

    Raises:
        FileNotFoundError: the folder does not exist and ``make_parents`` is False.
    """
    target = Path(path)
    if make_parents:
        target.parent.mkdir(parents=True, exist_ok=True)
    elif not target.parent.is_dir():
        raise FileNotFoundError(f"`out` directory {str(target.parent)!r} does not exist.")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    tmp, fd = _unique(target.parent, f".{target.name}.", ".tmp", lambda p: os.open(p, flags, 0o666))
    try:
        if callable(content):
            mode = os.fstat(fd).st_mode & 0o777  # what the kernel gave: 0o666 minus the umask
            os.close(fd)
            content(str(tmp))
            os.chmod(tmp, mode)  # in case the function replaced the file rather than writing into it
        else:
            with os.fdopen(fd, "wb") as handle:
                handle.write(content.encode("utf-8") if isinstance(content, str) else content)
                handle.flush()
                os.fsync(handle.fileno())
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
