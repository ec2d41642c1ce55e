"""Experiment design: pick the excitation whose data pins the chosen parameters down best (D-optimal).

For each candidate control sequence the measured trajectory's sensitivity to every parameter is taken by
central finite differences through ``mujoco.rollout.rollout`` — one model copy per perturbed parameter, all
candidates and perturbations in one batched, multi-threaded call. With measurement noise ``sigma`` the Fisher
information is ``F = J^T J / sigma^2`` and its inverse is the Cramér–Rao bound on the parameter covariance; the
design maximising ``log det F`` shrinks the joint confidence ellipsoid the most.

Parameters are the addresses of :mod:`randomizers.addressing` (``dof_damping[*]``, ``dof_armature[elbow]``,
``actuator_gain[shoulder]``, ``geom_friction[finger][0]``, ``body_mass[arm]``, ``gravity[z]`` ...), resolved and
written through the same effects the randomisers use (:mod:`randomizers.effects`), so servo bias terms follow
gains and inertias follow masses exactly as they do under randomisation.

Example:
    >>> import mujoco
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><option timestep="0.005"/><worldbody><body><joint name="hinge" damping="0.2"/>'
    ...     '<geom type="capsule" size=".02" fromto="0 0 0 0 0 -.3" mass="0.5"/></body></worldbody>'
    ...     '<actuator><motor name="m" joint="hinge" ctrlrange="-1 1"/></actuator></mujoco>')
    >>> result = design_experiment(model, "dof_damping[*]", n_steps=200, amplitudes=(0.2, 1.0),
    ...                            bands=((0.5, 2.0),), seed=0)
    >>> result.params, result.scores.shape
    (('dof_damping[hinge]',), (2,))
    >>> result.best.amplitude.tolist()  # the larger swing informs damping more
    [1.0]
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, overload

import mujoco
import mujoco.rollout
import numpy as np

from randomizers.parameters import ParameterSet
from sysid.excitation import ExcitationPolicy, SeedOrGenerator, _generator, as_limits, make_excitation
from sysid.params import ParameterSpace

__all__ = [
    "DesignResult",
    "Measure",
    "candidate_grid",
    "design_experiment",
    "fisher_information",
    "parameter_space",
]

Measure = Literal["qpos", "qvel", "state", "sensordata"]
_MEASURES = ("qpos", "qvel", "state", "sensordata")


def _split_params(params: str | Sequence[str]) -> list[str]:
    if isinstance(params, str):
        items = [p.strip() for p in params.split(",")]
    elif isinstance(params, Sequence) and all(isinstance(p, str) for p in params):
        items = [p.strip() for p in params]
    else:
        raise ValueError(f"`params` must be an address or a list of addresses. Received {params!r}.")
    items = [p for p in items if p]
    if not items:
        raise ValueError(f"`params` must name at least one parameter address. Received {params!r}.")
    return items


@overload
def parameter_space(
    model: mujoco.MjModel,
    params: str | Sequence[str] | ParameterSet,
    bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None = None,
    *,
    need_bounds: Literal[True] = True,
) -> ParameterSpace: ...


@overload
def parameter_space(
    model: mujoco.MjModel,
    params: str | Sequence[str] | ParameterSet,
    bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None = None,
    *,
    need_bounds: bool,
) -> ParameterSet: ...


def parameter_space(
    model: mujoco.MjModel,
    params: str | Sequence[str] | ParameterSet,
    bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None = None,
    *,
    need_bounds: bool = True,
) -> ParameterSet:
    """A :class:`sysid.params.ParameterSpace` from addresses given as a list or one comma-separated string.

    With ``need_bounds=False`` (experiment design: the Fisher information is local and ignores bounds) and no
    ``bounds``, the result is a bare :class:`randomizers.parameters.ParameterSet` (no bounds at all), so
    parameters with a zero or negative nominal need none.

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body name="arm"><joint name="shoulder"/><geom size=".1"/>'
        ...     '</body></worldbody></mujoco>')
        >>> parameter_space(model, "dof_damping[*], body_mass[arm]", need_bounds=False).addresses
        ('dof_damping[shoulder]', 'body_mass[arm]')
        >>> parameter_space(model, "dof_damping[elbow]")
        Traceback (most recent call last):
        ...
        ValueError: `params` entry 'dof_damping[elbow]': `joints` pattern 'elbow' matches no joint in the model. \
