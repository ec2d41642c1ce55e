"""One parameter vocabulary (randomizers.parameters), lossless fit results, latency units end to end, the joint
posterior effect and a new physics effect added by one class plus one registry line."""

from __future__ import annotations

import math
import re
from typing import Any

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import randomizers
import sim2real as s2r
import sysid
from noise_models import ActionLatency, ObservationLatency
from randomizers import (
    EFFECT_TYPES,
    BodyComOffset,
    Correlated,
    MultivariateNormal,
    PhysicsRandomizer,
    Uniform,
    dump_config,
    load_config,
)
from randomizers.parameters import EFFECT_FIELDS, Address, effect_for
from sim2real.recording import parse_set, record
from sysid import FitResult
from sysid.quality import FitQuality

XML = """<mujoco><worldbody>
  <body name="arm" pos="0 0 1"><joint name="shoulder" axis="0 1 0" damping="0.5"/>
    <geom name="upper" type="capsule" fromto="0 0 0 .3 0 0" size=".03"/>
    <body name="hand" pos=".3 0 0"><joint name="elbow" axis="0 1 0" damping="0.2"/>
      <geom name="lower" type="capsule" fromto="0 0 0 .3 0 0" size=".03"/></body></body>
</worldbody><actuator><motor name="m1" joint="shoulder"/><motor name="m2" joint="elbow"/></actuator></mujoco>"""


def test_one_translator_per_concept() -> None:
    # parse_set, effect_for, sysid's re-exports and the YAML registry are the same objects.
    assert sysid.EFFECT_FIELDS is EFFECT_FIELDS and randomizers.EFFECT_FIELDS is EFFECT_FIELDS
    assert sysid.params.effect_for is effect_for
    assert set(EFFECT_FIELDS.values()) <= set(EFFECT_TYPES.values())
    assert parse_set("geom_friction[pad*][2]=+0.1") == effect_for(Address.parse("geom_friction[pad*][2]"), "add", 0.1)
    # Any distribution goes through effect_for.
    assert effect_for(Address.parse("body_mass[arm]"), "scale", Uniform(0.9, 1.1)) == randomizers.Mass(
        scale=Uniform(0.9, 1.1), bodies="arm"
    )


def test_addresses_are_built_once_never_parsed_back(monkeypatch: pytest.MonkeyPatch) -> None:
    # Every effect binding hands out Address objects; a ParameterSet over effect-owned and raw fields resolves
    # its patterns with exactly one parse per user-given pattern (none of the expanded addresses is re-parsed).
    model = mujoco.MjModel.from_xml_string(XML)
    patterns = [
        "dof_damping[*]",
        "body_mass[arm]",
        "geom_friction[*][0]",
        "actuator_gain[m2]",
        "gravity[z]",
        "body_ipos[hand][1]",
        "actuator_biasprm[m1][1]",
    ]
    calls: list[str] = []
    original = Address.parse.__func__  # type: ignore[attr-defined]

    def counting(cls: type[Address], text: str | Address) -> Address:
        if not isinstance(text, Address):
            calls.append(text)
        return original(cls, text)

    monkeypatch.setattr(Address, "parse", classmethod(counting))
    space = randomizers.ParameterSet(model, patterns)
    assert calls == patterns
    assert all(type(a) is Address for a in space.addresses)
    assert [(a.field, a.element, a.component) for a in space.addresses[:3]] == [
        ("dof_damping", "shoulder", None),
        ("dof_damping", "elbow", None),
        ("body_mass", "arm", None),
    ]
    for cls in FIELD_EFFECT_SAMPLES:
        binding = cls.bind(model)
        assert binding.addresses and all(type(a) is Address for a in binding.addresses), cls


FIELD_EFFECT_SAMPLES = [
    effect_for(Address.parse(text), "scale", 1.0)
    for text in (
        "dof_damping[*]",
        "body_mass[*]",
        "geom_friction[*][1]",
        "actuator_gain[*]",
        "gravity[*]",
        "dof_armature[*]",
        "dof_frictionloss[*]",
        "jnt_stiffness[*]",
        "body_ipos[hand][0]",
    )
]


