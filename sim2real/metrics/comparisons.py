"""Comparisons between conditions: the gap from a reference (e.g. sim) to a target (e.g. real), paired or not,
and the probability that one set of runs beats another.

Example:
    >>> import numpy as np
    >>> returns = np.column_stack([np.linspace(90, 110, 20), np.linspace(60, 100, 20)])
    >>> g = gap(returns, paired=True, rng=0)
    >>> g.reference, g.target, round(g.absolute.value, 6)
    (0, 1, 20.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .bootstrap import (
    _DEFAULT_RESAMPLES,
    Estimate,
    Statistic,
    _check_enough,
    _column,
    _columns,
    _draw_counts,
    _estimate,
    _generator,
    _open_unit,
    _resamples,
    _runs_array,
    _statistic,
    _trim_mean,
)

__all__ = ["Gap", "gap", "probability_of_improvement", "unpaired_gap"]


@dataclass(frozen=True)
class Gap:
    """The performance lost from a reference condition (e.g. sim) to a target condition (e.g. real).

    Attributes:
        absolute: ``stat(reference) - stat(target)``; positive when the target does worse.
        relative: ``absolute / |stat(reference)|``; NaN when ``stat(reference)`` is 0. Resamples where it is 0 are
            left out of the interval; when they are more than the interval's tail, ``(1 - confidence) / 2``, the
            interval is NaN (undefined) rather than conditional on the rest.
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
    if np.mean(boots[:, 0] == 0) > (1.0 - confidence) / 2.0:
        # the reference is 0 in more resamples than the interval may cut off: the interval of the rest would be a
        # conditional one (e.g. 16.9% [16.9%, 16.9%] from 4 episodes, 3 of them 0), so there is none
        rel_boots = np.full_like(rel_boots, np.nan)
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
    return _estimate(points.mean(), boots.mean(axis=1), confidence, a.size + b.size, bounds=(0.0, 1.0))
