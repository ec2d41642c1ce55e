"""The frozen result objects of the gap report: one dataclass per kind of number, with documented shapes.

:class:`~sim2real.report.GapReport` holds tuples of these; :mod:`sim2real.report.statistics` computes them and
:mod:`sim2real.report.rendering` and :mod:`sim2real.report.figures` show them.

Example:
    >>> from sim2real.report.results import ParameterDraws
    >>> ParameterDraws("dof_damping[elbow]", low=0.5, mean=1.0, high=2.0, n=4).high
    2.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from sim2real.metrics import Estimate, RobustnessRadius

__all__ = [
    "Agreement",
    "ConditionInfo",
    "ConditionStats",
    "EpisodeTarget",
    "FitParameter",
    "GapStats",
    "GridMeans",
    "Improvement",
    "ParameterDraws",
    "PolicyDifference",
    "Prediction",
    "ReportFiles",
    "RobustnessCurve",
]


@dataclass(frozen=True)
class ConditionStats:
    """Summary statistics of one policy on one (non-sweep) condition.

    Attributes:
        policy: policy name.
        condition: condition name.
        kind: the condition's kind (``nominal``, ``randomized``, ``real`` or ``measured``).
        n: episodes (runs).
        mean: mean return with a stratified-bootstrap interval.
        iqm: interquartile mean with a stratified-bootstrap interval.
        cvar: mean of the worst ``alpha`` fraction of returns, with an interval.
        worst: the lowest return.
        success: success rate with a Wilson interval, or None when the condition reported no successes.
    """

    policy: str
    condition: str
    kind: str
    n: int
    mean: Estimate
    iqm: Estimate
    cvar: Estimate
    worst: float
    success: Estimate | None

    def statistic(self, name: str) -> Estimate:
        """The ``mean`` or ``iqm`` estimate."""
        return self.mean if name == "mean" else self.iqm


@dataclass(frozen=True)
class GapStats:
    """The performance one policy loses from ``reference`` to ``target`` (:func:`sim2real.metrics.gap`).

    Attributes:
        policy: policy name.
        reference: the reference condition (e.g. ``"sim"`` or ``"randomized"``).
        target: the target condition (e.g. ``"real"``).
        absolute: ``stat(reference) - stat(target)``; positive when the target does worse.
        relative: ``absolute / |stat(reference)|`` (NaN when ``stat(reference)`` is 0).
        paired: True when both conditions are simulated (row ``e`` is the same initial state), so runs were
            resampled jointly (over the episodes both ran, the first ``min`` of their counts, when the counts
            differ); False for measured returns (resampled independently, counts may differ).
        n_reference: runs on the reference.
        n_target: runs on the target (a paired gap uses the first ``min(n_reference, n_target)`` of each).
        statistic: ``"mean"`` or ``"iqm"``.
    """

    policy: str
    reference: str
    target: str
    absolute: Estimate
    relative: Estimate
    paired: bool
    n_reference: int
    n_target: int
    statistic: str


@dataclass(frozen=True)
class RobustnessCurve:
    """One policy's return along a one-parameter sweep, and its robustness radius.

    Attributes:
        policy: policy name.
        sweep: the sweep's name.
        axis: the swept parameter label, e.g. ``"Damping.scale"``.
        values: grid values, strictly increasing, shape ``(K,)``.
        conditions: the condition name at each grid value.
        nominal: the unperturbed grid value.
        points: the statistic at each grid value with its interval, shape ``(K,)``.
        radius: the largest distance from ``nominal`` keeping ``fraction`` of the reference return, or None (see
            ``note``).
        fraction: the fraction of the reference return to keep.
        note: why there is no radius ("" when there is one).
        statistic: ``"mean"`` or ``"iqm"``.
        reference: the condition whose return the threshold is a fraction of: the sim the policy was trained in
            (``GapReport.training``), or ``""`` for the sweep's own nominal point.
    """

    policy: str
    sweep: str
    axis: str
    values: tuple[float, ...]
    conditions: tuple[str, ...]
    nominal: float
    points: tuple[Estimate, ...]
    radius: RobustnessRadius | None
    fraction: float
    note: str
    statistic: str
    reference: str = ""

    @property
    def threshold(self) -> float | None:
        """``fraction`` times the nominal return (the line the radius is measured against), or None."""
        return None if self.radius is None else self.fraction * self.radius.nominal_return


@dataclass(frozen=True)
class GridMeans:
    """One policy's statistic over a two-parameter grid (a heatmap).

    Attributes:
        policy: policy name.
        grid: the grid's name.
        axes: the two parameter labels (x, y).
        x: x values, increasing, shape ``(I,)``.
        y: y values, increasing, shape ``(J,)``.
        values: ``values[i][j]`` is the statistic at ``(x[i], y[j])`` (NaN where the grid has no point).
        nominal: the unperturbed ``(x, y)``.
        statistic: ``"mean"`` or ``"iqm"``.
    """

    policy: str
    grid: str
    axes: tuple[str, str]
    x: tuple[float, ...]
    y: tuple[float, ...]
    values: tuple[tuple[float, ...], ...]
    nominal: tuple[float, float]
    statistic: str


@dataclass(frozen=True)
class Agreement:
    """Whether a simulated condition ranks the policies as the target does (SIMPLER's SRCC, Pearson and MMRV).

    Attributes:
        reference: the simulated condition compared (e.g. ``"sim"``).
        target: the target condition (e.g. ``"real"``).
        policies: the policies compared (those with returns on both).
        srcc: Spearman rank correlation of the per-policy statistic, or None when undefined (see ``note``).
        mmrv: mean maximum rank violation (0 = same ranking), in return units.
        note: why a value is missing ("" otherwise).
        pearson: Pearson (linear) correlation of the per-policy statistic, or None when undefined.
    """

    reference: str
    target: str
    policies: tuple[str, ...]
    srcc: Estimate | None
    mmrv: Estimate | None
    note: str
    pearson: Estimate | None = None


@dataclass(frozen=True)
class PolicyDifference:
    """``stat(x) - stat(y)`` on one condition: is policy ``x`` better than ``y`` there, beyond the noise?

    Attributes:
        condition: the condition (the target).
        x: first policy.
        y: second policy.
        difference: the difference of the statistic with its interval (paired when both ran the same simulated
            episodes).
        paired: whether runs were resampled jointly.
        n: runs per policy (the smaller count when unpaired).
        statistic: ``"mean"`` or ``"iqm"``.
    """

    condition: str
    x: str
    y: str
    difference: Estimate
    paired: bool
    n: int
    statistic: str

    @property
    def significant(self) -> bool:
        """The interval excludes 0."""
        return self.difference.low > 0.0 or self.difference.high < 0.0


@dataclass(frozen=True)
class Prediction:
    """Does a simulated condition predict the target, policy by policy? Read from the gaps from it to the target.

    Attributes:
        simulator: the simulated condition.
        target: the target condition.
        policies: the policies with a gap from ``simulator`` to ``target``.
        within: the largest end of any policy's relative-gap interval, in absolute value (0.013: every policy's
            target return is within 1.3% of its return in ``simulator``, at the report's confidence); NaN when a
            relative gap is undefined.
        differ: the policies whose gap interval excludes 0 (the simulator mispredicts them).
        worst: the policy with the largest ``|relative gap|`` point estimate among the mispredicted ones (among all
            when none is; "" when no relative gap is defined).
    """

    simulator: str
    target: str
    policies: tuple[str, ...]
    within: float
    differ: tuple[str, ...]
    worst: str


@dataclass(frozen=True)
class Improvement:
    """``P(x > y)``: the chance an episode of policy ``x`` beats one of policy ``y`` on ``condition``.

    Attributes:
        condition: the condition (the target).
        x: first policy.
        y: second policy.
        probability: the estimate with a bootstrap interval; 0.5 means neither is better.
    """

    condition: str
    x: str
    y: str
    probability: Estimate


@dataclass(frozen=True)
class ParameterDraws:
    """The values one addressed parameter took over the episodes of one condition.

    Attributes:
        address: the parameter address, e.g. ``"dof_damping[elbow]"``.
        low: smallest value drawn.
        mean: mean value drawn.
        high: largest value drawn.
        n: episodes with a value.
    """

    address: str
    low: float
    mean: float
    high: float
    n: int


@dataclass(frozen=True)
class ConditionInfo:
    """What a condition is, for the report.

    Attributes:
        name: condition name.
        kind: condition kind.
        description: one line.
        simulated: False for measured returns.
        hidden: the configuration is revealed only in the appendix.
        config: the configuration as canonical JSON text (effects, params; measured returns left out).
        draws: the parameter values drawn per episode, summarised.
        sweep: the sweep or grid a point belongs to, else None.
        value: the point's coordinates on the sweep's axes (empty otherwise).
    """

    name: str
    kind: str
    description: str
    simulated: bool
    hidden: bool
    config: str
    draws: tuple[ParameterDraws, ...]
    sweep: str | None = None
    value: tuple[float, ...] = ()


@dataclass(frozen=True)
class EpisodeTarget:
    """How many episodes were run on one condition to resolve a paired policy difference to a chosen precision.

    The goal is a half-width of the difference's interval of at most ``fraction`` of a reference return. A pilot
    (the first ``pilot_episodes``) estimates the standard deviation of the per-episode differences; with the normal
    approximation a ``confidence`` interval of ``n`` episodes has half-width ``z * sd / sqrt(n)``, so
    ``needed = ceil((z * sd / goal) ** 2)``; the episodes run are that, at least the pilot and at most ``cap``.
    ``half_width`` is then read from the report's own interval of the difference (NaN until it is).

    Attributes:
        condition: where the difference is taken (e.g. the real twin).
        x, y: the policies; the difference is ``stat(x) - stat(y)``.
        reference_policy, reference_condition: whose return the goal is a fraction of.
        reference_return: that return (the point estimate).
        fraction: the goal as a fraction of ``|reference_return|`` (e.g. 0.05).
        goal: ``fraction * |reference_return|``, the half-width asked for (NaN when the reference return is 0).
        pilot_episodes: episodes the standard deviation was estimated from.
        pilot_sd: standard deviation of the paired per-episode differences in the pilot.
        needed: episodes the pilot says reach the goal, or None when there is no goal (a reference return of 0).
        cap: the most episodes the budget allows on ``condition``.
        episodes: episodes run on ``condition``.
        half_width: ``(high - low) / 2`` of the report's interval of the difference at ``episodes``.
        confidence: the interval's coverage.
    """

    condition: str
    x: str
    y: str
    reference_policy: str
    reference_condition: str
    reference_return: float
    fraction: float
    goal: float
    pilot_episodes: int
    pilot_sd: float
    needed: int | None
    cap: int
    episodes: int
    half_width: float
    confidence: float

    @property
    def met(self) -> bool:
        """True when the achieved half-width is at most the goal."""
        return bool(self.half_width <= self.goal)

    @property
    def needed_now(self) -> int | None:
        """The episodes the goal asks for, re-estimated from the achieved interval (its half-width shrinks as one
        over the square root of the episodes): ``ceil(episodes * (half_width / goal) ** 2)``, at least one more than
        ran; :attr:`needed` when the goal was met or has no width. Differs from the pilot's :attr:`needed` when the
        pilot's spread was off.

        Example:
            >>> t = EpisodeTarget("real", "calibrated", "randomized", "nominal", "sim", 974.5, 0.05, 48.7, 32, 173.0,
            ...                   49, 128, 49, 55.8, 0.95)
            >>> t.met, t.needed, t.needed_now
            (False, 49, 65)
        """
        if self.met or self.needed is None or not math.isfinite(self.goal) or not math.isfinite(self.half_width):
            return self.needed
        return max(self.episodes + 1, math.ceil(self.episodes * (self.half_width / self.goal) ** 2 - 1e-9))

    @property
    def capped(self) -> bool:
        """True when the budget's cap stopped the episodes short of what the pilot asked for."""
        return self.needed is not None and self.needed > self.episodes


@dataclass(frozen=True)
class FitParameter:
    """One parameter of a sysid fit.

    Attributes:
        address: parameter address.
        estimate: fitted value.
        stderr: standard error.
        low: lower end of the 95% interval.
        high: upper end of the 95% interval.
        truth: the true value from the log's metadata (a simulated twin), or None. Shown only in the appendix.
    """

    address: str
    estimate: float
    stderr: float
    low: float
    high: float
    truth: float | None


@dataclass(frozen=True)
class ReportFiles:
    """The files :meth:`GapReport.write` wrote.

    Attributes:
        directory: the output directory.
        html: ``report.html`` (self-contained).
        markdown: ``report.md`` (links to ``figures/``).
        json: ``report.json`` (written last: its presence marks a complete report).
        figures: ``figures/<name>.png``, in :meth:`GapReport.figure_names` order.
    """

    directory: Path
    html: Path
    markdown: Path
    json: Path
    figures: tuple[Path, ...]
