"""Parameter covariance that survives coloured residuals (internal to :func:`sysid.fit`).

The Gauss–Newton covariance ``s² (JᵀJ)⁻¹`` is exact only when the weighted residuals are white. An unmodelled
effect leaves slow, correlated errors along a trajectory, and then it is too small — intervals that look precise
and miss the truth. :func:`hac_covariance` is the heteroskedasticity-and-autocorrelation-consistent (Newey–West)
sandwich ``A⁻¹ B A⁻¹`` with ``A = JᵀJ`` and ``B`` the Bartlett-weighted long-run covariance of the per-row scores
``g_t = Σ_c J_tcᵀ r_tc`` inside each shooting segment. :func:`combine` keeps the Gauss–Newton covariance when it is
the larger and inflates each parameter's standard error to the sandwich's when the residuals say so.

Example:
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> jac = rng.normal(size=(400, 2)); r = rng.normal(size=400)
    >>> keys = np.arange(400); seg = np.zeros(400, dtype=int)
    >>> hac = hac_covariance(jac, r, seg, keys, unknowns=2)
    >>> classical = np.linalg.inv(jac.T @ jac) * float(r @ r) / 398
    >>> bool(np.allclose(np.sqrt(np.diag(hac) / np.diag(classical)), 1.0, atol=0.25))
    True
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["bandwidth", "combine", "hac_covariance", "identifiability"]


def bandwidth(rows: int) -> int:
    """Newey–West lag truncation for ``rows`` scores: ``floor(4 (rows/100)^(2/9))``, at least 1.

    Example:
        >>> bandwidth(100), bandwidth(1000)
        (4, 6)
    """
    return max(1, math.floor(4.0 * (max(rows, 1) / 100.0) ** (2.0 / 9.0)))


def hac_covariance(
    jac: np.ndarray, r: np.ndarray, segment: np.ndarray, row: np.ndarray, unknowns: int, lags: int | None = None
) -> np.ndarray:
    """Newey–West sandwich covariance of least-squares parameters.

    Args:
        jac: (N, P) weighted Jacobian of the parameters (nuisance directions already projected out).
        r: (N,) weighted residuals at the estimate.
        segment: (N,) shooting segment of every residual (no correlation is counted across segments).
        row: (N,) time row of every residual (entries on one row, e.g. several channels, form one score).
        unknowns: every fitted scalar (parameters and nuisance), for the small-sample factor ``N / (N - unknowns)``.
        lags: Bartlett truncation (default :func:`bandwidth` of the rows per segment).

    Returns:
        (P, P) covariance ``A⁻¹ B A⁻¹``.
    """
    n, p = jac.shape
    contrib = jac * r[:, None]
    key = segment.astype(np.int64) * (int(row.max()) + 1 if row.size else 1) + row.astype(np.int64)
    uniq, inverse = np.unique(key, return_inverse=True)
    scores = np.zeros((uniq.size, p))
    np.add.at(scores, inverse, contrib)
    seg_of = uniq // (int(row.max()) + 1 if row.size else 1)
    counts = np.bincount(np.unique(seg_of, return_inverse=True)[1])
    lag = bandwidth(int(np.median(counts)) if counts.size else 1) if lags is None else lags
    meat = scores.T @ scores
    for k in range(1, lag + 1):
        if scores.shape[0] <= k:
            break
        ok = seg_of[k:] == seg_of[:-k]  # scores are sorted by (segment, row): lag k pairs inside a segment
        a, b = scores[k:][ok], scores[:-k][ok]
        gamma = a.T @ b
        meat += (1.0 - k / (lag + 1.0)) * (gamma + gamma.T)
    bread = np.linalg.pinv(jac.T @ jac)
    cov = bread @ meat @ bread * (n / max(1, n - unknowns))
    return 0.5 * (cov + cov.T)


def combine(classical: np.ndarray, hac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The classical covariance with each standard error raised to the sandwich's where that is larger.

    Returns:
        ``(covariance, inflation)`` with ``inflation`` (P,) >= 1 the factor applied to each standard error;
        correlations stay the classical ones.

    Example:
        >>> cov, f = combine(np.diag([1.0, 4.0]), np.diag([4.0, 1.0]))
        >>> f.tolist(), np.diag(cov).tolist()
        ([2.0, 1.0], [4.0, 4.0])
    """
    c, h = np.diag(classical), np.diag(hac)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.sqrt(np.where(c > 0, h / c, 1.0))
    inflation = np.where(np.isfinite(ratio), np.maximum(ratio, 1.0), 1.0)
    return classical * np.outer(inflation, inflation), inflation


def identifiability(
    addresses: tuple[str, ...], fisher: np.ndarray, theta: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, float, list[str]]:
    """Covariance (unscaled) from the profiled Fisher matrix, its relative condition number and warnings."""
    scale = np.maximum(np.abs(theta), 1e-6 * (upper - lower))
    rel = fisher * np.outer(scale, scale)
    eigval, eigvec = np.linalg.eigh(0.5 * (rel + rel.T))
    top = max(float(eigval[-1]), 1e-300)
    floor = top * 1e-16
    safe = np.maximum(eigval, floor)
    cov = (eigvec / safe) @ eigvec.T * np.outer(scale, scale)
    cond = top / max(float(eigval[0]), floor)
    warnings: list[str] = []
    for k in range(len(eigval)):
        lam = float(eigval[k])
        rel_sd = 1.0 / math.sqrt(max(lam, floor))
        if lam > top * 1e-10 and rel_sd < 0.5:
            continue
        v = eigvec[:, k] / np.max(np.abs(eigvec[:, k]))
        terms = [(float(c), addresses[i]) for i, c in enumerate(v) if abs(c) >= 0.1]
        terms.sort(key=lambda t: -abs(t[0]))
        combo = " ".join(f"{'-' if c < 0 else '+'} {abs(c):.2g}·Δ{a}/{a}" for c, a in terms).lstrip("+ ")
        what = ", ".join(a for _, a in terms)
        warnings.append(
            f"not identifiable: the data cannot separate {what}; the relative combination {combo} is only "
            f"determined to ±{100 * rel_sd:.3g}% (condition number {cond:.3g})."
        )
    return cov, cond, warnings
