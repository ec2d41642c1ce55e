"""Writing a gap report to disk: every file rendered in memory, staged in a sibling folder, moved into place.

The atomic single-file write and the staging folder come from :mod:`randomizers.files`, the one place that knows
how to write without leaving half-written files (and without touching the process umask).

Example:
    >>> import tempfile
    >>> from pathlib import Path
    >>> from sim2real.report.results import ReportFiles
    >>> out = Path(tempfile.mkdtemp()) / "report"
    >>> _files(out, ["returns"]) == ReportFiles(out, out / "report.html", out / "report.md", out / "report.json",
    ...                                         (out / "figures" / "returns.png",))
    True
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from randomizers.files import atomic_write, make_temp_dir
from sim2real.report import rendering
from sim2real.report.results import ReportFiles

if TYPE_CHECKING:
    from sim2real.report.gap_report import GapReport

__all__ = ["check_out", "write"]

#: The files of a report beside its ``figures/`` folder; only these (and ``figures/<name>.png``) are replaced.
REPORT_FILES = ("report.md", "report.html", "report.json")


def _in_the_way(out: Path, figures: Iterable[str]) -> str | None:
    """What in an existing report folder would stop the renames that replace its report midway (after the old
    ``report.json`` is gone and some files are new), or None."""
    if not out.is_dir():
        return None
    folder = out / "figures"
    if folder.exists() and not folder.is_dir():
        return f"{str(folder)!r} is a file, where the figures go"
    if folder.is_dir() and not os.access(folder, os.W_OK | os.X_OK):
        return f"{str(folder)!r} is not writable"
    for path in (*(out / name for name in REPORT_FILES), *(folder / f"{name}.png" for name in figures)):
        if path.is_dir():
            return f"{str(path)!r} is a folder, where a report file goes"
    return None


def check_out(out_dir: str | os.PathLike[str], argument: str = "`out_dir`") -> Path:
    """Checks, before any work, that a report can be written to ``out_dir``: a folder that can be created or
    written (:func:`sim2real.output_paths.check_folder`) and, if it exists, whose ``report.*`` files and
    ``figures/`` folder can be replaced (none of them a folder, resp. a file).

    Example:
        >>> import tempfile
        >>> out = Path(tempfile.mkdtemp())
        >>> (out / "report.html").mkdir()
        >>> check_out(out, "--out")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sim2real.output_paths.OutputPathError: --out must be a folder whose report files can be replaced; '.../report.html' is a folder, where a report file goes. Received '...'.

    Raises:
        sim2real.output_paths.OutputPathError: it cannot be.
    """
    from sim2real.output_paths import OutputPathError, check_folder

    target = check_folder(out_dir, argument)
    problem = _in_the_way(target, ())
    if problem is not None:
        raise OutputPathError(
            f"{argument} must be a folder whose report files can be replaced; {problem}. Received {os.fspath(out_dir)!r}."
        )
    return target


def write(report: GapReport, out_dir: str | os.PathLike[str]) -> ReportFiles:
    """Writes ``report.html``, ``report.md``, ``report.json`` and ``figures/<name>.png`` of ``report`` into
    ``out_dir`` (see :meth:`GapReport.write <sim2real.report.GapReport.write>`).

    Raises:
        NotADirectoryError: ``out_dir`` exists and is not a directory.
        OSError: in an existing ``out_dir``, a report file is a folder, ``figures`` a file or not writable
            (checked before anything in it changes).
    """
    from sim2real.output_paths import held_signals

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"`out_dir` must be a directory. Received the file {str(out)!r}.")
    figures = report.figures()
    markdown = rendering.to_markdown(report, figure_dir="figures")
    page = rendering.to_html(report, figures)
    text = rendering.json_text(report)
    parent = out.parent if str(out.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    tmp = make_temp_dir(parent, prefix=f".{out.name}.", suffix=".tmp")
    try:
        for name, png in figures.items():
            atomic_write(tmp / "figures" / f"{name}.png", png)
        atomic_write(tmp / "report.md", markdown)
        atomic_write(tmp / "report.html", page)
        atomic_write(tmp / "report.json", text)
        problem = _in_the_way(out, figures)  # checked again: the folder may have changed during the work
        if problem is not None:
            raise OSError(errno.EEXIST, f"{problem}; nothing in {str(out)!r} was changed")
        with held_signals():  # the old report or the new one, never a mix, even on Ctrl-C
            if not out.exists():
                os.replace(tmp, out)
            else:
                _replace_in(out, tmp, [f"figures/{name}.png" for name in figures])
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return _files(out, figures)


def _replace_in(out: Path, tmp: Path, figures: list[str]) -> None:
    """Moves the new report in ``tmp`` into the existing folder ``out``, all of it or nothing: the old files are
    first moved aside into ``tmp/.old`` (the old ``report.json`` first, the new one in last, so its presence marks
    a complete report); if a rename fails, what was moved in is taken out and the old files go back."""
    old = tmp / ".old"
    (old / "figures").mkdir(parents=True)
    names = [*figures, *REPORT_FILES]
    aside: list[str] = []
    placed: list[str] = []
    made_figures = not (out / "figures").exists()
    try:
        for name in ["report.json", *(n for n in names if n != "report.json")]:
            if (out / name).exists():
                os.replace(out / name, old / name)
                aside.append(name)
        (out / "figures").mkdir(exist_ok=True)
        for name in names:
            os.replace(tmp / name, out / name)
            placed.append(name)
    except BaseException:
        for name in reversed(placed):
            (out / name).unlink(missing_ok=True)
        for name in reversed(aside):
            os.replace(old / name, out / name)
        if made_figures:
            with contextlib.suppress(OSError):
                (out / "figures").rmdir()
        raise


def _files(out: Path, figures: Iterable[str]) -> ReportFiles:
    return ReportFiles(
        directory=out,
        html=out / "report.html",
        markdown=out / "report.md",
        json=out / "report.json",
        figures=tuple(out / "figures" / f"{name}.png" for name in figures),
    )