def test_every_registered_effect_is_exported() -> None:
    for name in EFFECT_TYPES:
        assert getattr(randomizers, name) is EFFECT_TYPES[name] and name in randomizers.__all__
        assert getattr(s2r, name) is EFFECT_TYPES[name] and name in s2r.__all__


def test_address_is_its_text_and_pickles() -> None:
    import pickle

    address = Address.parse("geom_friction[finger][0]")
    assert address == "geom_friction[finger][0]" and {str(address): 1}[address] == 1
    back = pickle.loads(pickle.dumps(address))
    assert (back.field, back.element, back.component) == ("geom_friction", "finger", 0)
    with pytest.raises(AttributeError, match="Address is immutable"):
        address.field = "x"


def test_design_needs_no_fake_bounds() -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    space = sysid.parameter_space(model, "dof_frictionloss[*]", need_bounds=False)
    assert not hasattr(space, "lower") and space.nominal.tolist() == [0.0, 0.0]


# ---------------------------------------------------------------------------------------------- FitResult JSON

_floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
_timesteps = st.just(math.nan) | st.floats(min_value=1e-4, max_value=0.1)
_names = st.sampled_from(["dof_damping[a]", "body_mass[b]", "geom_friction[c][1]", "gravity[z]", "actuator_gain[m]"])


@st.composite
def _results(draw: st.DrawFn) -> FitResult:
    addresses = draw(st.lists(_names, min_size=0, max_size=4, unique=True))
    p = len(addresses)
    channels = tuple(draw(st.lists(st.sampled_from(["qpos[a]", "qvel[a]", "s1"]), max_size=3, unique=True)))
    n = draw(st.integers(0, 3))

    def vec(*shape: int) -> np.ndarray:
        return np.array(draw(st.lists(_floats, min_size=math.prod(shape), max_size=math.prod(shape)))).reshape(shape)

    def mapping(keys: list[str]) -> dict[str, float]:
        return {k: draw(_floats) for k in draw(st.lists(st.sampled_from(keys), unique=True))}

    return FitResult(
        addresses=tuple(addresses),
        estimates=vec(p),
        stderr=vec(p),
        ci95=vec(p, 2),
        crlb_sd=vec(p),
        covariance=vec(p, p),
        correlation=vec(p, p),
        bounds=vec(p, 2),
        latency=mapping(["action", "obs"]),
        timestep=draw(_timesteps),
        control_timestep=draw(_timesteps),
        noise_std=mapping(list(channels) or ["x"]),
        fit_percent=mapping(list(channels) or ["x"]),
        whiteness_pvalue=mapping(list(channels) or ["x"]),
        warnings=tuple(draw(st.lists(st.text(max_size=20), max_size=3))),
        condition_number=draw(_floats),
        cost=draw(_floats),
        n_residuals=draw(st.integers(0, 10**6)),
        dof=draw(st.integers(-10, 10**6)),
        iterations=draw(st.integers(0, 1000)),
        converged=draw(st.booleans()),
        wall_time=draw(_floats),
        channels=channels,
        trace_time=vec(n),
        trace_measured=vec(n, len(channels)),
        trace_predicted=vec(n, len(channels)),
        trace_source=draw(st.sampled_from(["fit", "validation"])),
        true_params=draw(st.none() | st.just({a: 1.5 for a in addresses})),
        quality=FitQuality(
            fit_percent=mapping(list(channels) or ["x"]),
            whiteness_pvalue=mapping(list(channels) or ["x"]),
            at_bounds=tuple(draw(st.lists(st.sampled_from(addresses), unique=True))) if addresses else (),
            condition_number=draw(_floats),
            identifiable=draw(st.booleans()),
            validation_ratio=draw(_floats),
            se_inflation=mapping(addresses or ["x"]),
            horizon=draw(st.integers(0, 10**4)),
            segments=draw(st.integers(0, 10**4)),
            reasons=tuple(draw(st.lists(st.text(max_size=20), max_size=3))),
        ),
    )


