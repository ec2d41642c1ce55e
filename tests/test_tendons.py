"""Tendon parameters in the one vocabulary: ``TendonStiffness`` / ``TendonDamping`` / ``TendonFrictionLoss`` effects,
``tendon_*[name]`` addresses for ``record --set`` and ``sysid fit --params``, and the fit's export back to effects.

The robot is generated here: a two-link arm with a two-finger gripper whose fingers a fixed tendon couples (with
stiffness, damping and friction loss; a motor drives that tendon), a spatial cable from a world anchor to the
wrist, and an unnamed fixed tendon.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import assert_same_model, model_arrays, run_cli

import randomizers
import sysid
from randomizers import (
    Constant,
    ParameterSet,
    PhysicsRandomizer,
    TendonDamping,
    TendonFrictionLoss,
    TendonStiffness,
    Uniform,
    dump_effects,
    effect_for,
    load_effects,
)

GRIPPER_ARM = """<mujoco model="tendon_gripper_arm">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <custom><numeric name="sim2real_control_timestep" data="0.01"/></custom>
  <worldbody>
    <site name="anchor" pos="0.3 0.2 0.5"/>
    <body name="upper" pos="0 0 0.5">
      <joint name="shoulder" axis="0 0 1" range="-1.5 1.5" damping="0.5" armature="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="1"/>
      <body name="fore" pos="0.2 0 0">
        <joint name="elbow" axis="0 0 1" range="-2 2" damping="0.2" armature="0.01"/>
        <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.02" mass="0.5"/>
        <site name="wrist" pos="0.15 0 0"/>
        <body name="left" pos="0.17 0.02 0">
          <joint name="left" type="slide" axis="0 1 0" range="-0.04 0.04" damping="0.05"/>
          <geom type="box" size="0.02 0.005 0.01" mass="0.05"/>
        </body>
        <body name="right" pos="0.17 -0.02 0">
          <joint name="right" type="slide" axis="0 -1 0" range="-0.04 0.04" damping="0.05"/>
          <geom type="box" size="0.02 0.005 0.01" mass="0.05"/>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    <fixed name="coupling" stiffness="20" damping="0.8" frictionloss="0.01" springlength="0">
      <joint joint="left" coef="1"/><joint joint="right" coef="1"/>
    </fixed>
    <spatial name="cable" stiffness="5" damping="0.3"><site site="anchor"/><site site="wrist"/></spatial>
    <fixed damping="0.1"><joint joint="shoulder" coef="1"/><joint joint="elbow" coef="-1"/></fixed>
  </tendon>
  <actuator>
    <motor name="shoulder" joint="shoulder" ctrlrange="-3 3"/>
    <motor name="elbow" joint="elbow" ctrlrange="-2 2"/>
    <motor name="squeeze" tendon="coupling" ctrlrange="-0.5 0.5"/>
  </actuator>
