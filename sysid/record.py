"""Simulated trajectory logs: :func:`record_log` rolls a model out open loop under given commands (MuJoCo's threaded
``mujoco.rollout``), with action and observation latency and Gaussian sensor noise (one sigma, one per channel or one
per entry), and returns a validated :class:`~sysid.logs.TrajectoryLog` whose ``meta`` holds the truth.

Example:
    >>> import mujoco, numpy as np
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body><joint name="hinge" damping="0.1"/>'
    ...     '<geom size=".1" pos="0 0 -.2"/></body></worldbody>'
    ...     '<actuator><motor name="m" joint="hinge"/></actuator></mujoco>')
    >>> log = record_log(model, np.full((20, 1), 0.5), n_substeps=5, noise_std={"qpos": 1e-3},
    ...                  rng=np.random.default_rng(0))
    >>> log.meta["noise_std"]["qpos"], log.qpos.shape
    (0.001, (20, 1))
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import mujoco.rollout
import numpy as np

from noise_models.timing import convert_time
from sysid.logs import TrajectoryLog, _jsonable, channel_names

__all__ = ["NoiseStd", "record_log"]


#: The measured channels ``noise_std`` may name, with the model width each per-entry array must have.
_NOISE_CHANNELS: tuple[tuple[str, str], ...] = (("qpos", "nq"), ("qvel", "nv"), ("sensordata", "nsensordata"))

#: ``noise_std`` of :func:`record_log`: one sigma, or per channel one sigma or one sigma per entry.
NoiseStd = float | Mapping[str, float | Sequence[float] | np.ndarray]


def _noise_for(noise_std: NoiseStd | None, key: str, model: mujoco.MjModel) -> float | np.ndarray:
    """The sigma of channel ``key``: a float (the same for every entry), or a (width,) array of per-entry sigmas
    when they differ (an array of equal values becomes its float, so it draws exactly what the float draws)."""
    if noise_std is None:
        return 0.0
    if isinstance(noise_std, Mapping):
        allowed = [name for name, _ in _NOISE_CHANNELS]
        unknown = [k for k in noise_std if k not in allowed]
        if unknown:
            raise ValueError(
                f"`noise_std` keys must be among {', '.join(repr(a) for a in allowed)}. Received {unknown[0]!r}."
            )
        value = noise_std.get(key, 0.0)
    else:
        value = noise_std
    width_name = dict(_NOISE_CHANNELS)[key]
    width = int(getattr(model, width_name))
    allowed_text = f"a finite number >= 0 or a 1-D array of {width_name}={width} finite numbers >= 0"
    if isinstance(value, (bool, str, bytes)):
        raise ValueError(f"`noise_std` for {key!r} must be {allowed_text}. Received {value!r}.")
    if isinstance(value, (int, float, np.integer, np.floating)):
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"`noise_std` for {key!r} must be {allowed_text}. Received {value!r}.")
        return float(value)
    if not isinstance(noise_std, Mapping):  # one sigma for every channel; per-entry arrays go per channel
        raise ValueError(
            "`noise_std` must be a finite number >= 0 or a mapping of 'qpos', 'qvel', 'sensordata' to sigmas. "
            f"Received {type(value).__name__}."
        )
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`noise_std` for {key!r} must be {allowed_text}. Received {value!r}.") from err
    if array.ndim != 1 or array.shape[0] != width:
        raise ValueError(f"`noise_std` for {key!r} must be {allowed_text}. Received shape {array.shape}.")
    bad = np.flatnonzero(~np.isfinite(array) | (array < 0))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"`noise_std` for {key!r} must be {allowed_text}. Received {float(array[i])!r} at entry {i}.")
    if width and np.all(array == array[0]):
        return float(array[0])
    return 0.0 if not width else array.copy()


def record_log(
    model: mujoco.MjModel,
    ctrl: np.ndarray,
    *,
    n_substeps: int = 1,
    initial_qpos: np.ndarray | None = None,
    initial_qvel: np.ndarray | None = None,
    action_latency: int = 0,
    initial_ctrl: np.ndarray | None = None,
    obs_latency: int = 0,
    noise_std: NoiseStd | None = None,
    rng: np.random.Generator | None = None,
    task: str = "",
    true_params: Mapping[str, float] | None = None,
    nthread: int | None = None,
) -> TrajectoryLog:
    """Simulates ``model`` open loop under ``ctrl`` (through ``mujoco.rollout``) and logs it.

    The physics sees ``ctrl[t - action_latency]`` during control step ``t`` and ``initial_ctrl`` before the first
    command arrives (default zeros, a suite task's reset command, and what ``sim2real record`` logs; sim2real's
    latency wrapper holds the env's own reset command, for an MJCF arm with servos its home keyframe's set points:
    pass it to log that; :func:`sysid.fit` predicts no row from those steps); ``sensordata[t]`` is
    the reading of the state ``obs_latency`` control steps earlier (the first reading repeats before that). Gaussian noise of ``noise_std`` is added to ``qpos``, ``qvel`` and
    ``sensordata`` after that (``ctrl`` is logged as commanded, without noise).

    Args:
        model: the model to simulate (not modified).
        ctrl: (T, nu) for one episode or (E, T, nu) for E episodes of equal length.
        n_substeps: physics steps per control step; ``control_timestep = n_substeps * opt.timestep``.
        initial_qpos: (nq,) or (E, nq); defaults to ``model.qpos0``.
        initial_qvel: (nv,) or (E, nv); defaults to zeros.
        action_latency: whole control steps between command and actuation (>= 0).
        initial_ctrl: (nu,) or (E, nu), the command the actuators hold until the first one arrives (with
            ``action_latency`` > 0; stored in ``meta["initial_ctrl"]``); defaults to zeros.
        obs_latency: whole control steps by which ``sensordata`` lags the state (>= 0).
        noise_std: one sigma for every measured channel, or ``{"qpos": s, "qvel": s, "sensordata": s}`` where each
            ``s`` is one sigma for the channel or a 1-D array of one sigma per entry (nq for ``qpos``, nv for
            ``qvel``, nsensordata for ``sensordata``; see :func:`channel_names` for the order): a hinge's entries
            in rad and rad/s, a slide's in m and m/s. A channel left out gets no noise. Stored per entry in
            ``meta["noise_std_per_entry"]``.
        rng: the Generator for the noise (required when any sigma is > 0).
        task: stored in ``meta["task"]``.
        true_params: stored in ``meta["true_params"]`` (ground truth for tests and benchmarks).
        nthread: rollout threads (default ``os.cpu_count()``).

    Returns:
        A validated :class:`TrajectoryLog` with ``episode`` set when E > 1.
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"`model` must be a mujoco.MjModel. Received {type(model).__name__}.")
    controls = np.asarray(ctrl, dtype=np.float64)
    if controls.ndim == 2:
        controls = controls[None]
    if controls.ndim != 3 or controls.shape[2] != model.nu or controls.shape[1] < 2:
        raise ValueError(
            f"`ctrl` must have shape (T, nu) or (E, T, nu) with nu={model.nu} and T >= 2. Received shape "
            f"{np.shape(ctrl)}."
        )
    if not np.all(np.isfinite(controls)):
        raise ValueError("`ctrl` must be finite. Received NaN or inf.")
    for name, value in (("n_substeps", n_substeps), ("action_latency", action_latency), ("obs_latency", obs_latency)):
        low = 1 if name == "n_substeps" else 0
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"`{name}` must be an int >= {low}. Received {value!r}.")
    if obs_latency and not model.nsensordata:  # the log would claim a lag that nothing shows
        raise ValueError(
            "`obs_latency` delays the model's sensordata (qpos and qvel are the true state), and this model has no "
            f"sensors. Received {obs_latency!r}; give 0, or add <sensor> elements to the MJCF."
        )
    episodes, steps, _ = controls.shape
    sigmas = {key: _noise_for(noise_std, key, model) for key, _ in _NOISE_CHANNELS}
    if any(np.any(s > 0) for s in sigmas.values()) and not isinstance(rng, np.random.Generator):
        raise ValueError(f"`rng` must be a numpy Generator when `noise_std` > 0. Received {rng!r}.")

    def initial(value: np.ndarray | None, default: np.ndarray, name: str) -> np.ndarray:
        if value is None:
            return np.tile(default, (episodes, 1))
        array = np.asarray(value, dtype=np.float64)
        array = np.tile(array, (episodes, 1)) if array.ndim == 1 else array
        if array.shape != (episodes, default.shape[0]):
            raise ValueError(
                f"`{name}` must have shape ({default.shape[0]},) or ({episodes}, {default.shape[0]}). "
                f"Received shape {np.shape(value)}."
            )
        return array

    qpos0 = initial(initial_qpos, model.qpos0.copy(), "initial_qpos")
    qvel0 = initial(initial_qvel, np.zeros(model.nv), "initial_qvel")
    hold = initial(initial_ctrl, np.zeros(model.nu), "initial_ctrl")
    if not np.all(np.isfinite(hold)):
        raise ValueError("`initial_ctrl` must be finite. Received NaN or inf.")
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    data = mujoco.MjData(model)
    states = np.empty((episodes, mujoco.mj_stateSize(model, spec)))
    for e in range(episodes):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = qpos0[e]
        data.qvel[:] = qvel0[e]
        mujoco.mj_getState(model, data, states[e], spec)
    # The physics sees the command issued ``action_latency`` control steps earlier; before the first one arrives,
    # the command held at reset.
    source = np.arange(steps) - action_latency
    applied = np.where((source >= 0)[None, :, None], controls[:, np.clip(source, 0, None)], hold[:, None, :])
    applied = np.repeat(applied, n_substeps, axis=1)
    threads = nthread or os.cpu_count() or 1
    datas = [mujoco.MjData(model) for _ in range(min(threads, episodes))]
    nstep = steps * n_substeps
    state_out, sensor_out = mujoco.rollout.rollout(model, datas, states, applied, nstep=nstep)
    # rollout returns the state after each physics step; row t of the log is the state before step t.
    trajectory = np.concatenate([states[:, None], state_out[:, n_substeps - 1 : -1 : n_substeps]], axis=1)
    offset = 1  # mjSTATE_TIME comes first
    qpos = trajectory[:, :, offset : offset + model.nq].copy()
    qvel = trajectory[:, :, offset + model.nq : offset + model.nq + model.nv].copy()
    time = trajectory[:, :, 0].copy()
    sensordata = None
    if model.nsensordata:
        # rollout's sensordata of step n is evaluated at the state before step n.
        sensordata = sensor_out[:, ::n_substeps].copy()
        lagged = np.clip(np.arange(steps) - obs_latency, 0, None)
        sensordata = sensordata[:, lagged]
    act = None
    if model.na:
        start = offset + model.nq + model.nv
        act = trajectory[:, :, start : start + model.na].copy()
    measured = {"qpos": qpos, "qvel": qvel, "sensordata": sensordata}
    for key, sigma in sigmas.items():
        clean = measured[key]
        if np.any(sigma > 0) and clean is not None:
            assert rng is not None
            # a (width,) sigma broadcasts over the last axis: entry k of every row gets sigma[k]
            measured[key] = clean + rng.normal(0.0, sigma, size=clean.shape)
    names = channel_names(model)
    meta: dict[str, Any] = {
        "task": task,
        "timestep": float(model.opt.timestep),
        "control_timestep": float(model.opt.timestep) * n_substeps,
        "joint_names": [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}" for j in range(model.njnt)],
        "actuator_names": [n[5:-1] for n in names["ctrl"]],
        "sensor_names": names["sensordata"],
        "true_latency_seconds": {
            side: convert_time(
                steps_, "control_steps", "seconds", timestep=float(model.opt.timestep), substeps=n_substeps
            )
            for side, steps_ in (("action", action_latency), ("obs", obs_latency))
        },
        # one number per channel when its entries share it (what older logs hold), else the per-entry list
        "noise_std": {key: _jsonable(sigma) for key, sigma in sigmas.items()},
        "noise_std_per_entry": {
            key: np.broadcast_to(sigmas[key], (int(getattr(model, width)),)).tolist() for key, width in _NOISE_CHANNELS
        },
    }
    if action_latency and initial_ctrl is not None:
        meta["initial_ctrl"] = hold.tolist()
    if true_params is not None:
        meta["true_params"] = {str(k): float(v) for k, v in true_params.items()}

    def flat(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else a.reshape(episodes * steps, *a.shape[2:])

    return TrajectoryLog(
        time=flat(time),  # type: ignore[arg-type]
        qpos=flat(measured["qpos"]),  # type: ignore[arg-type]
        qvel=flat(measured["qvel"]),  # type: ignore[arg-type]
        ctrl=flat(controls),  # type: ignore[arg-type]
        sensordata=flat(measured["sensordata"]),
        episode=np.repeat(np.arange(episodes), steps) if episodes > 1 else None,
        act=flat(act),
        meta=meta,
    )