@settings(max_examples=60, deadline=None)
@given(_results())
def test_fit_result_json_round_trip_is_lossless(result: FitResult) -> None:
    back = FitResult.from_json(result.to_json())
    assert back == result
    assert back.quality == result.quality and back.ok == result.ok
    for name in ("correlation", "covariance", "bounds"):
        np.testing.assert_array_equal(getattr(back, name), getattr(result, name))


def test_equality_sees_every_field() -> None:
    fit = FitResult.from_estimates({"dof_damping[a]": (1.0, 0.1)}, bounds={"dof_damping[a]": (0.1, 10.0)})
    assert fit == FitResult.from_json(fit.to_json())
    assert fit.bounds.tolist() == [[0.1, 10.0]]
    from dataclasses import replace

    assert fit != replace(fit, correlation=np.array([[0.5]]))
    assert fit != replace(fit, latency={"action": 0.04})


# ---------------------------------------------------------------------------------------------- to_effects


def test_to_effects_rule_is_the_documented_default() -> None:
    fit = FitResult.from_estimates({"dof_damping[a]": (1.0, 0.01), "actuator_gain[m]": (2.0, 0.5)})
    damping, gain = fit.to_effects()
    assert damping.distribution == Uniform(0.9, 1.1)  # 10% wins over 2 stderr
    assert gain.distribution == Uniform(1.0, 3.0)  # 2 stderr wins over 10%
    assert fit.to_effects(width=1.0, min_relative_width=0.0)[1].distribution == Uniform(1.5, 2.5)
    with pytest.raises(ValueError, match=re.escape("`kind` must be 'uniform' or 'posterior'. Received 'normal'.")):
        fit.to_effects(kind="normal")  # type: ignore[arg-type]


def test_posterior_effect_draws_jointly_reports_each_address_and_restores() -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    nominal = model.dof_damping.copy(), model.actuator_gainprm.copy(), model.actuator_biasprm.copy()
    cov = np.array([[0.01, 0.0095], [0.0095, 0.01]])
    fit = FitResult(
        addresses=("dof_damping[shoulder]", "actuator_gain[m1]"),
        estimates=np.array([0.6, 1.2]),
        stderr=np.sqrt(np.diag(cov)),
        ci95=np.zeros((2, 2)),
        crlb_sd=np.zeros(2),
        covariance=cov,
        correlation=cov / 0.01,
        bounds=np.array([[0.05, 5.0], [0.1, 10.0]]),
    )
    (effect,) = fit.to_effects(kind="posterior")
    assert effect == Correlated(
        ["dof_damping[shoulder]", "actuator_gain[m1]"],
        MultivariateNormal((0.6, 1.2), tuple(map(tuple, cov.tolist())), low=(0.05, 0.1), high=(5.0, 10.0)),
    )
    assert load_config(dump_config([effect])) == [effect]  # YAML round trip
    r = PhysicsRandomizer([effect], seed=7)
    r.bind(model, mujoco.MjData(model))
    draws = []
    for _ in range(200):
        r.begin_episode()
        r.apply()
        p = r.current_params
        assert (
            model.dof_damping[0] == p["dof_damping[shoulder]"]
            and model.actuator_gainprm[0, 0] == p["actuator_gain[m1]"]
        )
        draws.append([p["dof_damping[shoulder]"], p["actuator_gain[m1]"]])
    assert np.corrcoef(np.array(draws).T)[0, 1] > 0.85  # one joint draw, not two independent ones
    r.restore_nominal()
    for before, after in zip(nominal, (model.dof_damping, model.actuator_gainprm, model.actuator_biasprm), strict=True):
        np.testing.assert_array_equal(before, after)


def test_correlated_has_its_own_stream() -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    damping = randomizers.Damping(scale=Uniform(0.5, 2.0), joints="elbow")
    joint = Correlated(["body_mass[hand]"], MultivariateNormal((1.0,), ((0.01,),), low=(0.5,)))
    alone = PhysicsRandomizer([damping], seed=3)
    both = PhysicsRandomizer([joint, damping], seed=3)
    for r in (alone, both):
        r.bind(model, mujoco.MjData(model))
        r.begin_episode()
        r.apply()
        r.restore_nominal()
    assert alone.current_params == {"dof_damping[elbow]": 0.2}
    alone.begin_episode(seed=1)
    alone.apply()
    both.begin_episode(seed=1)
    both.apply()
    assert alone.current_params["dof_damping[elbow]"] == both.current_params["dof_damping[elbow]"]
    assert "body_mass[hand]" in both.current_params


