"""One statistic per condition, each with its interval: mean, IQM, CVaR, worst case, success rate, aggregate.

Example:
    >>> import numpy as np
    >>> returns = np.column_stack([np.arange(1.0, 21.0), np.arange(1.0, 21.0) * 2])
    >>> [e.value for e in mean(returns, rng=0)], worst_case(returns)
    ([10.5, 21.0], array([1., 2.]))
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from .bootstrap import (
    _DEFAULT_RESAMPLES,
    Estimate,
    Statistic,
    _check_enough,
    _draw_counts,
    _estimate,
    _generator,
    _open_unit,
    _per_condition,
    _resamples,
    _runs_array,
    _statistic,
    _trim_mean,
    _window,
    _window_mean,
)

__all__ = ["aggregate", "cvar", "iqm", "iqm_point", "mean", "success_rate", "worst_case"]


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
    from scipy import stats as _stats  # (imported when used: scipy.stats costs ~0.5 s at import)

    z = float(_stats.norm.ppf(0.5 + confidence / 2.0))
    out = []
    for p in x.mean(axis=0):
        denom = 1.0 + z * z / n
        centre = (p + z * z / (2 * n)) / denom
        half = z / denom * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n))
        low, high = max(0.0, float(centre - half)), min(1.0, float(centre + half))
        out.append(Estimate(float(p), low, high, confidence, n, "wilson"))
    return tuple(out)
