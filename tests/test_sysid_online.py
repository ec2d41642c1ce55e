"""Online joint state-parameter estimation (UKF) and RTS smoothing, sim-to-sim on small inline models."""

from __future__ import annotations

import re
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest
from conftest import assert_same_model, model_arrays

from sysid.excitation import PRBS, Multisine
from sysid.online import OnlineEstimator, estimate_noise_std, estimate_online
from sysid.record import record_log

PENDULUM = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="link">
      <joint name="hinge" axis="0 1 0" damping="{damping}"/>
      <geom type="capsule" size=".02" fromto="0 0 0 0 0 -.3" mass=".5"/>
    </body>
  </worldbody>
  <actuator><motor name="motor" joint="hinge" ctrlrange="-1 1"/></actuator>
  <sensor><jointpos name="angle" joint="hinge"/><jointvel name="rate" joint="hinge"/></sensor>
</mujoco>
"""

DOUBLE = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" axis="0 1 0" damping="{d1}"/>
      <geom type="capsule" size=".02" fromto="0 0 0 0 0 -.3" mass=".5"/>
      <body name="fore" pos="0 0 -.3">
        <joint name="elbow" axis="0 1 0" damping="{d2}"/>
        <geom type="capsule" size=".02" fromto="0 0 0 0 0 -.3" mass=".3"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="shoulder" joint="shoulder" ctrlrange="-1 1"/>
    <motor name="elbow" joint="elbow" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""

TRUE_DAMPING = 0.2


@pytest.fixture(scope="module")
def pendulum_truth() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(PENDULUM.format(damping=TRUE_DAMPING))


@pytest.fixture(scope="module")
def pendulum_guess() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(PENDULUM.format(damping=0.1))


@pytest.fixture(scope="module")
def pendulum_controls(pendulum_truth: mujoco.MjModel) -> np.ndarray:
    return Multisine(pendulum_truth, amplitude=0.6, band=(0.3, 3.0), seed=1).signal(300, 0.01)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ukf_recovers_damping_within_its_three_sigma(
    pendulum_truth: mujoco.MjModel, pendulum_guess: mujoco.MjModel, pendulum_controls: np.ndarray, seed: int
) -> None:
    log = record_log(
        pendulum_truth, pendulum_controls, n_substeps=2, noise_std={"qpos": 2e-3}, rng=np.random.default_rng(seed)
    )
    result = estimate_online(log, pendulum_guess, "dof_damping[hinge]", initial_std=0.7)
    assert result.params == ("dof_damping[hinge]",)
    error = abs(result.estimate[0] - TRUE_DAMPING)
    assert error < 3 * result.stderr[0], (result.estimate, result.stderr)
    # It really converged: from a guess 50% off to within 2%, with an uncertainty far below the prior's.
    assert error < 0.02 * TRUE_DAMPING
    assert result.stderr[0] < 0.05 * TRUE_DAMPING
    assert result.history_sd[-1, 0] < 0.1 * result.history_sd[0, 0]
    lo, hi = result.ci95[0]
    assert lo < result.estimate[0] < hi
    # Consistent filter: the normalised innovations average about their dimension (1 channel).
    assert 0.7 < result.nis.mean() < 1.4


def test_rts_smoother_beats_the_raw_measurements(
    pendulum_truth: mujoco.MjModel, pendulum_guess: mujoco.MjModel, pendulum_controls: np.ndarray
) -> None:
    rng = np.random.default_rng(5)
    noisy = record_log(pendulum_truth, pendulum_controls, n_substeps=2, noise_std={"qpos": 3e-3}, rng=rng)
    clean = record_log(pendulum_truth, pendulum_controls, n_substeps=2)
    result = estimate_online(noisy, pendulum_guess, "dof_damping[hinge]")
    assert result.qpos_smoothed is not None and result.qvel_smoothed is not None

    def rmse(a: np.ndarray) -> float:
        return float(np.sqrt(np.mean((a - clean.qpos) ** 2)))

    raw, filtered, smoothed = rmse(noisy.qpos), rmse(result.qpos_filtered), rmse(result.qpos_smoothed)
    assert smoothed < 0.25 * raw
    assert smoothed < filtered < raw
    # Velocity is never measured here, yet the smoother reconstructs it far better than differencing.
    differenced = np.gradient(noisy.qpos[:, 0], noisy.control_timestep)
    vel_err = np.sqrt(np.mean((result.qvel_smoothed[:, 0] - clean.qvel[:, 0]) ** 2))
    assert vel_err < 0.2 * np.sqrt(np.mean((differenced - clean.qvel[:, 0]) ** 2))
    no_smooth = estimate_online(noisy, pendulum_guess, "dof_damping[hinge]", smooth=False)
    assert no_smooth.qpos_smoothed is None
    np.testing.assert_array_equal(no_smooth.estimate, result.estimate)


def test_two_joints_two_dampings_over_episodes() -> None:
    truth = mujoco.MjModel.from_xml_string(DOUBLE.format(d1=0.3, d2=0.1))
    guess = mujoco.MjModel.from_xml_string(DOUBLE.format(d1=0.15, d2=0.2))
    controls = np.stack([PRBS(truth, amplitude=0.6, f_max=3.0, seed=s).signal(200, 0.01) for s in (10, 11)])
    log = record_log(
        truth, controls, n_substeps=2, noise_std={"qpos": 1e-3, "qvel": 1e-2}, rng=np.random.default_rng(0)
    )
    assert log.episode_bounds() == [(0, 200), (200, 400)]
    before = model_arrays(guess)
    result = estimate_online(log, guess, ["dof_damping[*]"], measure="state")
    assert_same_model(before, guess)  # the filter simulates a private copy
    assert result.params == ("dof_damping[shoulder]", "dof_damping[elbow]")
    truth_values = np.array([0.3, 0.1])
    assert np.all(np.abs(result.estimate - truth_values) < 3 * result.stderr), (result.estimate, result.stderr)
    assert np.all(np.abs(result.estimate - truth_values) < 0.03 * truth_values)
    assert result.cov.shape == (2, 2) and np.all(np.linalg.eigvalsh(result.cov) > 0)
    # Each episode restarts the state: the second begins at its own logged pose, not the first's end.
    assert np.abs(result.qpos_filtered[200] - log.qpos[200]).max() < 5e-3
    assert 0.7 * 4 < result.nis.mean() < 1.4 * 4
    assert set(result.to_dict()) == set(result.params)


def test_sensor_measurements_identify_gain(pendulum_truth: mujoco.MjModel, pendulum_controls: np.ndarray) -> None:
    truth = mujoco.MjModel.from_xml_string(PENDULUM.format(damping=TRUE_DAMPING))
    truth.actuator_gainprm[0, 0] = 1.4
    log = record_log(
        truth, pendulum_controls, n_substeps=2, noise_std={"sensordata": 1e-3}, rng=np.random.default_rng(1)
    )
    result = estimate_online(log, pendulum_truth, "actuator_gain[motor]", measure="sensordata")
    assert abs(result.estimate[0] - 1.4) < 3 * result.stderr[0]
    assert abs(result.estimate[0] - 1.4) < 0.02


def test_step_by_step_estimator_matches_the_batch_run(
    pendulum_truth: mujoco.MjModel, pendulum_guess: mujoco.MjModel, pendulum_controls: np.ndarray
) -> None:
    log = record_log(
        pendulum_truth, pendulum_controls[:100], n_substeps=2, noise_std={"qpos": 2e-3}, rng=np.random.default_rng(3)
    )
    batch = estimate_online(
        log, pendulum_guess, "dof_damping[hinge]", meas_std=2e-3, initial_qvel_std=0.1, smooth=False
    )
    live = OnlineEstimator(pendulum_guess, "dof_damping[hinge]", n_substeps=2, meas_std=2e-3)
    live.reset(log.qpos[0], log.qvel[0], qpos_std=2e-3, qvel_std=0.1)
    for t in range(log.num_steps):
        live.update(log.qpos[t], log.ctrl[t])
        if t + 1 < log.num_steps:
            live.predict(log.ctrl[t])
    np.testing.assert_allclose(live.estimate, batch.estimate, rtol=1e-12)
    np.testing.assert_allclose(live.cov, batch.cov, rtol=1e-9)
    np.testing.assert_allclose(live.state[0], batch.qpos_filtered[-1], rtol=1e-12)


def test_duck_typed_log_of_plain_arrays(
    pendulum_truth: mujoco.MjModel, pendulum_guess: mujoco.MjModel, pendulum_controls: np.ndarray
) -> None:
    log = record_log(
        pendulum_truth, pendulum_controls[:150], n_substeps=2, noise_std={"qpos": 1e-3}, rng=np.random.default_rng(4)
    )
    plain = SimpleNamespace(
        qpos=log.qpos, qvel=log.qvel, ctrl=log.ctrl, meta={"timestep": 0.005, "control_timestep": 0.01}
    )
    a = estimate_online(plain, pendulum_guess, "dof_damping[hinge]", meas_std=1e-3, initial_qvel_std=0.1)
    b = estimate_online(log, pendulum_guess, "dof_damping[hinge]", meas_std=1e-3, initial_qvel_std=0.1)
    np.testing.assert_array_equal(a.estimate, b.estimate)
    np.testing.assert_array_equal(a.qpos_smoothed, b.qpos_smoothed)


def test_noise_level_is_estimated_from_the_data() -> None:
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 4.0, 2000)[:, None]
    signal = np.hstack([np.sin(3 * t), 0.5 * np.cos(t)])
    sigma = estimate_noise_std(signal + rng.normal(0.0, [0.002, 0.01], size=signal.shape))
    np.testing.assert_allclose(sigma, [0.002, 0.01], rtol=0.1)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"measure": "torque"},
            "`measure` must be one of ['qpos', 'state', 'sensordata', 'qpos+sensordata']. Received 'torque'.",
        ),
        (
            {"meas_std": [1e-3, 1e-3]},
            "`meas_std` must be a number > 0 or 1 of them (one per measured channel). Received [0.001, 0.001].",
        ),
        ({"initial": {"dof_damping[elbow]": 1.0}}, "`initial` must give a value for exactly ['dof_damping[hinge]']."),
        (
            {"initial": [-0.1]},
            "`initial` of dof_damping[hinge] must be > 0: a parameter with a positive lower bound is filtered in log space. Received -0.1.",
        ),
        ({"initial_std": 0.0}, "`initial_std` must be a number > 0 or 1 of them. Received 0.0."),
        (
            {"initial": [5.0]},
            "`initial` of dof_damping[hinge] must lie within its bounds [0.01, 1.0] (pass `bounds` to widen them). "
            "Received 5.0.",
        ),
        ({"alpha": 2.0}, "`alpha` must be in (0, 1]. Received 2.0."),
        ({"process_std": 1e-3}, "`process_std` must be a (qpos_std, qvel_std) pair. Received 0.001."),
        ({"params": "dof_damping[knee]"}, "`joints` pattern 'knee' matches no joint in the model."),
    ],
)
def test_bad_arguments_are_named(pendulum_guess: mujoco.MjModel, kwargs: dict, message: str) -> None:  # type: ignore[type-arg]
    args = {"params": "dof_damping[hinge]", "meas_std": 1e-3, **kwargs}
    with pytest.raises(ValueError, match=re.escape(message)):
        OnlineEstimator(pendulum_guess, **args)


def test_bad_models_and_logs_are_named(pendulum_truth: mujoco.MjModel, pendulum_controls: np.ndarray) -> None:
    free = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><freejoint/><geom size=".1"/></body></worldbody></mujoco>'
    )
    with pytest.raises(ValueError, match=re.escape("Received nq=7, nv=6.")):
        OnlineEstimator(free, "body_mass[*]")
    log = record_log(pendulum_truth, pendulum_controls[:20], n_substeps=2)
    double = mujoco.MjModel.from_xml_string(DOUBLE.format(d1=0.1, d2=0.1))
    with pytest.raises(ValueError, match=re.escape("`log.meta['timestep']` must equal the model's opt.timestep")):
        estimate_online(
            log,
            mujoco.MjModel.from_xml_string(PENDULUM.format(damping=0.1).replace("0.005", "0.002")),
            "dof_damping[*]",
        )
    with pytest.raises(
        ValueError, match=re.escape("`log.qpos` must have shape (T, 2) to match the model. Received shape (20, 1).")
    ):
        estimate_online(log, double, "dof_damping[*]")
    no_sensors = SimpleNamespace(qpos=log.qpos, qvel=log.qvel, ctrl=log.ctrl, sensordata=None, meta=log.meta)
    with pytest.raises(ValueError, match=re.escape("`measure` 'sensordata' needs `sensordata` in the log.")):
        estimate_online(no_sensors, pendulum_truth, "dof_damping[*]", measure="sensordata")


def test_parameters_with_a_zero_lower_bound_are_filtered_in_their_own_units(
    pendulum_truth: mujoco.MjModel, pendulum_controls: np.ndarray
) -> None:
    log = record_log(
        pendulum_truth, pendulum_controls, n_substeps=2, noise_std={"qpos": 2e-3}, rng=np.random.default_rng(6)
    )
    guess = mujoco.MjModel.from_xml_string(PENDULUM.format(damping=0.0))
    result = estimate_online(
        log, guess, "dof_damping[hinge]", bounds={"dof_damping[hinge]": (0.0, 1.0)}, initial=[0.1], initial_std=0.1
    )
    assert abs(result.estimate[0] - TRUE_DAMPING) < 3 * result.stderr[0]
    assert abs(result.estimate[0] - TRUE_DAMPING) < 0.02 * TRUE_DAMPING
