"""Agreement between sim and real across policies: does sim rank the policies as real does (SRCC, MMRV), and do
its scores follow real's linearly (Pearson)?

SRCC is Spearman's rank correlation coefficient (ranks only); :func:`pearson` is the linear correlation SIMPLER
reports beside it. Both are computed over the per-policy statistic; their intervals resample runs within each
(policy, sim/real) stratum and are bias-corrected when the attenuated replicates would miss the estimate (see
:mod:`~sim2real.metrics.bootstrap`).

Example:
    >>> import numpy as np
    >>> sim = np.tile([0.2, 0.5, 0.9], (20, 1))
    >>> real = np.tile([0.1, 0.3, 0.4], (20, 1))  # the same order as sim
    >>> round(srcc(sim, real, rng=0).value, 6), mmrv(sim, real, rng=0).value
    (1.0, 0.0)
    >>> round(pearson(sim, real, rng=0).value, 4)
    0.9631
"""

from __future__ import annotations

from typing import Literal

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

__all__ = ["mmrv", "pearson", "srcc"]


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
        from scipy import stats as _stats  # (imported when used: scipy.stats costs ~0.5 s at import)

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
    method: Literal["pearson", "spearman"] = "spearman",
    statistic: Statistic = "mean",
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> Estimate:
    """Sim-vs-real rank correlation across policies: Spearman's by default, as the name says (``method='pearson'``
    gives the linear correlation, also :func:`pearson`).

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
        >>> round(srcc(sim, real, rng=0).value, 6)
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
    return _estimate(value, _correlation(s_boot, r_boot, method), confidence, n, bounds=(-1.0, 1.0))


def pearson(
    sim: ArrayLike,
    real: ArrayLike,
    *,
    statistic: Statistic = "mean",
    rng: np.random.Generator | int,
    confidence: float = 0.95,
    num_resamples: int = _DEFAULT_RESAMPLES,
) -> Estimate:
    """Pearson (linear) correlation of the per-policy sim and real scores: ``srcc(..., method='pearson')``.

    Args:
        sim: Sim returns, shape ``(num_runs_sim, num_policies)``.
        real: Real returns, shape ``(num_runs_real, num_policies)``, policies in the same column order.
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
        >>> sim, real = np.tile([1.0, 2.0, 3.0], (20, 1)), np.tile([2.0, 4.0, 6.0], (20, 1))
        >>> round(pearson(sim, real, rng=0).value, 6)
        1.0
    """
    return srcc(
        sim, real, method="pearson", statistic=statistic, rng=rng, confidence=confidence, num_resamples=num_resamples
    )


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
    return _estimate(value, _mmrv(s_boot, r_boot), confidence, n, bounds=(0.0, np.inf))
