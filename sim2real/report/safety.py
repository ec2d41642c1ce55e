"""The report's Safety section: a :class:`sim2real.safety.SafetyTable` as format-neutral blocks and JSON.

The renderer turns each block (a mapping of :class:`~sim2real.report.rendering._Block` fields) into Markdown and
HTML like every other section; :meth:`SafetyTable.to_dict` is the ``"safety"`` entry of ``report.json``.

Example:
    >>> import numpy as np
    >>> from sim2real.conditions import nominal
    >>> from sim2real.evaluation_results import Evaluation
    >>> from sim2real.safety import SafetyTable, load_limits
    >>> quantities = {"joint_limit_hits": np.array([0.0, 3.0]), "effort_ratio": np.array([0.4, 1.0]),
    ...               "contact_force": np.full(2, np.nan), "ee_speed": np.full(2, np.nan), "diverged": np.zeros(2)}
    >>> evaluation = Evaluation(task="demo", seed=0, episodes=2, max_steps=None, policies=("slam",),
    ...     conditions=(nominal(),), returns={"slam": {"sim": np.zeros(2)}}, successes={}, lengths={}, draws={},
    ...     safety={"slam": {"sim": quantities}})
    >>> blocks = safety_blocks(SafetyTable.build(evaluation, load_limits({"joint_limit_hits": 0})))
    >>> blocks[2]["header"]
    ('policy', 'condition', 'joint-limit hits (steps)', 'effort / limit', 'diverged (episodes)')
    >>> blocks[2]["rows"][0]
    ('slam', 'sim', '3 / 3 VIOLATED (limit 0); 1 of 2 episodes over, 95% 9.45%-90.5%', '1 / 1', '0 / 2')
"""

from __future__ import annotations

from typing import Any

from sim2real.safety import QUANTITIES, SafetyRow, SafetyTable, _pct

__all__ = ["safety_blocks"]

#: Column heading of each quantity.
HEADINGS = {
    "joint_limit_hits": "joint-limit hits (steps)",
    "effort_ratio": "effort / limit",
    "contact_force": "contact force (N)",
    "ee_speed": "end-effector speed (m/s)",
    "joint_speed_ratio": "joint speed / limit",
    "diverged": "diverged (episodes)",
}


def _num(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4g}"


def _cell(row: SafetyRow) -> str:
    if row.quantity == "diverged":
        text = f"{_num(row.worst)} / {row.episodes}"
    else:
        text = f"{_num(row.worst)} / {_num(row.cvar)}"
    if row.peak:  # which joint was the fastest against its limit
        text += f" ({row.peak})"
    if row.kind == "sweep" and row.worst > 0:  # which perturbation is the dangerous one
        text += f" at {row.point}"
    if row.violated:
        text += f" VIOLATED (limit {_num(row.limit)})"
    if row.limit is not None and row.over is not None and row.over_rate is not None:
        # The verdict's evidence: how many episodes crossed the limit, and what rate the data still allow.
        what = "diverged" if row.quantity == "diverged" else "over"
        low, high = row.over_rate.low, row.over_rate.high
        text += f"; {row.over} of {row.episodes} episodes {what}, 95% {_pct(low)}-{_pct(high)}"
    return text


def _sampling(substeps: int | None) -> str:
    """What a once-per-control-step sample sees, given the physics steps per control step."""
    if substeps is None:
        return "Sampled once per control step (a peak between two samples, inside the physics substeps, is not seen)."
    if substeps == 1:
        return "Sampled once per control step, which is every physics step here (1 physics step per control step)."
    return f"Sampled once per control step, every {substeps} physics steps: a peak inside the substeps is not seen."


def safety_blocks(table: SafetyTable) -> list[dict[str, Any]]:
    """The Safety section: heading, an explanation with the limits, the table and the violations (if any)."""
    limits = table.limits
    measured = [q for q in QUANTITIES if any(r.quantity == q for r in table.rows)]
    declared = [f"{HEADINGS[q]} <= {_num(limits.limit(q))}" for q in QUANTITIES if limits.limit(q) is not None]
    gate = "the worst episode" if limits.statistic == "worst" else f"CVaR {limits.alpha:g}"
    text = (
        f"Per policy and condition: worst episode / CVaR {limits.alpha:g} (mean of the worst {limits.alpha:.0%} of "
        "episodes); a sweep row pools every point of the sweep. Diverged: diverged episodes / episodes. Where a "
        "limit is declared, the episodes over it and the 95% (Wilson) interval of that rate follow. "
        + _sampling(table.substeps)
        + " "
        + (
            f"Declared limits (checked on {gate}; divergences on the count): {'; '.join(declared)}."
            if declared
            else "No limits declared: the quantities are reported, nothing is checked."
        )
    )
    cells: dict[tuple[str, str], dict[str, str]] = {}
    for row in table.rows:
        cells.setdefault((row.policy, row.condition if row.kind == "condition" else f"{row.condition} (sweep)"), {})[
            row.quantity
        ] = _cell(row)
    rows = tuple(
        (policy, condition, *(values.get(q, "n/a") for q in measured)) for (policy, condition), values in cells.items()
    )
    blocks: list[dict[str, Any]] = [
        {"kind": "h2", "text": "Safety", "style": "safety"},
        {"kind": "p", "text": text},
        {"kind": "table", "header": ("policy", "condition", *(HEADINGS[q] for q in measured)), "rows": rows},
    ]
    if table.violations:
        blocks.append({"kind": "p", "text": f"{len(table.violations)} violation(s) of the declared envelope:"})
        blocks.append({"kind": "list", "items": tuple(v.message for v in table.violations)})
    else:
        blocks.append({"kind": "p", "text": "Every policy stays within the declared envelope on every condition."})
    return blocks