</mujoco>
"""

NO_TENDONS = '<mujoco><worldbody><body><joint name="a"/><geom size=".1"/></body></worldbody></mujoco>'


@pytest.fixture
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(GRIPPER_ARM)


@pytest.fixture
def arm_file(tmp_path: Path) -> Path:
    path = tmp_path / "gripper_arm.xml"
    path.write_text(GRIPPER_ARM)
    return path


def _randomizer(model: mujoco.MjModel, effects: list[randomizers.Effect], seed: int = 0) -> PhysicsRandomizer:
    r = PhysicsRandomizer(effects, seed=seed)
    r.bind(model, mujoco.MjData(model))
    r.begin_episode()
    r.apply()
    return r


def test_effects_write_their_tendons_entries_and_report_them(model: mujoco.MjModel) -> None:
    assert model.tendon_stiffness.tolist() == [20.0, 5.0, 0.0]
    before = model_arrays(model)
    r = _randomizer(
        model,
        [
            TendonStiffness(set=12.5, tendons="coupling"),
            TendonDamping(scale=Uniform(2.0, 3.0), tendons=["cable", "#2"]),
            TendonFrictionLoss(add=0.04, tendons="coup*"),
        ],
    )
    assert model.tendon_stiffness.tolist() == [12.5, 5.0, 0.0]
    assert model.tendon_frictionloss.tolist() == [0.05, 0.0, 0.0]
    d_cable, d_unnamed = (float(v) for v in model.tendon_damping[1:])
    assert model.tendon_damping[0] == 0.8
    assert 0.6 <= d_cable <= 0.9 and 0.2 <= d_unnamed <= 0.3 and d_cable / 0.3 != d_unnamed / 0.1  # one draw each
    assert r.current_params == {
        "tendon_stiffness[coupling]": 12.5,
        "tendon_damping[cable]": d_cable,
        "tendon_damping[#2]": d_unnamed,
        "tendon_frictionloss[coupling]": 0.05,
    }
    # every other field untouched: only the three tendon arrays differ from the snapshot
    after = model_arrays(model)
    assert sorted(k for k in before if before[k].tobytes() != after[k].tobytes()) == [
        "tendon_damping",
        "tendon_frictionloss",
        "tendon_stiffness",
    ]
    r.restore_nominal()
    assert_same_model(before, model)


def test_shared_draws_one_factor_for_every_tendon_and_restore_is_bitwise(model: mujoco.MjModel) -> None:
    before = model_arrays(model)
    for episode in range(3):  # perturbations never compound across episodes
        r = _randomizer(model, [TendonDamping(scale=Uniform(0.5, 2.0), shared=True)], seed=episode)
        factors = model.tendon_damping / before["tendon_damping"]
        assert np.allclose(factors, factors[0]) and factors[0] != 1.0
        r.restore_nominal()
        assert_same_model(before, model)


def test_effects_validate_like_the_joint_effects() -> None:
    with pytest.raises(ValueError) as err:
        TendonDamping(scale=Uniform(-0.5, 1.0))
    assert str(err.value) == (
        "`scale` of TendonDamping must not go below 0 (tendon_damping must stay non-negative). "
        "Received Uniform(low=-0.5, high=1.0) with support [-0.5, 1.0]."
    )
    with pytest.raises(TypeError, match=r"^`tendons` of TendonStiffness must be a name pattern"):
        TendonStiffness(scale=1.1, tendons=[])
    assert repr(TendonFrictionLoss(add=0.1, tendons="cable", schedule="startup")) == (
        "TendonFrictionLoss(add=Constant(value=0.1), tendons='cable', schedule='startup')"
    )
    assert TendonDamping(scale=1.2).key == "TendonDamping[tendons=*]"


def test_unknown_tendon_names_the_close_matches(model: mujoco.MjModel) -> None:
    with pytest.raises(ValueError) as err:
        TendonDamping(scale=1.2, tendons="cupling").bind(model)
    assert str(err.value) == (
        "`tendons` pattern 'cupling' matches no tendon in the model. Close matches: 'coupling'. "
        "Known tendons: 'coupling', 'cable', '#2'."
    )


def test_a_model_without_tendons_refuses_a_tendon_effect_as_one_without_joints_refuses_damping() -> None:
    no_tendons = mujoco.MjModel.from_xml_string(NO_TENDONS)
    no_joints = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=".1"/></worldbody></mujoco>')
    with pytest.raises(ValueError) as tendon_err:
        PhysicsRandomizer([TendonDamping(scale=1.2)], seed=0).bind(no_tendons, mujoco.MjData(no_tendons))
    with pytest.raises(ValueError) as joint_err:
        PhysicsRandomizer([randomizers.Damping(scale=1.2)], seed=0).bind(no_joints, mujoco.MjData(no_joints))
    assert str(tendon_err.value) == "`tendons` pattern '*' matches no tendon in the model. The model has no tendons."
    assert str(joint_err.value) == "`joints` pattern '*' matches no joint in the model. The model has no joints."


def test_yaml_config_round_trip() -> None:
    effects = load_effects(
        "effects:\n"
        "  - {type: TendonDamping, scale: [0.5, 2.0], tendons: coupling}\n"
        "  - {type: TendonStiffness, set: {type: LogUniform, low: 10, high: 40}, tendons: [coupling, cable], shared: true}\n"
        "  - {type: TendonFrictionLoss, add: 0.01, schedule: {interval: {steps: 50}}}\n"
    )
    assert effects == [
        TendonDamping(scale=Uniform(0.5, 2.0), tendons="coupling"),
        TendonStiffness(set=randomizers.LogUniform(10, 40), tendons=["coupling", "cable"], shared=True),
        TendonFrictionLoss(add=Constant(0.01), schedule=randomizers.Interval(steps=50)),
    ]
    assert load_effects(dump_effects(effects)) == effects
    assert {"TendonDamping", "TendonStiffness", "TendonFrictionLoss"} <= set(randomizers.EFFECT_TYPES)


def test_addresses_expand_read_write_and_restore(model: mujoco.MjModel) -> None:
    assert randomizers.EFFECT_FIELDS["tendon_damping"] is TendonDamping
    space = ParameterSet(model, ["tendon_damping[*]", "tendon_stiffness[coupling]", "tendon_lengthspring[cable][1]"])
    assert space.addresses == (
        "tendon_damping[coupling]",
        "tendon_damping[cable]",
        "tendon_damping[#2]",
        "tendon_stiffness[coupling]",
        "tendon_lengthspring[cable][1]",
    )
    assert space.nominal[:4].tolist() == [0.8, 0.3, 0.1, 20.0]
    assert space.nominal[4] == model.tendon_lengthspring[1, 1] > 0  # the cable's rest length, computed at qpos0
    before = model_arrays(model)
    binding = space.bind(model)
    binding.apply(np.array([1.0, 2.0, 3.0, 4.0, 0.25]))
    assert model.tendon_damping.tolist() == [1.0, 2.0, 3.0]
    assert model.tendon_stiffness[0] == 4.0 and model.tendon_lengthspring[1, 1] == 0.25
    binding.restore()
    assert_same_model(before, model)
    assert effect_for(randomizers.Address.parse("tendon_frictionloss[cable]"), "add", 0.1) == TendonFrictionLoss(
        add=0.1, tendons="cable"
    )


def test_record_then_fit_recovers_the_tendon_damping_and_exports_it(tmp_path: Path, arm_file: Path) -> None:
    log, fit_path = tmp_path / "log.npz", tmp_path / "fit.json"
    code, out, err = run_cli(
        ["record", "--model", str(arm_file), "--set", "tendon_damping[coupling]=*1.5", "--episodes", "2",
         "--steps", "100", "--obs-noise", "0.001", "--quiet", "--out", str(log)]
    )  # fmt: skip
    assert code == 0, err
    assert "true params {'tendon_damping[coupling]': 1.2000000000000002}" in out
    code, out, err = run_cli(
        ["sysid", "fit", str(log), "--model", str(arm_file), "--params", "tendon_damping[coupling]", "--quiet",
         "--out", str(fit_path)]
    )  # fmt: skip
    assert code == 0, err
    fit = sysid.FitResult.from_json(fit_path)
    assert fit.addresses == ("tendon_damping[coupling]",)
    low, high = fit.ci95[0]
    assert 0.8 < low < 0.8 * 1.5 < high, (low, high)  # covers the truth, tells it from the nominal 0.8

    effects = fit.to_effects(noise=False)
    assert type(effects[0]) is TendonDamping and effects[0].patterns == ("coupling",)
    text = fit.to_randomizers()
    assert "type: TendonDamping" in text and randomizers.load_config(text) == fit.to_effects()

    import sim2real as s2r

    env = s2r.make(f"model:{arm_file}", params=fit)
    handle = s2r.find_physics(env)
    assert handle is not None
    assert handle.model.tendon_damping.tolist() == [fit.estimates[0], 0.3, 0.1]
    env.close()


def test_fit_of_an_unknown_tendon_is_a_one_line_error_naming_the_tendons(tmp_path: Path, arm_file: Path) -> None:
    log = tmp_path / "log.npz"
    code, _, err = run_cli(
        ["record", "--model", str(arm_file), "--episodes", "1", "--steps", "20", "--quiet", "--out", str(log)]
    )
    assert code == 0, err
    code, out, err = run_cli(
        ["sysid", "fit", str(log), "--model", str(arm_file), "--params", "tendon_stiffness[nope]", "--quiet",
         "--out", str(tmp_path / "fit.json")]
    )  # fmt: skip
    assert code == 2 and out == ""
    assert err.count("\n") == 1, err
    assert "`tendons` pattern 'nope' matches no tendon in the model. Known tendons: 'coupling', 'cable', '#2'." in err
    assert not (tmp_path / "fit.json").exists()


def test_wrapped_env_contract_seed_twin_vector_env_checker_and_restore(arm_file: Path) -> None:
    """The shared effect contract (tests/test_contract.py) on a model with tendons: values in use equal
    op(nominal, distribution.sample(stream(seed, key, episode))), sub-envs draw their own values, gymnasium's checker
    passes, and close() restores the model bitwise."""
    from gymnasium.utils.env_checker import check_env

    import sim2real as s2r
    from randomizers import stream

    effects = [
        TendonDamping(scale=randomizers.LogUniform(0.5, 2.0)),
        TendonStiffness(add=Uniform(0.0, 5.0), tendons=["coupling", "cable"]),
    ]
    env = s2r.wrap(s2r.make(f"model:{arm_file}"), *effects, seed=7)
    model = env.unwrapped.model
    before = model_arrays(model)
    nominals = [e.bind(model) for e in effects]
    for episode in range(2):
        _, info = env.reset()
        params = info["sim2real"]["params"]
        for k, (effect, nominal) in enumerate(zip(effects, nominals, strict=True)):
            gen = stream(env.randomizer.root_seed, env.randomizer.stream_names[k], episode)
            expected = nominal.values(np.asarray(effect.distribution.sample(gen, nominal.draw_count())))
            assert [params[a] for a in nominal.addresses] == expected.tolist()
        assert model.tendon_damping.tolist() == [params[f"tendon_damping[{n}]"] for n in ("coupling", "cable", "#2")]
        env.step(np.zeros(3, np.float32))
    env.close()
    assert_same_model(before, model)

    envs = s2r.make_vec(f"model:{arm_file}", 3, effects[0], seed=0)
    _, info = envs.reset()
    assert len(set(np.asarray(info["sim2real"]["params"]["tendon_damping[coupling]"]).tolist())) == 3
    envs.close()
    check_env(s2r.wrap(s2r.make(f"model:{arm_file}"), *effects, seed=0), skip_render_check=True)


def test_a_raw_tendon_armature_write_refreshes_what_mj_setconst_derives(model: mujoco.MjModel) -> None:
    # Tendon armature enters the mass matrix, so (like dof_armature) a write of it runs mj_setConst: the tendon's
    # inverse weight must move. Stiffness, damping and friction loss derive nothing (checked: mj_setConst leaves
    # every other field alone after them), so their effects need no mj_setConst.
    space = ParameterSet(model, ["tendon_armature[coupling]", "tendon_damping[coupling]"])
    assert space.bind(model).needs_set_const and space.bind(model).set_const_inputs == {"tendon_armature"}
    assert not ParameterSet(model, ["tendon_stiffness[*]", "tendon_damping[*]"]).bind(model).needs_set_const
    invweight = float(model.tendon_invweight0[0])
    space.write(model, {"tendon_armature[coupling]": 0.5})
    assert model.tendon_armature[0] == 0.5 and model.tendon_invweight0[0] < invweight / 5


def test_a_posterior_export_draws_tendon_parameters_jointly_and_clips_them_at_zero(arm_file: Path) -> None:
    import sim2real as s2r

    fit = sysid.FitResult.from_estimates(
        {"tendon_damping[coupling]": (1.2, 0.05), "tendon_stiffness[cable]": (6.0, 0.3)}
    )
    (effect,) = fit.to_effects(kind="posterior", noise=False)
    assert isinstance(effect, randomizers.Correlated)
    assert effect.distribution.low == (0.0, 0.0)  # both fields owned by effects that must stay non-negative
    assert randomizers.load_config(fit.to_randomizers(kind="posterior")) == fit.to_effects(kind="posterior")
    env = s2r.wrap(s2r.make(f"model:{arm_file}"), effect, seed=0)
    model = env.unwrapped.model
    before = model_arrays(model)
    _, info = env.reset()
    params = info["sim2real"]["params"]
    assert list(params) == ["tendon_damping[coupling]", "tendon_stiffness[cable]"]
    assert model.tendon_damping[0] == params["tendon_damping[coupling]"] != 0.8
    assert model.tendon_stiffness[1] == params["tendon_stiffness[cable]"] != 5.0
    env.close()
    assert_same_model(before, model)