def test_correlated_errors() -> None:
    with pytest.raises(ValueError, match=re.escape("must have one component per address (2). Received 1 components.")):
        Correlated(["dof_damping[a]", "dof_damping[b]"], MultivariateNormal((1.0,), ((1.0,),)))
    with pytest.raises(
        ValueError, match=re.escape("must name single elements (no patterns). Received ['dof_damping[*]']")
    ):
        Correlated(["dof_damping[*]"], MultivariateNormal((1.0,), ((1.0,),)))
    with pytest.raises(TypeError, match=re.escape("write it into several addresses with randomizers.Correlated")):
        randomizers.Damping(scale=MultivariateNormal((1.0,), ((1.0,),)))


# ---------------------------------------------------------------------------------------------- BodyComOffset


def test_body_com_offset_is_applied_reported_and_restored_bitwise() -> None:
    env = s2r.wrap(s2r.make("sim2real/arm-reach"), s2r.BodyComOffset(add=Uniform(-0.02, 0.02), axis="z"), seed=0)
    model = _handle(env).model
    nominal = model.body_ipos.copy()
    derived = model.dof_M0.copy(), model.body_invweight0.copy()
    _, info = env.reset(seed=0)
    params = info["sim2real"]["params"]
    offsets = {k: v for k, v in params.items() if k.startswith("body_ipos[")}
    assert offsets and all(k.endswith("][2]") for k in offsets)
    for address, value in offsets.items():
        a = Address.parse(address)
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, a.element)
        assert model.body_ipos[bid, 2] == value and -0.02 <= value - nominal[bid, 2] < 0.02
    assert not np.array_equal(model.dof_M0, derived[0])  # mj_setConst ran
    env.close()
    np.testing.assert_array_equal(model.body_ipos, nominal)
    np.testing.assert_array_equal(model.dof_M0, derived[0])
    np.testing.assert_array_equal(model.body_invweight0, derived[1])
    effect = BodyComOffset(add=Uniform(-0.01, 0.01), bodies="hand", axis=["x", "z"])
    assert load_config(dump_config([effect])) == [effect]
    assert effect_for(Address.parse("body_ipos[hand][1]"), "add", 0.01) == BodyComOffset(
        add=0.01, bodies="hand", axis="y"
    )


_COM_XML = """<mujoco><worldbody>
  <body name="pendulum" pos="0 0 1"><joint name="p" axis="0 1 0"/>
    <inertial pos="{p}" mass="0.5" diaginertia="0.01 0.02 0.03"/><geom size=".05" contype="0" conaffinity="0"/></body>
  <body name="puck" pos="1 0 1" {simple}><joint name="px" type="slide" axis="1 0 0"/>
    <joint name="pz" type="slide" axis="0 0 1"/><joint name="py" axis="0 1 0"/>
    <inertial pos="{p}" mass="0.5" diaginertia="0.01 0.02 0.03"/><geom size=".05" contype="0" conaffinity="0"/></body>
</worldbody><actuator><motor joint="p"/><motor joint="px"/><motor joint="py"/></actuator></mujoco>"""


def _swing(model: mujoco.MjModel) -> np.ndarray:
    data = mujoco.MjData(model)
    data.qvel[:] = [0.3, -0.2, 1.0, 0.5]
    states = []
    for k in range(200):
        data.ctrl[:] = np.sin(0.05 * k + np.arange(3))
        mujoco.mj_step(model, data)
        states.append(np.concatenate([data.qpos, data.qvel]))
    return np.array(states)


