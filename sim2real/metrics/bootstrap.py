"""The stratified bootstrap every interval of :mod:`sim2real.metrics` comes from, and the checks before it.

Intervals are percentile intervals of a **stratified bootstrap**: runs are resampled with replacement
independently within each condition (the stratum), as in rliable. The bootstrap draws only from the
``numpy.random.Generator`` passed as ``rng`` (an int is taken as the seed of a fresh ``default_rng``), never from
the global ``np.random``: the same seed gives bitwise-identical intervals.

Every interval contains its point estimate. When the plain percentile interval would miss it (the replicates are
median-biased: a correlation of noisy means, a censored radius), the replicates are shifted so that their median is
the estimate and ``Estimate.method`` reads ``'percentile bootstrap, median-bias corrected'``. A non-finite estimate
(a relative gap from a reference of 0) has a non-finite interval.

When the data are too thin for the interval asked, the functions still answer but warn with
:class:`FewSamplesWarning`. The rule (see :func:`minimum_runs`): every resampled stratum needs at least
``max(10, ceil(0.5 / (1 - confidence)))`` runs — 10 at 95%, 50 at 99% — because below ~10 runs the percentile
bootstrap is markedly too narrow (it covers ~91% instead of 95% for the mean of 10 normal draws) and because the
empirical distribution must put at least half a run's mass in the two tails the interval cuts off. The bootstrap
also needs ``num_resamples * (1 - confidence) / 2 >= 25`` resamples in each cut-off tail (1000 resamples at 95%)
for the interval ends to be stable.

Example:
    >>> import numpy as np
    >>> points, boots = _columns(np.arange(20.0)[:, None], "mean", np.random.default_rng(0), 1000)
    >>> points, boots.shape
    (array([9.5]), (1000, 1))
    >>> str(_estimate(points[0], boots[:, 0], 0.95, 20)).startswith("9.5 [")
    True
"""

from __future__ import annotations

import math
import os
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["Estimate", "FewSamplesWarning", "Statistic", "minimum_runs"]

Statistic = Literal["mean", "iqm"]
_STATISTICS = ("mean", "iqm")
_BOOTSTRAP = "percentile bootstrap"
_BIAS_CORRECTED = "percentile bootstrap, median-bias corrected"
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


# The metrics package's own folder: a warning raised under a public metric skips every frame in it.
_PACKAGE_DIR = os.path.dirname(__file__)


def _stacklevel() -> int:
    """Stack level of the first frame outside this package, so warnings point at the user's call."""
    frame: FrameType | None = sys._getframe(1)
    level = 1
    while frame is not None and os.path.dirname(frame.f_code.co_filename) == _PACKAGE_DIR:
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
    from scipy import stats as _stats  # (imported when used: scipy.stats costs ~0.5 s at import)

    return np.asarray(_stats.trim_mean(x, 0.25, axis=axis), dtype=np.float64)


def _interval(boots: np.ndarray, confidence: float) -> tuple[float, float]:
    tail = (1.0 - confidence) / 2.0
    finite = boots[np.isfinite(boots)]
    if finite.size == 0:
        return math.nan, math.nan
    low, high = np.quantile(finite, [tail, 1.0 - tail])
    return float(low), float(high)


def _estimate(
    value: float,
    boots: np.ndarray,
    confidence: float,
    n: int,
    bounds: tuple[float, float] = (-math.inf, math.inf),
) -> Estimate:
    """The percentile interval of ``boots`` around ``value``, made to contain ``value`` when the replicates are
    median-biased.

    A percentile interval that misses its own point estimate means the bootstrap distribution is shifted away from
    the estimate by more than its spread (a correlation of noisy per-policy means is attenuated once in the data and
    twice in a resample; a censored radius piles replicates on the grid's end). Then the replicates are shifted so
    their median is the estimate (the bias-corrected percentile interval of a location shift), clipped to ``bounds``
    (the statistic's range), and ``method`` says so. A non-finite estimate gets a non-finite interval: there is
    nothing to cover.
    """
    value = float(value)
    if not math.isfinite(value):
        return Estimate(value, math.nan, math.nan, confidence, int(n), _BOOTSTRAP)
    low, high = _interval(boots, confidence)
    method = _BOOTSTRAP
    rounding = 1e-9 * max(abs(value), abs(low), abs(high)) if math.isfinite(low) else 0.0
    if math.isfinite(low) and low - rounding <= value <= high + rounding:
        low, high = min(low, value), max(high, value)  # a point computed in another summation order
    elif math.isfinite(low):
        finite = boots[np.isfinite(boots)]
        shift = value - float(np.median(finite))
        low, high = _interval(finite + shift, confidence)
        low, high = min(low, value), max(high, value)  # rounding of the shift must not push the point outside
        low, high = max(low, bounds[0]), min(high, bounds[1])
        method = _BIAS_CORRECTED
    elif not math.isfinite(low):
        low = high = math.nan
    return Estimate(value, low, high, confidence, int(n), method)


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
