"""Levenberg–Marquardt over the simulation-error problem, and its stopping rules (internal to :func:`sysid.fit`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sysid._problem import Problem

COST_ATOL = 1e-2  # ½χ² decrease below which Levenberg–Marquardt stops (see lm)
SETTLED = 0.02  # Gauss–Newton parameter step (in standard errors) below which the parameters have settled


@dataclass
class State:
    """A Levenberg–Marquardt iterate: parameters, segment initial states, delays and what the solve left."""

    theta: np.ndarray
    x0: np.ndarray
    delay: int
    obs: int
    cost: float = math.inf
    iterations: int = 0
    converged: bool = False
    # Residual and Jacobian at (theta, x0) under the problem's current weights, when the last solve left them fresh.
    r: np.ndarray | None = None
    jac: np.ndarray | None = None


class Progress:
    def __init__(self, enabled: bool) -> None:
        self.bar = None
        if enabled:
            from tqdm.auto import tqdm

            self.bar = tqdm(desc="sysid.fit", unit="it", leave=False)

    def step(self, stage: str, cost: float) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(f"{stage} cost={cost:.6g}", refresh=False)
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def fd_steps(theta: np.ndarray, lower: np.ndarray, upper: np.ndarray, rel: float) -> np.ndarray:
    return rel * np.maximum(np.abs(theta), 1e-3 * (upper - lower))


def lm(
    problem: Problem,
    st: State,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    fit_x0: bool,
    fit_params: bool = True,
    max_iter: int,
    fd_step: float,
    progress: Progress,
    stage: str,
    ftol: float = 1e-10,
    xtol: float = 1e-9,
    atol: float = COST_ATOL,
) -> State:
    """Box-projected Levenberg–Marquardt with Marquardt scaling; returns the improved state."""
    theta, x0 = st.theta.copy(), st.x0.copy()
    p = problem.space.size if fit_params else 0
    nx = problem.nx
    lam = 1e-3
    converged = False
    iterations = 0
    r, jac = problem.jacobian(theta, st.delay, st.obs, x0, fd_steps(theta, lower, upper, fd_step), fit_x0, fit_params)
    fresh = True
    cost = 0.5 * float(r @ r)
    while iterations < max_iter:
        g = jac.T @ r
        h = jac.T @ jac
        diag = np.maximum(np.diag(h), 1e-12 * max(float(np.max(np.diag(h))), 1e-300))
        if p and settled(h, g, diag, p):
            converged = True
            break
        iterations += 1
        accepted = False
        while lam < 1e12:
            try:
                delta = -np.linalg.solve(h + lam * np.diag(diag), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            theta_new = np.clip(theta + delta[:p], lower, upper) if p else theta
            x0_new = x0 + delta[p:].reshape(-1, nx) if fit_x0 else x0
            r_new = problem.residuals(theta_new, st.delay, st.obs, x0_new)[0]
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                accepted = True
                break
            lam *= 6.0
        if not accepted:
            converged = True  # no descent direction left at machine precision
            break
        step_small = not p or np.all(np.abs(theta_new - theta) <= xtol * (np.abs(theta) + 1e-3 * (upper - lower)))
        decrease = cost - cost_new
        theta, x0, cost = theta_new, x0_new, cost_new
        lam = max(lam / 4.0, 1e-10)
        progress.step(stage, cost)
        # An absolute floor too: a step that lowers ½χ² by 1e-2 moves the estimate by under a tenth of its
        # standard error (and the next step far less), below what the data can tell apart.
        fresh = False
        if decrease <= max(ftol * max(cost, 1e-300), atol) or step_small:
            converged = True
            break
        r, jac = problem.jacobian(
            theta, st.delay, st.obs, x0, fd_steps(theta, lower, upper, fd_step), fit_x0, fit_params
        )
        fresh = True
    keep = fresh and fit_params
    return State(theta, x0, st.delay, st.obs, cost, iterations, converged, r if keep else None, jac if keep else None)


def settled(h: np.ndarray, g: np.ndarray, diag: np.ndarray, p: int) -> bool:
    """Whether the full Gauss–Newton step moves every parameter by under ``SETTLED`` of its standard error.

    Initial-state nuisance directions (contacts, marginally stable modes) can crawl for many iterations after the
    parameters have settled; they do not change the estimates, so they are not chased.
    """
    try:
        inv = np.linalg.inv(h + 1e-12 * np.diag(diag))
    except np.linalg.LinAlgError:
        return False
    se = np.sqrt(np.maximum(np.diag(inv)[:p], 1e-300))
    step = -(inv @ g)[:p]
    return bool(np.all(np.abs(step) <= SETTLED * se))
