"""Uncertainty of a :func:`sysid.fit` estimate from the weighted Jacobian at it (internal).

The nuisance initial states are profiled out segment by segment; the Fisher information of what is left gives
the Cramér–Rao SDs and identifiability; the covariance is the Gauss–Newton one widened to the Newey–West sandwich
where the residuals are coloured; intervals use Student's t on the residual degrees of freedom.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from sysid._problem import Problem
from sysid.covariance import combine, hac_covariance, identifiability
from sysid.quality import INFORMATIVE_SHARE

__all__ = ["Statistics", "estimate_statistics", "profile_states"]


@dataclass(frozen=True)
class Statistics:
    """What the Jacobian at the estimate says: shapes (P,) or (P, P) unless noted."""

    cost: float
    n_residuals: int
    dof: int
    s2: float  # residual variance per degree of freedom (1 when the weights are right)
    crlb: np.ndarray
    covariance: np.ndarray
    inflation: np.ndarray  # sandwich / Gauss–Newton standard-error ratio (>= 1)
    stderr: np.ndarray
    ci95: np.ndarray  # (P, 2)
    correlation: np.ndarray
    condition: float
    informative: tuple[str, ...]  # channels carrying a real share of some parameter's information
    at_bounds: np.ndarray  # indices of parameters at a bound
    warnings: tuple[str, ...]


def profile_states(problem: Problem, jac: np.ndarray, p: int) -> np.ndarray:
    """(N, P) parameter columns of ``jac`` with each segment's initial-state columns projected out.

    A segment's initial state touches only that segment's rows, so small column-scaled normal equations per
    segment do it (LAPACK's threaded QR of even a 500x22 block took ~0.3 s on the loaded 2-core box).
    """
    jp = jac[:, :p].copy()
    for k, idx in enumerate(problem.segment_rows()):
        jx = jac[idx, p + k * problem.nxa : p + (k + 1) * problem.nxa]
        scale = np.maximum(np.linalg.norm(jx, axis=0), 1e-300)
        jx = jx / scale
        try:
            coef = np.linalg.solve(jx.T @ jx, jx.T @ jp[idx])
        except np.linalg.LinAlgError:
            coef = np.linalg.lstsq(jx, jp[idx], rcond=None)[0]
        jp[idx] -= jx @ coef
    return jp


def estimate_statistics(
    problem: Problem,
    theta: np.ndarray,
    r: np.ndarray,
    jac: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    fitted: bool,
    unknowns: int,
) -> Statistics:
    """Standard errors, intervals, CRLB and warnings from the residual ``r`` and Jacobian ``jac`` at ``theta``."""
    space = problem.space
    cost = 0.5 * float(r @ r)
    p = space.size
    jp = profile_states(problem, jac, p) if fitted and jac.shape[1] > p else jac[:, :p]
    fisher = jp.T @ jp
    # Share of each parameter's information that each channel carries: whiteness is judged where it matters.
    per_channel = np.zeros((len(problem.channels), p))
    np.add.at(per_channel, problem.channel_of_residual(), jp**2)
    share = per_channel / np.maximum(np.diag(fisher), 1e-300)
    informative = tuple(
        name for c, name in enumerate(problem.channels) if p == 0 or float(share[c].max()) >= INFORMATIVE_SHARE
    )
    cov_unit, cond, warns = identifiability(space.addresses, fisher, theta, lower, upper)
    n_res = int(r.size)
    dof = max(1, n_res - unknowns)
    s2 = 2.0 * cost / dof
    crlb = np.sqrt(np.maximum(np.diag(cov_unit), 0.0))
    # Coloured residuals (unmodelled dynamics) make s²(JᵀJ)⁻¹ too small: widen to the sandwich where larger.
    hac = hac_covariance(jp, r, *problem.residual_keys(), unknowns)
    covariance, inflation = combine(cov_unit * s2, hac)
    stderr = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    tq = float(stats.t.ppf(0.975, dof))
    ci95 = np.stack([theta - tq * stderr, theta + tq * stderr], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = covariance / np.outer(stderr, stderr)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    for i in range(p):
        for j in range(i + 1, p):
            if abs(corr[i, j]) > 0.99 and not any(space.addresses[i] in w and space.addresses[j] in w for w in warns):
                warns.append(
                    f"strongly correlated: {space.addresses[i]} and {space.addresses[j]} (correlation "
                    f"{corr[i, j]:+.3f}); the data mostly fix a combination of the two."
                )
    span = upper - lower
    at_bounds = np.flatnonzero((theta - lower <= 1e-6 * span) | (upper - theta <= 1e-6 * span))
    for i in map(int, at_bounds):
        warns.append(
            f"{space.addresses[i]} = {theta[i]:.6g} sits at its bound [{lower[i]:.6g}, {upper[i]:.6g}]; widen "
            "`bounds` or check the model."
        )
    return Statistics(
        cost=cost,
        n_residuals=n_res,
        dof=dof,
        s2=s2,
        crlb=crlb,
        covariance=covariance,
        inflation=inflation,
        stderr=stderr,
        ci95=ci95,
        correlation=corr,
        condition=cond,
        informative=informative,
        at_bounds=at_bounds,
        warnings=tuple(warns),
    )
