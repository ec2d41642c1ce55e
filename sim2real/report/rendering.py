"""The gap report as documents: a plain-text summary, JSON-ready data, Markdown and one self-contained HTML page.

:func:`document` lays the report out once as format-neutral blocks; :func:`to_markdown` and :func:`to_html` render
those same blocks, so the two never drift apart. Every user-supplied string is escaped for its format. Hidden
configurations and the sysid ground truth appear only in the last section, :data:`APPENDIX`.

Example:
    >>> print(_md_table(["policy", "a|b"], [["<x>", "1"]])[2])
    | \\<x\\> | 1 |
    >>> _cell(None), _pct1(0.1234)
    ('n/a', '12.3%')
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from sim2real.metrics import Estimate
from sim2real.report.figures import plan
from sim2real.report.results import ConditionInfo, GapStats, ParameterDraws, RobustnessCurve

if TYPE_CHECKING:
    from sim2real.report.gap_report import GapReport

__all__ = ["APPENDIX", "document", "html_page", "json_text", "summary", "to_dict", "to_html", "to_markdown"]

#: The heading of the last section, the only place hidden configurations and sysid ground truth appear.
APPENDIX = "Appendix: the real target"
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
    ".muted{color:#666;font-size:.9em}"
)


@dataclass(frozen=True)
class _Block:
    """One piece of the document (plain text; escaped when rendered): a heading (``h1``-``h3``; ``style`` is its
    anchor), a paragraph ``p`` (lines; ``style`` is its CSS class), ``code``, a ``list`` of ``items``, a ``table``
    (``header``, ``rows``) or a ``figure`` (``items[0]`` its name, ``text`` its caption)."""

    kind: str
    text: str = ""
    header: tuple[str, ...] = ()
    rows: tuple[tuple[str, ...], ...] = ()
    items: tuple[str, ...] = ()
    style: str = ""


def summary(report: GapReport) -> str:
    """The report's opening paragraph as plain text: the gap before and after randomisation per policy.

    The first line names the study; then one line per policy (at most 8), then agreement and warnings.
    """
    lines = [
        f"{len(report.policies)} polic{'y' if len(report.policies) == 1 else 'ies'} evaluated on {report.task} under "
        f"{len(report.conditions)} condition(s), {report.episodes} episode(s) per simulated condition (seed "
        f"{report.seed})."
    ]
    for policy in report.policies[:8]:
        parts = []
        for ref in (report.reference, report.randomized):
            if ref is None or report.target is None:
                continue
            try:
                g = report.gap(policy, ref, report.target)
            except KeyError:
                continue
            parts.append(_gap_phrase(g))
        if parts:
            lines.append(f"{policy!r} " + "; ".join(parts) + ".")
    if len(report.policies) > 8:
        lines.append(f"... and {len(report.policies) - 8} more policies (see the gap table).")
    for a in report.agreement:
        if a.srcc is not None:
            lines.append(
                f"{a.reference} ranks the {len(a.policies)} policies like {a.target} with correlation "
                f"{_cell(a.srcc)} (MMRV {_cell(a.mmrv)})."
            )
    if report.target is None:
        lines.append("No target condition: no sim-to-real gap is reported.")
    if report.warnings:
        lines.append(f"{len(report.warnings)} kind(s) of warning were raised while computing (see Warnings).")
    return "\n".join(lines)


def to_dict(report: GapReport) -> dict[str, Any]:
    """Every number of the report as plain JSON-ready data (non-finite numbers become None).

    Hidden conditions' configurations and draws and the sysid ground truth are under ``"appendix"``.
    """

    def cond(info: ConditionInfo) -> dict[str, Any]:
        out: dict[str, Any] = {
            "name": info.name,
            "kind": info.kind,
            "description": info.description,
            "simulated": info.simulated,
            "hidden": info.hidden,
        }
        if not info.hidden:
            out["config"] = json.loads(info.config)
            out["draws"] = [_draw_dict(d) for d in info.draws]
        return out

    hidden = [c for c in report.conditions if c.hidden]
    return {
        "title": report.title,
        "summary": report.summary(),
        "evaluation": {
            "task": report.task,
            "seed": report.seed,
            "episodes": report.episodes,
            "max_steps": report.max_steps,
            "env_steps": report.env_steps,
            "policies": list(report.policies),
            "conditions": [cond(c) for c in report.conditions],
        },
        "roles": {"reference": report.reference, "randomized": report.randomized, "target": report.target},
        "settings": {
            "statistic": report.statistic,
            "confidence": report.confidence,
            "alpha": report.alpha,
            "fraction": report.fraction,
            "num_resamples": report.num_resamples,
            "rng_seed": report.rng_seed,
        },
        "stats": [
            {
                "policy": s.policy,
                "condition": s.condition,
                "kind": s.kind,
                "n": s.n,
                "mean": _estimate_dict(s.mean),
                "iqm": _estimate_dict(s.iqm),
                "cvar": _estimate_dict(s.cvar),
                "worst": _finite(s.worst),
                "success": _estimate_dict(s.success),
            }
            for s in report.stats
        ],
        "gaps": [
            {
                "policy": g.policy,
                "reference": g.reference,
                "target": g.target,
                "absolute": _estimate_dict(g.absolute),
                "relative": _estimate_dict(g.relative),
                "paired": g.paired,
                "n_reference": g.n_reference,
                "n_target": g.n_target,
                "statistic": g.statistic,
            }
            for g in report.gaps
        ],
        "robustness": [
            {
                "policy": c.policy,
                "sweep": c.sweep,
                "axis": c.axis,
                "values": list(c.values),
                "conditions": list(c.conditions),
                "nominal": c.nominal,
                "points": [_estimate_dict(p) for p in c.points],
                "fraction": c.fraction,
                "statistic": c.statistic,
                "note": c.note,
                "radius": None
                if c.radius is None
                else {
                    "radius": _estimate_dict(c.radius.radius),
                    "nominal_return": _finite(c.radius.nominal_return),
                    "threshold": _finite(c.threshold if c.threshold is not None else math.nan),
                    "censored": c.radius.censored,
                },
            }
            for c in report.robustness
        ],
        "grids": [
            {
                "policy": g.policy,
                "grid": g.grid,
                "axes": list(g.axes),
                "x": list(g.x),
                "y": list(g.y),
                "values": [[_finite(v) for v in row] for row in g.values],
                "nominal": list(g.nominal),
                "statistic": g.statistic,
            }
            for g in report.grids
        ],
        "agreement": [
            {
                "reference": a.reference,
                "target": a.target,
                "policies": list(a.policies),
                "srcc": _estimate_dict(a.srcc),
                "mmrv": _estimate_dict(a.mmrv),
                "note": a.note,
            }
            for a in report.agreement
        ],
        "improvements": [
            {"condition": i.condition, "x": i.x, "y": i.y, "probability": _estimate_dict(i.probability)}
            for i in report.improvements
        ],
        "fit": None
        if not report.fit_parameters and report.fit is None
        else {
            "params": {
                p.address: {
                    "estimate": _finite(p.estimate),
                    "stderr": _finite(p.stderr),
                    "ci95": [_finite(p.low), _finite(p.high)],
                }
                for p in report.fit_parameters
            },
            "fit_percent": {k: _finite(v) for k, v in report.fit_percent},
            "warnings": list(report.fit_warnings),
        },
        "contact_sheet": None if report.contact_sheet_shape is None else {"shape": list(report.contact_sheet_shape)},
        "figures": report.figure_names(),
        "notes": list(report.notes),
        "skipped": list(report.skipped),
        "warnings": list(report.warnings),
        "versions": dict(report.versions),
        "appendix": {
            "conditions": [
                {"name": c.name, "config": json.loads(c.config), "draws": [_draw_dict(d) for d in c.draws]}
                for c in hidden
            ],
            "fit_truth": {p.address: _finite(p.truth) for p in report.fit_parameters if p.truth is not None},
        },
        **({} if report.safety is None else {"safety": report.safety.to_dict()}),  # sim2real.report.safety
    }


def json_text(report: GapReport, indent: int | None = 1) -> str:
    """:func:`to_dict` as JSON text, keys sorted (bitwise reproducible)."""
    return json.dumps(to_dict(report), indent=indent, sort_keys=True, allow_nan=False) + "\n"


def document(report: GapReport) -> list[_Block]:
    """The report as format-neutral blocks (plain, unescaped text); :func:`to_markdown` and :func:`to_html`
    render the same blocks, so the two never drift apart."""
    names = {(kind, key): name for name, kind, key in plan(report)}
    stat, conf = report.statistic, f"{report.confidence:.0%}"
    doc = [
        _Block("h1", report.title),
        _Block("p", report.summary(), style="summary"),
        _Block(
            "p",
            f"Task {report.task}, {report.episodes} episode(s) per simulated condition, seed {report.seed}, "
            f"{report.env_steps} environment steps. {conf} intervals from a stratified bootstrap "
            f"({report.num_resamples} resamples, rng seed {report.rng_seed}); success rates with Wilson intervals. "
            "Simulated conditions share initial states episode by episode, so gaps between them are paired.",
            style="muted",
        ),
    ]

    def figure(kind: str, key: str, caption: str) -> None:
        name = names.get((kind, key))
        if name is not None:
            doc.append(_Block("figure", caption, items=(name,)))

    def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> None:
        doc.append(_Block("table", header=tuple(header), rows=tuple(tuple(r) for r in rows)))

    if report.stats:
        conditions = list(dict.fromkeys(s.condition for s in report.stats))
        doc += [_Block("h2", "Returns"), _Block("p", f"{stat} return [{conf} interval] per policy and condition.")]
        table(["policy", *conditions], [[p, *(_cell_for(report, p, c) for c in conditions)] for p in report.policies])
        figure("returns", "", f"{stat} return per policy and condition, with {conf} interval whiskers")
        doc.append(_Block("h3", "Detail"))
        table(
            ["policy", "condition", "n", "mean", "IQM", f"CVaR {report.alpha:g}", "worst", "success"],
            [
                [
                    s.policy,
                    s.condition,
                    str(s.n),
                    _cell(s.mean),
                    _cell(s.iqm),
                    _cell(s.cvar),
                    _num(s.worst),
                    _cell(s.success),
                ]
                for s in report.stats
            ],
        )
    if report.gaps:
        doc += [
            _Block("h2", "Sim-to-real gaps"),
            _Block(
                "p",
                f"absolute = {stat}(from) - {stat}(to), positive when the target does worse; relative = absolute / "
                f"|{stat}(from)|. Paired: resampled jointly (same initial states); unpaired: independently.",
            ),
        ]
        table(
            ["policy", "from", "to", "absolute", "relative", "paired", "runs"],
            [
                [
                    g.policy,
                    g.reference,
                    g.target,
                    _cell(g.absolute),
                    _pct(g.relative),
                    "yes" if g.paired else "no",
                    f"{g.n_reference} / {g.n_target}",
                ]
                for g in report.gaps
            ],
        )
    if report.robustness:
        doc += [
            _Block("h2", "Robustness"),
            _Block(
                "p",
                f"Radius: the largest distance from the nominal value that keeps {report.fraction:g} of the nominal "
                f"{stat} return (censored: the sweep never crossed the threshold there, so the radius is a lower "
                "bound).",
            ),
        ]
        table(
            ["policy", "sweep", "nominal", "nominal return", "radius", "censored"],
            [_radius_row(c) for c in report.robustness],
        )
        for sweep in dict.fromkeys(c.sweep for c in report.robustness):
            figure("robustness", sweep, f"robustness curves over {sweep} ({conf} bands)")
    if report.grids:
        doc.append(_Block("h2", "Parameter grids"))
        for grid in dict.fromkeys(g.grid for g in report.grids):
            figure("heatmap", grid, f"{stat} return over {grid}")
        for g in report.grids:
            doc.append(_Block("p", f"{g.policy} on {g.grid} ({stat}; rows {g.axes[0]}, columns {g.axes[1]}):"))
            table(
                [f"{g.axes[0]} \\ {g.axes[1]}", *(f"{v:g}" for v in g.y)],
                [[f"{x:g}", *(_num(v) for v in row)] for x, row in zip(g.x, g.values, strict=True)],
            )
    if report.agreement:
        doc += [
            _Block("h2", "Agreement across policies"),
            _Block(
                "p",
                "SRCC: Pearson correlation of the per-policy scores between a simulated condition and the target; "
                "MMRV: mean maximum rank violation (0 = the same ranking), in return units.",
            ),
        ]
        table(
            ["sim", "target", "policies", "SRCC", "MMRV", "note"],
            [
                [a.reference, a.target, str(len(a.policies)), _cell(a.srcc), _cell(a.mmrv), a.note]
                for a in report.agreement
            ],
        )
    if report.improvements:
        doc.append(_Block("h2", f"Probability of improvement on {report.target}"))
        table(["x", "y", "P(x > y)"], [[i.x, i.y, _cell(i.probability)] for i in report.improvements])
    if report.fit is not None or report.fit_parameters:
        doc.append(_Block("h2", "System identification"))
        table(
            ["parameter", "estimate", "stderr", "95% interval"],
            [
                [p.address, _num(p.estimate, 6), _num(p.stderr, 3), f"[{_num(p.low, 6)}, {_num(p.high, 6)}]"]
                for p in report.fit_parameters
            ],
        )
        if report.fit_percent:
            doc.append(_Block("p", "held-out fit: " + ", ".join(f"{k} {v:.1f}%" for k, v in report.fit_percent)))
        if report.fit_warnings:
            doc.append(_Block("list", items=tuple(f"fit warning: {w}" for w in report.fit_warnings)))
        if report.fit is not None and len(report.fit.channels):
            figure("sysid_fit", "", "measured vs simulated signals and residuals")
    if report.contact_sheet is not None:
        doc.append(_Block("h2", "Visual randomisation"))
        figure("contact_sheet", "", "contact sheet of randomised first frames")
    doc.append(_Block("h2", "Conditions"))
    rows, drawn = [], []
    for group in _condition_groups(report):
        c = group[0]
        if c.sweep is not None:
            rows.append([c.sweep, c.kind, f"{len(group)} points: {_points_text(group)}", f"e.g. {c.config}"])
        elif c.hidden:
            rows.append([c.name, c.kind, c.description, "(in the appendix)"])
        else:
            rows.append([c.name, c.kind, c.description, c.config])
            drawn += [[c.name, *_draw_row(d)] for d in c.draws]
    table(["condition", "kind", "description", "configuration"], rows)
    if drawn:
        doc.append(_Block("p", "Parameter values drawn per episode:"))
        table(["condition", "parameter", "low", "mean", "high", "episodes"], drawn)
    if report.notes or report.skipped:
        doc += [_Block("h2", "Notes"), _Block("list", items=(*report.notes, *report.skipped))]
    if report.warnings:
        doc += [_Block("h2", "Warnings"), _Block("list", items=report.warnings)]
    doc += [
        _Block("h2", "Settings"),
        _Block(
            "p",
            f"statistic {stat}, confidence {report.confidence:g}, CVaR alpha {report.alpha:g}, radius fraction "
            f"{report.fraction:g}, {report.num_resamples} resamples, rng seed {report.rng_seed}; "
            + ", ".join(f"{k} {v}" for k, v in report.versions),
        ),
    ]
    if report.safety is not None:  # the Safety section, built by sim2real.report.safety
        from sim2real.report.safety import safety_blocks

        doc += [_Block(**block) for block in safety_blocks(report.safety)]
    hidden = [c for c in report.conditions if c.hidden]
    truths = [p for p in report.fit_parameters if p.truth is not None]
    if hidden or truths:
        doc.append(_Block("h2", APPENDIX, style="appendix"))
        for c in hidden:
            doc += [_Block("h3", f"{c.name} ({c.kind})"), _Block("p", c.description), _Block("code", c.config)]
            if c.draws:
                table(["parameter", "low", "mean", "high", "episodes"], [_draw_row(d) for d in c.draws])
        if truths:
            doc.append(_Block("h3", "sysid estimates against the true parameters"))
            table(
                ["parameter", "estimate", "95% interval", "true", "inside"],
                [
                    [
                        p.address,
                        _num(p.estimate, 6),
                        f"[{_num(p.low, 6)}, {_num(p.high, 6)}]",
                        _num(p.truth or 0.0, 6),
                        "yes" if p.low <= (p.truth or 0.0) <= p.high else "no",
                    ]
                    for p in truths
                ],
            )
    return doc


def _condition_groups(report: GapReport) -> list[list[ConditionInfo]]:
    """Conditions in order, the points of each visible sweep or grid gathered into one group."""
    groups: list[list[ConditionInfo]] = []
    index: dict[str, list[ConditionInfo]] = {}
    for c in report.conditions:
        if c.sweep is None or c.hidden:
            groups.append([c])
        elif c.sweep in index:
            index[c.sweep].append(c)
        else:
            index[c.sweep] = [c]
            groups.append(index[c.sweep])
    return groups


def _cell_for(report: GapReport, policy: str, condition: str) -> str:
    for s in report.stats:
        if s.policy == policy and s.condition == condition:
            return _cell(s.statistic(report.statistic))
    return "n/a"


def to_markdown(report: GapReport, figure_dir: str | None = None) -> str:
    """The report as Markdown (the same sections and tables as :func:`to_html`).

    With ``figure_dir`` (``write`` passes ``"figures"``) each figure is linked as ``<figure_dir>/<name>.png``;
    without it figures are left out. User strings are escaped (no raw HTML, no broken tables).
    """
    out: list[str] = []
    for block in document(report):
        if block.kind in ("h1", "h2", "h3"):
            out += [f"{'#' * int(block.kind[1])} {_md(block.text)}", ""]
        elif block.kind in ("p", "code"):
            out += ["  \n".join(_md(line) for line in block.text.splitlines()), ""]
        elif block.kind == "list":
            out += [*(f"- {_md(item)}" for item in block.items), ""]
        elif block.kind == "table":
            out += [*_md_table(block.header, block.rows), ""]
        elif block.kind == "figure" and figure_dir is not None:
            name = block.items[0]
            out += [f"![{_md(block.text)}]({figure_dir}/{name}.png)", ""]
    return "\n".join(out).rstrip("\n") + "\n"


def to_html(report: GapReport, figures: Mapping[str, bytes]) -> str:
    """One self-contained HTML page: ``figures`` (name to PNG bytes) embedded as base64, inline CSS, no scripts, no
    external resources; every user-supplied string escaped. Hidden configurations only in the final appendix."""
    body: list[str] = []
    for block in document(report):
        style = f" class='{_e(block.style)}'" if block.style else ""
        if block.kind in ("h1", "h2", "h3"):
            anchor = f" id='{_e(block.style)}'" if block.style else ""
            body.append(f"<{block.kind}{anchor}>{_e(block.text)}</{block.kind}>")
        elif block.kind == "p":
            body.append(f"<p{style}>{'<br>'.join(_e(line) for line in block.text.splitlines())}</p>")
        elif block.kind == "code":
            body.append(f"<pre>{_e(block.text)}</pre>")
        elif block.kind == "list":
            body.append("<ul>" + "".join(f"<li>{_e(item)}</li>" for item in block.items) + "</ul>")
        elif block.kind == "table":
            body.append(_html_table(block.header, block.rows))
        elif block.kind == "figure" and block.items[0] in figures:
            name = block.items[0]
            data = base64.b64encode(figures[name]).decode("ascii")
            body.append(
                f"<figure><img alt='{_e(name)}' src='data:image/png;base64,{data}'>"
                f"<figcaption>{_e(block.text)}</figcaption></figure>"
            )
    return html_page(report.title, "\n".join(body))


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _estimate_dict(e: Estimate | None) -> dict[str, Any] | None:
    if e is None:
        return None
    return {
        "value": _finite(e.value),
        "low": _finite(e.low),
        "high": _finite(e.high),
        "confidence": e.confidence,
        "n": e.n,
        "method": e.method,
    }


def _num(value: float, digits: int = 4) -> str:
    return f"{value:.{digits}g}" if math.isfinite(value) else "n/a"


def _cell(e: Estimate | None) -> str:
    if e is None:
        return "n/a"
    return f"{_num(e.value)} [{_num(e.low)}, {_num(e.high)}]"


def _pct(e: Estimate) -> str:
    return f"{_pct1(e.value)} [{_pct1(e.low)}, {_pct1(e.high)}]"


def _pct1(value: float) -> str:
    return f"{100.0 * value:.1f}%" if math.isfinite(value) else "n/a"


def _md(text: str) -> str:
    """Markdown-safe inline text: no raw HTML, no table breaks."""
    text = " ".join(str(text).split())
    return re.sub(r"([\\`*_\[\]<>|#])", r"\\\1", text)


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _gap_phrase(g: GapStats) -> str:
    where = f"from {g.reference} to {g.target}"
    pairing = "paired" if g.paired else f"unpaired, {g.n_reference} vs {g.n_target} runs"
    rel = g.relative
    if math.isfinite(rel.value):
        if rel.value >= 0:
            amount = f"loses {_pct(rel)}"
        else:
            amount = f"gains {_pct1(-rel.value)} [{_pct1(-rel.high)}, {_pct1(-rel.low)}]"
        return f"{amount} {where} (gap {_cell(g.absolute)}, {pairing})"
    return f"has a gap of {_cell(g.absolute)} {where} ({pairing})"


def _radius_row(c: RobustnessCurve) -> list[str]:
    if c.radius is None:
        return [c.policy, c.sweep, f"{c.nominal:g}", "n/a", f"n/a ({c.note})", ""]
    r = c.radius
    return [
        c.policy,
        c.sweep,
        f"{c.nominal:g}",
        _num(r.nominal_return),
        _cell(r.radius),
        "yes (lower bound)" if r.censored else "no",
    ]


def _points_text(group: Sequence[ConditionInfo]) -> str:
    return ", ".join(
        f"{c.value[0]:g}" if len(c.value) == 1 else "(" + ", ".join(f"{v:g}" for v in c.value) + ")" for c in group
    )


def _draw_dict(d: ParameterDraws) -> dict[str, Any]:
    return {"address": d.address, "low": _finite(d.low), "mean": _finite(d.mean), "high": _finite(d.high), "n": d.n}


def _draw_row(d: ParameterDraws) -> list[str]:
    return [d.address, _num(d.low, 6), _num(d.mean, 6), _num(d.high, 6), str(d.n)]


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(_md(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_md(c) for c in row) + " |" for row in rows]
    return lines


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in row) + "</tr>" for row in rows)
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
