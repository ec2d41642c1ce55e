"""Composer (Jaco) tasks, dm_env adapter behaviour, YAML configs, and pinned error messages."""

from __future__ import annotations

import re

import numpy as np
import pytest

import sim2real as s2r
from randomizers import EFFECT_TYPES, Address, load_effects

# -- composer: physics is recompiled on every reset ---------------------------------------------


def test_composer_randomisation_reaches_each_episodes_physics() -> None:
    env = s2r.wrap(
        s2r.make("dmc/jaco-reach_site"),
        s2r.Mass(scale=s2r.Uniform(0.5, 1.5), bodies="jaco_arm/b_*"),
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0), joints="jaco_arm/joint_*"),
        seed=0,
    )
    seen = []
    for seed in range(3):
        _, info = env.reset(seed=seed)
        physics = env.unwrapped.physics
        model = physics.model.ptr
        params = info["sim2real"]["params"]
        mass = params["body_mass[jaco_arm/b_1]"]
        assert model.body_mass[model.body("jaco_arm/b_1").id] == mass  # the new physics got it
        assert model.dof_damping[model.joint("jaco_arm/joint_2").dofadr[0]] == params["dof_damping[jaco_arm/joint_2]"]
        seen.append(mass)
        obs, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
        assert np.isfinite(obs).all() and info["sim2real"]["params"] == params
    assert len(set(seen)) == 3


def test_composer_same_seed_same_trajectory() -> None:
    def run() -> np.ndarray:
        env = s2r.wrap(s2r.make("dmc/jaco-lift_brick"), s2r.Friction(scale=s2r.Uniform(0.5, 1.5)), seed=3)
        obs, _ = env.reset(seed=1)
        frames = [obs]
        for k in range(5):
            obs, *_ = env.step(np.full(env.action_space.shape, 0.1 * (k % 2), np.float32))
            frames.append(obs)
        env.close()
        return np.stack(frames)

    assert run().tobytes() == run().tobytes()


def test_composer_hook_removed_on_close() -> None:
    base = s2r.make("dmc/jaco-reach_site")
    env = s2r.wrap(base, s2r.Mass(scale=2.0, bodies="jaco_arm/b_1"), seed=0)
    env.reset(seed=0)
    env.close()
    base.reset(seed=0)
    model = base.physics.model.ptr
    fresh = s2r.make("dmc/jaco-reach_site")
    fresh.reset(seed=0)
    assert (
        model.body_mass[model.body("jaco_arm/b_1").id]
        == fresh.physics.model.ptr.body_mass[model.body("jaco_arm/b_1").id]
    )


# -- dm_env -> gymnasium adapter -----------------------------------------------------------------


def test_adapter_spaces_flatten_and_dict() -> None:
    flat = s2r.make("dmc/manipulator-bring_ball")
    keep = s2r.make("dmc/manipulator-bring_ball", flatten=False)
    assert flat.observation_space.dtype == np.float32 and flat.action_space.dtype == np.float32
    obs_flat, _ = flat.reset(seed=0)
    obs_dict, _ = keep.reset(seed=0)
    assert set(obs_dict) == set(keep.observation_space.spaces)
    assert np.array_equal(obs_flat, np.concatenate([v.ravel() for v in obs_dict.values()]))
    assert keep.observation_space.contains(obs_dict)


def test_adapter_exposes_physics_and_time_limit() -> None:
    env = s2r.make("dmc/reacher-easy", time_limit=0.1)
    assert env.unwrapped.physics.model.nu == 2 and env.unwrapped.n_substeps == 1
    env.reset(seed=0)
    steps = 0
    truncated = False
    while not truncated:
        _, _, terminated, truncated, _ = env.step(np.zeros(2, np.float32))
        steps += 1
        assert not terminated
    assert steps == 5  # 0.1 s at the 0.02 s control step


def test_gym_passthrough() -> None:
    env = s2r.make("gym/Pusher-v5")
    assert env.spec is not None and env.spec.id == "Pusher-v5"
    assert s2r.find_physics(env).source == "gymnasium"


# -- YAML ------------------------------------------------------------------------------------------


