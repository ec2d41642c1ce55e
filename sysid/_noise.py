"""Per-channel noise levels for the weights of :func:`sysid.fit` (internal).

Two estimates: a model-free one from the log alone (the start), and one from the residuals of a fitted model
(the re-weighting). Weighting every channel by ``1/σ_c`` is what lets the estimator reach the Cramér–Rao bound.
"""

from __future__ import annotations

import math

import numpy as np

from sysid._problem import Problem

__all__ = ["difference_sigma", "residual_sigma"]


def difference_sigma(problem: Problem) -> np.ndarray:
    """Model-free noise level per channel: the k-th difference of white noise has variance C(2k, k)·σ².

    A smooth signal adds to every order but less to higher ones (a sampled velocity with fast content inflates
    the second difference several-fold), so the smallest estimate over orders 2–6 is taken.
    """
    out = []
    for y, seg in zip(problem.channel_measurements(), problem.channel_segments(), strict=True):
        pieces = [y[seg == s] for s in np.unique(seg)]
        estimates = []
        for k in range(2, 7):
            dk = [np.diff(ys, k) for ys in pieces if ys.size >= k + 1]
            flat = np.concatenate(dk) if dk else np.zeros(0)
            if flat.size >= 8 or (k == 2 and flat.size):
                estimates.append(math.sqrt(float(np.mean(flat**2)) / math.comb(2 * k, k)))
        sigma = min(estimates) if estimates else 0.0
        floor = 1e-9 * (float(np.std(y)) + 1e-9)
        out.append(max(sigma, floor, 1e-12))
    return np.asarray(out)


def residual_sigma(
    problem: Problem, values: np.ndarray, delay: int, obs_delay: int, x0: np.ndarray, unknowns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Noise level per channel from the residuals at ``values``, degrees of freedom shared out by row count; and
    those degrees of freedom (``sigma² · dof / σ²`` is chi-square with ``dof`` when the model is right)."""
    pred, sens = problem.simulate(values, delay, x0)
    errors = problem.channel_errors(*problem.raw_residuals(pred, sens, obs_delay))
    total = sum(e.size for e in errors)
    out, dofs = [], []
    for e, y in zip(errors, problem.channel_measurements(), strict=True):
        dof = max(1.0, e.size * (1.0 - unknowns / max(total, 1)))
        sigma = math.sqrt(float(np.sum(e**2)) / dof)
        out.append(max(sigma, 1e-9 * (float(np.std(y)) + 1e-9), 1e-12))
        dofs.append(dof)
    return np.asarray(out), np.asarray(dofs)
