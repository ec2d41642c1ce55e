"""The shared contract every physics effect passes (DESIGN.md, house style 5).

single env, composed, vector env, seed twin, restore after a hypothesis-generated sequence of
resets/steps (bitwise), and each API's own checker (gymnasium, dm_env, TorchRL).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_restored, model_arrays
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import sim2real as s2r
from randomizers import PhysicsRandomizer, stream

# One instance of each effect, with ranges valid on sim2real/arm-reach (position servos, no springs).
EFFECTS = {
    "Friction": s2r.Friction(scale=s2r.Uniform(0.5, 1.5), geoms=["finger*", "palm"], axis=["sliding", "torsional"]),
    "Mass": s2r.Mass(scale=s2r.Uniform(0.7, 1.3), bodies="*arm"),
    "Damping": s2r.Damping(scale=s2r.LogUniform(0.5, 2.0)),
    "Armature": s2r.Armature(scale=s2r.Uniform(0.8, 1.2), joints=["shoulder_pitch", "elbow_pitch"]),
    "FrictionLoss": s2r.FrictionLoss(add=s2r.Uniform(0.0, 0.05)),
    "Stiffness": s2r.Stiffness(add=s2r.TruncatedNormal(0.5, 0.5, low=0.0, high=1.0), joints="wrist*"),
    "ActuatorGain": s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2)),
    "Gravity": s2r.Gravity(add=s2r.Normal(0.0, 0.1), axes="xy"),
    "Push": s2r.Push(force=s2r.Uniform(1.0, 3.0), interval=s2r.Choice((2.0, 3.0)), bodies="hand"),
}
IDS = list(EFFECTS)
TASK = "sim2real/arm-reach"
ACTIONS = np.random.default_rng(123).uniform(-0.05, 0.05, size=(40, 3)).astype(np.float32)


def rollout(env, seed: int, steps: int = 20) -> tuple[np.ndarray, list[dict[str, float]]]:
    obs, info = env.reset(seed=seed)
    frames, params = [obs], [info["sim2real"]["params"]]
    for action in ACTIONS[:steps]:
        obs, _, terminated, truncated, info = env.step(action)
        frames.append(obs)
        params.append(info["sim2real"]["params"])
        if terminated or truncated:
            break
    return np.stack(frames), params


@pytest.mark.parametrize("name", IDS)
def test_single_env_reports_and_writes_values(name: str) -> None:
    effect = EFFECTS[name]
    env = s2r.wrap(s2r.make(TASK), effect, seed=0)
    model = env.unwrapped.model
    _, info = env.reset(seed=3)
    params = info["sim2real"]["params"]
    if name == "Push":
        assert params == {}
        for _ in range(6):
            _, _, _, _, info = env.step(np.zeros(3, np.float32))
        events = info["sim2real"]["events"]
        assert events and events[0].body == "hand" and 1.0 <= np.linalg.norm(events[0].force) <= 3.0
        return
    binding = effect.bind(model)  # a second binding reads the live (perturbed) values
    assert list(params) == list(binding.addresses)
    np.testing.assert_array_equal(binding.nominal, np.array(list(params.values())))
    assert params != dict(zip(binding.addresses, env.randomizer.nominal_params().values(), strict=True))
    env.close()


@pytest.mark.parametrize("name", [n for n in IDS if n != "Push"])  # Push: test_push_draws_match_stream
def test_seed_twin_matches_bare_generator(name: str) -> None:
    """The values in use equal op(nominal, distribution.sample(stream(seed, key, episode)))."""
    effect = EFFECTS[name]
    env = s2r.wrap(s2r.make(TASK), effect, seed=7)
    nominal = effect.bind(env.unwrapped.model)
    for episode in range(3):
        _, info = env.reset()
        root = env.randomizer.root_seed
        gen = stream(root, env.randomizer.stream_names[0], episode)
        draws = np.asarray(effect.distribution.sample(gen, nominal.draw_count()))
        expected = nominal.values(draws)
        np.testing.assert_array_equal(np.array(list(info["sim2real"]["params"].values())), expected)
    env.close()


def test_push_draws_match_stream() -> None:
    effect = EFFECTS["Push"]
    env = s2r.wrap(s2r.make(TASK), effect, seed=5)
    env.reset()
    for _ in range(3):
        _, _, _, _, info = env.step(np.zeros(3, np.float32))
    gen = stream(env.randomizer.root_seed, env.randomizer.stream_names[0], 0)
    gap = round(float(effect.interval.sample(gen)))
    assert info["sim2real"]["events"][0].step == gap
    gen.integers(1)
    direction = gen.normal(size=3)
    force = direction / np.linalg.norm(direction) * float(effect.force.sample(gen))
    np.testing.assert_array_equal(info["sim2real"]["events"][0].force, force)


def test_composed_draws_do_not_shift_each_other() -> None:
    """Enabling one effect never shifts another's draws."""
    env_all = s2r.wrap(s2r.make(TASK), *EFFECTS.values(), seed=11)
    _, info_all = env_all.reset(seed=4)
    for name, effect in EFFECTS.items():
        if name == "Push":
            continue
        env_one = s2r.wrap(s2r.make(TASK), effect, seed=11)
        _, info_one = env_one.reset(seed=4)
        for key, value in info_one["sim2real"]["params"].items():
            assert info_all["sim2real"]["params"][key] == value, (name, key)


