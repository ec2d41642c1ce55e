"""Online joint state-parameter estimation with an unscented Kalman filter, and RTS smoothing of logs.

The filter's state is ``[qpos, qvel, params]``. Its process model is one control step of MuJoCo (``n_substeps``
calls of ``mj_step`` with the logged command held) on a private model copy into which each sigma point's
parameters are written through :class:`sysid.params.ParameterSpace` (the same effects the randomisers use);
parameters follow a random walk (by default a constant). Parameters whose lower bound is positive (the default
bounds of damping, armature, masses, gains ... are ``[nominal / 10, nominal * 10]``) are filtered in log space,
so no sigma point ever simulates negative damping; values written into the model are clipped to the bounds.
Estimates and covariances are reported in the parameters' own units (delta method). Measurements are ``qpos``, ``qpos`` and ``qvel``, sensor readings or ``qpos`` plus
sensors.

:class:`OnlineEstimator` runs step by step (for a live robot); :func:`estimate_online` runs it over a
:class:`sysid.logs.TrajectoryLog`, restarting the state (not the parameters) at each episode, and smooths every
episode with filterpy's Rauch–Tung–Striebel smoother to give denoised joint trajectories.

Example:
    >>> import mujoco, numpy as np
    >>> from sysid.record import record_log
    >>> xml = ('<mujoco><option timestep="0.01"/><worldbody><body><joint name="hinge" axis="0 1 0" damping="{}"/>'
    ...        '<geom type="capsule" size=".02" fromto="0 0 0 0 0 -.3" mass=".5"/></body></worldbody>'
    ...        '<actuator><motor name="m" joint="hinge" ctrlrange="-1 1"/></actuator></mujoco>')
    >>> truth = mujoco.MjModel.from_xml_string(xml.format(0.2))
    >>> ctrl = 0.5 * np.sin(np.arange(300) * 0.05)[:, None]
    >>> log = record_log(truth, ctrl, noise_std={"qpos": 1e-3}, rng=np.random.default_rng(0))
    >>> guess = mujoco.MjModel.from_xml_string(xml.format(0.1))
    >>> result = estimate_online(log, guess, "dof_damping[hinge]")
    >>> result.params
    ('dof_damping[hinge]',)
    >>> bool(abs(result.estimate[0] - 0.2) < 3 * result.stderr[0])
    True
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import mujoco
import numpy as np
import scipy.linalg
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from sysid.design import parameter_space
from sysid.params import ParameterSpace

__all__ = ["OnlineEstimator", "OnlineMeasure", "OnlineResult", "estimate_noise_std", "estimate_online"]

OnlineMeasure = Literal["qpos", "state", "sensordata", "qpos+sensordata"]
_MEASURES = ("qpos", "state", "sensordata", "qpos+sensordata")


def estimate_noise_std(y: np.ndarray, order: int = 3) -> np.ndarray:
    """Per-column white-noise sigma of a finely sampled smooth signal, from its ``order``-th differences.

    A k-th difference removes smooth content (it scales as ``dt**k``) and multiplies white noise variance by
    ``binom(2k, k)``; the median absolute deviation keeps the estimate robust to the occasional fast event.

    Args:
        y: ``(T, n)`` samples (``T > order + 1``).
        order: difference order (1..6).

    Returns:
        ``(n,)`` sigmas (a tiny floor of ``1e-9`` keeps them usable as noise levels).

    Example:
        >>> rng = np.random.default_rng(0)
        >>> t = np.linspace(0, 10, 5000)[:, None]
        >>> float(estimate_noise_std(np.sin(t) + rng.normal(0, 0.01, t.shape))[0]).__round__(3)
        0.01
    """
    arr = np.asarray(y, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if isinstance(order, bool) or not isinstance(order, int) or not 1 <= order <= 6:
        raise ValueError(f"`order` must be an int in [1, 6]. Received {order!r}.")
    if arr.ndim != 2 or arr.shape[0] <= order + 1:
        raise ValueError(f"`y` must have shape (T, n) with T > order + 1 = {order + 1}. Received shape {arr.shape}.")
    diff = np.diff(arr, n=order, axis=0)
    mad = np.median(np.abs(diff - np.median(diff, axis=0)), axis=0)
    return np.maximum(1.4826 * mad / math.sqrt(math.comb(2 * order, order)), 1e-9)


@dataclass(frozen=True, eq=False)
class OnlineResult:
    """Joint state-parameter estimates from :func:`estimate_online`.

    Attributes:
        params: scalar parameter addresses, length ``p``.
        estimate: final filtered parameter values, shape ``(p,)``.
        cov: their covariance in the parameters' own units, shape ``(p, p)``.
        history: filtered parameter means after each log row, shape ``(T, p)``.
        history_sd: their standard deviations, shape ``(T, p)``.
        qpos_filtered: filtered joint positions, shape ``(T, nq)``.
        qvel_filtered: filtered joint velocities, shape ``(T, nv)``.
        qpos_smoothed: RTS-smoothed joint positions, shape ``(T, nq)`` (None when smoothing was off).
        qvel_smoothed: RTS-smoothed joint velocities, shape ``(T, nv)`` (None when smoothing was off).
        meas_std: measurement noise sigma used per measured channel, shape ``(ny,)``.
        nis: normalised innovation squared per row (``chi^2`` with ``ny`` dof when the filter is consistent),
            shape ``(T,)``.
        log_likelihood: sum of the innovations' Gaussian log densities.
    """

    params: tuple[str, ...]
    estimate: np.ndarray
    cov: np.ndarray
    history: np.ndarray
    history_sd: np.ndarray
    qpos_filtered: np.ndarray
    qvel_filtered: np.ndarray
    qpos_smoothed: np.ndarray | None
    qvel_smoothed: np.ndarray | None
    meas_std: np.ndarray
    nis: np.ndarray
    log_likelihood: float

    @property
    def stderr(self) -> np.ndarray:
        """Standard errors ``sqrt(diag(cov))``, shape ``(p,)``."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def ci95(self) -> np.ndarray:
        """Normal 95% intervals ``estimate ± 1.96 stderr``, shape ``(p, 2)``."""
        return np.stack([self.estimate - 1.96 * self.stderr, self.estimate + 1.96 * self.stderr], axis=1)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """``{address: {"estimate", "stderr", "ci95": [lo, hi]}}`` (JSON-ready)."""
        return {
            name: {"estimate": float(e), "stderr": float(s), "ci95": [float(lo), float(hi)]}
            for name, e, s, (lo, hi) in zip(self.params, self.estimate, self.stderr, self.ci95, strict=True)
        }


