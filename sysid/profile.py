"""Profile-likelihood check of parameters the data barely inform (issue #17).

The standard errors of :func:`sysid.fit` come from the curvature of the cost at the estimate. Where that
curvature is flat — a joint the log hardly moves, a parameter traded off against another — the quadratic picture
behind a ``±1.96 SE`` interval is wrong: the cost may rise steeply on one side and never on the other.
:func:`profile_intervals` walks such a parameter away from its estimate, re-fits every other parameter (and the
segments' initial states) at each step, and reads the 95% interval off the likelihood ratio
``2 (cost(θ_i) - cost_min) / s² <= χ²₁(0.95)``. A side on which the cost never rises that far before the search
bound is *open*: the data do not bound the parameter there.

Example:
    >>> check = ProfileCheck("dof_damping[wrist]", 0.4, 0.01, 5.0, False, True, 0.2, 0.6)
    >>> check.open, check.describe()
    (True, 'dof_damping[wrist]: profile-likelihood 95% interval [0.01, 5 (the search bound: not bounded by the data)] (Wald [0.2, 0.6])')
    >>> ProfileCheck.from_dict(check.to_dict()) == check
    True
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import stats

from sysid._problem import Problem
from sysid._solver import Progress, State, lm

__all__ = ["CHI2_95", "FLAT_RELATIVE_SE", "ProfileCheck", "flat_parameters", "profile_intervals"]

#: Likelihood-ratio threshold of a 95% interval for one parameter.
CHI2_95 = float(stats.chi2.ppf(0.95, 1))
#: Standard error over |estimate| from which the curvature counts as flat and the profile is computed.
FLAT_RELATIVE_SE = 0.25
_MULTIPLES = (
    1.0,
    2.0,
    4.0,
    math.inf,
)  # profile points: estimate ± these multiples of the Wald half-width (inf: the bound)
_PROFILE_ITERATIONS = 6


@dataclass(frozen=True)
class ProfileCheck:
    """The profile-likelihood 95% interval of one barely informed parameter.

    Attributes:
        address: the parameter.
        estimate: the fitted value.
        low: lower end of the profile interval (the search bound when ``open_low``).
        high: upper end (the search bound when ``open_high``).
        open_low: the cost never rose to the 95% level below the estimate, down to the search bound.
        open_high: the same above the estimate.
        wald_low: the reported (curvature) interval's lower end, for comparison.
        wald_high: its upper end.
    """

    address: str
    estimate: float
    low: float
    high: float
    open_low: bool
    open_high: bool
    wald_low: float
    wald_high: float

    @property
    def open(self) -> bool:
        """True when the data bound the parameter on at most one side."""
        return self.open_low or self.open_high

    def describe(self) -> str:
        """One line: the profile interval, which sides are open, and the Wald interval."""
        unbounded = " (the search bound: not bounded by the data)"
        low = f"{self.low:.6g}{unbounded if self.open_low else ''}"
        high = f"{self.high:.6g}{unbounded if self.open_high else ''}"
        return (
            f"{self.address}: profile-likelihood 95% interval [{low}, {high}] (Wald "
            f"[{self.wald_low:.6g}, {self.wald_high:.6g}])"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (:meth:`from_dict` inverts it)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ProfileCheck:
        """The inverse of :meth:`to_dict`."""
        return cls(
            address=str(data["address"]),
            estimate=float(data["estimate"]),
            low=float(data["low"]),
            high=float(data["high"]),
            open_low=bool(data["open_low"]),
            open_high=bool(data["open_high"]),
            wald_low=float(data["wald_low"]),
            wald_high=float(data["wald_high"]),
        )


def flat_parameters(estimates: np.ndarray, stderr: np.ndarray, ci95: np.ndarray, bounds: np.ndarray) -> list[int]:
    """Indices of parameters with flat curvature: standard error above :data:`FLAT_RELATIVE_SE` of the estimate,
    or a Wald interval that reaches past a search bound.

    Example:
        >>> flat_parameters(np.array([1.0, 1.0, 0.1]), np.array([0.01, 0.5, 0.01]),
        ...                 np.array([[0.98, 1.02], [0.0, 2.0], [0.08, 0.12]]), np.array([[0.1, 10]] * 3))
        [1, 2]
    """
    out = []
    for i in range(estimates.size):
        wide = stderr[i] > FLAT_RELATIVE_SE * max(abs(float(estimates[i])), 1e-300)
        past = ci95[i, 0] < bounds[i, 0] or ci95[i, 1] > bounds[i, 1]
        if wide or past or not math.isfinite(float(stderr[i])):
            out.append(i)
    return out


def _crossing(a: float, da: float, b: float, db: float) -> float:
    """Where the deviance reaches :data:`CHI2_95` between ``(a, da)`` and ``(b, db)``: the signed root of the
    deviance is close to linear in the parameter (exactly for a quadratic cost)."""
    ra, rb = math.sqrt(da), math.sqrt(db)
    return a + (math.sqrt(CHI2_95) - ra) / max(rb - ra, 1e-300) * (b - a)


def _deviance(
    problem: Problem,
    warm: State,
    i: int,
    value: float,
    lower: np.ndarray,
    upper: np.ndarray,
    base: float,
    s2: float,
    fit_x0: bool,
    fd_step: float,
) -> tuple[float, State]:
    """The likelihood-ratio statistic with parameter ``i`` held at ``value`` and the rest re-fitted from ``warm``."""
    lo, hi = lower.copy(), upper.copy()
    lo[i] = hi[i] = value
    start = State(warm.theta.copy(), warm.x0.copy(), warm.delay, warm.obs)
    start.theta[i] = value
    done = lm(
        problem,
        start,
        lo,
        hi,
        fit_x0=fit_x0,
        max_iter=_PROFILE_ITERATIONS,
        fd_step=fd_step,
        progress=Progress(False),
        stage="profile",
        free=np.arange(lower.size) != i,
    )
    return 2.0 * max(done.cost - base, 0.0) / max(s2, 1e-300), done


def profile_intervals(
    problem: Problem,
    state: State,
    lower: np.ndarray,
    upper: np.ndarray,
    indices: list[int],
    s2: float,
    wald: np.ndarray,
    *,
    fit_x0: bool,
    fd_step: float,
) -> tuple[ProfileCheck, ...]:
    """Profiles each parameter in ``indices`` on ``problem`` around ``state`` (the fit's optimum).

    Args:
        problem: the final fitting problem (its weights as at the optimum).
        state: the optimum (parameters, initial states, delays, cost).
        lower: search bounds (P,).
        upper: search bounds (P,).
        indices: the parameters to profile.
        s2: residual variance factor of the fit (``2 cost / dof``).
        wald: (P, 2) the fit's 95% intervals.
        fit_x0: whether the segments' initial states are fitted (re-fitted at every profile point).
        fd_step: relative finite-difference step.

    Returns:
        One :class:`ProfileCheck` per index.
    """
    out = []
    base = state.cost
    for i in indices:
        ends: list[float] = []
        opened: list[bool] = []
        half = max(float(wald[i, 1] - wald[i, 0]) / 2.0, 1e-6 * max(abs(float(state.theta[i])), 1e-3))

        def deviance(value: float, warm: State, i: int = i) -> tuple[float, State]:
            return _deviance(problem, warm, i, value, lower, upper, base, s2, fit_x0, fd_step)

        for sign, bound in ((-1.0, float(lower[i])), (1.0, float(upper[i]))):
            prev_value, prev_dev = float(state.theta[i]), 0.0
            warm = State(state.theta.copy(), state.x0.copy(), state.delay, state.obs)
            end, is_open = bound, True
            for multiple in _MULTIPLES:
                value = float(np.clip(state.theta[i] + sign * multiple * half, lower[i], upper[i]))
                if value == prev_value:
                    break
                dev, done = deviance(value, warm)
                if dev >= CHI2_95:
                    # One refinement: the deviance at the interpolated end decides which side brackets the level.
                    guess = _crossing(prev_value, prev_dev, value, dev)
                    dev_g, _ = deviance(guess, warm)
                    if dev_g >= CHI2_95:
                        end = _crossing(prev_value, prev_dev, guess, dev_g)
                    else:
                        end = _crossing(guess, dev_g, value, dev)
                    is_open = False
                    break
                prev_value, prev_dev, warm = value, dev, done
                if value == bound:
                    break
            ends.append(end)
            opened.append(is_open)
        out.append(
            ProfileCheck(
                address=problem.space.addresses[i],
                estimate=float(state.theta[i]),
                low=ends[0],
                high=ends[1],
                open_low=opened[0],
                open_high=opened[1],
                wald_low=float(wald[i, 0]),
                wald_high=float(wald[i, 1]),
            )
        )
    return tuple(out)