def test_same_seed_gives_bitwise_identical_trajectories() -> None:
    a = s2r.wrap(s2r.make(TASK), *EFFECTS.values(), seed=2)
    b = s2r.wrap(s2r.make(TASK), *EFFECTS.values(), seed=2)
    for seed in (0, 1):
        obs_a, params_a = rollout(a, seed)
        obs_b, params_b = rollout(b, seed)
        assert obs_a.tobytes() == obs_b.tobytes()
        assert params_a == params_b
    obs_c, _ = rollout(s2r.wrap(s2r.make(TASK), *EFFECTS.values(), seed=3), 1)
    assert obs_c.tobytes() != obs_b.tobytes()


def test_episodes_draw_fresh_values_and_never_compound() -> None:
    effect = s2r.Mass(scale=s2r.Uniform(0.5, 1.5), bodies="forearm")
    env = s2r.wrap(s2r.make(TASK), effect, seed=0)
    model = env.unwrapped.model
    nominal = float(model.body_mass[model.body("forearm").id])
    inertia = model.body_inertia[model.body("forearm").id].copy()
    seen = set()
    for _ in range(20):
        _, info = env.reset()
        value = info["sim2real"]["params"]["body_mass[forearm]"]
        seen.add(value)
        assert 0.5 * nominal <= value < 1.5 * nominal
        # inertia moves with the mass, and mj_setConst refreshed the derived subtree mass
        np.testing.assert_allclose(model.body_inertia[model.body("forearm").id], inertia * value / nominal)
        assert model.body_subtreemass[model.body("forearm").id] >= value
    assert len(seen) == 20


@pytest.mark.parametrize("name", IDS)
def test_vector_env_gives_independent_draws(name: str) -> None:
    envs = s2r.make_vec(TASK, 3, EFFECTS[name], seed=0)
    obs, info = envs.reset()
    assert obs.shape == (3, 16)
    if name != "Push":
        columns = list(info["sim2real"]["params"].values())
        first = np.array(columns[0])
        assert len(set(first.tolist())) == 3, "each sub-env must draw its own values"
    envs.step(np.zeros((3, 3), np.float32))
    obs, info = envs.reset(seed=0)
    again = s2r.make_vec(TASK, 3, EFFECTS[name], seed=0)
    obs2, info2 = again.reset(seed=0)
    assert obs.tobytes() == obs2.tobytes()
    for key, values in info["sim2real"]["params"].items():
        np.testing.assert_array_equal(values, info2["sim2real"]["params"][key])
    envs.close()
    again.close()


