"""The gap report as documents: a plain-text summary, JSON-ready data, Markdown and one self-contained HTML page.

:func:`document` lays the report out once as format-neutral blocks; :func:`to_markdown` and :func:`to_html` render
those same blocks, so the two never drift apart. Every user-supplied string is escaped for its format. Hidden
configurations and the sysid ground truth appear only in the last section, :data:`APPENDIX`.

Example:
    >>> _cell(None), _pct1(0.1234)
    ('n/a', '12.3%')
"""

from __future__ import annotations

import base64
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from sim2real.metrics import Estimate
from sim2real.report import findings
from sim2real.report.figures import plan
from sim2real.report.labels import parameter_unit
from sim2real.report.markup import _e, _html_table, _md, _md_table, html_page
from sim2real.report.results import ConditionInfo, GapStats, ParameterDraws, RobustnessCurve
from sim2real.report.serialize import json_text, to_dict

if TYPE_CHECKING:
    from sim2real.report.gap_report import GapReport

# to_dict / json_text live in sim2real.report.serialize (re-exported: the report's entry points stay here).
__all__ = ["APPENDIX", "document", "html_page", "json_text", "summary", "to_dict", "to_html", "to_markdown"]

#: The heading of the last section, the only place hidden configurations and sysid ground truth appear.
APPENDIX = "Appendix: the real target"


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
    muted: tuple[tuple[int, int], ...] = ()  # (row, column) of table cells shown greyed (e.g. censored radii)


