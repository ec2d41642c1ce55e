"""Pure evaluation metrics with honest intervals, over one documented shape.

Every function takes episode returns as an array of shape ``(num_runs, num_conditions)``: each row is one
independent run (an episode or a training seed), each column one condition (nominal sim, randomised sim, the
"real" target, a point of a perturbation grid, a task or a policy). Nothing here touches an environment; the
functions only need numpy and scipy.

Intervals are percentile intervals of a **stratified bootstrap** (bias-corrected when the replicates would miss the
point estimate: every interval contains its estimate) (:mod:`~sim2real.metrics.bootstrap` says how they
are drawn and when the data are too thin for them, warning with :class:`FewSamplesWarning`); success rates get a
Wilson score interval instead (no resampling).

Result objects are frozen dataclasses: :class:`Estimate` (value and interval), :class:`Gap` and
:class:`RobustnessRadius`.

The package's modules, by role: :mod:`~sim2real.metrics.bootstrap` (argument checks, the few-samples rule, the
stratified bootstrap and :class:`Estimate`), :mod:`~sim2real.metrics.estimates` (one statistic per condition:
mean, IQM, CVaR, worst case, success rate, and the pooled aggregate), :mod:`~sim2real.metrics.comparisons`
(between conditions: gaps and the probability of improvement), :mod:`~sim2real.metrics.robustness` (the radius of
a perturbation sweep) and :mod:`~sim2real.metrics.agreement` (sim against real across policies: SRCC (Spearman), Pearson, MMRV).
The modules import one another relatively, so the package loads with numpy and scipy alone.

Example:
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> returns = np.column_stack([rng.normal(100, 10, 30), rng.normal(80, 20, 30)])  # sim, real
    >>> sim, real = mean(returns, rng=1)
    >>> round(sim.value, 2), round(real.value, 2)
    (98.79, 85.52)
    >>> g = gap(returns, reference=0, target=1, paired=False, rng=1)
    >>> g.absolute.low < g.absolute.value < g.absolute.high
    True
"""

from __future__ import annotations

from .agreement import mmrv, pearson, srcc
from .bootstrap import Estimate, FewSamplesWarning, minimum_runs
from .bootstrap import Statistic as Statistic  # the `statistic` argument's type: public, not in __all__
from .comparisons import Gap, gap, probability_of_improvement, unpaired_gap
from .estimates import aggregate, cvar, iqm, iqm_point, mean, success_rate, worst_case
from .robustness import RobustnessRadius, robustness_radius

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
    "pearson",
    "probability_of_improvement",
    "robustness_radius",
    "srcc",
    "success_rate",
    "unpaired_gap",
    "worst_case",
]