def test_gymnasium_sync_vector_env_with_seeded_reset() -> None:
    import gymnasium as gym

    effect = s2r.Damping(scale=s2r.Uniform(0.5, 2.0))
    envs = gym.vector.SyncVectorEnv([lambda: s2r.wrap(s2r.make(TASK), effect, seed=1) for _ in range(2)])
    _, info = envs.reset(seed=10)  # gymnasium gives sub-env i the seed 10 + i
    a, b = info["sim2real"]["params"]["dof_damping[base_yaw]"]
    assert a != b


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(st.integers(0, 1000), st.integers(1, 12).map(lambda n: -n)), min_size=1, max_size=8))
def test_restore_after_any_sequence_is_bitwise(sequence: list[int]) -> None:
    """Non-negative ints reset with that seed, negative ints step that many times; close() restores.

    The task itself writes its target into ``site_pos`` at reset: fields an unwrapped twin run
    through the same calls changes are the env's own business and are compared with the twin.
    """
    env = s2r.wrap(s2r.make(TASK), *EFFECTS.values(), seed=0)
    twin = s2r.make(TASK)
    model = env.unwrapped.model
    before = model_arrays(model)
    for target in (env, twin):
        target.reset(seed=0)
        for item in sequence:
            if item >= 0:
                target.reset(seed=item)
            else:
                for k in range(-item):
                    target.step(ACTIONS[k])
    env.close()
    assert_restored(before, model, twin.unwrapped.model)
    assert not env.unwrapped.data.xfrc_applied.any()


def test_restore_nominal_on_dm_control_suite() -> None:
    env, twin = s2r.make("dmc/manipulator-bring_ball"), s2r.make("dmc/manipulator-bring_ball")
    model = s2r.find_physics(env).model
    before = model_arrays(model)
    effects = (s2r.Mass(scale=s2r.Uniform(0.5, 1.5)), s2r.Friction(scale=s2r.Uniform(0.5, 1.5)), s2r.Armature(add=0.1))
    wrapped = s2r.wrap(env, *effects, seed=0)
    for target in (wrapped, twin):
        for seed in range(3):
            target.reset(seed=seed)
            target.step(np.zeros(wrapped.action_space.shape, np.float32))
    wrapped.restore_nominal()
    # the task moves its target bodies itself (body_pos/quat): those fields must match the twin's
    assert_restored(before, model, s2r.find_physics(twin).model)


def test_startup_and_interval_schedules() -> None:
    startup = s2r.Damping(scale=s2r.Uniform(0.5, 2.0), schedule="startup")
    every3 = s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2), schedule=s2r.Interval(steps=3))
    env = s2r.wrap(s2r.make(TASK), startup, every3, seed=0)
    _, info0 = env.reset()
    _, info1 = env.reset()
    key = "dof_damping[base_yaw]"
    assert info0["sim2real"]["params"][key] == info1["sim2real"]["params"][key]
    gains = [info1["sim2real"]["params"]["actuator_gain[elbow_pitch]"]]
    for _ in range(6):
        _, _, _, _, info = env.step(np.zeros(3, np.float32))
        gains.append(info["sim2real"]["params"]["actuator_gain[elbow_pitch]"])
    # the value entering step k was drawn at the resample before it: changes at steps 3 and 6
    assert gains[0] == gains[1] == gains[2] != gains[3] == gains[4] == gains[5] != gains[6]
    model = env.unwrapped.model
    assert model.actuator_biasprm[2, 1] == -model.actuator_gainprm[2, 0]  # servo bias moves with kp


def test_interval_in_seconds() -> None:
    effect = s2r.Gravity(add=s2r.Uniform(-1, 1), axes="z", schedule=s2r.Interval(seconds=0.1))
    env = s2r.wrap(s2r.make(TASK), effect, seed=0)
    _, info = env.reset()
    values = [info["sim2real"]["params"]["gravity[z]"]]
    for _ in range(12):  # 0.02 s control steps: resamples at t >= 0.1 and t >= 0.2 after the first step
        _, _, _, _, info = env.step(np.zeros(3, np.float32))
        values.append(info["sim2real"]["params"]["gravity[z]"])
    assert len(set(values)) == 3


