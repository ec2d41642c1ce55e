"""The "real" twin is one Condition: recorded through the env the evaluation scores it on (sim2real.twin)."""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

import sysid
from noise_models import ActionLatency, Gaussian, ObservationLatency, ObservationNoise
from sim2real.conditions import real
from sim2real.physics import find_physics
from sim2real.twin import record_condition, sensor_noise_std

PARAMS = {"dof_damping[arm_root]": 0.3, "actuator_gain[root]": 0.8}


def _replay(model: mujoco.MjModel, log: sysid.TrajectoryLog, substeps: int, delay: int, episode: int) -> np.ndarray:
    """qpos of one logged episode re-simulated from its first logged state: ``ctrl`` of row t applied from physics
    step ``t * substeps + delay`` on, the reset command (zeros) before the first one arrives."""
    rows = np.flatnonzero(log.episode == episode) if log.episode is not None else np.arange(len(log.time))
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = log.qpos[rows[0]], log.qvel[rows[0]]
    mujoco.mj_forward(model, data)
    out = [np.array(data.qpos)]
    for k in range(len(rows) * substeps):
        source = (k - delay) // substeps
        data.ctrl[:] = log.ctrl[rows[source]] if source >= 0 else 0.0
        mujoco.mj_step(model, data)
        if (k + 1) % substeps == 0:
            out.append(np.array(data.qpos))
    return np.array(out[:-1])


@pytest.mark.parametrize("seconds", [0.0, 0.02, 0.025])
def test_twin_log_is_the_evaluated_env_with_its_latency(seconds: float) -> None:
    # manipulator: 10 physics steps of 1 ms per control step; 25 ms is not a whole number of control steps.
    twin = real([ActionLatency(seconds=seconds)] if seconds else [], params=PARAMS)
    log = record_condition("dmc/manipulator-bring_ball", twin, episodes=2, steps=30, seed=3)
    assert log.meta["true_latency_seconds"] == {"action": seconds, "obs": 0.0}
    assert log.meta["true_params"]["dof_damping[arm_root]"] == 0.3
    env = twin.base_env("dmc/manipulator-bring_ball")  # the model the evaluation runs on, params written
    handle = find_physics(env)
    assert handle is not None
    delay = round(seconds / handle.model.opt.timestep)
    for episode in (0, 1):
        rows = log.episode == episode
        np.testing.assert_allclose(_replay(handle.model, log, 10, delay, episode), log.qpos[rows], rtol=0, atol=1e-9)
    # The logged commands are what the excitation sent (the delay acts on the actuators, not on the log).
    excitation = sysid.make_excitation("multisine", (-np.ones(5), np.ones(5)), amplitude=0.5, seed=3)
    np.testing.assert_allclose(log.ctrl[:30], excitation.signal(30, 0.01).astype(np.float32), rtol=0, atol=0)
    env.close()


def test_twin_sensor_noise_is_the_encoders_noise() -> None:
    twin = real([ObservationNoise(Gaussian(0.01))], params=PARAMS)
    clean = record_condition("dmc/manipulator-bring_ball", real([], params=PARAMS), episodes=1, steps=200, seed=0)
    noisy = record_condition("dmc/manipulator-bring_ball", twin, episodes=1, steps=200, seed=0)
    assert sensor_noise_std(twin) == 0.01 and noisy.meta["noise_std"]["qpos"] == 0.01
    np.testing.assert_array_equal(noisy.ctrl, clean.ctrl)
    residual = np.concatenate([(noisy.qpos - clean.qpos).ravel(), (noisy.qvel - clean.qvel).ravel()])
    assert 0.009 < residual.std() < 0.011 and abs(residual.mean()) < 0.001


def test_twin_models_a_state_log_cannot_carry_are_refused(tmp_path: Path) -> None:
    twin = real([ObservationLatency(steps=2)], name="lagged")
    message = (
        "condition 'lagged': a state log can carry one ObservationNoise(Gaussian) on every channel (the encoders' "
        "noise) besides physics and actuator-side models. Received ObservationLatency(steps=2.0)."
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        record_condition("dmc/manipulator-bring_ball", twin, episodes=1, steps=5)
    with pytest.raises(ValueError, match=re.escape("record_condition drives the actuators through the action")):
        record_condition("sim2real/arm-reach", real([]), episodes=1, steps=5)
    with pytest.raises(ValueError, match=re.escape("`steps` must be an int >= 2. Received 1.")):
        record_condition("dmc/manipulator-bring_ball", real([]), episodes=1, steps=1)


def test_twin_fit_export_and_record_again_keep_the_delay() -> None:
    # The study's loop: twin -> log through its env -> fit -> exported effects -> a calibrated condition -> a log
    # through *its* env. The fit is ok (the episodes' first rows, driven by commands sent before the log began, are
    # not predicted), its intervals hold the truth, and the exported delay is the twin's, in physics steps.
    truth = {"dof_damping[shoulder]": 0.03, "dof_damping[wrist]": 0.025, "actuator_gain[wrist]": 0.8}
    twin = real([ActionLatency(seconds=0.04), ObservationNoise(Gaussian(0.005))], params=truth)
    log = record_condition("dmc/reacher-easy", twin, episodes=3, steps=200, seed=1)
    env = real([]).base_env("dmc/reacher-easy")
    handle = find_physics(env)
    assert handle is not None
    fit = sysid.fit(log, handle.model, list(truth), latency=True, seed=0, progress=False)
    env.close()
    assert fit.ok, fit.quality
    assert fit.latency == {"action": 0.04} and fit.latency_physics_steps == {"action": 2}
    for address, (low, high) in zip(fit.addresses, fit.ci95, strict=True):
        assert low <= truth[address] <= high, (address, low, truth[address], high)
    exported = fit.to_effects()
    assert ActionLatency(seconds=0.04) in exported
    calibrated = real([e for e in exported if not isinstance(e, ObservationNoise)], name="calibrated")
    again = record_condition("dmc/reacher-easy", calibrated, episodes=1, steps=30, seed=1)
    assert again.meta["true_latency_seconds"]["action"] == 0.04
    env = calibrated.base_env("dmc/reacher-easy")
    handle = find_physics(env)
    assert handle is not None
    # The drawn calibrated parameters as the env held them, then a replay with exactly 2 physics steps of delay.
    for address, value in again.meta["true_params"].items():
        if address in truth:
            sysid.ParameterSpace(handle.model, [address]).write(handle.model, {address: value})
    np.testing.assert_allclose(_replay(handle.model, again, 1, 2, 0), again.qpos, rtol=0, atol=1e-9)
    env.close()
