"""Pure evaluation metrics with honest intervals, over one documented shape.

Every function takes episode returns as an array of shape ``(num_runs, num_conditions)``: each row is one
independent run (an episode or a training seed), each column one condition (nominal sim, randomised sim, the
"real" target, a point of a perturbation grid, a task or a policy). Nothing here touches an environment; the
functions only need numpy and scipy.

Intervals are percentile intervals of a **stratified bootstrap**: runs are resampled with replacement
independently within each condition (the stratum), as in rliable. The bootstrap draws only from the
``numpy.random.Generator`` passed as ``rng`` (an int is taken as the seed of a fresh ``default_rng``), never from
the global ``np.random``: the same seed gives bitwise-identical intervals. Success rates get a Wilson score
interval instead (no resampling).

When the data are too thin for the interval asked, the functions still answer but warn with
:class:`FewSamplesWarning`. The rule (see :func:`minimum_runs`): every resampled stratum needs at least
``max(10, ceil(0.5 / (1 - confidence)))`` runs — 10 at 95%, 50 at 99% — because below ~10 runs the percentile
bootstrap is markedly too narrow (it covers ~91% instead of 95% for the mean of 10 normal draws) and because the
empirical distribution must put at least half a run's mass in the two tails the interval cuts off. The bootstrap
also needs ``num_resamples * (1 - confidence) / 2 >= 25`` resamples in each cut-off tail (1000 resamples at 95%)
for the interval ends to be stable.

Result objects are frozen dataclasses: :class:`Estimate` (value and interval), :class:`Gap` and
:class:`RobustnessRadius`.

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

import math
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats as _stats

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

Statistic = Literal["mean", "iqm"]
_STATISTICS = ("mean", "iqm")
_BOOTSTRAP = "percentile bootstrap"
_DEFAULT_RESAMPLES = 2000


class FewSamplesWarning(UserWarning):
    """The data (runs per stratum) or the bootstrap (resamples) are too few for the interval asked.

    The rule is documented in the module docstring and computed by :func:`minimum_runs`.
    """


@dataclass(frozen=True)
class Estimate:
    """A point estimate with a two-sided confidence interval.

    Attributes:
        value: The statistic on the observed data.
        low: Lower end of the interval.
        high: Upper end of the interval.
        confidence: Nominal coverage of ``[low, high]``, e.g. 0.95.
        n: Number of observations (runs, summed over every array and condition) the estimate rests on.
        method: How the interval was made: ``'percentile bootstrap'`` or ``'wilson'``.

    Example:
        >>> e = Estimate(value=0.5, low=0.4, high=0.6, confidence=0.95, n=100, method="wilson")
        >>> str(e)
        '0.5 [0.4, 0.6] (95% wilson, n=100)'
    """

    value: float
    low: float
    high: float
    confidence: float
    n: int
    method: str

    def __str__(self) -> str:
        return f"{self.value:.4g} [{self.low:.4g}, {self.high:.4g}] ({self.confidence:.0%} {self.method}, n={self.n})"


@dataclass(frozen=True)
class Gap:
    """The performance lost from a reference condition (e.g. sim) to a target condition (e.g. real).

    Attributes:
        absolute: ``stat(reference) - stat(target)``; positive when the target does worse.
        relative: ``absolute / |stat(reference)|``; NaN when ``stat(reference)`` is 0 (resamples where it is 0 are
            left out of the interval).
        reference: Column index of the reference condition.
        target: Column index of the target condition.
        paired: Whether runs were resampled jointly (row ``i`` of both columns is one paired run).
        statistic: ``'mean'`` or ``'iqm'``.
    """

    absolute: Estimate
    relative: Estimate
    reference: int
    target: int
    paired: bool
    statistic: str


@dataclass(frozen=True)
class RobustnessRadius:
    """The largest perturbation that keeps a fraction of the nominal return.

    Attributes:
        radius: Distance from the nominal grid value, with its bootstrap interval.
        fraction: Required fraction of the nominal return, e.g. 0.9.
        nominal: The grid value of the unperturbed condition.
        nominal_return: The statistic (mean or IQM) of the returns at the nominal grid value.
        censored: True when no grid point on the binding side fell below the threshold, so ``radius.value`` is the
            extent of the grid there: a lower bound, not a measured crossing.
        statistic: ``'mean'`` or ``'iqm'``.
    """

    radius: Estimate
    fraction: float
    nominal: float
    nominal_return: float
    censored: bool
    statistic: str


# --------------------------------------------------------------------------------------------------------------------
# Validation


def _runs_array(values: ArrayLike, name: str, columns: str = "num_conditions") -> np.ndarray:
    try:
        arr = np.asarray(values)
    except ValueError:
        raise ValueError(
            f"`{name}` must be a 2-D array of shape (num_runs, {columns}). Received a ragged sequence."
        ) from None
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"`{name}` must be a numeric array. Received dtype {arr.dtype}.")
    if arr.ndim != 2:
        raise ValueError(f"`{name}` must be a 2-D array of shape (num_runs, {columns}). Received shape {arr.shape}.")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"`{name}` must hold at least one run and one column. Received shape {arr.shape}.")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr)
    if bad.any():
        run, col = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"`{name}` must be finite. Received {arr[run, col]} at run {run}, column {col}.")
    return arr


def _open_unit(value: float, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"`{name}` must be a number in (0, 1). Received {value!r}.")
    if not 0.0 < float(value) < 1.0:
        raise ValueError(f"`{name}` must be in (0, 1). Received {value!r}.")
    return float(value)


def _generator(rng: np.random.Generator | int) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        if rng < 0:
            raise ValueError(f"`rng` must be a numpy.random.Generator or a non-negative int seed. Received {rng}.")
        return np.random.default_rng(int(rng))
    raise TypeError(
        f"`rng` must be a numpy.random.Generator or a non-negative int seed. Received {type(rng).__name__}."
    )


def _resamples(num_resamples: int) -> int:
    if isinstance(num_resamples, bool) or not isinstance(num_resamples, (int, np.integer)) or num_resamples < 1:
        raise ValueError(f"`num_resamples` must be a positive int. Received {num_resamples!r}.")
    return int(num_resamples)


def _statistic(statistic: str) -> Statistic:
    if statistic not in _STATISTICS:
        raise ValueError(f"`statistic` must be one of {', '.join(map(repr, _STATISTICS))}. Received {statistic!r}.")
    return statistic  # type: ignore[return-value]  # checked against _STATISTICS just above


def _column(index: int, name: str, num: int) -> int:
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < num:
        raise ValueError(f"`{name}` must be a condition index in [0, {num}). Received {index!r}.")
    return int(index)


def _stacklevel() -> int:
    """Stack level of the first frame outside this module, so warnings point at the user's call."""
    frame: FrameType | None = sys._getframe(1)
    level = 1
    while frame is not None and frame.f_code.co_filename == __file__:
        frame = frame.f_back
        level += 1
    return level