def _positive_std(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"`{name}` must be a finite number >= 0. Received {value!r}.")
    out = float(value)
    if not (math.isfinite(out) and out >= 0):
        raise ValueError(f"`{name}` must be a finite number >= 0. Received {value!r}.")
    return out


class OnlineEstimator:
    """A step-by-step UKF over ``[qpos, qvel, params]`` driven by MuJoCo.

    Call :meth:`reset` with the first measured state, then for every control step :meth:`update` with that
    step's measurement and :meth:`predict` with the command applied until the next one. The model passed in is
    never modified (the filter simulates a private copy).

    Args:
        model: the model at the starting guess; hinge and slide joints only (``nq == nv``), no actuator states.
        params: parameter addresses (a list or one comma-separated string), e.g. ``"dof_damping[*]"``.
        bounds: ``{address or pattern: (low, high)}`` or one pair per ``params`` entry, as in
            :class:`sysid.params.ParameterSpace` (default ``[nominal / 10, nominal * 10]``; needed for a
            non-positive nominal). A positive lower bound puts the parameter in log space.
        n_substeps: physics steps per control step.
        measure: ``"qpos"``, ``"state"`` (qpos and qvel), ``"sensordata"`` or ``"qpos+sensordata"``.
        meas_std: measurement noise sigma: one number or one per measured channel.
        initial: starting parameter values ``(p,)`` or ``{address: value}`` (default: the model's values).
        initial_std: prior sigma of each parameter; relative (a sigma in log space) for log-space parameters,
            absolute for the others. One number or ``(p,)``.
        process_std: per-control-step random-walk sigma of ``(qpos, qvel)`` — model error the filter tolerates.
        param_process_std: per-step random-walk sigma of the parameters (in the filter's units; 0 = constant).
        alpha: sigma-point spread of the scaled unscented transform (0 < alpha <= 1).

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body><joint name="j" damping="0.1"/><geom size=".1"/></body></worldbody>'
        ...     '<actuator><motor joint="j"/></actuator></mujoco>')
        >>> OnlineEstimator(model, "dof_damping[j]", initial=[0.0])
        Traceback (most recent call last):
        ...
        ValueError: `initial` of dof_damping[j] must be > 0: a parameter with a positive lower bound is filtered in \
log space. Received 0.0.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        params: str | Sequence[str],
        *,
        bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None = None,
        n_substeps: int = 1,
        measure: OnlineMeasure = "qpos",
        meas_std: float | Sequence[float] | np.ndarray = 1e-3,
        initial: Sequence[float] | Mapping[str, float] | np.ndarray | None = None,
        initial_std: float | Sequence[float] = 0.5,
        process_std: tuple[float, float] = (1e-6, 1e-4),
        param_process_std: float = 0.0,
        alpha: float = 1.0,
    ) -> None:
        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"`model` must be a mujoco.MjModel. Received {type(model).__name__}.")
        if model.nq != model.nv:
            raise ValueError(
                "`model` must have hinge and slide joints only (nq == nv): the filter averages qpos linearly, "
                f"which quaternions do not allow. Received nq={model.nq}, nv={model.nv}."
            )
        if model.na:
            raise ValueError(f"`model` must have no actuator activations (na == 0). Received na={model.na}.")
        if isinstance(n_substeps, bool) or not isinstance(n_substeps, (int, np.integer)) or n_substeps < 1:
            raise ValueError(f"`n_substeps` must be an int >= 1. Received {n_substeps!r}.")
        if measure not in _MEASURES:
            raise ValueError(f"`measure` must be one of {list(_MEASURES)}. Received {measure!r}.")
        if "sensordata" in measure and model.nsensordata == 0:
            raise ValueError(f"`measure` {measure!r} needs sensors in the model. Received a model with nsensordata=0.")
        isalpha = isinstance(alpha, (int, float)) and not isinstance(alpha, bool)
        if not isalpha or not 0 < alpha <= 1:
            raise ValueError(f"`alpha` must be in (0, 1]. Received {alpha!r}.")
        if not (isinstance(process_std, (tuple, list)) and len(process_std) == 2):
            raise ValueError(f"`process_std` must be a (qpos_std, qvel_std) pair. Received {process_std!r}.")
        q_std = [_positive_std(v, "process_std") for v in process_std]
        p_std = _positive_std(param_process_std, "param_process_std")

        self.model = copy.copy(model)
        self.data = mujoco.MjData(self.model)
        self.pmap: ParameterSpace = parameter_space(self.model, params, bounds)
        self._write = self.pmap.writer(self.model)
        self._lower, self._upper = np.asarray(self.pmap.lower), np.asarray(self.pmap.upper)
        self.n_substeps = int(n_substeps)
        self.measure = measure
        nq, nv, p = model.nq, model.nv, self.pmap.size
        self._nq, self._nv, self._p = nq, nv, p
        self._log = self._lower > 0

        theta0 = self._initial_values(initial)
        sd0 = np.asarray(initial_std, dtype=np.float64)
        sd0 = np.full(p, float(sd0)) if sd0.ndim == 0 else sd0
        if sd0.shape != (p,) or not np.all(np.isfinite(sd0)) or not np.all(sd0 > 0):
            raise ValueError(f"`initial_std` must be a number > 0 or {p} of them. Received {initial_std!r}.")
        self._theta0 = theta0
        self._phi0 = np.where(self._log, np.log(np.where(self._log, theta0, 1.0)), theta0)
        self._phi_sd0 = sd0

        self.ny = {"qpos": nq, "state": nq + nv, "sensordata": model.nsensordata}.get(measure, nq + model.nsensordata)
        sigma = np.asarray(meas_std, dtype=np.float64)
        sigma = np.full(self.ny, float(sigma)) if sigma.ndim == 0 else sigma
        if sigma.shape != (self.ny,) or not np.all(np.isfinite(sigma)) or not np.all(sigma > 0):
            raise ValueError(
                f"`meas_std` must be a number > 0 or {self.ny} of them (one per measured channel). "
                f"Received {meas_std!r}."
            )
        self.meas_std = sigma
        n = nq + nv + p
        points = MerweScaledSigmaPoints(n, alpha=float(alpha), beta=2.0, kappa=0.0, sqrt_method=_psd_sqrt)
        ukf = UnscentedKalmanFilter(n, self.ny, 1.0, self._hx, self._fx, points, sqrt_fn=_psd_sqrt)
        ukf.Q = np.diag(np.concatenate([np.full(nq, q_std[0] ** 2), np.full(nv, q_std[1] ** 2), np.full(p, p_std**2)]))
        ukf.R = np.diag(sigma**2)
        ukf.x = np.concatenate([model.qpos0, np.zeros(nv), self._phi0])
        ukf.P = np.diag(np.concatenate([np.full(nq, 1e-2), np.full(nv, 1e-2), sd0**2]))
        self.ukf = ukf
        self._ctrl = np.zeros(model.nu)
        self._ctrl_table: np.ndarray | None = None
        self._nis = 0.0
        self._loglik = 0.0

    def _initial_values(self, initial: object) -> np.ndarray:
        p = self.pmap.size
        if initial is None:
            theta = self.pmap.nominal.copy()
        elif isinstance(initial, Mapping):
            unknown = sorted(set(initial) - set(self.pmap.addresses))
            missing = [a for a in self.pmap.addresses if a not in initial]
            if unknown or missing:
                raise ValueError(
                    f"`initial` must give a value for exactly {list(self.pmap.addresses)}. Received keys "
                    f"{sorted(initial)} (missing {missing}, unknown {unknown})."
                )
            theta = np.array([float(initial[a]) for a in self.pmap.addresses])
        else:
            theta = np.asarray(initial, dtype=np.float64)
            if theta.shape != (p,):
                raise ValueError(f"`initial` must have shape ({p},) or be a mapping. Received {initial!r}.")
        for name, value, logged in zip(self.pmap.addresses, theta, self._log, strict=True):
            if not math.isfinite(value):
                raise ValueError(f"`initial` of {name} must be finite. Received {value!r}.")
            if logged and value <= 0:
                raise ValueError(
                    f"`initial` of {name} must be > 0: a parameter with a positive lower bound is filtered in log "
                    f"space. Received {float(value)!r}."
                )
        outside = np.flatnonzero((theta < self._lower) | (theta > self._upper))
        if outside.size:
            i = int(outside[0])
            raise ValueError(
                f"`initial` of {self.pmap.addresses[i]} must lie within its bounds [{float(self._lower[i])!r}, "
                f"{float(self._upper[i])!r}] (pass `bounds` to widen them). Received {float(theta[i])!r}."
            )
        return theta

    # --- the filter's models -------------------------------------------------------------------------
    def _theta(self, phi: np.ndarray) -> np.ndarray:
        return np.where(self._log, np.exp(np.clip(phi, -700, 700)), phi)

    def _fx(self, x: np.ndarray, dt: float, ctrl: np.ndarray | None = None) -> np.ndarray:
        # filterpy's RTS smoother calls fx(x, dts[k]) without extra arguments, so the smoother passes the log
        # row index in the ``dt`` slot and the command is looked up from the table; predict passes ``ctrl``.
        if ctrl is None:
            assert self._ctrl_table is not None
            ctrl = self._ctrl_table[int(dt)]
        nq, nv = self._nq, self._nv
        self._write(np.clip(self._theta(x[nq + nv :]), self._lower, self._upper))
        data = self.data
        data.qpos[:] = x[:nq]
        data.qvel[:] = x[nq : nq + nv]
        data.ctrl[:] = ctrl
        warnings = data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
        for _ in range(self.n_substeps):
            mujoco.mj_step(self.model, data)
        if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number != warnings:
            # MuJoCo silently resets an unstable simulation; a reset sigma point would poison the estimate.
            raise FloatingPointError(
                "a sigma point's simulation became unstable (MuJoCo reset it). Try a smaller `initial_std`, tighter "
                "`bounds` or a smaller timestep."
            )
        out = x.copy()
        out[:nq] = data.qpos
        out[nq : nq + nv] = data.qvel
        return out

    def _hx(self, x: np.ndarray) -> np.ndarray:
        nq, nv = self._nq, self._nv
        if self.measure == "qpos":
            return x[:nq].copy()
        if self.measure == "state":
            return x[: nq + nv].copy()
        self._write(np.clip(self._theta(x[nq + nv :]), self._lower, self._upper))
        data = self.data
        data.qpos[:] = x[:nq]
        data.qvel[:] = x[nq : nq + nv]
        data.ctrl[:] = self._ctrl
        mujoco.mj_forward(self.model, data)
        if self.measure == "sensordata":
            return data.sensordata.copy()
        return np.concatenate([x[:nq], data.sensordata])

    # --- public stepping -----------------------------------------------------------------------------
    def reset(
        self, qpos: np.ndarray, qvel: np.ndarray | None = None, qpos_std: float = 1e-3, qvel_std: float = 0.1
    ) -> None:
        """Starts a new episode at ``qpos`` (and ``qvel``, default zeros); parameters keep their estimate.

        The state gets prior sigmas ``qpos_std`` and ``qvel_std`` and no correlation with the parameters.
        """
        nq, nv = self._nq, self._nv
        qpos = np.asarray(qpos, dtype=np.float64)
        qvel = np.zeros(nv) if qvel is None else np.asarray(qvel, dtype=np.float64)
        if qpos.shape != (nq,) or qvel.shape != (nv,):
            raise ValueError(f"`qpos`/`qvel` must have shapes ({nq},)/({nv},). Received {qpos.shape}/{qvel.shape}.")
        ukf = self.ukf
        x = ukf.x.copy()
        x[:nq], x[nq : nq + nv] = qpos, qvel
        P = ukf.P.copy()
        P[: nq + nv, :] = 0.0
        P[:, : nq + nv] = 0.0
        P[:nq, :nq] = np.eye(nq) * _positive_std(qpos_std, "qpos_std") ** 2
        P[nq : nq + nv, nq : nq + nv] = np.eye(nv) * _positive_std(qvel_std, "qvel_std") ** 2
        ukf.x, ukf.P = x, P
        # filterpy's update() reuses the sigma points of the last predict(); a reset must replace them too.
        ukf.sigmas_f = ukf.points_fn.sigma_points(x, P)

    def predict(self, ctrl: np.ndarray) -> None:
        """Propagates the belief through one control step with ``ctrl`` (shape ``(nu,)``) held."""
        self._ctrl = np.asarray(ctrl, dtype=np.float64)
        self.ukf.predict(ctrl=self._ctrl)
        self._check("predict")

    def update(self, z: np.ndarray, ctrl: np.ndarray | None = None) -> None:
        """Corrects the belief with measurement ``z`` (``(ny,)``); ``ctrl`` is the command at this instant
        (only sensor readings that depend on it, e.g. actuator forces, use it)."""
        if ctrl is not None:
            self._ctrl = np.asarray(ctrl, dtype=np.float64)
        ukf = self.ukf
        ukf.update(np.asarray(z, dtype=np.float64))
        ukf.P = 0.5 * (ukf.P + ukf.P.T)
        self._check("update")
        y, s_inv = ukf.y, ukf.SI
        self._nis = float(y @ s_inv @ y)
        sign, logdet = np.linalg.slogdet(ukf.S)
        self._loglik = -0.5 * (self._nis + logdet + len(y) * math.log(2 * math.pi)) if sign > 0 else -math.inf

    def _check(self, stage: str) -> None:
        if not (np.all(np.isfinite(self.ukf.x)) and np.all(np.isfinite(self.ukf.P))):
            raise FloatingPointError(
                f"the UKF diverged in {stage} (non-finite state or covariance). Try a smaller `initial_std`, a "
                "larger `process_std` or check that the log and the model match."
            )

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Current ``(qpos, qvel)`` estimate."""
        nq, nv = self._nq, self._nv
        return self.ukf.x[:nq].copy(), self.ukf.x[nq : nq + nv].copy()

    @property
    def estimate(self) -> np.ndarray:
        """Current parameter estimate in the parameters' own units, shape ``(p,)``."""
        return self._theta(self.ukf.x[self._nq + self._nv :])

    @property
    def cov(self) -> np.ndarray:
        """Current parameter covariance in the parameters' own units, shape ``(p, p)`` (delta method for the
        log-space ones)."""
        k = self._nq + self._nv
        jac = np.where(self._log, self.estimate, 1.0)
        return self.ukf.P[k:, k:] * np.outer(jac, jac)


