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

__all__ = ["write"]


def write(report: GapReport, out_dir: str | os.PathLike[str]) -> ReportFiles:
    """Writes ``report.html``, ``report.md``, ``report.json`` and ``figures/<name>.png`` of ``report`` into
    ``out_dir`` (see :meth:`GapReport.write <sim2real.report.GapReport.write>`).

    Raises:
        NotADirectoryError: ``out_dir`` exists and is not a directory.
    """
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
        if not out.exists():
            os.replace(tmp, out)
        else:
            (out / "report.json").unlink(missing_ok=True)
            (out / "figures").mkdir(exist_ok=True)
            for name in figures:
                os.replace(tmp / "figures" / f"{name}.png", out / "figures" / f"{name}.png")
            for name in ("report.md", "report.html", "report.json"):
                os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return _files(out, figures)


def _files(out: Path, figures: Iterable[str]) -> ReportFiles:
    return ReportFiles(
        directory=out,
        html=out / "report.html",
        markdown=out / "report.md",
        json=out / "report.json",
        figures=tuple(out / "figures" / f"{name}.png" for name in figures),
    )
