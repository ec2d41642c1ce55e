"""sysid's online estimator reads the measurement noise a log declares per column (``record_log`` writes one sigma
per column when the columns differ: ``record --obs-noise qpos[lift]=...``), not only one number per channel."""

from __future__ import annotations

import mujoco
import numpy as np

from sysid.online import estimate_noise_std, estimate_online
from sysid.record import record_log

# A slide joint (m) and two hinges (rad) with servos: encoders of different quality per joint.
ARM = """
<mujoco model="mixed">
  <option timestep="0.005"/>
  <worldbody>
    <body name="carriage">
      <joint name="lift" type="slide" axis="0 0 1" damping="3"/>
      <geom type="box" size="0.05 0.05 0.05" mass="1"/>
      <body name="upper" pos="0 0 0.05">
        <joint name="shoulder" type="hinge" axis="0 1 0" damping="0.4"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="0.5"/>
        <body name="fore" pos="0.3 0 0">
          <joint name="elbow" type="hinge" axis="0 1 0" damping="0.2"/>
          <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.3"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position joint="lift" kp="60"/>
    <motor joint="shoulder" gear="4"/>
    <motor joint="elbow" gear="2"/>
  </actuator>
</mujoco>
"""


def _log(qpos_std: object, qvel_std: object) -> object:
    model = mujoco.MjModel.from_xml_string(ARM)
    t = np.arange(120)[:, None]
    ctrl = np.concatenate([0.05 * np.sin(0.07 * t), 0.6 * np.sin(0.05 * t), 0.4 * np.cos(0.09 * t)], axis=1)
    return record_log(
        model, ctrl, n_substeps=2, noise_std={"qpos": qpos_std, "qvel": qvel_std}, rng=np.random.default_rng(3)
    )


def test_per_column_declared_noise_is_the_filter_s_measurement_sigma() -> None:
    log = _log(np.array([1e-4, 1e-3, 0.0]), np.array([2e-3, 2e-2, 2e-2]))
    assert log.meta["noise_std"]["qpos"] == [1e-4, 1e-3, 0.0]  # one per column: they differ
    model = mujoco.MjModel.from_xml_string(ARM)
    result = estimate_online(log, model, "dof_damping[shoulder]", measure="state", smooth=False)
    # Declared columns as declared; the noise-free elbow column (0: declares nothing) estimated from the data.
    expected = np.array([1e-4, 1e-3, estimate_noise_std(log.qpos)[2], 2e-3, 2e-2, 2e-2])
    np.testing.assert_array_equal(result.meas_std, expected)


def test_one_declared_number_per_channel_is_read_as_before() -> None:
    log = _log(1e-3, 2e-2)
    model = mujoco.MjModel.from_xml_string(ARM)
    result = estimate_online(log, model, "dof_damping[shoulder]", measure="state", smooth=False)
    np.testing.assert_array_equal(result.meas_std, np.array([1e-3] * 3 + [2e-2] * 3))
