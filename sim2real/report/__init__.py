"""The gap report: every number of a sim-to-real study, with honest intervals, as HTML, Markdown, JSON and PNG.

:meth:`GapReport.build` turns an :class:`~sim2real.evaluation.Evaluation` (plus, optionally, a sysid
:class:`~sysid.result.FitResult` and a contact sheet of the visual randomisation) into a frozen
:class:`GapReport` that holds every number the report shows: per policy and condition the mean and IQM
(stratified-bootstrap intervals), CVaR, worst case and success rate (Wilson); the absolute and relative gap from
the nominal sim and from the randomised sim to the "real" target (paired when both conditions are simulated,
since row ``e`` is the same initial state everywhere; unpaired for measured returns); robustness curves and
radii per sweep (against each policy's training sim); grid means for heatmaps; for every simulator, whether it
predicts the target policy by policy, and its rank agreement (SRCC = Spearman, Pearson, MMRV); paired differences
between policies on the target, from which the headline is read (:mod:`~sim2real.report.findings`); the
probability that one policy beats another on the target. Warnings raised by :mod:`sim2real.metrics` (e.g. too few runs for
the interval asked) are collected into the report rather than lost.

Reproducible: every interval draws from its own generator, :func:`stream` ``(seed, *key)``, keyed by what it
measures, so :meth:`GapReport.to_json` is bitwise identical for the same evaluation and ``rng``, and adding a
policy or a sweep does not move any other interval. Figures are rendered with matplotlib's Agg canvas at a fixed
dpi and without version or time stamps, so they too are byte-identical for the same data.

Configurations of hidden conditions (a "real" twin with held-out parameters) and the sysid ground truth appear
only in the last section, "Appendix: the real target".

The package's modules, by role: :mod:`~sim2real.report.results` (the frozen result objects),
:mod:`~sim2real.report.statistics` (checking the arguments) and :mod:`~sim2real.report.computing` (computing the
numbers), :mod:`~sim2real.report.findings` (the headline in sentences), :mod:`~sim2real.report.labels` (display
names and units), :mod:`~sim2real.report.figures` (deterministic PNGs), :mod:`~sim2real.report.rendering` (summary,
Markdown, HTML) with :mod:`~sim2real.report.markup`, :mod:`~sim2real.report.serialize` (JSON), :mod:`~sim2real.report.files` (writing a report
atomically) and :mod:`~sim2real.report.gap_report` (:class:`GapReport`, which ties them together).

Example:
    >>> import numpy as np
    >>> from sim2real.evaluation import Evaluation, nominal, real
    >>> rng = np.random.default_rng(0)
    >>> sim = rng.normal(100.0, 5.0, 20)
    >>> evaluation = Evaluation(
    ...     task="demo", seed=0, episodes=20, max_steps=None, policies=("ppo",),
    ...     conditions=(nominal(), real(params={"body_mass[arm]": 1.2})),
    ...     returns={"ppo": {"sim": sim, "real": sim - rng.normal(10.0, 2.0, 20)}},
    ...     successes={}, lengths={}, draws={})
    >>> report = GapReport.build(evaluation, rng=0)
    >>> g = report.gap("ppo")
    >>> g.paired, g.absolute.low < g.absolute.value < g.absolute.high
    (True, True)
    >>> print(report.summary().splitlines()[1])
    sim mispredicts real for 1 of 1 policy ('ppo': their 95% gap interval excludes 0); largest: 'ppo' loses 10.2% [9.6%, 10.9%] from sim to real (gap 10.12 [9.528, 10.76], paired).
    >>> print(report.summary().splitlines()[2])
    'ppo' loses 10.2% [9.6%, 10.9%] from sim to real (gap 10.12 [9.528, 10.76], paired).
"""

from __future__ import annotations

from sim2real.report.figures import png_bytes
from sim2real.report.gap_report import GapReport
from sim2real.report.rendering import APPENDIX, html_page
from sim2real.report.results import (
    Agreement,
    ConditionInfo,
    ConditionStats,
    EpisodeTarget,
    FitParameter,
    GapStats,
    GridMeans,
    Improvement,
    ParameterDraws,
    PolicyDifference,
    Prediction,
    ReportFiles,
    RobustnessCurve,
)
from sim2real.report.statistics import MAIN_KINDS, stream

__all__ = [
    "APPENDIX",
    "MAIN_KINDS",
    "Agreement",
    "ConditionInfo",
    "ConditionStats",
    "EpisodeTarget",
    "FitParameter",
    "GapReport",
    "GapStats",
    "GridMeans",
    "Improvement",
    "ParameterDraws",
    "PolicyDifference",
    "Prediction",
    "ReportFiles",
    "RobustnessCurve",
    "html_page",
    "png_bytes",
    "stream",
]
