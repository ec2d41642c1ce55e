"""A driver CSV sampled on a jittery clock fits like an on-grid one, and a wrong model is still caught.

A servo's velocity jumps its slope at every command, so samples taken +-2 ms off a 20 ms grid cannot be
interpolated onto it: the interpolation error (about 10x the sensor noise here) made the residuals of the right
model coloured and every such fit "not ok". The rows now keep their own sample times and the fit predicts them
there. Measured on a 5-joint arm (BENCHMARKS.md, 2026-11-27): fits ok 0/30 -> 30/30 at +-2 ms.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

import sysid

ARM = """
<mujoco model="jitter_arm">
  <option timestep="0.002" integrator="implicitfast"/>
  <default><joint armature="0.03" damping="1.0"/><geom contype="0" conaffinity="0" density="800"/></default>
  <worldbody>
    <body name="link1" pos="0 0 0.3">
      <joint name="shoulder" axis="0 1 0" range="-90 90" damping="3.0" armature="0.06"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04" mass="2.2"/>
      <body name="link2" pos="0.3 0 0">
        <joint name="elbow" axis="0 1 0" range="-135 135" damping="1.5" armature="0.04"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.035" mass="1.4"/>
        <body name="hand" pos="0.25 0 0">
          <joint name="wrist" axis="0 1 0" range="-100 100" damping="0.5" armature="0.02"/>
          <geom type="box" size="0.04 0.03 0.02" mass="0.5"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position joint="shoulder" kp="200" kv="12" ctrlrange="-1.5 1.5" forcerange="-80 80"/>
    <position joint="elbow" kp="100" kv="6" ctrlrange="-2.3 2.3" forcerange="-40 40"/>
    <position joint="wrist" kp="20" kv="1" ctrlrange="-1.7 1.7" forcerange="-10 10"/>
  </actuator>
  <keyframe><key name="home" qpos="-0.4 0.9 -0.3"/></keyframe>
</mujoco>
"""
SUB, STEPS, NOISE = 10, 300, 2e-3
PARAMS = ["dof_damping[shoulder]", "dof_damping[elbow]"]
NAMES = ("shoulder", "elbow", "wrist")
COLUMNS = {"time": "t_ms", "qpos": "*_deg", "qvel": "*_dps", "ctrl": "cmd_*"}
UNITS = {"t_ms": "ms", "*_deg": "deg", "*_dps": "deg/s"}


def _driver_csv(path: Path, truth: mujoco.MjModel, jitter: int, seed: int) -> None:
    """The truth simulated at the physics rate under servo set-points held for a control step each, sampled by a
    driver whose clock is up to ``jitter`` physics steps off the grid, with sensor noise, written in degrees."""
    rng = np.random.default_rng(seed)
    t = np.arange(STEPS) * SUB * truth.opt.timestep
    freq = np.array([[0.4, 0.7, 0.9], [1.7, 2.3, 1.9], [3.1, 3.7, 2.7]])
    phase = rng.uniform(0, 2 * math.pi, freq.shape)
    ctrl = truth.key_qpos[0] + sum(
        0.12 * np.sin(2 * math.pi * f * t[:, None] + p) for f, p in zip(freq, phase, strict=True)
    )
    fine = sysid.record_log(truth, np.repeat(ctrl, SUB, axis=0), initial_qpos=truth.key_qpos[0])
    rows = np.arange(STEPS) * SUB + rng.integers(-jitter, jitter + 1, STEPS)
    rows[0] = 0
    table = np.column_stack(
        [
            1e3 * fine.time[rows],
            np.degrees(fine.qpos[rows] + rng.normal(0, NOISE, (STEPS, 3))),
            np.degrees(fine.qvel[rows] + rng.normal(0, NOISE, (STEPS, 3))),
            ctrl,  # row k carries command k, applied from grid point k
        ]
    )
    header = ["t_ms", *(f"{n}_deg" for n in NAMES), *(f"{n}_dps" for n in NAMES), *(f"cmd_{n}" for n in NAMES)]
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.9g")


def _fit(path: Path, model: mujoco.MjModel) -> tuple[sysid.TrajectoryLog, sysid.FitResult]:
    meta = {"timestep": float(model.opt.timestep), "control_timestep": SUB * float(model.opt.timestep)}
    log = sysid.load_csv(path, COLUMNS, meta=meta, model=model, units=UNITS)
    return log, sysid.fit(log, model, PARAMS, n_starts=8, progress=False)


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(ARM)


def test_a_right_model_fits_ok_from_a_jittery_clock_and_covers_the_truth(tmp_path, model) -> None:
    truth = mujoco.MjModel.from_xml_string(ARM)
    truth.dof_damping[:2] *= [1.3, 0.8]
    path = tmp_path / "driver.csv"
    _driver_csv(path, truth, jitter=1, seed=5)  # +-2 ms on a 20 ms period
    with warnings.catch_warnings():
        warnings.simplefilter("error", sysid.CsvWarning)  # no gap, no degrees warning: nothing to say
        log, result = _fit(path, model)
    assert log.meta["csv"]["resampled"] is True
    assert log.meta["csv"]["max_jitter_s"] == pytest.approx(0.002)
    assert log.meta["csv"]["interpolated_rows"] == 0
    assert result.ok, result.quality.reasons  # before: "residuals far from white" (linear interpolation)
    for (low, high), true in zip(result.ci95, truth.dof_damping[:2], strict=True):
        assert low <= true <= high, (low, true, high)
    # every channel's noise is the sensor's, not the interpolation's (which was ~10x it on the velocities)
    assert max(result.noise_std.values()) < 1.5 * NOISE, result.noise_std


@pytest.mark.parametrize(
    "wrong",
    [
        pytest.param(lambda m: m.dof_frictionloss.__setitem__(slice(None), [0.5, 0.3, 0.05]), id="friction"),
        pytest.param(lambda m: m.body_mass.__setitem__(2, 2.2), id="mass"),
    ],
)
def test_a_wrong_model_is_still_not_ok_from_a_jittery_clock(tmp_path, model, wrong) -> None:
    truth = mujoco.MjModel.from_xml_string(ARM)
    wrong(truth)
    mujoco.mj_setConst(truth, mujoco.MjData(truth))
    path = tmp_path / "driver.csv"
    _driver_csv(path, truth, jitter=1, seed=6)
    _, result = _fit(path, model)
    assert not result.ok
    assert any("far from white" in r or "does not reproduce" in r for r in result.quality.reasons), result.quality
