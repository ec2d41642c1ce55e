"""The gap report as JSON-ready data (``report.json``): every number the documents show, with its interval."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

from sim2real.metrics import Estimate
from sim2real.report import findings
from sim2real.report.labels import parameter_unit
from sim2real.report.results import ConditionInfo, EpisodeTarget, ParameterDraws

if TYPE_CHECKING:
    from sim2real.report.gap_report import GapReport

__all__ = ["json_text", "to_dict"]


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
    # conditions run with another number of episodes than report.episodes (e.g. more on the target)
    counts = {c: list(n) for c, n in report.episode_counts().items()}
    uneven = any(n != [report.episodes] for n in counts.values())
    return {
        "title": report.title,
        "summary": report.summary(),
        "lead": report.lead,
        "findings": list(findings.findings(report)),
        "budget_warnings": list(findings.budget_warnings(report)),
        "labels": {"policies": dict(report.policy_labels), "conditions": dict(report.condition_labels)},
        "training": dict(report.training),
        "control_timestep": report.control_timestep,
        "substeps": report.substeps,
        "differences": [
            {
                "condition": d.condition,
                "x": d.x,
                "y": d.y,
                "difference": _estimate_dict(d.difference),
                "paired": d.paired,
                "n": d.n,
                "significant": d.significant,
                "statistic": d.statistic,
            }
            for d in report.differences
        ],
        "predictions": [
            {
                "simulator": p.simulator,
                "target": p.target,
                "policies": list(p.policies),
                "within": _finite(p.within),
                "differ": list(p.differ),
                "worst": p.worst,
            }
            for p in report.predictions
        ],
        "evaluation": {
            "task": report.task,
            "seed": report.seed,
            "episodes": report.episodes,
            **({"episodes_by_condition": counts} if uneven else {}),
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
                "reference": c.reference,
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
                "pearson": _estimate_dict(a.pearson),
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
                    "unit": parameter_unit(p.address, report.linear, report.tendons),
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
        **({} if report.episode_target is None else {"episode_target": _target_dict(report.episode_target)}),
        **({} if report.observation_unit is None else {"observation_unit": report.observation_unit}),
    }


def json_text(report: GapReport, indent: int | None = 1) -> str:
    """:func:`to_dict` as JSON text, keys sorted (bitwise reproducible)."""
    return json.dumps(to_dict(report), indent=indent, sort_keys=True, allow_nan=False) + "\n"


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


def _target_dict(t: EpisodeTarget) -> dict[str, Any]:
    return {
        "condition": t.condition,
        "x": t.x,
        "y": t.y,
        "reference": {"policy": t.reference_policy, "condition": t.reference_condition},
        "reference_return": _finite(t.reference_return),
        "fraction": t.fraction,
        "goal_half_width": _finite(t.goal),
        "pilot_episodes": t.pilot_episodes,
        "pilot_sd": _finite(t.pilot_sd),
        "needed": t.needed,
        "cap": t.cap,
        "episodes": t.episodes,
        "half_width": _finite(t.half_width),
        "confidence": t.confidence,
        "met": t.met,
        "capped": t.capped,
    }


def _draw_dict(d: ParameterDraws) -> dict[str, Any]:
    return {"address": d.address, "low": _finite(d.low), "mean": _finite(d.mean), "high": _finite(d.high), "n": d.n}