Known joints: 'shoulder'.
    """
    if isinstance(params, ParameterSet):
        return params
    items = _split_params(params)
    if bounds is None and not need_bounds:
        return ParameterSet(model, items)
    return ParameterSpace(model, items, bounds)


def _fd_steps(nominal: np.ndarray, rel_step: float) -> np.ndarray:
    # Relative steps keep the truncation/rounding balance independent of units; a zero nominal has no scale,
    # so it takes the relative step itself as an absolute one.
    return np.where(nominal != 0, rel_step * np.abs(nominal), rel_step)


def _measure_slices(model: mujoco.MjModel, measure: str) -> tuple[slice | None, int]:
    if measure not in _MEASURES:
        raise ValueError(f"`measure` must be one of {list(_MEASURES)}. Received {measure!r}.")
    first = 1  # mjSTATE_FULLPHYSICS starts with time
    if measure == "qpos":
        return slice(first, first + model.nq), model.nq
    if measure == "qvel":
        return slice(first + model.nq, first + model.nq + model.nv), model.nv
    if measure == "state":
        return slice(first, first + model.nq + model.nv), model.nq + model.nv
    if model.nsensordata == 0:
        raise ValueError("`measure` 'sensordata' needs sensors in the model. Received a model with nsensordata=0.")
    return None, model.nsensordata


def _noise_vector(noise_std: float | Sequence[float], ny: int) -> np.ndarray:
    arr = np.asarray(noise_std, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(ny, float(arr))
    if arr.shape != (ny,) or not np.all(np.isfinite(arr)) or not np.all(arr > 0):
        raise ValueError(
            f"`noise_std` must be a number > 0 or {ny} of them (one per measured channel). Received {noise_std!r}."
        )
    return arr


def _initial_state(model: mujoco.MjModel, qpos: Any, qvel: Any) -> np.ndarray:
    data = mujoco.MjData(model)
    if qpos is not None:
        arr = np.asarray(qpos, dtype=np.float64)
        if arr.shape != (model.nq,):
            raise ValueError(f"`initial_qpos` must have shape ({model.nq},). Received shape {arr.shape}.")
        data.qpos[:] = arr
    if qvel is not None:
        arr = np.asarray(qvel, dtype=np.float64)
        if arr.shape != (model.nv,):
            raise ValueError(f"`initial_qvel` must have shape ({model.nv},). Received shape {arr.shape}.")
        data.qvel[:] = arr
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    return state


def _controls_of(candidate: object, n_steps: int, dt: float, nu: int, i: int) -> np.ndarray:
    if isinstance(candidate, ExcitationPolicy):
        if candidate.nu != nu:
            raise ValueError(f"`candidates[{i}]` drives {candidate.nu} actuators; the model has nu={nu}.")
        return candidate.signal(n_steps, dt)
    arr = np.asarray(candidate, dtype=np.float64)
    if arr.shape != (n_steps, nu) or not np.all(np.isfinite(arr)):
        raise ValueError(
            f"`candidates[{i}]` must be an ExcitationPolicy or a finite array of shape (n_steps, nu) = "
            f"({n_steps}, {nu}). Received shape {arr.shape}."
        )
    return arr


def fisher_information(
    model: mujoco.MjModel,
    params: str | Sequence[str] | ParameterSet,
    controls: np.ndarray,
    *,
    n_substeps: int = 1,
    measure: Measure = "qpos",
    noise_std: float | Sequence[float] = 1e-3,
    initial_qpos: Any = None,
    initial_qvel: Any = None,
    rel_step: float = 1e-4,
    nthread: int | None = None,
) -> np.ndarray:
    """Fisher information ``J^T J`` (noise-weighted) of one or several control sequences.

    Args:
        model: the model at the nominal parameters (not modified).
        params: addresses (a list or one comma-separated string) or a :class:`sysid.params.ParameterSpace`.
        controls: ``(T, nu)`` or ``(C, T, nu)`` controls at the control rate (held for ``n_substeps``).
        n_substeps: physics steps per control step.
        measure: what is observed after each control step: ``"qpos"``, ``"qvel"``, ``"state"`` (both) or
            ``"sensordata"``.
        noise_std: measurement noise sigma, one number or one per measured channel.
        initial_qpos: ``(nq,)`` start pose (default ``model.qpos0``).
        initial_qvel: ``(nv,)`` start velocity (default zeros).
        rel_step: central-difference step relative to each nominal value.
        nthread: rollout threads (default: the CPU count).

    Returns:
        ``(p, p)`` for one sequence or ``(C, p, p)`` for several.
    """
    pmap = parameter_space(model, params, need_bounds=False)
    arr = np.asarray(controls, dtype=np.float64)
    single = arr.ndim == 2
    if single:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[2] != model.nu or arr.shape[1] < 1:
        raise ValueError(f"`controls` must have shape (T, nu) or (C, T, nu) with nu={model.nu}. Received {arr.shape}.")
    fisher = _fisher_batch(
        model, pmap, arr, n_substeps, measure, noise_std, initial_qpos, initial_qvel, rel_step, nthread
    )
    return fisher[0] if single else fisher


def _fisher_batch(
    model: mujoco.MjModel,
    pmap: ParameterSet,
    controls: np.ndarray,
    n_substeps: int,
    measure: str,
    noise_std: float | Sequence[float],
    initial_qpos: Any,
    initial_qvel: Any,
    rel_step: float,
    nthread: int | None,
) -> np.ndarray:
    if isinstance(n_substeps, bool) or not isinstance(n_substeps, (int, np.integer)) or n_substeps < 1:
        raise ValueError(f"`n_substeps` must be an int >= 1. Received {n_substeps!r}.")
    if isinstance(rel_step, bool) or not isinstance(rel_step, (int, float)) or not (0 < rel_step < 0.1):
        raise ValueError(f"`rel_step` must be in (0, 0.1). Received {rel_step!r}.")
    cols, ny = _measure_slices(model, measure)
    sigma = _noise_vector(noise_std, ny)
    p = pmap.size
    steps = _fd_steps(pmap.nominal, rel_step)
    # One model per parameter set: +h and -h for each parameter (central differences need no nominal run).
    models: list[mujoco.MjModel] = []
    for i in range(p):
        for sign in (1.0, -1.0):
            twin = copy.copy(model)
            values = pmap.nominal.copy()
            values[i] += sign * steps[i]
            pmap.writer(twin)(values)
            models.append(twin)
    n_models = len(models)
    n_cand = controls.shape[0]
    state0 = _initial_state(model, initial_qpos, initial_qvel)
    batch_models = models * n_cand
    applied = np.repeat(np.repeat(controls, n_models, axis=0), n_substeps, axis=1)
    threads = max(1, min(nthread or os.cpu_count() or 1, len(batch_models)))
    datas = [mujoco.MjData(model) for _ in range(threads)]
    state, sensordata = mujoco.rollout.rollout(batch_models, datas, state0[None], applied)
    # Measured: the state at the end of each control step. rollout's sensordata of a step is evaluated before
    # integrating it, so the reading after control step k sits at the start of step k + 1 (the last is never made).
    y = state[:, n_substeps - 1 :: n_substeps, cols] if cols is not None else sensordata[:, n_substeps::n_substeps]
    y = y.reshape(n_cand, n_models, -1, ny) / sigma
    plus, minus = y[:, 0::2], y[:, 1::2]
    jac = (plus - minus) / (2 * steps[None, :, None, None])  # (C, p, T, ny)
    jac = jac.reshape(n_cand, p, -1)
    if not np.all(np.isfinite(jac)):
        raise FloatingPointError(
            "the finite-difference sensitivities are not finite: a rollout diverged. Lower the amplitudes or "
            "check the model's timestep."
        )
    return np.einsum("cpt,cqt->cpq", jac, jac)


def _logdet(fisher: np.ndarray) -> float:
    if fisher.size == 0:
        return 0.0
    # Scale to a unit diagonal first so a badly conditioned but non-singular matrix keeps its log det.
    d = np.sqrt(np.clip(np.diag(fisher), 0.0, None))
    if np.any(d == 0):
        return -math.inf
    sign, value = np.linalg.slogdet(fisher / np.outer(d, d))
    if sign <= 0:
        return -math.inf
    return float(value + 2 * np.log(d).sum())


@dataclass(frozen=True, eq=False)
class DesignResult:
    """The outcome of :func:`design_experiment`.

    Attributes:
        params: the scalar parameter addresses, length ``p``.
        nominal: nominal parameter values, shape ``(p,)``.
        candidates: the designs compared (excitation policies or ``(n_steps, nu)`` arrays), length ``C``.
        scores: ``log det`` of each candidate's Fisher information, shape ``(C,)`` (``-inf`` when singular).
        fisher: each candidate's Fisher information in the parameters' own units, shape ``(C, p, p)``.
        best_index: index of the highest score.
        n_steps: control steps per experiment.
        control_timestep: seconds per control step.
    """

    params: tuple[str, ...]
    nominal: np.ndarray
    candidates: tuple[Any, ...]
    scores: np.ndarray
    fisher: np.ndarray
    best_index: int
    n_steps: int
    control_timestep: float

    @property
    def best(self) -> Any:
        """The chosen design."""
        return self.candidates[self.best_index]

    @property
    def logdet(self) -> float:
        """``log det`` of the chosen design's Fisher information."""
        return float(self.scores[self.best_index])

    @property
    def crlb_sd(self) -> np.ndarray:
        """Cramér–Rao lower bound on each parameter's standard deviation under the chosen design, ``(p,)``
        (``inf`` where the design cannot identify it)."""
        fisher = self.fisher[self.best_index]
        if not math.isfinite(self.logdet):
            return np.full(len(self.params), math.inf)
        return np.sqrt(np.diag(np.linalg.inv(fisher)))

    def controls(self) -> np.ndarray:
        """The chosen design's controls, shape ``(n_steps, nu)``."""
        best = self.best
        if isinstance(best, ExcitationPolicy):
            return best.signal(self.n_steps, self.control_timestep)
        return np.asarray(best, dtype=np.float64)


