"""Pure evaluation metrics with honest intervals (:mod:`sim2real.metrics.bootstrap`, about to be split by role)."""

from __future__ import annotations

from .bootstrap import (
    Estimate,
    FewSamplesWarning,
    Gap,
    RobustnessRadius,
    aggregate,
    cvar,
    gap,
    iqm,
    iqm_point,
    mean,
    minimum_runs,
    mmrv,
    probability_of_improvement,
    robustness_radius,
    srcc,
    success_rate,
    unpaired_gap,
    worst_case,
)
from .bootstrap import Statistic as Statistic

__all__ = [
    "Estimate",
    "FewSamplesWarning",
    "Gap",
    "RobustnessRadius",
    "aggregate",
    "cvar",
    "gap",
    "iqm",
    "iqm_point",
    "mean",
    "minimum_runs",
    "mmrv",
    "probability_of_improvement",
    "robustness_radius",
    "srcc",
    "success_rate",
    "unpaired_gap",
    "worst_case",
]
