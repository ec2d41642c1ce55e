"""sysid.fit on small inline arms: exact and noisy recovery, latency, identifiability, far starts, exports."""

from __future__ import annotations

import json
import os
import re

import mujoco
import numpy as np
import pytest

from randomizers import load_effects
from sysid import FitResult, ParameterSpace, fit, record_log

ARM = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" axis="0 1 0" damping="0.2" armature="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body name="lower" pos="0.3 0 0">
        <joint name="elbow" axis="0 1 0" damping="0.1" armature="0.005" frictionloss="0.02"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.025"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="shoulder" joint="shoulder" gear="2"/>
    <position name="elbow" joint="elbow" kp="4" kv="0.1"/>
  </actuator>
  <sensor><jointpos name="elbow_angle" joint="elbow"/><jointvel name="shoulder_rate" joint="shoulder"/></sensor>
</mujoco>
"""
PARAMS = ["dof_damping[*]", "dof_armature[*]", "actuator_gain[*]"]


def excitation(seed: int, steps: int, episodes: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(steps) * 0.01
    out = np.zeros((episodes, steps, 2))
    for e in range(episodes):
        for j in range(2):
            for f in rng.uniform(0.3, 4.0, 3):
                out[e, :, j] += 0.3 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return out


@pytest.fixture(scope="module")
def truth() -> tuple[mujoco.MjModel, dict[str, float]]:
    model = mujoco.MjModel.from_xml_string(ARM)
    space = ParameterSpace(model, PARAMS)
    return model, dict(zip(space.addresses, space.nominal.tolist(), strict=True))


def shifted(factor: float, params: list[str] = PARAMS) -> mujoco.MjModel:
    """The ARM model with the ``params`` multiplied by ``factor`` (the starting guess)."""
    model = mujoco.MjModel.from_xml_string(ARM)
    space = ParameterSpace(model, params)
    space.writer(model)(space.nominal * factor)
    return model


def test_noise_free_recovery_to_1e_4(truth) -> None:
    model, values = truth
    log = record_log(model, excitation(0, 120), n_substeps=2, true_params=values)
    result = fit(log, shifted(1.5), PARAMS, global_search=False, seed=0)
    expected = np.array([values[a] for a in result.addresses])
    np.testing.assert_allclose(result.estimates, expected, rtol=1e-4)
    assert all(v > 99.9 for v in result.fit_percent.values())
    assert result.true_params == values


def test_noisy_recovery_inside_intervals(truth) -> None:
    model, values = truth
    sigma = {"qpos": 2e-3, "qvel": 2e-2, "sensordata": 2e-3}
    log = record_log(model, excitation(1, 150), n_substeps=2, noise_std=sigma, rng=np.random.default_rng(7))
    result = fit(log, shifted(1.3), PARAMS, global_search=False, seed=0)
    expected = np.array([values[a] for a in result.addresses])
    lo, hi = result.ci95.T
    assert np.all((lo <= expected) & (expected <= hi)), result.summary()
    np.testing.assert_allclose(result.stderr, result.crlb_sd, rtol=0.2)
    assert result.noise_std["qpos[elbow]"] == pytest.approx(2e-3, rel=0.15)
    assert result.noise_std["qvel[shoulder]"] == pytest.approx(2e-2, rel=0.15)
    assert result.noise_std["elbow_angle"] == pytest.approx(2e-3, rel=0.15)


def test_latency_recovered_exactly(truth) -> None:
    model, _ = truth
    log = record_log(model, excitation(2, 100), n_substeps=2, action_latency=3, obs_latency=2)
    params = ["dof_damping[*]", "actuator_gain[*]"]
    result = fit(log, shifted(1.2, params), params, latency=True, n_starts=8)
    assert result.latency_control_steps == {"action": 3.0, "obs": 2.0}
    assert result.latency_physics_steps == {"action": 6.0, "obs": 4.0}
    assert result.latency == pytest.approx({"action": 3 * result.control_timestep, "obs": 2 * result.control_timestep})
    np.testing.assert_allclose(
        result.estimates, ParameterSpace(model, ["dof_damping[*]", "actuator_gain[*]"]).nominal, rtol=1e-4
    )


def test_unidentifiable_pair_is_flagged() -> None:
    xml = ARM.replace(
        '<motor name="shoulder" joint="shoulder" gear="2"/>',
        '<motor name="left" joint="shoulder" gear="1"/><motor name="right" joint="shoulder" gear="1"/>',
    )
    model = mujoco.MjModel.from_xml_string(xml)
    ctrl = excitation(3, 80)
    ctrl = np.concatenate([ctrl[..., :1], ctrl[..., :1], ctrl[..., 1:]], axis=2)  # both motors get the same command
    log = record_log(model, ctrl, n_substeps=2)
    params = ["actuator_gain[left]", "actuator_gain[right]", "dof_damping[shoulder]"]
    result = fit(log, model, params, initial=[1.5, 0.5, 0.2], global_search=False)
    flagged = [w for w in result.warnings if w.startswith("not identifiable")]
    assert flagged and "actuator_gain[left]" in flagged[0] and "actuator_gain[right]" in flagged[0]
    assert "dof_damping[shoulder]" not in flagged[0]
    assert result.condition_number > 1e10
    assert result.estimates[0] + result.estimates[1] == pytest.approx(2.0, rel=1e-6)


def test_far_start_converges(truth) -> None:
    model, values = truth
    log = record_log(model, excitation(4, 120), n_substeps=2)
    for factor in (3.0, 1.0 / 3.0):
        result = fit(log, shifted(factor), PARAMS, n_starts=16, seed=1)
        expected = np.array([values[a] for a in result.addresses])
        np.testing.assert_allclose(result.estimates, expected, rtol=1e-4, err_msg=f"start x{factor}")


def test_exports(tmp_path, truth) -> None:
    model, _ = truth
    log = record_log(model, excitation(5, 80), n_substeps=2, noise_std=1e-3, rng=np.random.default_rng(0))
    result = fit(
        log,
        model,
        ["dof_damping[*]", "geom_friction[*][0]"],
        bounds={"geom_friction[*][0]": (0.1, 2.0)},
        global_search=False,
    )
    doc = json.loads(result.to_json(os.path.join(tmp_path, "r.json")))
    assert {"params", "covariance", "correlation", "latency", "noise_std", "fit_percent", "warnings"} <= set(doc)
    entry = doc["params"]["dof_damping[elbow]"]
    assert set(entry) == {"estimate", "stderr", "ci95", "crlb_sd", "bounds"} and len(entry["ci95"]) == 2
    assert FitResult.from_json(result.to_json()) == result
    # Friction never touches this contact-free arm: flagged, and the export falls back to the bounds.
    assert any("geom_friction" in w and "not identifiable" in w for w in result.warnings)
    effects = load_effects(result.to_randomizers(width=2.0))
    assert [type(e).__name__ for e in effects] == ["Damping", "Damping", "Friction", "Friction"]
    low, high = effects[0].distribution.support
    assert low < result.estimates[0] < high
    figure = result.plot(os.path.join(tmp_path, "fit.png"))
    assert os.path.getsize(os.path.join(tmp_path, "fit.png")) > 1000 and len(figure.axes) >= 2
    with pytest.raises(
        ValueError, match=re.escape("`width` must be a finite number >= 0. Received -1.")
    ):
        result.to_randomizers(width=-1)


def test_argument_errors(truth) -> None:
    model, _ = truth
    log = record_log(model, excitation(6, 30, episodes=1)[0], n_substeps=2)
    with pytest.raises(ValueError, match=re.escape("`latency['action']` must be an int >= 0 or an inclusive range")):
        fit(log, model, ["dof_damping[*]"], latency={"action": (3, 1)})
    with pytest.raises(
        ValueError, match=re.escape("`bounds` must be given for 'dof_frictionloss[shoulder]': its nominal value is 0.0")
    ):
        fit(log, model, ["dof_frictionloss[*]"])
    with pytest.raises(
        ValueError,
        match=re.escape(
            "`initial` value of 'dof_damping[shoulder]' must lie within its bounds [0.02, 2.0]. Received 5.0."
        ),
    ):
        fit(log, model, ["dof_damping[shoulder]"], initial=[5.0])
    with pytest.raises(
        ValueError,
        match=re.escape(
            "`params` entry 'dof_damping[elbw]': `joints` pattern 'elbw' matches no joint in the model. "
            "Close matches: 'elbow'. Known joints: 'shoulder', 'elbow'."
        ),
    ):
        fit(log, model, ["dof_damping[elbw]"])
    wrong = mujoco.MjModel.from_xml_string(ARM.replace('<option timestep="0.005"/>', '<option timestep="0.002"/>'))
    with pytest.raises(
        ValueError, match=re.escape("`meta['timestep']` must equal the model's opt.timestep=0.002. Received 0.005.")
    ):
        fit(log, wrong, ["dof_damping[*]"])