def candidate_grid(
    kind: str,
    limits: object,
    *,
    amplitudes: Sequence[float],
    bands: Sequence[tuple[float, float]],
    duration: float,
    seed: SeedOrGenerator = 0,
    **kwargs: Any,
) -> list[ExcitationPolicy]:
    """Excitations of one ``kind`` over every (amplitude, band) pair, amplitude-major.

    ``band = (f_low, f_high)`` maps to each kind's own knobs: a multisine's ``band``; a chirp sweeping
    ``f_low -> f_high`` over ``duration``; a PRBS with ``f_max = f_high``; random steps held for
    ``0.443 / f_high`` s (the same 3 dB edge as a PRBS). All candidates draw from one seeded stream.

    Example:
        >>> grid = candidate_grid("prbs", ([-1.0], [1.0]), amplitudes=(0.5, 1.0), bands=((0.1, 2.0),), duration=5.0)
        >>> [(float(c.amplitude[0]), round(c.f_max, 3)) for c in grid]
        [(0.5, 2.0), (1.0, 2.0)]
    """
    gen = _generator(seed)
    out: list[ExcitationPolicy] = []
    for amplitude in amplitudes:
        for band in bands:
            if not (isinstance(band, (tuple, list)) and len(band) == 2):
                raise ValueError(f"`bands` must hold (f_low, f_high) pairs. Received {band!r}.")
            lo, hi = float(band[0]), float(band[1])
            if kind == "multisine":
                extra: dict[str, Any] = {"band": (lo, hi)}
            elif kind == "chirp":
                extra = {"f0": lo, "f1": hi, "duration": duration}
            elif kind == "prbs":
                extra = {"f_max": hi}
            elif kind == "random":
                extra = {"hold": 0.443 / hi}
            else:
                extra = {}
            out.append(make_excitation(kind, limits, amplitude=amplitude, seed=gen, **extra, **kwargs))
    return out