def test_yaml_round_trip_with_schedules(tmp_path) -> None:
    text = """
effects:
  - type: Damping
    scale: {type: LogUniform, low: 0.5, high: 2.0}
    joints: ["shoulder", "wrist"]
    schedule: {interval: {steps: 10}}
  - type: Push
    force: [0.0, 2.0]
    interval: 20
  - type: Gravity
    add: {type: Normal, mean: 0.0, std: 0.1}
    axes: z
    schedule: startup
"""
    path = tmp_path / "effects.yaml"
    path.write_text(text)
    effects = load_effects(path)
    assert effects[0] == s2r.Damping(
        scale=s2r.LogUniform(0.5, 2.0), joints=["shoulder", "wrist"], schedule=s2r.Interval(steps=10)
    )
    assert effects[1] == s2r.Push(force=s2r.Uniform(0.0, 2.0), interval=20.0)
    env = s2r.wrap(s2r.make("dmc/reacher-easy"), effects, seed=0)
    _, info = env.reset(seed=0)
    assert "gravity[z]" in info["sim2real"]["params"]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "effects:\n  - type: Fiction\n    scale: 1.0\n",
            # the registry, not a list kept here: a new effect is one class plus one registry line
            "{f}: effects[0].type must be one of "
            + str(sorted(EFFECT_TYPES)).replace("{", "{{")
            + ". Received 'Fiction'.",
        ),
        (
            "effects:\n  - type: Mass\n    scale: [-1.0, 2.0]\n",
            "{f}: effects[0]: `scale` of Mass must be > 0 over its whole support (body_mass of 0 is singular). Received Uniform(low=-1.0, high=2.0) with support [-1.0, 2.0].",
        ),
        (
            "effects:\n  - type: Mass\n    scale: {type: Gauss, std: 1}\n",
            "{f}: effects[0].scale: `type` must be one of ['Choice', 'Constant', 'LogUniform', 'MultivariateNormal', 'Normal', 'TruncatedNormal', 'Uniform']. Received 'Gauss'.",
        ),
        (
            "effects:\n  - type: Damping\n    scale: 1.0\n    schedule: hourly\n",
            "{f}: effects[0].schedule: `schedule` must be 'reset', 'startup' or {{interval: {{steps: N}}}} / {{interval: {{seconds: T}}}}. Received 'hourly'.",
        ),
        ("effect: []\n", "{f}: the top level must be a mapping with an `effects` list. Received {{'effect': []}}."),
    ],
)
def test_yaml_errors_name_file_and_key(tmp_path, text: str, message: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=re.escape(message.format(f=path))):
        load_effects(path)


# -- pinned messages for bad input -----------------------------------------------------------------


def test_unknown_element_lists_close_matches() -> None:
    env = s2r.make("dmc/reacher-easy")
    with pytest.raises(
        ValueError,
        match=re.escape(
            "`geoms` pattern 'fnger' matches no geom in the model. Close matches: 'finger'. Known geoms: 'ground', 'wall_x', 'wall_y', 'wall_neg_x', 'wall_neg_y', 'root', 'target', 'arm', 'hand', 'finger'."
        ),
    ):
        s2r.wrap(env, s2r.Friction(scale=1.1, geoms="fnger"))


def test_add_that_would_go_negative_is_rejected_at_wrap() -> None:
    env = s2r.make("dmc/reacher-easy")
    with pytest.raises(
        ValueError,
        match=re.escape(
            "`add` of Damping would make dof_damping[shoulder] negative: nominal 0.01 + lowest draw -0.5 < 0. Received Uniform(low=-0.5, high=0.5)."
        ),
    ):
        s2r.wrap(env, s2r.Damping(add=s2r.Uniform(-0.5, 0.5)))