def _psd_sqrt(matrix: np.ndarray) -> np.ndarray:
    # filterpy wants an upper-triangular factor U with U^T U = P. Round-off can leave P barely indefinite after an
    # update; symmetrise and add the smallest jitter that makes Cholesky succeed instead of failing the run.
    sym = 0.5 * (matrix + matrix.T)
    jitter = 0.0
    scale = float(np.max(np.abs(np.diag(sym)))) or 1.0
    for _ in range(8):
        try:
            return scipy.linalg.cholesky(sym + jitter * np.eye(sym.shape[0]), lower=False)
        except np.linalg.LinAlgError:
            jitter = scale * 1e-12 if jitter == 0.0 else jitter * 100
    raise FloatingPointError("the UKF covariance is not positive definite; the filter diverged.")


def _rows(log: Any, model: mujoco.MjModel, measure: str) -> tuple[np.ndarray, ...]:
    qpos = np.asarray(log.qpos, dtype=np.float64)
    qvel = np.asarray(log.qvel, dtype=np.float64)
    ctrl = np.asarray(log.ctrl, dtype=np.float64)
    sensordata = None if getattr(log, "sensordata", None) is None else np.asarray(log.sensordata, dtype=np.float64)
    widths = {"qpos": (qpos, model.nq), "qvel": (qvel, model.nv), "ctrl": (ctrl, model.nu)}
    if "sensordata" in measure:
        if sensordata is None:
            raise ValueError(f"`measure` {measure!r} needs `sensordata` in the log. Received a log without it.")
        widths["sensordata"] = (sensordata, model.nsensordata)
    for key, (array, width) in widths.items():
        if array.ndim != 2 or array.shape[1] != width or array.shape[0] != qpos.shape[0]:
            raise ValueError(
                f"`log.{key}` must have shape (T, {width}) to match the model. Received shape {array.shape}."
            )
    return qpos, qvel, ctrl, sensordata  # type: ignore[return-value]