def summary(report: GapReport) -> str:
    """The report's opening paragraph as plain text, every claim with an interval from the report.

    The caller's lead paragraph (:attr:`GapReport.lead`, e.g. the study's) comes first, then a line naming the
    study, the headline read from significance (:func:`sim2real.report.findings.findings`), one line per policy with
    its gaps (at most 8), and the budget warnings.
    """
    lines = [report.lead] if report.lead else []
    lines.append(
        f"{len(report.policies)} polic{'y' if len(report.policies) == 1 else 'ies'} evaluated on {report.task} under "
        f"{len(report.conditions)} condition(s), {findings.episodes_text(report)} (seed {report.seed})."
    )
    if report.episode_target is not None and findings.episode_target_sentence(report) not in report.lead:
        lines.append(findings.episode_target_sentence(report))
    lines += [f for f in findings.findings(report) if f not in report.lead]  # the lead may say it already
    for policy in report.policies[:8]:
        parts = [_gap_phrase(g) for g in report.gaps if g.policy == policy and g.target == report.target]
        if parts:
            lines.append(f"{policy!r} " + "; ".join(parts) + ".")
    if len(report.policies) > 8:
        lines.append(f"... and {len(report.policies) - 8} more policies (see the gap table).")
    if report.target is None:
        lines.append("No target condition: no sim-to-real gap is reported.")
    lines += [f"Warning: {w}" for w in findings.budget_warnings(report)]
    if report.warnings:
        lines.append(f"{len(report.warnings)} kind(s) of warning were raised while computing (see Warnings).")
    return "\n".join(lines)


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
            f"Task {report.task}, {findings.episodes_text(report)}, seed {report.seed}, "
            f"{report.env_steps} environment steps. {conf} intervals from a stratified bootstrap "
            f"({report.num_resamples} resamples, rng seed {report.rng_seed}); success rates with Wilson intervals. "
            "Simulated conditions share initial states episode by episode, so gaps between them are paired"
            + (
                "; a gap between two simulated conditions that ran different numbers of episodes (more on the "
                "target) is paired over the episodes both ran (the first min of the two counts in its runs column)."
                if len({n for counts in report.episode_counts().values() for n in counts} | {report.episodes}) > 1
                else "."
            ),
            style="muted",
        ),
    ]

    def figure(kind: str, key: str, caption: str) -> None:
        name = names.get((kind, key))
        if name is not None:
            doc.append(_Block("figure", caption, items=(name,)))

    def table(header: Sequence[str], rows: Sequence[Sequence[str]], muted: Sequence[tuple[int, int]] = ()) -> None:
        doc.append(_Block("table", header=tuple(header), rows=tuple(tuple(r) for r in rows), muted=tuple(muted)))

    def lab(name: str, role: str = "condition") -> str:
        return report.label(name, role)

    if report.stats:
        conditions = list(dict.fromkeys(s.condition for s in report.stats))
        doc += [_Block("h2", "Returns"), _Block("p", f"{stat} return [{conf} interval] per policy and condition.")]
        table(
            ["policy", *(lab(c) for c in conditions)],
            [[lab(p, "policy"), *(_cell_for(report, p, c) for c in conditions)] for p in report.policies],
        )
        figure("returns", "", f"{stat} return per policy and condition, with {conf} interval whiskers")
        doc.append(_Block("h3", "Detail"))
        table(
            ["policy", "condition", "n", "mean", "IQM", f"CVaR {report.alpha:g}", "worst", "success"],
            [
                [
                    lab(s.policy, "policy"),
                    lab(s.condition),
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
                f"gap = {stat}(from) - {stat}(to): positive when the target does worse (the policy loses), negative "
                f"when it does better (gains); relative = gap / |{stat}(from)|. Paired: resampled jointly (same "
                "initial states); unpaired: independently.",
            ),
        ]
        table(
            ["policy", "from", "to", "gap", "relative", "reads", "paired", "runs"],
            [
                [
                    lab(g.policy, "policy"),
                    lab(g.reference),
                    lab(g.target),
                    _cell(g.absolute),
                    _relative_cell(g),
                    _reads(g),
                    "yes" if g.paired else "no",
                    f"{g.n_reference} / {g.n_target}",
                ]
                for g in report.gaps
            ],
        )
    if report.predictions:
        doc += [
            _Block("h2", "Does each simulator predict the target?"),
            _Block(
                "p",
                f"Per simulator, the policies' paired gaps to the target (above): 'within' is the largest end of any "
                f"policy's {conf} interval of the relative gap; a policy is mispredicted when its gap interval "
                "excludes 0.",
            ),
        ]
        table(
            ["simulator", "target", "policies", "within", "mispredicted"],
            [
                [
                    lab(p.simulator),
                    lab(p.target),
                    str(len(p.policies)),
                    _pct1(p.within) if math.isfinite(p.within) else "undefined (a return of 0)",
                    ", ".join(lab(x, "policy") for x in p.differ) or "none",
                ]
                for p in report.predictions
            ],
        )
    if report.differences:
        doc += [
            _Block("h2", f"Policy differences on {lab(report.target or '')}"),
            _Block("p", f"{stat}(x) - {stat}(y) [{conf} interval]; significant when the interval excludes 0."),
        ]
        table(
            ["x", "y", "x - y", "significant", "paired", "episodes"],
            [
                [
                    lab(d.x, "policy"),
                    lab(d.y, "policy"),
                    findings.signed(d.difference, 4),
                    "yes" if d.significant else "no",
                    "yes" if d.paired else "no",
                    str(d.n),
                ]
                for d in report.differences
            ],
        )
    if report.robustness:
        doc += [
            _Block("h2", "Robustness"),
            _Block(
                "p",
                f"Radius: the largest distance from the nominal value that keeps {report.fraction:g} of the policy's "
                f"{stat} return in the sim it was trained in (the reference). '>= sweep end' (greyed): the curve never "
                "fell below the threshold within the sweep, so the radius is only a lower bound; '0': the threshold "
                "is missed already at the nominal value.",
            ),
        ]
        rows = [_radius_row(report, c) for c in report.robustness]
        censored = [(i, 4) for i, c in enumerate(report.robustness) if c.radius is not None and c.radius.censored]
        table(["policy", "sweep", "nominal", "reference return", "radius", "interval"], rows, censored)
        for sweep in dict.fromkeys(c.sweep for c in report.robustness):
            axis = next(c.axis for c in report.robustness if c.sweep == sweep)
            figure(
                "robustness",
                sweep,
                f"robustness to {report.axis_label(axis).text} (sweep {sweep}; {conf} bands)",
            )
    if report.grids:
        doc.append(_Block("h2", "Parameter grids"))
        for grid in dict.fromkeys(g.grid for g in report.grids):
            figure("heatmap", grid, f"{stat} return over {grid}")
        for g in report.grids:
            ax = report.axis_label(g.axes[0])
            ay = report.axis_label(g.axes[1])
            doc.append(
                _Block("p", f"{lab(g.policy, 'policy')}, {stat} return over {ax.text} × {ay.text} (grid {g.grid}):")
            )
            table(  # rows y (top: largest, as in the heatmap), columns x: the figure's layout
                [f"{ay.text} \\ {ax.text}", *(f"{v * ax.factor:g}" for v in g.x)],
                [
                    [f"{y * ay.factor:g}", *(_num(row[j]) for row in g.values)]
                    for j, y in reversed(list(enumerate(g.y)))
                ],
            )
    if report.agreement:
        doc += [
            _Block("h2", "Agreement across policies"),
            _Block(
                "p",
                "SRCC: Spearman rank correlation of the per-policy scores between a simulated condition and the "
                "target; Pearson: their linear correlation; MMRV: mean maximum rank violation (0 = the same ranking), "
                "in return units.",
            ),
        ]
        table(
            ["sim", "target", "policies", "SRCC (Spearman)", "Pearson", "MMRV", "note"],
            [
                [
                    lab(a.reference),
                    lab(a.target),
                    str(len(a.policies)),
                    _cell(a.srcc),
                    _cell(a.pearson),
                    _cell(a.mmrv),
                    a.note,
                ]
                for a in report.agreement
            ],
        )
    if report.improvements:
        doc.append(_Block("h2", f"Probability of improvement on {report.target}"))
        table(
            ["x", "y", "P(x > y)"],
            [[lab(i.x, "policy"), lab(i.y, "policy"), _cell(i.probability)] for i in report.improvements],
        )
    if report.fit is not None or report.fit_parameters:
        doc.append(_Block("h2", "System identification"))
        table(
            ["parameter", "unit", "estimate", "stderr", "95% interval"],
            [
                [
                    p.address,
                    parameter_unit(p.address, report.linear, report.tendons),
                    _num(p.estimate, 6),
                    _num(p.stderr, 3),
                    f"[{_num(p.low, 6)}, {_num(p.high, 6)}]",
                ]
                for p in report.fit_parameters
            ],
        )
        if report.fit_percent:
            doc.append(_Block("p", "held-out fit: " + ", ".join(f"{k} {v:.1f}%" for k, v in report.fit_percent)))
        if report.fit_warnings:
            doc.append(_Block("list", items=tuple(f"fit warning: {w}" for w in report.fit_warnings)))
        if report.fit is not None and len(report.fit.channels):
            pages = [key for _, kind, key in plan(report) if kind == "sysid_fit"]
            for key in pages:
                figure(
                    "sysid_fit",
                    key,
                    f"measured vs simulated signals and residuals, all {len(report.fit.channels)} channels "
                    f"(page {int(key) + 1} of {len(pages)})",
                )
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
    budget = findings.budget_warnings(report)
    if report.warnings or budget:
        doc += [_Block("h2", "Warnings"), _Block("list", items=(*budget, *report.warnings))]
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
            out += [*_md_table(block.header, block.rows, block.muted), ""]
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
            body.append(_html_table(block.header, block.rows, block.muted))
        elif block.kind == "figure" and block.items[0] in figures:
            name = block.items[0]
            data = base64.b64encode(figures[name]).decode("ascii")
            body.append(
                f"<figure><img alt='{_e(name)}' src='data:image/png;base64,{data}'>"
                f"<figcaption>{_e(block.text)}</figcaption></figure>"
            )
    return html_page(report.title, "\n".join(body))


def _num(value: float, digits: int = 4) -> str:
    return f"{value:.{digits}g}" if math.isfinite(value) else "n/a"


def _cell(e: Estimate | None) -> str:
    return findings.cell(e)


def _pct(e: Estimate) -> str:
    return f"{_pct1(e.value)} [{_pct1(e.low)}, {_pct1(e.high)}]"


def _pct1(value: float) -> str:
    return f"{100.0 * value:.1f}%" if math.isfinite(value) else "n/a"


def _gap_phrase(g: GapStats) -> str:
    return findings.gap_phrase(g)


def _relative_cell(g: GapStats) -> str:
    if not math.isfinite(g.relative.value):
        return f"undefined: the {g.reference} return is 0"
    if not math.isfinite(g.relative.low):
        return f"{_pct1(g.relative.value)} (no interval: the {g.reference} return is 0 in too many resamples)"
    return _pct(g.relative)


def _reads(g: GapStats) -> str:
    """The gap in words, by the sign of its point estimate, and whether its interval excludes 0."""
    ab = g.absolute
    verb = "loses" if ab.value > 0 else "gains" if ab.value < 0 else "same"
    if ab.low > 0 or ab.high < 0:
        return f"{verb} (significant)"
    return f"{verb} (not significant)" if verb != "same" else "same"


def _radius_row(report: GapReport, c: RobustnessCurve) -> list[str]:
    label = report.axis_label(c.axis)
    unit = f" {label.unit}" if label.unit else ""
    policy, sweep = report.label(c.policy, "policy"), label.text
    nominal = f"{c.nominal * label.factor:g}"
    if c.radius is None:
        return [policy, sweep, nominal, "n/a", f"n/a ({c.note})", ""]
    r = c.radius
    trained = f" ({report.label(c.reference, 'condition')})" if c.reference else " (nominal point)"
    reference = _num(r.nominal_return) + trained
    value = r.radius.value * label.factor
    interval = f"[{_num(r.radius.low * label.factor)}, {_num(r.radius.high * label.factor)}]"
    if r.censored:
        return [policy, sweep, nominal, reference, f">= {_num(value)}{unit} (sweep end; not crossed)", interval]
    if value == 0:
        return [policy, sweep, nominal, reference, f"0{unit} (missed at the nominal value)", interval]
    return [policy, sweep, nominal, reference, f"{_num(value)}{unit}", interval]


def _points_text(group: Sequence[ConditionInfo]) -> str:
    return ", ".join(
        f"{c.value[0]:g}" if len(c.value) == 1 else "(" + ", ".join(f"{v:g}" for v in c.value) + ")" for c in group
    )


def _draw_row(d: ParameterDraws) -> list[str]:
    return [d.address, _num(d.low, 6), _num(d.mean, 6), _num(d.high, 6), str(d.n)]
