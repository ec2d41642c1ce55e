"""Robustness over a perturbation sweep: how far from the nominal the returns keep a fraction of its value.

Example:
    >>> import numpy as np
    >>> grid = np.array([-0.2, -0.1, 0.0, 0.1, 0.2])
    >>> returns = np.tile([80.0, 95.0, 100.0, 95.0, 80.0], (20, 1))
    >>> r = robustness_radius(grid, returns, fraction=0.9, rng=0)
    >>> round(r.radius.value, 6), r.nominal_return, r.censored  # 90 is crossed a third of the way from 95 to 80
    (0.133333, 100.0, False)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .bootstrap import (
    _DEFAULT_RESAMPLES,
    Estimate,
    Statistic,
    _check_enough,
    _columns,
    _estimate,
    _generator,
    _open_unit,
    _resamples,
    _runs_array,
    _statistic,
)

__all__ = ["RobustnessRadius", "robustness_radius"]


@dataclass(frozen=True)
class RobustnessRadius:
    """The largest perturbation that keeps a fraction of the nominal return.

    Attributes:
        radius: Distance from the nominal grid value, with its bootstrap interval.
        fraction: Required fraction of the nominal return, e.g. 0.9.
        nominal: The grid value of the unperturbed condition.
        nominal_return: The return the threshold is a fraction of: the statistic (mean or IQM) of the returns at the
            nominal grid value, or of the ``reference`` runs when they were given (e.g. the policy's own training
            sim).
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
# Robustness over a perturbation sweep


def _radius(
    curve: np.ndarray, distances: np.ndarray, nominal_index: int, thresholds: np.ndarray, interpolate: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Radius and censoring flag per row of ``curve`` (shape ``(B, K)``), against ``thresholds`` ``(B,)``."""
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
    reference: ArrayLike | None = None,
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
        paired: Resample runs jointly across grid points (row ``i`` is the same seed at every grid point), and with
            ``reference`` when it has as many runs.
        reference: Runs ``(num_runs_ref,)`` of the condition whose return the threshold is a fraction of (e.g. the
            sim the policy was trained in); default: the returns at the nominal grid value. When the nominal grid
            point itself falls below the threshold, the radius is 0.
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
    ref = None if reference is None else _runs_array(np.asarray(reference)[:, None], "reference", "1")
    if ref is not None and paired and ref.shape[0] == x.shape[0]:
        points, boots = _columns(np.column_stack([x, ref]), statistic, gen, num_resamples, paired=True)
        ref_point, ref_boots = points[-1], boots[:, -1]
        points, boots = points[:-1], boots[:, :-1]
    else:
        points, boots = _columns(x, statistic, gen, num_resamples, paired=bool(paired))
        if ref is None:
            ref_point, ref_boots = points[nominal_index], boots[:, nominal_index]
        else:
            ref_points, ref_all = _columns(ref, statistic, gen, num_resamples)
            ref_point, ref_boots = ref_points[0], ref_all[:, 0]
    if ref_point <= 0:
        where = "at the nominal grid value" if ref is None else "of `reference`"
        raise ValueError(
            f"`returns` {where} must have a positive {statistic} to keep a fraction of it "
            f"(shift the returns so that 0 is the worst acceptable). Received {ref_point:g}."
        )
    _check_enough("robustness_radius", [x.shape[0]], confidence, num_resamples)
    distances = np.abs(g - g[nominal_index])
    value, censored = _radius(points[None, :], distances, nominal_index, np.array([fraction * ref_point]), interpolate)
    boot_radius, _ = _radius(boots, distances, nominal_index, fraction * ref_boots, interpolate)
    return RobustnessRadius(
        radius=_estimate(value[0], boot_radius, confidence, x.size, bounds=(0.0, np.inf)),
        fraction=float(fraction),
        nominal=float(g[nominal_index]),
        nominal_return=float(ref_point),
        censored=bool(censored[0]),
        statistic=statistic,
    )