def minimum_runs(confidence: float = 0.95) -> int:
    """The fewest runs per stratum for which a bootstrap interval at ``confidence`` is not flagged.

    Args:
        confidence: Nominal coverage in (0, 1).

    Returns:
        ``max(10, ceil(0.5 / (1 - confidence)))``.

    Example:
        >>> minimum_runs(0.95), minimum_runs(0.99), minimum_runs(0.5)
        (10, 50, 10)
    """
    confidence = _open_unit(confidence, "confidence")
    # round() first so 0.5 / 0.05 = 10.000000000000002 does not become 11
    return max(10, math.ceil(round(0.5 / (1.0 - confidence), 9)))


def _check_enough(what: str, sizes: Sequence[int], confidence: float, num_resamples: int) -> None:
    need = minimum_runs(confidence)
    fewest = min(sizes)
    if fewest < need:
        warnings.warn(
            f"{what}: {fewest} runs in a stratum are too few for a {confidence:g} bootstrap interval "
            f"(need >= {need}); the interval is likely too narrow.",
            FewSamplesWarning,
            stacklevel=_stacklevel(),
        )
    tail = num_resamples * (1.0 - confidence) / 2.0
    if tail < 25 - 1e-9:
        need_resamples = math.ceil(round(50.0 / (1.0 - confidence), 9))
        warnings.warn(
            f"{what}: {num_resamples} resamples leave {tail:g} in each tail of a {confidence:g} interval "
            f"(use num_resamples >= {need_resamples}); the interval ends are noisy.",
            FewSamplesWarning,
            stacklevel=_stacklevel(),
        )


# --------------------------------------------------------------------------------------------------------------------
# Bootstrap machinery: resamples are represented by how often each run was drawn (counts), so order statistics of a
# resample (IQM, CVaR) come from cumulative counts over the sorted runs, with no per-resample sort.


def _draw_counts(gen: np.random.Generator, n: int, num_resamples: int) -> np.ndarray:
    """``(num_resamples, n)`` draw counts of ``n`` runs resampled with replacement, ``num_resamples`` times."""
    idx = gen.integers(0, n, size=(num_resamples, n))
    idx += (n * np.arange(num_resamples))[:, None]
    return np.bincount(idx.ravel(), minlength=num_resamples * n).reshape(num_resamples, n)


def _window(statistic: str, n: int, alpha: float = 0.0) -> tuple[float, float]:
    """Positions ``[lo, hi)`` of the sorted sample that the statistic averages."""
    if statistic == "mean":
        return 0.0, float(n)
    if statistic == "iqm":
        # scipy.stats.trim_mean(x, 0.25), which rliable uses: floor(n / 4) values cut from each end
        cut = int(0.25 * n)
        return float(cut), float(n - cut)
    return 0.0, alpha * n  # cvar: the worst alpha fraction, the boundary run counted fractionally


