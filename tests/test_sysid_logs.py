"""Trajectory logs: round trips, the recorder against a Python mj_step loop, and one pinned message per bad log."""

from __future__ import annotations

import os
import re

import mujoco
import numpy as np
import pytest

from sysid import LogError, TrajectoryLog, channel_names, load_csv, load_log, record_log, save_log, validate_log

ARM = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" axis="0 1 0" damping="0.2"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body name="lower" pos="0.3 0 0">
        <joint name="elbow" axis="0 1 0" damping="0.1"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.025"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="shoulder" joint="shoulder" gear="1"/>
    <position name="elbow" joint="elbow" kp="4"/>
  </actuator>
  <sensor><jointpos name="elbow_angle" joint="elbow"/><actuatorfrc name="elbow_force" actuator="elbow"/></sensor>
</mujoco>
"""


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(ARM)


@pytest.fixture(scope="module")
def log(model: mujoco.MjModel) -> TrajectoryLog:
    ctrl = np.random.default_rng(0).normal(0.0, 0.3, size=(40, 2))
    return record_log(model, ctrl, n_substeps=2, task="arm")


def _arrays(log: TrajectoryLog) -> dict[str, np.ndarray]:
    return dict(log.to_arrays())


def _write(tmp_path, arrays: dict[str, np.ndarray]) -> str:
    path = os.path.join(tmp_path, "bad.npz")
    np.savez(path, **arrays)
    return path


def test_record_matches_python_step_loop(model: mujoco.MjModel) -> None:
    ctrl = np.random.default_rng(1).normal(0.0, 0.5, size=(30, 2))
    log = record_log(model, ctrl, n_substeps=3, action_latency=2, obs_latency=1)
    data = mujoco.MjData(model)
    qpos, sensors = [], []
    for t in range(30):
        qpos.append(data.qpos.copy())
        data.ctrl[:] = ctrl[t - 2] if t >= 2 else 0.0  # the reset command until the first one arrives
        for k in range(3):
            mujoco.mj_step(model, data)
            if k == 0:
                sensors.append(data.sensordata.copy())
    np.testing.assert_array_equal(log.qpos, np.array(qpos))
    np.testing.assert_array_equal(log.sensordata, np.array(sensors)[np.clip(np.arange(30) - 1, 0, None)])
    assert log.meta["control_timestep"] == pytest.approx(0.015)
    assert log.meta["true_latency_seconds"] == {"action": pytest.approx(0.03), "obs": pytest.approx(0.015)}
    legacy = TrajectoryLog(
        time=log.time,
        qpos=log.qpos,
        qvel=log.qvel,
        ctrl=log.ctrl,
        meta={
            **{k: v for k, v in log.meta.items() if k != "true_latency_seconds"},
            "true_latency_steps": {"action": 2, "obs": 1},
        },
    )  # an older log: latency in control steps, read as seconds
    assert legacy.meta["true_latency_seconds"] == {"action": pytest.approx(0.03), "obs": pytest.approx(0.015)}


def test_round_trip_and_atomic_write(tmp_path, log: TrajectoryLog, model: mujoco.MjModel) -> None:
    path = os.path.join(tmp_path, "sub", "log.npz")
    save_log(log, path)
    assert sorted(os.listdir(os.path.dirname(path))) == ["log.npz"]  # no temp file left behind
    back = load_log(path, model=model)
    for key in ("time", "qpos", "qvel", "ctrl", "sensordata"):
        np.testing.assert_array_equal(getattr(back, key), getattr(log, key))
    assert back.meta == log.meta
    assert not back.qpos.flags.writeable


def test_episodes_and_noise(model: mujoco.MjModel) -> None:
    ctrl = np.zeros((3, 10, 2))
    with pytest.raises(
        ValueError, match=re.escape("`rng` must be a numpy Generator when `noise_std` > 0. Received None.")
    ):
        record_log(model, ctrl, noise_std=0.1)
    log = record_log(model, ctrl, noise_std={"qpos": 0.01}, rng=np.random.default_rng(0))
    clean = record_log(model, ctrl)
    assert log.episode_bounds() == [(0, 10), (10, 20), (20, 30)]
    assert 0.005 < np.std(log.qpos - clean.qpos) < 0.02
    np.testing.assert_array_equal(log.qvel, clean.qvel)


def test_missing_key(tmp_path, log: TrajectoryLog) -> None:
    arrays = _arrays(log)
    del arrays["qvel"]
    path = _write(tmp_path, arrays)
    msg = (
        f"`qvel` is missing from {path!r}; a log needs keys time, qpos, qvel, ctrl, meta. "
        "Received keys ctrl, meta, qpos, sensordata, time."
    )
    with pytest.raises(LogError, match=re.escape(msg)):
        load_log(path)


def test_wrong_shape(tmp_path, log: TrajectoryLog) -> None:
    arrays = _arrays(log)
    arrays["qpos"] = arrays["qpos"][:-1]
    path = _write(tmp_path, arrays)
    msg = f"{path}: `qpos` must have shape (T, nq) with T = len(time) = 40. Received shape (39, 2)."
    with pytest.raises(LogError, match=re.escape(msg)):
        load_log(path)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite(tmp_path, log: TrajectoryLog, bad: float) -> None:
    arrays = _arrays(log)
    arrays["ctrl"] = arrays["ctrl"].copy()
    arrays["ctrl"][7, 1] = bad
    path = _write(tmp_path, arrays)
    msg = f"{path}: `ctrl` must be finite (no NaN or inf). Received 1 non-finite value(s), first at row 7, column 1: {bad!r}."
    with pytest.raises(LogError, match=re.escape(msg)):
        load_log(path)


def test_model_mismatch(tmp_path, log: TrajectoryLog) -> None:
    path = os.path.join(tmp_path, "log.npz")
    save_log(log, path)
    other = mujoco.MjModel.from_xml_string(
        ARM.replace('<position name="elbow" joint="elbow" kp="4"/>', "").replace(
            '<actuatorfrc name="elbow_force" actuator="elbow"/>', ""
        )
    )
    msg = f"{path}: `ctrl` must have nu=1 columns to match the model. Received 2 columns (shape (40, 2))."
    with pytest.raises(LogError, match=re.escape(msg)):
        load_log(path, model=other)
    three = mujoco.MjModel.from_xml_string(
        ARM.replace(
            "</body>\n    </body>", '</body>\n      <body><joint name="extra"/><geom size=".01"/></body>\n    </body>'
        )
    )
    with pytest.raises(
        LogError,
        match=re.escape(
            "`qpos` must have nq=3 columns to match the model (its joints in order: shoulder, elbow, extra; a log "
            "must carry every joint's state, or be fitted on a copy of the MJCF without the joints it lacks). "
            "Received 2 columns"
        ),
    ):
        validate_log(log, three)


def test_non_monotonic_time(tmp_path, log: TrajectoryLog) -> None:
    arrays = _arrays(log)
    arrays["time"] = arrays["time"].copy()
    arrays["time"][5] = arrays["time"][3]
    path = _write(tmp_path, arrays)
    t3, t4 = float(arrays["time"][3]), float(arrays["time"][4])
    msg = (
        f"{path}: `time` must be strictly increasing within each episode. Received time[5]={t3!r} after time[4]={t4!r}."
    )
    with pytest.raises(LogError, match=re.escape(msg)):
        load_log(path)


def test_truncated_file(tmp_path, log: TrajectoryLog) -> None:
    path = os.path.join(tmp_path, "log.npz")
    save_log(log, path)
    size = os.path.getsize(path)
    with open(path, "r+b") as handle:
        handle.truncate(size // 2)
    with pytest.raises(
        LogError,
        match=re.escape(
            f"`path` {path!r} must be a complete .npz trajectory log. Received a truncated or corrupt file ({size // 2} bytes;"
        ),
    ):
        load_log(path)


def test_bad_meta(log: TrajectoryLog) -> None:
    with pytest.raises(
        LogError,
        match=re.escape(
            "`meta['control_timestep']` must be a whole multiple (>= 1) of `meta['timestep']`. Received control_timestep=0.0125, timestep=0.005."
        ),
    ):
        TrajectoryLog(
            time=log.time,
            qpos=log.qpos,
            qvel=log.qvel,
            ctrl=log.ctrl,
            meta={"timestep": 0.005, "control_timestep": 0.0125},
        )


def test_csv_import(tmp_path, log: TrajectoryLog, model: mujoco.MjModel) -> None:
    path = os.path.join(tmp_path, "robot.csv")
    header = "t,q_shoulder,q_elbow,dq_shoulder,dq_elbow,u_shoulder,u_elbow"
    table = np.column_stack([log.time, log.qpos, log.qvel, log.ctrl])
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt="%.17g")
    columns = {"time": "t", "qpos": "q_*", "qvel": ["dq_shoulder", "dq_elbow"], "ctrl": "u_*"}
    back = load_csv(path, columns, meta=log.meta, model=model)
    np.testing.assert_array_equal(back.qvel, log.qvel)
    msg = (
        f"`columns['qvel']` names column 'dq_elbw', which CSV file {path!r} does not have. Close matches: 'dq_elbow', 'q_elbow', 'u_elbow'. "
        "Received columns: 't', 'q_shoulder', 'q_elbow', 'dq_shoulder', 'dq_elbow', 'u_shoulder', 'u_elbow'."
    )
    with pytest.raises(LogError, match=re.escape(msg)):
        load_csv(path, {**columns, "qvel": ["dq_shoulder", "dq_elbw"]}, meta=log.meta)
    with open(path) as handle:
        lines = handle.readlines()
    with open(path, "w") as handle:
        handle.writelines([*lines[:-1], "0.3,0.1\n"])
    with pytest.raises(
        LogError,
        match=re.escape(
            f"`path` {path!r} row {len(lines)} must have 7 fields like the header. Received 2 (truncated file?)."
        ),
    ):
        load_csv(path, columns, meta=log.meta)


def test_channel_names(model: mujoco.MjModel) -> None:
    names = channel_names(model)
    assert names["qpos"] == ["qpos[shoulder]", "qpos[elbow]"]
    assert names["sensordata"] == ["elbow_angle", "elbow_force"]