def test_body_com_offset_on_bodies_mujoco_compiled_as_simple() -> None:
    # MuJoCo compiles a body whose centre of mass is at its frame origin as "simple"; mj_setConst used to die with
    # "compiled as simple but sameframe no longer holds". A one-dof body switches to the general path while the
    # effect is bound and moves like the model compiled with that offset; the flags come back bitwise on restore.
    offset = [0.02, -0.01, 0.03]
    model = mujoco.MjModel.from_xml_string(_COM_XML.format(p="0 0 0", simple=""))
    flags = model.body_simple.copy(), model.dof_simplenum.copy()
    nominal = _swing(model)
    randomizer = PhysicsRandomizer(
        [BodyComOffset(set=v, bodies="pendulum", axis=a, name=f"com-{a}") for a, v in zip("xyz", offset, strict=True)],
        seed=0,
    )
    randomizer.bind(model, mujoco.MjData(model))
    randomizer.begin_episode()
    randomizer.apply()
    reference = mujoco.MjModel.from_xml_string(_COM_XML.format(p="0 0 0", simple=""))
    compiled = mujoco.MjModel.from_xml_string(_COM_XML.format(p=" ".join(map(str, offset)), simple=""))
    reference.body_ipos[1] = compiled.body_ipos[1]
    reference.body_simple[1], reference.dof_simplenum[0] = 0, 0
    mujoco.mj_setConst(reference, mujoco.MjData(reference))
    moved = _swing(model)
    assert np.abs(moved - nominal).max() > 0.1
    np.testing.assert_allclose(moved, _swing(reference), rtol=0, atol=1e-12)
    randomizer.restore_nominal()
    np.testing.assert_array_equal(model.body_simple, flags[0])
    np.testing.assert_array_equal(model.dof_simplenum, flags[1])
    np.testing.assert_array_equal(_swing(model), nominal)
    # A simple body with several dofs has no mass-matrix entries for the coupling: a clear error, not a FatalError.
    with pytest.raises(
        ValueError,
        match=re.escape(
            "BodyComOffset cannot move the centre of mass of ['puck']: MuJoCo compiled this body as 'simple' (frames "
            "coincide, several dofs), so the mass matrix has no entries for the coupling an offset creates. Add "
            'simple="false" to the <body> in the MJCF (MjSpec: body.simple = False) or leave it out of `bodies`. '
            "Received bodies=('*',)."
        ),
    ):
        PhysicsRandomizer([BodyComOffset(add=0.01)], seed=0).bind(model, mujoco.MjData(model))
    # ... and with simple="false" the puck moves exactly like the model compiled with the offset.
    free = mujoco.MjModel.from_xml_string(_COM_XML.format(p="0 0 0", simple='simple="false"'))
    compiled = mujoco.MjModel.from_xml_string(_COM_XML.format(p=" ".join(map(str, offset)), simple='simple="false"'))
    randomizer = PhysicsRandomizer(
        [BodyComOffset(set=v, axis=a, name=f"com-{a}") for a, v in zip("xyz", offset, strict=True)], seed=0
    )
    randomizer.bind(free, mujoco.MjData(free))
    randomizer.begin_episode()
    randomizer.apply()
    np.testing.assert_array_equal(_swing(free), _swing(compiled))


def test_body_com_offset_on_manipulator_names_the_simple_ball() -> None:
    with pytest.raises(ValueError, match=re.escape("centre of mass of ['ball']")):
        s2r.wrap(s2r.make("dmc/manipulator-bring_ball"), BodyComOffset(add=Uniform(-0.01, 0.01)), seed=0).reset(seed=0)
    env = s2r.wrap(
        s2r.make("dmc/manipulator-bring_ball"), BodyComOffset(add=Uniform(-0.01, 0.01), bodies="*arm"), seed=0
    )
    _, info = env.reset(seed=0)
    assert any(k.startswith("body_ipos[upper_arm]") for k in info["sim2real"]["params"])
    env.step(env.action_space.sample())
    env.close()


# ---------------------------------------------------------------------------------------------- latency units


def _handle(env: Any) -> s2r.PhysicsHandle:
    handle = s2r.find_physics(env)
    assert handle is not None
    return handle


