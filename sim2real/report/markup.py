"""Markup for the report's documents: Markdown and HTML escaping, tables (with greyed cells) and the house page.

Example:
    >>> print(_md_table(["policy", "a|b"], [["<x>", "1"]])[2])
    | \\<x\\> | 1 |
    >>> "class='censored'" in _html_table(["r"], [["≥ 3"]], [(0, 0)])
    True
"""

from __future__ import annotations

import html
import re
from collections.abc import Sequence
from typing import Any

__all__ = ["html_page"]

_STYLE = (
    "body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;max-width:1100px;margin:2em auto;"
    "padding:0 1em;color:#222;line-height:1.45}"
    "h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}"
    "table{border-collapse:collapse;margin:.6em 0;font-size:.92em}"
    "th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}"
    "th:first-child,td:first-child{text-align:left}th{background:#f3f3f3}"
    "pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.85em}"
    "img{max-width:100%;height:auto}figure{margin:1em 0}figcaption{font-size:.85em;color:#555}"
    ".summary{background:#eef4fb;border-left:4px solid #3a78c2;padding:.6em 1em}"
    ".muted{color:#666;font-size:.9em}td.censored{color:#999;background:#f7f7f7;font-style:italic}"
)


def _md(text: str) -> str:
    """Markdown-safe inline text: no raw HTML, no table breaks."""
    text = " ".join(str(text).split())
    return re.sub(r"([\\`*_\[\]<>|#])", r"\\\1", text)


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]], muted: Sequence[tuple[int, int]] = ()) -> list[str]:
    grey = set(muted)

    def one(r: int, c: int, text: str) -> str:
        return f"*{_md(text)}*" if (r, c) in grey and text else _md(text)

    lines = ["| " + " | ".join(_md(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(one(r, c, t) for c, t in enumerate(row)) + " |" for r, row in enumerate(rows)]
    return lines


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]], muted: Sequence[tuple[int, int]] = ()) -> str:
    grey = set(muted)
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join(
        "<tr>"
        + "".join(
            f"<td class='censored'>{_e(t)}</td>" if (r, c) in grey else f"<td>{_e(t)}</td>" for c, t in enumerate(row)
        )
        + "</tr>"
        for r, row in enumerate(rows)
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def html_page(title: str, body: str) -> str:
    """A self-contained HTML page (inline CSS, no scripts, no external resources) around ``body`` (already
    escaped HTML); ``title`` is escaped here. The house look of every HTML report (gap report, sysid fit).

    Example:
        >>> html_page("a <b>", "<p>hi</p>").count("&lt;b&gt;")
        1
    """
    return (
        "<!doctype html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{_e(title)}</title><style>{_STYLE}</style></head>\n<body>\n{body}\n</body></html>\n"
    )