@pytest.mark.parametrize("task", ["gym/Reacher-v5", "dmc/reacher-easy"])
def test_divergence_ends_episode_without_nan(task: str) -> None:
    env = s2r.wrap(s2r.make(task), s2r.ActuatorGain(set=1e14), s2r.Damping(set=0.0), seed=0)
    _, info = env.reset(seed=0)
    assert info["sim2real"]["diverged"] is False
    for _ in range(50):
        obs, _, _, truncated, info = env.step(np.ones(2, np.float32))
        assert np.isfinite(obs).all()
        if info["sim2real"]["diverged"]:
            assert truncated
            break
    else:
        pytest.fail("the simulation never diverged")


# -- each API's own checker -------------------------------------------------------------------


@pytest.mark.parametrize("name", IDS)
def test_gymnasium_check_env(name: str) -> None:
    from gymnasium.utils.env_checker import check_env

    env = s2r.wrap(s2r.make(TASK), EFFECTS[name], seed=0)
    check_env(env, skip_render_check=True)


@pytest.mark.parametrize("name", [n for n in IDS if n != "Push"])
def test_torchrl_check_env_specs(name: str) -> None:
    from torchrl.envs import GymWrapper
    from torchrl.envs.utils import check_env_specs

    env = s2r.wrap(GymWrapper(s2r.make(TASK)), EFFECTS[name], seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(5)
    names = env.transform.param_names if not hasattr(env.transform, "__len__") else env.transform[-1].param_names
    assert td["sim2real_params"].shape == (5, len(names))
    assert td["next", "sim2real_params"].dtype.is_floating_point


def test_torchrl_dm_control_env_draws_per_reset() -> None:
    from torchrl.envs import DMControlEnv
    from torchrl.envs.utils import check_env_specs

    env = s2r.wrap(DMControlEnv("reacher", "easy"), s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), seed=0)
    check_env_specs(env, seed=0)
    a = env.reset()["sim2real_params"].clone()
    b = env.reset()["sim2real_params"].clone()
    assert not (a == b).all()
    env.transform.restore_nominal()


def _dm_env_tests() -> type:
    import unittest

    from dm_control import suite
    from dm_env import test_utils

    class WrappedReacherTest(test_utils.EnvironmentTestMixin, unittest.TestCase):
        def make_object_under_test(self):  # type: ignore[no-untyped-def]
            return s2r.wrap(
                suite.load("reacher", "easy"),
                s2r.Friction(scale=s2r.Uniform(0.5, 1.5)),
                s2r.Mass(scale=s2r.Uniform(0.8, 1.2)),
                s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
                s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2)),
                s2r.Push(force=1.0, interval=5.0),
                seed=0,
            )

    return WrappedReacherTest


TestDmEnvContract = _dm_env_tests()


def test_dm_env_wrapper_reports_and_restores() -> None:
    from dm_control import suite

    env, twin = (
        suite.load("reacher", "easy", task_kwargs={"random": 1}),
        suite.load("reacher", "easy", task_kwargs={"random": 1}),
    )
    before = model_arrays(env.physics.model.ptr)
    wrapped = s2r.wrap(env, s2r.Mass(scale=s2r.Uniform(0.5, 1.5)), seed=0)
    wrapped.reset()
    first = wrapped.current_params
    wrapped.reset()
    twin.reset()
    twin.reset()
    assert wrapped.current_params != first
    wrapped.restore_nominal()
    assert_restored(before, env.physics.model.ptr, twin.physics.model.ptr)


def test_engine_without_env() -> None:
    """randomizers works on a bare model: the layer below sim2real needs no env."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="b"><joint name="j" damping="2"/><geom size=".1"/></body></worldbody></mujoco>'
    )
    r = PhysicsRandomizer([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], seed=0)
    r.bind(model, mujoco.MjData(model))
    r.begin_episode(seed=5)
    r.apply()
    first = r.current_params
    r.begin_episode(seed=5)
    r.apply()
    assert r.current_params == first