@pytest.mark.parametrize(
    ("build", "error", "message"),
    [
        (
            lambda: s2r.Mass(scale=s2r.Normal(1.0, 0.1)),
            ValueError,
            "`scale` of Mass must be > 0 over its whole support (body_mass of 0 is singular). Received Normal(mean=1.0, std=0.1) with support [-inf, inf].",
        ),
        (
            lambda: s2r.Friction(set=-0.1),
            ValueError,
            "`set` of Friction must not go below 0 (geom_friction must stay non-negative). Received Constant(value=-0.1) with support [-0.1, -0.1].",
        ),
        (
            lambda: s2r.Damping(scale=1.0, add=0.1),
            ValueError,
            "Damping needs exactly one of `scale`, `add` or `set`. Received ['add', 'scale'].",
        ),
        (lambda: s2r.Damping(), ValueError, "Damping needs exactly one of `scale`, `add` or `set`. Received none."),
        (
            lambda: s2r.Damping(scale="wide"),
            TypeError,
            "`scale` must be a number or a Distribution (Constant, Uniform, LogUniform, Normal, TruncatedNormal, Choice). Received 'wide' of type str.",
        ),
        (
            lambda: s2r.Friction(scale=1.0, axis="spin"),
            ValueError,
            "`axis` of Friction must be one or more of ['sliding', 'torsional', 'rolling']. Received 'spin'.",
        ),
        (
            lambda: s2r.Damping(scale=1.0, schedule="often"),
            ValueError,
            "`schedule` must be 'startup', 'reset' or an Interval(steps=...|seconds=...). Received 'often'.",
        ),
        (
            lambda: s2r.Push(force=-1.0, interval=5),
            ValueError,
            "`force` of Push must not go below 0. Received Constant(value=-1.0).",
        ),
        (lambda: s2r.Uniform(1.0, 0.0), ValueError, "`high` of Uniform must be >= `low`. Received low=1.0, high=0.0."),
        (lambda: s2r.Normal(0.0, float("nan")), ValueError, "`std` of Normal must be finite. Received nan."),
        (
            lambda: s2r.make("dmc/reacher-easy", colour="red"),
            TypeError,
            "`options` for 'dmc/reacher-easy' must be among ['flatten', 'render_mode', 'width', 'height', 'camera', 'time_limit', 'textures']. Received unknown ['colour'].",
        ),
        (
            lambda: s2r.make("gym/NoSuchEnv-v0"),
            ValueError,
            "`task_id` 'gym/NoSuchEnv-v0': gymnasium cannot make 'NoSuchEnv-v0'",
        ),
        (
            lambda: s2r.wrap(object(), s2r.Damping(scale=1.0)),
            TypeError,
            "`env` must be a gymnasium.Env, a dm_env.Environment (dm-control) or a TorchRL EnvBase. Received builtins.object.",
        ),
        (
            lambda: s2r.wrap(s2r.make("dmc/reacher-easy"), "Damping"),
            TypeError,
            f"`effects` must be effects from `randomizers` ({', '.join(EFFECT_TYPES)}), models from `noise_models` (ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold, ControlJitter) or lists of them. Received 'Damping' of type str.",
        ),
        (
            lambda: s2r.wrap(s2r.make("dmc/reacher-easy"), seed=-3),
            ValueError,
            "`seed` must be None, a non-negative int or a sequence of them. Received -3.",
        ),
        (lambda: s2r.make_vec("dmc/reacher-easy", 0), ValueError, "`num_envs` must be an int >= 1. Received 0."),
    ],
)
def test_bad_input_messages(build, error: type[Exception], message: str) -> None:
    with pytest.raises(error, match=re.escape(message)):
        build()


def test_physics_effect_on_env_without_mujoco() -> None:
    import gymnasium as gym

    with pytest.raises(
        TypeError,
        match=re.escape(
            "`env` of type gymnasium.wrappers.common.TimeLimit has no MuJoCo model, so the physics effects (Mass) cannot reach it."
        ),
    ):
        s2r.wrap(gym.make("CartPole-v1"), s2r.Mass(scale=1.1))


def test_vector_env_itself_is_rejected() -> None:
    import gymnasium as gym

    envs = gym.vector.SyncVectorEnv([lambda: s2r.make("dmc/reacher-easy")])
    with pytest.raises(TypeError, match="`env` is a gymnasium VectorEnv: wrap each sub-environment instead"):
        s2r.wrap(envs, s2r.Mass(scale=1.1))


def test_address_parsing_round_trip() -> None:
    for text in ("geom_friction[finger][0]", "body_mass[jaco_arm/b_1]", "gravity[z]"):
        assert str(Address.parse(text)) == text


def test_effects_are_immutable_values() -> None:
    a = s2r.Mass(scale=s2r.Uniform(0.8, 1.2), bodies="arm*")
    b = s2r.Mass(scale=s2r.Uniform(0.8, 1.2), bodies="arm*")
    assert a == b and hash(a) == hash(b) and a != s2r.Mass(scale=s2r.Uniform(0.8, 1.3), bodies="arm*")
    with pytest.raises(AttributeError, match=re.escape("Mass is immutable; build a new effect instead.")):
        a.shared = True  # type: ignore[misc]
    with pytest.raises(Exception, match="cannot assign to field"):
        s2r.Uniform(0, 1).low = 2  # type: ignore[misc]


def test_find_physics_of_a_closed_composer_env_is_none() -> None:
    # A closed composer env frees its physics behind a weak proxy: reading it raised ReferenceError, which broke
    # every later texture upload (the pixel layer looks up the physics of each env it still holds).
    env = s2r.make("dmc/jaco-reach_site")
    assert s2r.find_physics(env) is not None
    env.close()
    assert s2r.find_physics(env) is None