def _applied_commands(task: str, effects: list) -> np.ndarray:
    """``data.ctrl`` at every physics step of six control steps at full action."""
    env = s2r.wrap(s2r.make(task), *effects, seed=0) if effects else s2r.make(task)
    handle = _handle(env)
    env.reset(seed=0)
    applied: list[np.ndarray] = []

    def each_physics_step(run: Any, n: int, *rest: Any) -> None:
        for _ in range(n):
            applied.append(handle.data.ctrl.copy())
            run(1)

    remove = handle.intercept_step(each_physics_step)
    for _ in range(6):
        env.step(env.action_space.high)  # type: ignore[union-attr]
    remove()
    env.close()
    return np.array(applied)


def _delay_physics_steps(task: str, effects: list) -> int:
    """The shift (physics steps) that lines the commands the actuators received up with the undelayed ones."""
    nominal, delayed = _applied_commands(task, []), _applied_commands(task, effects)
    return next(d for d in range(len(nominal)) if np.array_equal(delayed[d:], nominal[: len(nominal) - d]))


_CASES = [
    ("sim2real/arm-reach", "action", "dof_damping[elbow_pitch]"),
    ("dmc/manipulator-bring_ball", "action", "dof_damping[arm_elbow]"),
]


@pytest.mark.parametrize(("task", "kind", "param"), _CASES)
def test_fitted_latency_survives_export_in_physics_steps(task: str, kind: str, param: str) -> None:
    """Twin with a 2-control-step latency -> fit -> exported effects -> recorded again: the same delay in physics
    steps (20 on these 10-substep tasks), where the old export gave ActionLatency(steps=2), a tenth of it."""
    handle = _handle(s2r.make(task))
    assert handle.substeps == 10
    dt = float(handle.model.opt.timestep)
    delays = (2, 0) if kind == "action" else (0, 2)
    log = record(task, policy="prbs", episodes=1, steps=30, seed=1, latency=delays[0], obs_latency=delays[1])
    fit = sysid.fit(
        log, handle.model, [param], latency={kind: (0, 3)}, progress=False, global_search=False, validation=0.0
    )
    assert fit.latency_control_steps[kind] == 2 and fit.latency_physics_steps[kind] == 20
    exported = [e for e in fit.to_effects() if isinstance(e, (ActionLatency, ObservationLatency))]
    model = ActionLatency if kind == "action" else ObservationLatency
    assert exported == [model(seconds=20 * dt)]
    again = record(task, effects=exported, policy="prbs", episodes=1, steps=30, seed=1)
    assert again.meta["true_latency_seconds"] == log.meta["true_latency_seconds"]
    np.testing.assert_array_equal(again.qpos, log.qpos)
    np.testing.assert_array_equal(again.sensordata, log.sensordata)
    if kind == "action":  # and the simulator a policy trains in delays the actuators by the same physics steps
        assert _delay_physics_steps(task, exported) == 20


def test_observation_latency_export_keeps_physics_steps_on_manipulator() -> None:
    """The sensor lag leaves a fit in seconds and comes back as the same control (and physics) steps. (Fitting it
    needs informative sensors: arm-reach has none and manipulator's touch sensors read 0 in free motion.)"""
    from dataclasses import replace

    task = "dmc/manipulator-bring_ball"
    handle = _handle(s2r.make(task))
    dt = float(handle.model.opt.timestep)
    log = record(task, policy="prbs", episodes=1, steps=20, seed=1, obs_latency=2)
    fit = replace(
        FitResult.from_estimates({"dof_damping[arm_elbow]": (0.1, 0.01)}),
        latency={"obs": 2 * 10 * dt},
        timestep=dt,
        control_timestep=10 * dt,
    )
    assert fit.latency_control_steps == {"obs": 2.0} and fit.latency_physics_steps == {"obs": 20.0}
    exported = [e for e in fit.to_effects() if isinstance(e, ObservationLatency)]
    assert exported == [ObservationLatency(seconds=20 * dt)]
    again = record(task, effects=exported, policy="prbs", episodes=1, steps=20, seed=1)
    assert again.meta["true_latency_seconds"] == log.meta["true_latency_seconds"]
    assert log.meta["true_latency_seconds"] == {"action": 0.0, "obs": pytest.approx(20 * dt)}
