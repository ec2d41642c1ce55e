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
    # When the solve stopped because its last step barely lowered the cost: the residual at (theta, x0) and the
    # Jacobian of the iterate before that step (under the same weights), for the statistics (see lm).
    last_r: np.ndarray | None = None
    prior_jac: np.ndarray | None = None


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
    free: np.ndarray | None = None,
) -> State:
    """Box-projected Levenberg–Marquardt with Marquardt scaling; returns the improved state.

    ``free`` (P,) bool keeps the other parameters where they are (a profile-likelihood point). A residual and
    Jacobian on ``st`` (left by a previous solve, under the problem's current weights) are used, not recomputed.
    """
    theta, x0 = st.theta.copy(), st.x0.copy()
    p_all = problem.space.size if fit_params else 0
    chosen = np.arange(p_all) if free is None else np.flatnonzero(free[:p_all])
    p = int(chosen.size)

    def columns(jac: np.ndarray) -> np.ndarray:
        return jac if p == p_all else np.concatenate([jac[:, chosen], jac[:, p_all:]], axis=1)

    nx = problem.nxa
    lam = 1e-3
    converged = False
    iterations = 0
    columns_expected = p_all + (problem.seg.count * nx if fit_x0 else 0)
    if st.r is not None and st.jac is not None and free is None and st.jac.shape[1] == columns_expected:
        r, jac = st.r, st.jac  # left fresh at (theta, x0) by the previous solve, under the current weights
    else:
        r, jac = problem.jacobian(
            theta, st.delay, st.obs, x0, fd_steps(theta, lower, upper, fd_step), fit_x0, fit_params
        )
    fresh = True
    stopped_small, last_decrease = False, math.inf
    cost = 0.5 * float(r @ r)
    rows = problem.segment_rows() if fit_x0 else []
    while iterations < max_iter:
        normal = NormalEquations(columns(jac), r, rows, p, nx if fit_x0 else 0)
        diag = np.maximum(normal.diag, 1e-12 * max(float(np.max(normal.diag, initial=0.0)), 1e-300))
        if p and settled(normal, diag):
            converged = True
            break
        iterations += 1
        accepted = False
        while lam < 1e12:
            try:
                delta = normal.step(lam * diag)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            theta_new = theta.copy()
            theta_new[chosen] = np.clip(theta[chosen] + delta[:p], lower[chosen], upper[chosen])
            x0_new = x0
            if fit_x0:
                x0_new = x0.copy()
                x0_new[:, problem.x_dims] += delta[p:].reshape(-1, nx)
            r_new = problem.residuals(theta_new, st.delay, st.obs, x0_new)[0]
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                accepted = True
                break
            lam *= 6.0
        if not accepted:
            converged = True  # no descent direction left at machine precision
            break
        step_small = bool(p) and np.all(np.abs(theta_new - theta) <= xtol * (np.abs(theta) + 1e-3 * (upper - lower)))
        decrease = cost - cost_new
        theta, x0, cost = theta_new, x0_new, cost_new
        lam = max(lam / 4.0, 1e-10)
        progress.step(stage, cost)
        # An absolute floor too: a step that lowers ½χ² by 1e-2 moves the estimate by under a tenth of its
        # standard error (and the next step far less), below what the data can tell apart.
        fresh = False
        if decrease <= max(ftol * max(cost, 1e-300), atol) or step_small:
            converged = True
            stopped_small, last_decrease = True, decrease
            break
        r, jac = problem.jacobian(
            theta, st.delay, st.obs, x0, fd_steps(theta, lower, upper, fd_step), fit_x0, fit_params
        )
        fresh = True
    keep = fresh and fit_params and p == p_all
    # A final Gauss–Newton step that lowered ½χ² by d moved the unknowns by about sqrt(2 d) standard errors; for
    # d <= COST_ATOL that is under 0.14, and the Jacobian one iterate back describes the estimate to ~1e-5
    # relative in its standard errors, so the statistics need not roll out a Jacobian again.
    near = stopped_small and fit_params and p == p_all and last_decrease <= COST_ATOL
    return State(
        theta,
        x0,
        st.delay,
        st.obs,
        cost,
        iterations,
        converged,
        r if keep else None,
        jac if keep else None,
        r_new if near else None,
        jac if near else None,
    )


