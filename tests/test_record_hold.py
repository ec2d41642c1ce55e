"""``record_log(initial_ctrl=)``: the command the actuators hold until the first delayed one arrives (default zeros,
what ``sim2real record`` logs and its excitation plan's joint-limit check now simulates too: before, the check held the
first command while the log fed zeros)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sysid import record_log

# Two position servos homed far from 0, joint ranges around home (radians), gravity off: at its set point an arm
# rests exactly, and a command of 0 swings both joints out of range within a few control steps.
ARM = """
<mujoco model="homed">
  <compiler angle="radian"/>
  <option timestep="0.002" gravity="0 0 0"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" type="hinge" axis="0 1 0" range="0.9 1.5" damping="0.5"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="0.5"/>
      <body name="fore" pos="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0" range="-1.4 -0.8" damping="0.3"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.3"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="shoulder_servo" joint="shoulder" kp="20" ctrlrange="0.9 1.5"/>
    <position name="elbow_servo" joint="elbow" kp="10" ctrlrange="-1.4 -0.8"/>
  </actuator>
  <keyframe>
    <key name="home" qpos="1.2 -1.1" ctrl="1.2 -1.1"/>
  </keyframe>
</mujoco>
"""
HOME = np.array([1.2, -1.1])


def _manual(model: mujoco.MjModel, ctrl: np.ndarray, hold: np.ndarray, latency: int, substeps: int) -> np.ndarray:
    """qpos before each control step, with ``hold`` applied until ``ctrl[t - latency]`` arrives (mj_step by hand)."""
    data = mujoco.MjData(model)
    data.qpos[:] = HOME
    rows = []
    for t in range(len(ctrl)):
        rows.append(data.qpos.copy())
        data.ctrl[:] = ctrl[t - latency] if t >= latency else hold
        mujoco.mj_step(model, data, nstep=substeps)
    return np.array(rows)


def test_record_log_holds_initial_ctrl_until_the_first_command_arrives() -> None:
    model = mujoco.MjModel.from_xml_string(ARM)
    ctrl = np.column_stack([np.full(30, 1.4), np.full(30, -0.9)])
    log = record_log(model, ctrl, n_substeps=5, initial_qpos=HOME, action_latency=4, initial_ctrl=HOME)
    np.testing.assert_array_equal(log.qpos, _manual(model, ctrl, HOME, 4, 5))
    np.testing.assert_array_equal(log.qpos[:5], np.tile(HOME, (5, 1)))  # at rest on its set points until t = 4
    assert log.meta["initial_ctrl"] == [HOME.tolist()]
    default = record_log(model, ctrl, n_substeps=5, initial_qpos=HOME, action_latency=4)
    np.testing.assert_array_equal(default.qpos, _manual(model, ctrl, np.zeros(2), 4, 5))  # zeros, as before
    assert "initial_ctrl" not in default.meta


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (np.zeros(3), "`initial_ctrl` must have shape (2,) or (1, 2). Received shape (3,)."),
        (np.array([np.nan, 0.0]), "`initial_ctrl` must be finite. Received NaN or inf."),
    ],
)
def test_a_bad_initial_ctrl_is_refused_by_name(value: np.ndarray, message: str) -> None:
    model = mujoco.MjModel.from_xml_string(ARM)
    with pytest.raises(ValueError) as raised:
        record_log(model, np.zeros((5, 2)), action_latency=1, initial_ctrl=value)
    assert str(raised.value) == message