def _window_mean(sorted_values: np.ndarray, counts: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Mean over positions ``[lo, hi)`` of each resample; ``counts`` is ``(B, n)`` in the order of ``sorted_values``."""
    upper = np.cumsum(counts, axis=1, dtype=np.float64)
    lower = upper - counts
    overlap = np.clip(np.minimum(upper, hi) - np.maximum(lower, lo), 0.0, None)
    return overlap @ sorted_values / (hi - lo)


def _columns(
    x: np.ndarray,
    statistic: str,
    gen: np.random.Generator,
    num_resamples: int,
    *,
    alpha: float = 0.0,
    paired: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Point statistic per column ``(K,)`` and its stratified bootstrap replicates ``(B, K)``.

    Unpaired: each column's runs are resampled independently, in column order. Paired: one draw of run indices is
    shared by all columns (row ``i`` is one unit observed under every condition).
    """
    n, k = x.shape
    lo, hi = _window(statistic, n, alpha)
    ones = np.ones((1, n))
    shared = _draw_counts(gen, n, num_resamples) if paired else None
    points = np.empty(k)
    boots = np.empty((num_resamples, k))
    for j in range(k):
        order = np.argsort(x[:, j], kind="stable")
        values = x[order, j]
        counts = shared if shared is not None else _draw_counts(gen, n, num_resamples)
        points[j] = _window_mean(values, ones, lo, hi)[0]
        boots[:, j] = _window_mean(values, counts[:, order], lo, hi)
    if statistic == "iqm":
        # The same runs as the window, but summed as scipy sums them, so the point is rliable's to the last bit; the
        # replicates keep the (equal up to rounding) window sums, which need no per-resample sort.
        points = _trim_mean(x)
    return points, boots


def _trim_mean(x: np.ndarray, axis: int | None = 0) -> np.ndarray:
    """``scipy.stats.trim_mean(x, 0.25, axis)``: rliable's IQM, ``floor(n / 4)`` values cut from each end."""
    return np.asarray(_stats.trim_mean(x, 0.25, axis=axis), dtype=np.float64)


def _interval(boots: np.ndarray, confidence: float) -> tuple[float, float]:
    tail = (1.0 - confidence) / 2.0
    finite = boots[np.isfinite(boots)]
    if finite.size == 0:
        return math.nan, math.nan
    low, high = np.quantile(finite, [tail, 1.0 - tail])
    return float(low), float(high)


def _estimate(value: float, boots: np.ndarray, confidence: float, n: int) -> Estimate:
    low, high = _interval(boots, confidence)
    return Estimate(float(value), low, high, confidence, int(n), _BOOTSTRAP)


def _per_condition(
    what: str,
    returns: ArrayLike,
    statistic: str,
    rng: np.random.Generator | int,
    confidence: float,
    num_resamples: int,
    alpha: float = 0.0,
) -> tuple[Estimate, ...]:
    x = _runs_array(returns, "returns")
    confidence = _open_unit(confidence, "confidence")
    num_resamples = _resamples(num_resamples)
    gen = _generator(rng)
    _check_enough(what, [x.shape[0]], confidence, num_resamples)
    points, boots = _columns(x, statistic, gen, num_resamples, alpha=alpha)
    return tuple(_estimate(points[j], boots[:, j], confidence, x.shape[0]) for j in range(x.shape[1]))


# --------------------------------------------------------------------------------------------------------------------
# Per-condition statistics


def mean(
    returns: ArrayLike,
    *,
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> tuple[Estimate, ...]:
    """Mean return of each condition with a bootstrap interval.

    Args:
        returns: Array of shape ``(num_runs, num_conditions)``.
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the interval, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        One :class:`Estimate` per condition (column), in column order.

    Raises:
        ValueError: On a wrong shape, non-finite returns or an argument out of range.

    Example:
        >>> import numpy as np
        >>> returns = np.arange(40.0).reshape(20, 2)
        >>> first, second = mean(returns, rng=0)
        >>> first.value, second.value, first.low < first.value < first.high
        (19.0, 20.0, True)
    """
    return _per_condition("mean", returns, "mean", rng, confidence, num_resamples)


def iqm(
    returns: ArrayLike,
    *,
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> tuple[Estimate, ...]:
    """Interquartile mean of each condition with a bootstrap interval.

    The IQM is rliable's: ``floor(num_runs / 4)`` runs cut from each end and the rest averaged, robust to a few
    outlier episodes yet less noisy than the median. The value is :func:`iqm_point`, bitwise equal to
    ``scipy.stats.trim_mean(returns, 0.25, axis=0)`` (what rliable computes); each bootstrap replicate averages the
    same window of its resample. As with ``trim_mean``, the last bit of a column can depend on the array's memory
    layout (numpy sums a column of a C-ordered matrix run by run, a lone column pairwise).

    Args:
        returns: Array of shape ``(num_runs, num_conditions)``.
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the interval, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        One :class:`Estimate` per condition (column), in column order.

    Example:
        >>> import numpy as np
        >>> returns = np.append(np.arange(1.0, 20.0), 1000.0)[:, None]  # 1, ..., 19 and one outlier
        >>> (est,) = iqm(returns, rng=0)
        >>> est.value  # floor(20 / 4) = 5 runs cut from each end: the mean of 6, ..., 15
        10.5
    """
    return _per_condition("iqm", returns, "iqm", rng, confidence, num_resamples)


def iqm_point(returns: ArrayLike) -> np.ndarray:
    """Interquartile mean of each condition, without an interval: the value :func:`iqm` reports.

    Bitwise equal to ``scipy.stats.trim_mean(returns, 0.25, axis=0)``, rliable's IQM: ``floor(num_runs / 4)`` runs
    cut from each end (none below 4 runs) and the rest averaged.

    Args:
        returns: Array of shape ``(num_runs, num_conditions)``.

    Returns:
        Array of shape ``(num_conditions,)``.

    Example:
        >>> iqm_point([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [100.0, 4.0], [4.0, 0.0]])  # one run cut from each end
        array([3., 0.])
    """
    return _trim_mean(_runs_array(returns, "returns"))


def cvar(
    returns: ArrayLike,
    *,
    alpha: float = 0.1,
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> tuple[Estimate, ...]:
    """Conditional value at risk: the mean of the worst ``alpha`` fraction of returns, per condition.

    Exact on the empirical distribution: with ``n`` runs sorted ascending, the worst ``alpha * n`` runs are averaged
    and a run straddling the boundary counts with its fractional weight (``n = 10, alpha = 0.25``: the two worst
    runs fully and the third by half, divided by 2.5). Low returns are bad.

    Args:
        returns: Array of shape ``(num_runs, num_conditions)``.
        alpha: Tail fraction in (0, 1).
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the interval, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        One :class:`Estimate` per condition (column), in column order.

    Example:
        >>> import numpy as np
        >>> returns = np.arange(1.0, 21.0)[:, None]  # 1, 2, ..., 20
        >>> (worst10,) = cvar(returns, alpha=0.1, rng=0)
        >>> worst10.value  # mean of the 2 worst runs
        1.5
    """
    alpha = _open_unit(alpha, "alpha")
    return _per_condition("cvar", returns, "cvar", rng, confidence, num_resamples, alpha=alpha)


def worst_case(returns: ArrayLike) -> np.ndarray:
    """The lowest return of each condition.

    No interval: the sample minimum has no useful bootstrap (resamples can only repeat or raise it). Use :func:`cvar`
    for a tail statistic with an interval.

    Args:
        returns: Array of shape ``(num_runs, num_conditions)``.

    Returns:
        Array of shape ``(num_conditions,)``.

    Example:
        >>> worst_case([[3.0, 1.0], [2.0, 5.0]])
        array([2., 1.])
    """
    return _runs_array(returns, "returns").min(axis=0)


def aggregate(
    returns: ArrayLike,
    *,
    statistic: Statistic = "iqm",
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> Estimate:
    """One statistic pooled over all conditions (e.g. tasks), with a stratified bootstrap interval.

    This is rliable's aggregate: the statistic is taken over all ``num_runs * num_conditions`` returns at once, and
    each bootstrap resample redraws runs within each condition separately so that every condition keeps its weight.

    Args:
        returns: Array of shape ``(num_runs, num_conditions)``.
        statistic: ``'mean'`` or ``'iqm'``.
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the interval, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        An :class:`Estimate` with ``n = num_runs * num_conditions``.

    Example:
        >>> import numpy as np
        >>> returns = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [4.0, 40.0]] * 3)
        >>> round(aggregate(returns, statistic="iqm", rng=0).value, 4)  # trim_mean of the 24 values: 6 cut from each end
        9.25
    """
    statistic = _statistic(statistic)
    x = _runs_array(returns, "returns")
    confidence = _open_unit(confidence, "confidence")
    num_resamples = _resamples(num_resamples)
    gen = _generator(rng)
    n, k = x.shape
    _check_enough(f"aggregate {statistic}", [n], confidence, num_resamples)
    flat = x.T.ravel()  # condition by condition, matching the order the counts are drawn in
    counts = np.concatenate([_draw_counts(gen, n, num_resamples) for _ in range(k)], axis=1)
    order = np.argsort(flat, kind="stable")
    lo, hi = _window(statistic, flat.size)
    value = _window_mean(flat[order], np.ones((1, flat.size)), lo, hi)[0]
    if statistic == "iqm":
        value = float(_trim_mean(x, axis=None))  # rliable's aggregate IQM, to the last bit (see _columns)
    boots = _window_mean(flat[order], counts[:, order], lo, hi)
    return _estimate(value, boots, confidence, flat.size)


def success_rate(
    successes: ArrayLike,
    *,
    threshold: float | None = None,
    confidence: float = 0.95,
) -> tuple[Estimate, ...]:
    """Success rate of each condition with a Wilson score interval.

    The Wilson interval keeps its coverage near nominal for small ``n`` and for rates near 0 or 1, where the normal
    (Wald) interval collapses; it needs no resampling and so no generator.

    Args:
        successes: Array of shape ``(num_runs, num_conditions)`` of booleans or 0/1, or of returns when
            ``threshold`` is given.
        threshold: When given, a run succeeds if its return is ``>= threshold``.
        confidence: Nominal coverage of the interval, in (0, 1).

    Returns:
        One :class:`Estimate` per condition with ``method='wilson'``.

    Raises:
        ValueError: On values other than 0/1 without ``threshold``, a wrong shape or non-finite values.

    Example:
        >>> import numpy as np
        >>> outcomes = np.array([1] * 81 + [0] * 182)[:, None]  # Newcombe (1998): 81 of 263
        >>> (rate,) = success_rate(outcomes)
        >>> round(rate.value, 4), round(rate.low, 4), round(rate.high, 4)
        (0.308, 0.2553, 0.3662)
    """
    x = _runs_array(successes, "successes")
    confidence = _open_unit(confidence, "confidence")
    if threshold is not None:
        if isinstance(threshold, bool) or not isinstance(threshold, (int, float, np.integer, np.floating)):
            raise TypeError(f"`threshold` must be a number or None. Received {threshold!r}.")
        x = (x >= threshold).astype(np.float64)
    else:
        bad = (x != 0.0) & (x != 1.0)
        if bad.any():
            run, col = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(
                f"`successes` must hold only 0/1 or booleans (or pass `threshold`). "
                f"Received {x[run, col]} at run {run}, column {col}."
            )
    n = x.shape[0]
    z = float(_stats.norm.ppf(0.5 + confidence / 2.0))
    out = []
    for p in x.mean(axis=0):
        denom = 1.0 + z * z / n
        centre = (p + z * z / (2 * n)) / denom
        half = z / denom * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n))
        low, high = max(0.0, float(centre - half)), min(1.0, float(centre + half))
        out.append(Estimate(float(p), low, high, confidence, n, "wilson"))
    return tuple(out)


# --------------------------------------------------------------------------------------------------------------------
# Comparisons between conditions


def gap(
    returns: ArrayLike,
    *,
    reference: int = 0,
    target: int = 1,
    paired: bool = False,
    statistic: Statistic = "mean",
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> Gap:
    """Absolute and relative gap from a reference condition (e.g. sim) to a target (e.g. real), with intervals.

    Args:
        returns: Array of shape ``(num_runs, num_conditions)``.
        reference: Column of the reference condition.
        target: Column of the target condition.
        paired: True when row ``i`` of both columns comes from the same unit (same seed, same initial state, same
            trained policy): runs are then resampled jointly, which removes the shared variation from the interval.
            False resamples the two columns independently.
        statistic: ``'mean'`` or ``'iqm'``.
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the intervals, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        A :class:`Gap`; ``absolute = stat(reference) - stat(target)``, ``relative = absolute / |stat(reference)|``.

    Example:
        >>> import numpy as np
        >>> returns = np.column_stack([np.linspace(90, 110, 20), np.linspace(60, 100, 20)])
        >>> g = gap(returns, paired=True, rng=0)
        >>> round(g.absolute.value, 6), round(g.relative.value, 6)
        (20.0, 0.2)
    """
    statistic = _statistic(statistic)
    x = _runs_array(returns, "returns")
    reference = _column(reference, "reference", x.shape[1])
    target = _column(target, "target", x.shape[1])
    if target == reference:
        raise ValueError(f"`target` must differ from `reference`. Received {target} for both.")
    confidence = _open_unit(confidence, "confidence")
    num_resamples = _resamples(num_resamples)
    gen = _generator(rng)
    _check_enough("gap", [x.shape[0]], confidence, num_resamples)
    points, boots = _columns(x[:, [reference, target]], statistic, gen, num_resamples, paired=bool(paired))
    if statistic == "iqm":
        # from the whole matrix, as iqm(returns) does: numpy's sums (hence trim_mean's last bit) depend on the layout
        points = _trim_mean(x)[[reference, target]]
    return _gap(points, boots, 2 * x.shape[0], reference, target, bool(paired), statistic, confidence)


def _gap(
    points: np.ndarray,
    boots: np.ndarray,
    n: int,
    reference: int,
    target: int,
    paired: bool,
    statistic: str,
    confidence: float,
) -> Gap:
    """The :class:`Gap` from the (reference, target) statistic ``points`` ``(2,)`` and replicates ``(B, 2)``."""
    absolute = points[0] - points[1]
    abs_boots = boots[:, 0] - boots[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = absolute / abs(points[0]) if points[0] != 0 else math.nan
        rel_boots = np.where(boots[:, 0] != 0, abs_boots / np.abs(boots[:, 0]), np.nan)
    return Gap(
        absolute=_estimate(absolute, abs_boots, confidence, n),
        relative=_estimate(relative, rel_boots, confidence, n),
        reference=reference,
        target=target,
        paired=paired,
        statistic=statistic,
    )


def _runs_vector(values: ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise ValueError(f"`{name}` must be a 1-D array of runs, shape (num_runs,). Received shape {arr.shape}.")
    return _runs_array(arr[:, None], name, "1")


def unpaired_gap(
    reference: ArrayLike,
    target: ArrayLike,
    *,
    statistic: Statistic = "mean",
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> Gap:
    """:func:`gap` with ``paired=False`` for two conditions whose run counts may differ (e.g. 50 simulated
    episodes against 12 measured real-robot episodes).

    The two samples are resampled independently, reference first, exactly as :func:`gap` does for two columns of
    equal length: with equal counts, ``unpaired_gap(x[:, 0], x[:, 1], rng=s)`` equals
    ``gap(x, paired=False, rng=s)`` bitwise.

    Args:
        reference: Returns of the reference condition, shape ``(num_runs_reference,)``.
        target: Returns of the target condition, shape ``(num_runs_target,)``.
        statistic: ``'mean'`` or ``'iqm'``.
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the intervals, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        A :class:`Gap` with ``reference=0``, ``target=1``, ``paired=False`` and ``n`` the total number of runs.

    Example:
        >>> import numpy as np
        >>> g = unpaired_gap(np.linspace(90, 110, 30), np.linspace(60, 100, 12), rng=0)
        >>> round(g.absolute.value, 6), round(g.relative.value, 6), g.absolute.n
        (20.0, 0.2, 42)
    """
    statistic = _statistic(statistic)
    ref = _runs_vector(reference, "reference")
    tgt = _runs_vector(target, "target")
    confidence = _open_unit(confidence, "confidence")
    num_resamples = _resamples(num_resamples)
    gen = _generator(rng)
    _check_enough("gap", [ref.shape[0], tgt.shape[0]], confidence, num_resamples)
    ref_point, ref_boots = _columns(ref, statistic, gen, num_resamples)
    tgt_point, tgt_boots = _columns(tgt, statistic, gen, num_resamples)
    points = np.concatenate([ref_point, tgt_point])
    boots = np.concatenate([ref_boots, tgt_boots], axis=1)
    return _gap(points, boots, ref.shape[0] + tgt.shape[0], 0, 1, False, statistic, confidence)


def probability_of_improvement(
    x: ArrayLike,
    y: ArrayLike,
    *,
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> Estimate:
    """P(X > Y): the chance a run of X beats a run of Y, averaged over conditions, as in rliable.

    Per condition this is the Mann–Whitney U statistic over ``n_x * n_y`` (ties count one half); the conditions are
    then averaged. The interval resamples runs of X and of Y independently within each condition.

    Args:
        x: Returns of X, shape ``(num_runs_x, num_conditions)``.
        y: Returns of Y, shape ``(num_runs_y, num_conditions)``; the run counts may differ.
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the interval, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        An :class:`Estimate` in [0, 1]; 0.5 means neither is better.

    Example:
        >>> import numpy as np
        >>> x = np.arange(20.0)[:, None] + 5
        >>> round(probability_of_improvement(x, np.arange(20.0)[:, None], rng=0).value, 4)
        0.7188
    """
    a = _runs_array(x, "x")
    b = _runs_array(y, "y")
    if a.shape[1] != b.shape[1]:
        raise ValueError(
            f"`x` and `y` must have the same number of conditions (columns). Received {a.shape[1]} and {b.shape[1]}."
        )
    confidence = _open_unit(confidence, "confidence")
    num_resamples = _resamples(num_resamples)
    gen = _generator(rng)
    _check_enough("probability_of_improvement", [a.shape[0], b.shape[0]], confidence, num_resamples)
    nx, ny = a.shape[0], b.shape[0]
    points = np.empty(a.shape[1])
    boots = np.empty((num_resamples, a.shape[1]))
    for j in range(a.shape[1]):
        # wins[i, k] = 1 if x_i > y_k, 1/2 on a tie: U of a resample is c_x @ wins @ c_y
        wins = (a[:, j, None] > b[None, :, j]) + 0.5 * (a[:, j, None] == b[None, :, j])
        points[j] = wins.mean()
        cx = _draw_counts(gen, nx, num_resamples)
        cy = _draw_counts(gen, ny, num_resamples)
        boots[:, j] = np.einsum("bi,ik,bk->b", cx, wins, cy, optimize=True) / (nx * ny)
    return _estimate(points.mean(), boots.mean(axis=1), confidence, a.size + b.size)


# --------------------------------------------------------------------------------------------------------------------
# Robustness over a perturbation sweep


def _radius(
    curve: np.ndarray, distances: np.ndarray, nominal_index: int, fraction: float, interpolate: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Radius and censoring flag per row of ``curve`` (shape ``(B, K)``)."""
    thresholds = fraction * curve[:, nominal_index]
    best = np.full(curve.shape[0], np.inf)
    censored = np.zeros(curve.shape[0], dtype=bool)
    k = curve.shape[1]
    for side in (np.arange(nominal_index, k), np.arange(nominal_index, -1, -1)):
        if side.size < 2:
            continue
        d = distances[side]
        v = curve[:, side]
        fails = v < thresholds[:, None]
        has_fail = fails.any(axis=1)
        first = np.argmax(fails, axis=1)
        prev = np.maximum(first - 1, 0)
        rows = np.arange(curve.shape[0])
        v_prev, v_first = v[rows, prev], v[rows, first]
        if interpolate:
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.where(v_prev > v_first, (v_prev - thresholds) / (v_prev - v_first), 0.0)
            crossing = d[prev] + np.clip(step, 0.0, 1.0) * (d[first] - d[prev])
        else:
            crossing = d[prev].astype(np.float64)
        crossing = np.where(first == 0, 0.0, crossing)  # the nominal itself misses (non-positive nominal return)
        side_radius = np.where(has_fail, crossing, d[-1])
        take = side_radius < best
        censored = np.where(take, ~has_fail, censored | ((side_radius == best) & ~has_fail))
        best = np.minimum(best, side_radius)
    return best, censored


def robustness_radius(
    grid: ArrayLike,
    returns: ArrayLike,
    *,
    nominal: float = 0.0,
    fraction: float = 0.9,
    statistic: Statistic = "mean",
    interpolate: bool = True,
    paired: bool = False,
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> RobustnessRadius:
    """The largest perturbation around the nominal that keeps ``fraction`` of the nominal return.

    Walking outward from the nominal grid value on each side, the first grid point whose statistic falls below
    ``fraction * statistic(nominal)`` bounds the radius on that side; with ``interpolate`` the crossing is placed by
    linear interpolation between it and the last point that passed, otherwise the last passing point is taken. The
    radius is the smaller of the two sides (a one-sided sweep has one side). When nothing fails on the binding side,
    the radius is the grid's extent there and the result is ``censored``.

    Args:
        grid: Strictly increasing perturbation values, shape ``(num_conditions,)``, including both bounds of the sweep.
        returns: Array of shape ``(num_runs, num_conditions)``, column ``j`` at ``grid[j]``.
        nominal: The grid value of the unperturbed condition (e.g. 0 for an offset, 1 for a scale); must be on the
            grid.
        fraction: Fraction of the nominal return to keep, in (0, 1].
        statistic: ``'mean'`` or ``'iqm'`` of the returns at each grid point.
        interpolate: Interpolate the crossing linearly between grid points.
        paired: Resample runs jointly across grid points (row ``i`` is the same seed at every grid point).
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the interval, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        A :class:`RobustnessRadius` in the units of ``grid``.

    Raises:
        ValueError: On a grid that is not strictly increasing, does not match ``returns`` or does not contain
            ``nominal``, or a non-positive nominal return.

    Example:
        >>> import numpy as np
        >>> grid = np.array([0.0, 0.1, 0.2, 0.3, 0.4])
        >>> returns = np.tile([100.0, 98.0, 94.0, 86.0, 70.0], (20, 1))
        >>> r = robustness_radius(grid, returns, fraction=0.9, rng=0)
        >>> round(r.radius.value, 6), r.censored  # 90 is crossed halfway from 94 (0.2) to 86 (0.3)
        (0.25, False)
    """
    statistic = _statistic(statistic)
    x = _runs_array(returns, "returns")
    g = np.asarray(grid, dtype=np.float64)
    if g.ndim != 1:
        raise ValueError(f"`grid` must be 1-D. Received shape {g.shape}.")
    if g.size != x.shape[1]:
        raise ValueError(
            f"`grid` must have one value per condition (column) of `returns` ({x.shape[1]}). Received {g.size}."
        )
    if g.size < 2:
        raise ValueError(f"`grid` must have at least 2 values. Received {g.size}.")
    if not np.all(np.isfinite(g)) or not np.all(np.diff(g) > 0):
        raise ValueError(f"`grid` must be finite and strictly increasing. Received {g.tolist()}.")
    hits = np.flatnonzero(np.isclose(g, nominal, rtol=1e-9, atol=1e-12))
    if hits.size != 1:
        raise ValueError(f"`nominal` must be one of the grid values {g.tolist()}. Received {nominal!r}.")
    nominal_index = int(hits[0])
    if isinstance(fraction, bool) or not isinstance(fraction, (int, float, np.integer, np.floating)):
        raise TypeError(f"`fraction` must be a number in (0, 1]. Received {fraction!r}.")
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"`fraction` must be in (0, 1]. Received {fraction!r}.")
    confidence = _open_unit(confidence, "confidence")
    num_resamples = _resamples(num_resamples)
    gen = _generator(rng)
    points, boots = _columns(x, statistic, gen, num_resamples, paired=bool(paired))
    if points[nominal_index] <= 0:
        raise ValueError(
            f"`returns` at the nominal grid value must have a positive {statistic} to keep a fraction of it "
            f"(shift the returns so that 0 is the worst acceptable). Received {points[nominal_index]:g}."
        )
    _check_enough("robustness_radius", [x.shape[0]], confidence, num_resamples)
    distances = np.abs(g - g[nominal_index])
    value, censored = _radius(points[None, :], distances, nominal_index, float(fraction), interpolate)
    boot_radius, _ = _radius(boots, distances, nominal_index, float(fraction), interpolate)
    return RobustnessRadius(
        radius=_estimate(value[0], boot_radius, confidence, x.size),
        fraction=float(fraction),
        nominal=float(g[nominal_index]),
        nominal_return=float(points[nominal_index]),
        censored=bool(censored[0]),
        statistic=statistic,
    )


# --------------------------------------------------------------------------------------------------------------------
# Agreement between sim and real across policies


def _sim_real(
    what: str,
    sim: ArrayLike,
    real: ArrayLike,
    statistic: str,
    rng: np.random.Generator | int,
    confidence: float,
    num_resamples: int,
    min_policies: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    statistic = _statistic(statistic)
    s = _runs_array(sim, "sim", "num_policies")
    r = _runs_array(real, "real", "num_policies")
    if s.shape[1] != r.shape[1]:
        raise ValueError(
            f"`sim` and `real` must have the same number of policies (columns). Received {s.shape[1]} and {r.shape[1]}."
        )
    if s.shape[1] < min_policies:
        raise ValueError(f"`sim` and `real` must cover at least {min_policies} policies. Received {s.shape[1]}.")
    confidence = _open_unit(confidence, "confidence")
    num_resamples = _resamples(num_resamples)
    gen = _generator(rng)
    _check_enough(what, [s.shape[0], r.shape[0]], confidence, num_resamples)
    s_point, s_boot = _columns(s, statistic, gen, num_resamples)
    r_point, r_boot = _columns(r, statistic, gen, num_resamples)
    return s_point, s_boot, r_point, r_boot, s.size + r.size


def _correlation(a: np.ndarray, b: np.ndarray, method: str) -> np.ndarray:
    """Row-wise correlation of ``(B, P)`` arrays; NaN where a row is constant."""
    if method == "spearman":
        a = _stats.rankdata(a, axis=1)
        b = _stats.rankdata(b, axis=1)
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    denom = np.sqrt((a * a).sum(axis=1) * (b * b).sum(axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(denom > 0, (a * b).sum(axis=1) / denom, np.nan)


def srcc(
    sim: ArrayLike,
    real: ArrayLike,
    *,
    method: Literal["pearson", "spearman"] = "pearson",
    statistic: Statistic = "mean",
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> Estimate:
    """Sim-vs-real correlation coefficient across policies (SIMPLER uses Pearson).

    Each policy is summarised by the statistic of its runs in sim and in real; the correlation is taken across
    policies. The interval resamples runs within each (policy, sim/real) stratum; resamples in which every policy
    scores the same (correlation undefined) are left out.

    Args:
        sim: Sim returns (or 0/1 successes), shape ``(num_runs_sim, num_policies)``.
        real: Real returns, shape ``(num_runs_real, num_policies)``, policies in the same column order.
        method: ``'pearson'`` or ``'spearman'``.
        statistic: ``'mean'`` or ``'iqm'`` per policy.
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the interval, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        An :class:`Estimate` in [-1, 1].

    Raises:
        ValueError: With fewer than 3 policies, or when all policies score the same in sim or in real.

    Example:
        >>> import numpy as np
        >>> sim = np.tile([0.2, 0.5, 0.9], (20, 1))
        >>> real = np.tile([0.1, 0.3, 0.4], (20, 1))
        >>> round(srcc(sim, real, method="spearman", rng=0).value, 6)
        1.0
    """
    if method not in ("pearson", "spearman"):
        raise ValueError(f"`method` must be one of 'pearson', 'spearman'. Received {method!r}.")
    s_point, s_boot, r_point, r_boot, n = _sim_real(
        "srcc", sim, real, statistic, rng, confidence, num_resamples, min_policies=3
    )
    value = _correlation(s_point[None, :], r_point[None, :], method)[0]
    if not np.isfinite(value):
        raise ValueError(
            "`sim` and `real` must not score every policy the same: the correlation is undefined. "
            f"Received sim {s_point.tolist()} and real {r_point.tolist()}."
        )
    return _estimate(value, _correlation(s_boot, r_boot, method), confidence, n)


def _mmrv(s: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Row-wise MMRV of ``(B, P)`` sim and real scores."""
    disagree = (s[:, :, None] > s[:, None, :]) != (r[:, :, None] > r[:, None, :])
    violation = np.abs(r[:, :, None] - r[:, None, :]) * disagree
    return violation.max(axis=2).mean(axis=1)


def mmrv(
    sim: ArrayLike,
    real: ArrayLike,
    *,
    statistic: Statistic = "mean",
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> Estimate:
    """Mean maximum rank violation between sim and real across policies (SIMPLER, Li et al. 2024).

    ``MMRV = mean_i max_j |R_i - R_j| * 1[(S_i > S_j) != (R_i > R_j)]`` with ``S``, ``R`` the per-policy sim and real
    scores: for each policy, the largest real-performance margin by which sim orders it wrongly against another
    policy. 0 means sim ranks the policies exactly as real does; lower is better. Ties count as in SIMPLER's code
    (a tie on one side and a strict order on the other is a violation).

    Args:
        sim: Sim returns (or 0/1 successes), shape ``(num_runs_sim, num_policies)``.
        real: Real returns, shape ``(num_runs_real, num_policies)``, policies in the same column order.
        statistic: ``'mean'`` or ``'iqm'`` per policy.
        rng: Generator (or int seed) the bootstrap draws from.
        confidence: Nominal coverage of the interval, in (0, 1).
        num_resamples: Bootstrap resamples.

    Returns:
        An :class:`Estimate` in the units of ``real``.

    Example:
        >>> import numpy as np
        >>> sim = np.tile([0.2, 0.5, 0.9], (20, 1))
        >>> real = np.tile([0.1, 0.4, 0.3], (20, 1))  # sim swaps the last two; they differ by 0.1 in real
        >>> round(mmrv(sim, real, rng=0).value, 6)
        0.066667
    """
    s_point, s_boot, r_point, r_boot, n = _sim_real(
        "mmrv", sim, real, statistic, rng, confidence, num_resamples, min_policies=2
    )
    value = _mmrv(s_point[None, :], r_point[None, :])[0]
    return _estimate(value, _mmrv(s_boot, r_boot), confidence, n)