class NormalEquations:
    """Gauss–Newton normal equations ``JᵀJ δ = -Jᵀr`` of parameters plus per-segment initial states.

    A segment's initial state moves only that segment's residuals, so ``JᵀJ`` is an arrow matrix: a dense
    parameter block ``A`` (P×P), per segment a coupling ``B_k`` (P×nx) and a state block ``C_k`` (nx×nx). Solving
    through the Schur complement costs O(S·nx³) in small matrices instead of O((P + S·nx)³) in one dense one —
    and keeps off multi-threaded BLAS, which on a loaded 2-core box ran the dense QR/inverse ~10x slower than one
    thread (14 s of a 50 s manipulator fit).

    Args:
        jac: (N, P + S·nx) weighted Jacobian, parameter columns first, then segment after segment.
        r: (N,) weighted residual.
        rows: per segment, the indices of its residual entries (:meth:`sysid._problem.Problem.segment_rows`).
        p: parameter columns.
        nx: state columns per segment (0: no fitted initial states).

    Example:
        >>> rng = np.random.default_rng(0)
        >>> rows = [np.arange(0, 6), np.arange(6, 12)]
        >>> jac = np.zeros((12, 2 + 2 * 2))
        >>> jac[:, :2] = rng.normal(size=(12, 2))
        >>> jac[:6, 2:4], jac[6:, 4:6] = rng.normal(size=(6, 2)), rng.normal(size=(6, 2))
        >>> r = rng.normal(size=12)
        >>> dense = -np.linalg.solve(jac.T @ jac + np.eye(6), jac.T @ r)
        >>> bool(np.allclose(NormalEquations(jac, r, rows, 2, 2).step(np.ones(6)), dense))
        True
    """

    def __init__(self, jac: np.ndarray, r: np.ndarray, rows: list[np.ndarray], p: int, nx: int) -> None:
        self.p, self.nx = p, nx
        s = len(rows) if nx else 0
        self.s = s
        jp = jac[:, :p]
        self.a = jp.T @ jp
        self.gp = jp.T @ r
        self.b = np.empty((s, p, nx))
        self.c = np.empty((s, nx, nx))
        self.gx = np.empty((s, nx))
        for k, idx in enumerate(rows[:s]):
            jx = jac[idx, p + k * nx : p + (k + 1) * nx]
            self.c[k] = jx.T @ jx
            self.b[k] = jp[idx].T @ jx
            self.gx[k] = jx.T @ r[idx]
        self.diag = np.concatenate([np.diag(self.a), np.diagonal(self.c, axis1=1, axis2=2).ravel()])

    def _reduced(self, damp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Schur complement (P, P), reduced gradient (P,) and ``C_k⁻¹ [B_kᵀ | g_k]`` (S, nx, P+1)."""
        p, s, nx = self.p, self.s, self.nx
        schur = self.a + np.diag(damp[:p])
        reduced = self.gp.copy()
        solved = np.zeros((s, nx, p + 1))
        if s:
            c = self.c + damp[p:].reshape(s, nx)[:, :, None] * np.eye(nx)
            rhs = np.concatenate([np.transpose(self.b, (0, 2, 1)), self.gx[:, :, None]], axis=2)
            solved = np.linalg.solve(c, rhs)
            schur = schur - np.einsum("kpn,knq->pq", self.b, solved[:, :, :p])
            reduced = reduced - np.einsum("kpn,kn->p", self.b, solved[:, :, p])
        return schur, reduced, solved

    def step(self, damp: np.ndarray) -> np.ndarray:
        """The step δ (P + S·nx,) solving ``(JᵀJ + diag(damp)) δ = -Jᵀr``.

        Raises:
            numpy.linalg.LinAlgError: the damped system is singular.
        """
        schur, reduced, solved = self._reduced(damp)
        delta_p = -np.linalg.solve(schur, reduced) if self.p else np.zeros(0)
        delta_x = -(solved[:, :, self.p] + solved[:, :, : self.p] @ delta_p)
        return np.concatenate([delta_p, delta_x.ravel()])

    def parameter_step(self, damp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Parameter part of the step and of ``(JᵀJ + diag(damp))⁻¹`` (the initial states profiled out)."""
        schur, reduced, _ = self._reduced(damp)
        inv = np.linalg.inv(schur)
        return -(inv @ reduced), inv


def settled(normal: NormalEquations, diag: np.ndarray) -> bool:
    """Whether the full Gauss–Newton step moves every parameter by under ``SETTLED`` of its standard error.

    Initial-state nuisance directions (contacts, marginally stable modes) can crawl for many iterations after the
    parameters have settled; they do not change the estimates, so they are not chased.
    """
    try:
        step, inv = normal.parameter_step(1e-12 * diag)
    except np.linalg.LinAlgError:
        return False
    se = np.sqrt(np.maximum(np.diag(inv), 1e-300))
    return bool(np.all(np.abs(step) <= SETTLED * se))
