"""Atomic file writes shared by every package that saves results (configs, logs, reports, figures).

A write goes to a temporary file in the destination folder, which is then renamed over the target, so a
crash or Ctrl-C never leaves a half-written file. The file gets the usual permissions (``0o666`` minus the
umask), not ``mkstemp``'s private ``0o600``.

Example:
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "out", "a.txt")
    >>> atomic_write(path, "hello")
    >>> open(path).read()
    'hello'
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        if callable(content):
            os.close(fd)
            content(tmp)
        else:
            with os.fdopen(fd, "wb") as handle:
                handle.write(content.encode("utf-8") if isinstance(content, str) else content)
                handle.flush()
                os.fsync(handle.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