def _declared_std(meta: Any, key: str, width: int) -> np.ndarray | None:
    """The sigma of each of a channel's ``width`` columns as the log declares it (``meta["noise_std"]``: one number,
    or one per column as ``record_log`` writes when they differ), NaN where a column declares none (0 or absent);
    None when the log declares nothing usable for the channel."""
    declared = meta.get("noise_std") if isinstance(meta, Mapping) else None
    value = declared.get(key) if isinstance(declared, Mapping) else None
    if isinstance(value, bool) or value is None:
        return None
    try:
        sigma = np.broadcast_to(np.asarray(value, dtype=np.float64), (width,))
    except (TypeError, ValueError):
        return None
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, np.nan)
    return None if np.isnan(sigma).all() else sigma


def _default_meas_std(log: Any, measure: str, qpos: np.ndarray, qvel: np.ndarray, sensordata: Any) -> np.ndarray:
    meta = getattr(log, "meta", None)
    parts = []
    for key, array in (("qpos", qpos), ("qvel", qvel), ("sensordata", sensordata)):
        used = key in measure or (measure == "state" and key in ("qpos", "qvel"))
        if not used:
            continue
        sigma = _declared_std(meta, key, array.shape[1])
        if sigma is None:
            parts.append(estimate_noise_std(array))
        else:  # columns the log declares no sigma for (0: noise-free, or left out) are estimated from the data
            parts.append(np.where(np.isnan(sigma), estimate_noise_std(array), sigma))
    return np.concatenate(parts)