def design_experiment(
    model: mujoco.MjModel,
    params: str | Sequence[str],
    candidates: Sequence[Any] | None = None,
    *,
    n_steps: int = 500,
    n_substeps: int = 1,
    kind: str = "multisine",
    amplitudes: Sequence[float] = (0.25, 0.5, 1.0),
    bands: Sequence[tuple[float, float]] = ((0.2, 1.0), (0.2, 3.0), (0.5, 8.0)),
    measure: Measure = "qpos",
    noise_std: float | Sequence[float] = 1e-3,
    initial_qpos: Any = None,
    initial_qvel: Any = None,
    center: Any = None,
    rel_step: float = 1e-4,
    seed: SeedOrGenerator = 0,
    nthread: int | None = None,
) -> DesignResult:
    """Scores candidate experiments by ``log det`` of their Fisher information and picks the best (D-optimal).

    Args:
        model: the model at the nominal (best guess) parameters; not modified.
        params: parameter addresses (patterns allowed), e.g. ``"dof_damping[*]"``.
        candidates: excitation policies and/or ``(n_steps, nu)`` control arrays to compare. Default: a
            :func:`candidate_grid` of ``kind`` over ``amplitudes`` x ``bands`` within the model's actuator limits.
        n_steps: control steps per experiment.
        n_substeps: physics steps per control step (``control_timestep = n_substeps * opt.timestep``).
        kind: excitation kind of the default grid: ``"multisine"``, ``"chirp"``, ``"prbs"`` or ``"random"``.
        amplitudes: amplitude fractions of the default grid, each in ``(0, 1]``.
        bands: ``(f_low, f_high)`` Hz pairs of the default grid.
        measure: observed channels: ``"qpos"``, ``"qvel"``, ``"state"`` or ``"sensordata"``.
        noise_std: measurement noise sigma (one number or one per channel).
        initial_qpos: ``(nq,)`` start pose (default ``model.qpos0``).
        initial_qvel: ``(nv,)`` start velocity (default zeros).
        center: centre of each actuator's swing for the default grid (e.g. a servo home pose).
        rel_step: relative central-difference step.
        seed: seeds the default grid (ignored when ``candidates`` are given).
        nthread: rollout threads (default: the CPU count).

    Returns:
        A :class:`DesignResult`; ``result.best`` is the chosen design and ``result.crlb_sd`` its Cramér–Rao bound.

    Raises:
        ValueError: bad addresses, an empty candidate list, a candidate of the wrong shape, bad ``measure``.

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body><joint name="j" damping="0.1"/><geom size=".1" pos="0 0 -.2"/></body>'
        ...     '</worldbody><actuator><motor joint="j" ctrlrange="-1 1"/></actuator></mujoco>')
        >>> design_experiment(model, "dof_damping[*]", candidates=[])
        Traceback (most recent call last):
        ...
        ValueError: `candidates` must hold at least one design. Received an empty sequence.
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"`model` must be a mujoco.MjModel. Received {type(model).__name__}.")
    if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)) or n_steps < 2:
        raise ValueError(f"`n_steps` must be an int >= 2. Received {n_steps!r}.")
    pmap = parameter_space(model, params, need_bounds=False)
    dt = float(model.opt.timestep) * int(n_substeps)
    if candidates is None:
        limits = as_limits(model, center)
        candidates = candidate_grid(kind, limits, amplitudes=amplitudes, bands=bands, duration=n_steps * dt, seed=seed)
    candidates = tuple(candidates)
    if not candidates:
        raise ValueError("`candidates` must hold at least one design. Received an empty sequence.")
    controls = np.stack([_controls_of(c, int(n_steps), dt, model.nu, i) for i, c in enumerate(candidates)])
    fisher = _fisher_batch(
        model, pmap, controls, n_substeps, measure, noise_std, initial_qpos, initial_qvel, rel_step, nthread
    )
    scores = np.array([_logdet(f) for f in fisher])
    finite = np.isfinite(scores)
    best = int(np.argmax(np.where(finite, scores, -np.inf))) if finite.any() else 0
    return DesignResult(
        params=pmap.addresses,
        nominal=pmap.nominal.copy(),
        candidates=candidates,
        scores=scores,
        fisher=fisher,
        best_index=best,
        n_steps=int(n_steps),
        control_timestep=dt,
    )
