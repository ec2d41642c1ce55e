"""sysid on generated arms nobody tuned the fit on (issue 17): the generator, the experiment, honest intervals.

The arms here (seeds 31–33) were never used while developing the method (that used seeds 0–2 and 21–22) nor in
``benchmarks/bench_sysid_arms.py`` (seeds 11–14).
"""

from __future__ import annotations

import re

import mujoco
import numpy as np
import pytest

from sysid import ParameterSpace, fit
from sysid.synthetic import excitation_log, generate_arm, home_pose

CASES = (  # (dof, seed, actuators, frictionloss, joint_limits)
    (6, 31, "position", None, True),
    (6, 32, "motor", None, True),
    (6, 33, "position", 0.1, False),
)


def test_generated_arm_is_realistic_and_deterministic() -> None:
    for dof, actuators in ((6, "motor"), (7, "position")):
        xml = generate_arm(dof=dof, seed=5, actuators=actuators)
        assert xml == generate_arm(dof=dof, seed=5, actuators=actuators)
        model = mujoco.MjModel.from_xml_string(xml)
        assert (model.nq, model.nv, model.nu, model.njnt) == (dof, dof, dof, dof)
        masses = model.body_mass[1:]
        assert np.all((masses >= 0.5) & (masses <= 4.0)) and masses[0] >= masses[-1]
        assert np.all(model.body_inertia[1:] > 0) and np.all(model.dof_armature > 0)
        assert np.all(model.jnt_limited == 1) and np.all(model.dof_frictionloss > 0)
        assert model.opt.gravity[2] == pytest.approx(-9.81)
        assert mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_KEY, 0) == "home"
        home = home_pose(model)
        assert np.all((model.jnt_range[:, 0] < home) & (home < model.jnt_range[:, 1]))
        bias = model.actuator_biastype[0] == mujoco.mjtBias.mjBIAS_AFFINE
        assert bias == (actuators == "position")
        if actuators == "position":
            assert np.all(model.actuator_gainprm[:, 0] > 0) and np.all(model.actuator_biasprm[:, 2] < 0)  # kp, kv
    bare = mujoco.MjModel.from_xml_string(
        generate_arm(dof=6, seed=5, gravity=False, frictionloss=0.0, joint_limits=False)
    )
    assert np.all(bare.opt.gravity == 0) and np.all(bare.dof_frictionloss == 0) and np.all(bare.jnt_limited == 0)
    assert generate_arm(dof=6, seed=6) != generate_arm(dof=6, seed=5)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dof": 5}, "`dof` must be 6 or 7. Received 5."),
        ({"actuators": "velocity"}, "`actuators` must be one of ['motor', 'position']. Received 'velocity'."),
        ({"frictionloss": -1.0}, "`frictionloss` must be None or a number of N·m in [0, 50). Received -1.0."),
        ({"gravity": 1}, "`gravity` must be True or False. Received 1."),
        ({"seed": 1.5}, "`seed` must be an int. Received 1.5."),
    ],
)
def test_generate_arm_errors(kwargs, message) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        generate_arm(**kwargs)


def test_excitation_log_is_a_realistic_experiment() -> None:
    model = mujoco.MjModel.from_xml_string(generate_arm(dof=7, seed=8, actuators="motor"))
    log = excitation_log(model, duration=5.0, seed=2)
    assert log.num_steps == 250 and log.control_timestep == pytest.approx(0.02)
    home = home_pose(model)
    assert np.max(np.abs(log.qpos - home)) < 1.0  # stays around home (gravity compensated)
    assert np.max(np.ptp(log.qpos, axis=0)) > 0.1  # but moves
    limit = model.actuator_ctrlrange[:, 1]
    assert np.all(np.abs(log.ctrl) <= limit + 1e-12)
    # Noise of 1e-3 rad: the 4th difference of the logged angles has variance 70 sigma^2 (signal is negligible).
    d4 = np.diff(log.qpos, 4, axis=0)
    assert np.sqrt(np.mean(d4**2) / 70) == pytest.approx(1e-3, rel=0.25)
    assert not np.allclose(log.qpos[0], home, atol=1e-3)  # the true start is off home and logged noisily
    with pytest.raises(ValueError, match=re.escape("`control_timestep` must be a positive whole number of physics")):
        excitation_log(model, control_timestep=0.003)
    with pytest.raises(ValueError, match=re.escape("`amplitude` must be a number > 0. Received 0.")):
        excitation_log(model, amplitude=0)


@pytest.fixture(scope="module")
def fits():
    out = []
    for dof, seed, actuators, fl, limits in CASES:
        xml = generate_arm(dof=dof, seed=seed, actuators=actuators, frictionloss=fl, joint_limits=limits)
        truth_model = mujoco.MjModel.from_xml_string(xml)
        space = ParameterSpace(truth_model, ["dof_damping[*]"])
        truth = space.nominal * np.random.default_rng(seed).uniform(0.8, 1.3, space.size)
        space.writer(truth_model)(truth)
        log = excitation_log(truth_model, duration=5.0, seed=seed + 100)
        out.append((actuators, truth, fit(log, xml, ["dof_damping[*]"], progress=False)))
    return out


def test_default_intervals_cover_the_truth_on_unseen_arms(fits) -> None:
    inside = [(r.ci95[:, 0] <= t) & (t <= r.ci95[:, 1]) for _, t, r in fits]
    hits = int(sum(i.sum() for i in inside))
    total = sum(i.size for i in inside)
    assert total == 18
    assert hits >= 15, [r.summary() for _, _, r in fits]  # 95% intervals: >= 4 misses of 18 has probability 1.1%
    for _, truth, r in fits:
        assert r.ok, r.quality.reasons
        z = np.abs(r.estimates - truth) / r.stderr
        assert np.all(z < 4.5), r.summary()  # no confident miss (the failure the issue measured: z up to 50)
        assert np.all(r.stderr >= r.crlb_sd * (1 - 1e-9))  # never narrower than the Cramér–Rao bound


def test_horizon_follows_the_data(fits) -> None:
    by_kind = {a: r.quality for a, _, r in fits}
    # A torque-driven arm replayed open loop drifts off within a second: short shooting segments are chosen.
    assert 8 <= by_kind["motor"].horizon <= 60 and by_kind["motor"].segments >= 3
    # Servos hold the arm on its set-points: the open-loop replay does not drift, whole episodes are kept.
    assert by_kind["position"].horizon == 0 and by_kind["position"].segments == 1