def estimate_online(
    log: Any,
    model: mujoco.MjModel,
    params: str | Sequence[str],
    *,
    bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None = None,
    measure: OnlineMeasure = "qpos",
    meas_std: float | Sequence[float] | None = None,
    initial: Sequence[float] | Mapping[str, float] | np.ndarray | None = None,
    initial_std: float | Sequence[float] = 0.5,
    initial_qvel_std: float | None = None,
    process_std: tuple[float, float] = (1e-6, 1e-4),
    param_process_std: float = 0.0,
    smooth: bool = True,
    alpha: float = 1.0,
) -> OnlineResult:
    """Filters a trajectory log with the joint state-parameter UKF, then RTS-smooths each episode.

    Row ``t`` of the log is the state at ``time[t]`` and the command held over the next control step (the
    :mod:`sysid.logs` convention); the filter corrects with row ``t`` and then predicts through ``ctrl[t]``.
    Each episode restarts the state at its first measured row (velocity from ``qvel``) while the parameters carry
    their belief over.

    Args:
        log: a :class:`sysid.logs.TrajectoryLog` (or anything with ``qpos``, ``qvel``, ``ctrl``, optional
            ``sensordata``, ``episode_bounds()`` and ``meta`` with ``timestep`` and ``control_timestep``).
        model: the model at the starting guess (not modified); must match the log's widths.
        params: parameter addresses, e.g. ``"dof_damping[*]"``.
        bounds: parameter bounds as in :class:`OnlineEstimator` (default ``[nominal / 10, nominal * 10]``).
        measure: ``"qpos"``, ``"state"``, ``"sensordata"`` or ``"qpos+sensordata"``.
        meas_std: measurement sigma (number or per channel). Default: ``meta["noise_std"]`` where the log
            declares it, otherwise estimated from the data's high-order differences.
        initial: starting parameter values (default: the model's).
        initial_std: prior sigma of the parameters (relative for non-negative ones).
        initial_qvel_std: prior sigma of each episode's first velocity (default: the qvel noise the log declares,
            else estimated from the data).
        process_std: per-step random-walk sigma of ``(qpos, qvel)``.
        param_process_std: per-step random-walk sigma of the parameters (0: constant parameters).
        smooth: run the RTS smoother (filterpy ``rts_smoother``) over each episode.
        alpha: sigma-point spread.

    Returns:
        An :class:`OnlineResult`.

    Raises:
        ValueError: widths not matching the model, missing sensordata, bad arguments.
        FloatingPointError: the filter diverged.
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"`model` must be a mujoco.MjModel. Received {type(model).__name__}.")
    meta = getattr(log, "meta", None)
    if not isinstance(meta, Mapping) or "timestep" not in meta or "control_timestep" not in meta:
        raise ValueError(
            "`log.meta` must hold `timestep` and `control_timestep` (seconds). Received a log without them."
        )
    timestep = float(meta["timestep"])
    if abs(timestep - float(model.opt.timestep)) > 1e-9 * timestep:
        raise ValueError(
            f"`log.meta['timestep']` must equal the model's opt.timestep={float(model.opt.timestep)!r}. "
            f"Received {timestep!r}."
        )
    n_substeps = max(1, round(float(meta["control_timestep"]) / timestep))
    qpos, qvel, ctrl, sensordata = _rows(log, model, measure)
    sigma: float | Sequence[float] | np.ndarray = (
        _default_meas_std(log, measure, qpos, qvel, sensordata) if meas_std is None else meas_std
    )
    if initial_qvel_std is None:
        declared = _declared_std(meta, "qvel", qvel.shape[1])
        initial_qvel_std = float(estimate_noise_std(qvel).max() if declared is None else np.nanmax(declared))
    estimator = OnlineEstimator(
        model,
        params,
        bounds=bounds,
        n_substeps=n_substeps,
        measure=measure,
        meas_std=sigma,
        initial=initial,
        initial_std=initial_std,
        process_std=process_std,
        param_process_std=param_process_std,
        alpha=alpha,
    )
    nq, nv, p = model.nq, model.nv, estimator.pmap.size
    if measure == "qpos":
        zs = qpos
    elif measure == "state":
        zs = np.concatenate([qpos, qvel], axis=1)
    elif measure == "sensordata":
        zs = sensordata
    else:
        zs = np.concatenate([qpos, sensordata], axis=1)
    steps = qpos.shape[0]
    episodes: list[tuple[int, int]] = log.episode_bounds() if hasattr(log, "episode_bounds") else [(0, steps)]
    n = nq + nv + p
    xs = np.empty((steps, n))
    ps = np.empty((steps, n, n))
    nis = np.empty(steps)
    loglik = 0.0
    qpos_sd = estimator.meas_std[:nq] if measure in ("qpos", "state", "qpos+sensordata") else np.full(nq, 1e-2)
    for start, stop in episodes:
        estimator.reset(qpos[start], qvel[start], qpos_std=float(np.max(qpos_sd)), qvel_std=float(initial_qvel_std))
        for t in range(start, stop):
            estimator.update(zs[t], ctrl[t])
            xs[t], ps[t] = estimator.ukf.x, estimator.ukf.P
            nis[t] = estimator._nis
            loglik += estimator._loglik
            if t + 1 < stop:
                estimator.predict(ctrl[t])
    k = nq + nv
    jac = np.where(estimator._log[None], estimator._theta(xs[:, k:]), 1.0)
    history = estimator._theta(xs[:, k:])
    history_sd = np.sqrt(np.clip(np.diagonal(ps[:, k:, k:], axis1=1, axis2=2), 0.0, None)) * jac
    qpos_s = qvel_s = None
    if smooth:
        estimator._ctrl_table = ctrl
        smoothed = xs.copy()
        for start, stop in episodes:
            if stop - start < 2:
                continue
            sx, _, _ = estimator.ukf.rts_smoother(xs[start:stop], ps[start:stop], dts=np.arange(start, stop))
            smoothed[start:stop] = sx
        estimator._ctrl_table = None
        qpos_s, qvel_s = smoothed[:, :nq].copy(), smoothed[:, nq:k].copy()
    return OnlineResult(
        params=estimator.pmap.addresses,
        estimate=estimator.estimate,
        cov=estimator.cov,
        history=history,
        history_sd=history_sd,
        qpos_filtered=xs[:, :nq].copy(),
        qvel_filtered=xs[:, nq:k].copy(),
        qpos_smoothed=qpos_s,
        qvel_smoothed=qvel_s,
        meas_std=estimator.meas_std.copy(),
        nis=nis,
        log_likelihood=float(loglik),
    )
