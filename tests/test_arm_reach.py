"""Tests for the five-joint arm reaching task."""

from __future__ import annotations

import re
from collections.abc import Iterator

import mujoco
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

from sim2real.tasks.arm_reach import ARM_REACH_XML, JOINT_NAMES, ArmReachEnv


@pytest.fixture
def env() -> Iterator[ArmReachEnv]:
    environment = ArmReachEnv()
    yield environment
    environment.close()


@pytest.fixture(scope="module")
def rendering_available() -> None:
    # Headless machines may lack EGL/OSMesa; render tests are skipped rather than failed there.
    try:
        renderer = mujoco.Renderer(mujoco.MjModel.from_xml_string(ARM_REACH_XML), height=32, width=32)
    except Exception as exc:
        pytest.skip(f"MuJoCo rendering unavailable: {exc}")
    renderer.close()


def _frame(env: ArmReachEnv) -> np.ndarray:
    frame = env.render()
    assert isinstance(frame, np.ndarray)
    return frame


def _greedy(obs: np.ndarray) -> np.ndarray:
    return np.clip(obs[3:6] - obs[0:3], -0.05, 0.05).astype(np.float32)


def _rollout(env: ArmReachEnv, seed: int, actions: np.ndarray) -> np.ndarray:
    obs, _ = env.reset(seed=seed)
    trajectory = [obs]
    for action in actions:
        obs, _, terminated, truncated, _ = env.step(action)
        trajectory.append(obs)
        if terminated or truncated:
            break
    return np.stack(trajectory)


# Unbounded observation bounds are deliberate (joint velocities have no hard limit).
@pytest.mark.filterwarnings("ignore:.*Box observation space (minimum|maximum) value.*:UserWarning")
def test_passes_gymnasium_env_checker() -> None:
    environment = ArmReachEnv()
    check_env(environment, skip_render_check=True)
    environment.close()


def test_spaces_and_public_attributes(env: ArmReachEnv) -> None:
    assert isinstance(env.action_space, spaces.Box)
    assert env.action_space.shape == (3,)
    assert env.action_space.dtype == np.float32
    np.testing.assert_array_equal(env.action_space.low, np.full(3, -0.05, dtype=np.float32))
    np.testing.assert_array_equal(env.action_space.high, np.full(3, 0.05, dtype=np.float32))
    assert env.observation_space.shape == (16,)
    assert env.observation_space.dtype == np.float32
    unwrapped = env.unwrapped
    assert isinstance(unwrapped, ArmReachEnv)
    assert isinstance(unwrapped.model, mujoco.MjModel)
    assert isinstance(unwrapped.data, mujoco.MjData)
    assert env.n_substeps == 10
    assert env.model.opt.timestep == pytest.approx(0.002)
    assert env.control_timestep == pytest.approx(0.02)
    assert env.metadata["render_modes"] == ["rgb_array"]
    assert env.metadata["render_fps"] == 50


def test_model_has_named_elements(env: ArmReachEnv) -> None:
    model = env.model

    def names(obj: mujoco.mjtObj, count: int) -> set[str]:
        return {mujoco.mj_id2name(model, obj, i) for i in range(count)}

    assert {"base", "upper_arm", "forearm", "wrist", "hand"} <= names(mujoco.mjtObj.mjOBJ_BODY, model.nbody)
    assert {"floor", "finger_left", "finger_right"} <= names(mujoco.mjtObj.mjOBJ_GEOM, model.ngeom)
    assert names(mujoco.mjtObj.mjOBJ_JOINT, model.njnt) == set(JOINT_NAMES)
    assert names(mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu) == set(JOINT_NAMES)
    assert {"ee", "target"} <= names(mujoco.mjtObj.mjOBJ_SITE, model.nsite)
    assert "overview" in names(mujoco.mjtObj.mjOBJ_CAMERA, model.ncam)
    assert model.nmocap == 0


def test_observation_layout(env: ArmReachEnv) -> None:
    obs, info = env.reset(seed=3)
    ee_site = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_SITE, "ee")
    target_site = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_SITE, "target")
    np.testing.assert_allclose(obs[0:3], env.data.site_xpos[ee_site], atol=1e-6)
    np.testing.assert_allclose(obs[3:6], env.data.site_xpos[target_site], atol=1e-6)
    np.testing.assert_allclose(obs[6:11], env.data.qpos, atol=1e-6)
    np.testing.assert_allclose(obs[11:16], env.data.qvel, atol=1e-6)
    assert info["distance"] == pytest.approx(float(np.linalg.norm(obs[3:6] - obs[0:3])), abs=1e-5)
    assert info["is_success"] is False


def test_same_seed_gives_bitwise_identical_trajectories(env: ArmReachEnv) -> None:
    obs_a, _ = env.reset(seed=0)
    obs_b, _ = env.reset(seed=0)
    assert obs_a.tobytes() == obs_b.tobytes()

    actions = np.random.default_rng(123).uniform(-0.05, 0.05, size=(60, 3)).astype(np.float32)
    first = _rollout(env, 0, actions)
    second = _rollout(ArmReachEnv(), 0, actions)
    assert first.tobytes() == second.tobytes()


def test_different_seeds_give_different_targets(env: ArmReachEnv) -> None:
    targets = [env.reset(seed=seed)[0][3:6] for seed in range(8)]
    assert len({target.tobytes() for target in targets}) == len(targets)


def test_sampled_targets_respect_workspace_limits(env: ArmReachEnv) -> None:
    for seed in range(50):
        obs, info = env.reset(seed=seed)
        assert obs[5] >= 0.05 - 1e-6
        assert info["distance"] >= 0.10 - 1e-6


def test_greedy_controller_reaches_targets(env: ArmReachEnv) -> None:
    successes = 0
    for seed in range(10):
        obs, _ = env.reset(seed=seed)
        for _ in range(200):
            obs, reward, terminated, truncated, info = env.step(_greedy(obs))
            assert reward == pytest.approx(-info["distance"])
            if terminated or truncated:
                break
        assert terminated == info["is_success"]
        successes += int(info["is_success"])
    assert successes >= 9


def test_success_terminates_below_threshold(env: ArmReachEnv) -> None:
    obs, _ = env.reset(seed=0)
    for _ in range(200):
        obs, _, terminated, truncated, info = env.step(_greedy(obs))
        if terminated or truncated:
            break
    assert terminated
    assert not truncated
    assert info["is_success"] is True
    assert info["distance"] < env.success_threshold


def test_truncates_at_exactly_max_episode_steps(env: ArmReachEnv) -> None:
    # A target far outside the 0.7 m reach can never be hit, so only the time limit ends the episode.
    env.reset(seed=0, options={"target_pos": (1.5, 1.5, 1.5)})
    zero = np.zeros(3, dtype=np.float32)
    for step in range(1, 201):
        _, _, terminated, truncated, info = env.step(zero)
        assert not terminated
        assert info["is_success"] is False
        assert truncated == (step == 200)


def test_zero_action_holds_the_arm_still(env: ArmReachEnv) -> None:
    obs, _ = env.reset(seed=1)
    for _ in range(50):
        last, *_ = env.step(np.zeros(3, dtype=np.float32))
    np.testing.assert_allclose(last[0:3], obs[0:3], atol=1e-3)


def test_actions_are_clipped(env: ArmReachEnv) -> None:
    large = np.tile(np.array([[1.0, -1.0, 0.5]], dtype=np.float32), (20, 1))
    clipped = np.clip(large, -0.05, 0.05)
    assert _rollout(env, 2, large).tobytes() == _rollout(env, 2, clipped).tobytes()


def test_target_option_places_target(env: ArmReachEnv) -> None:
    obs, _ = env.reset(seed=0, options={"target_pos": [0.3, -0.2, 0.25]})
    np.testing.assert_allclose(obs[3:6], [0.3, -0.2, 0.25], atol=1e-6)
    np.testing.assert_allclose(env.target_pos, [0.3, -0.2, 0.25])


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"goal": 1}, "`options` keys must be among ['target_pos']. Received ['goal']."),
        (
            {"target_pos": (1.0, 2.0)},
            "`options['target_pos']` must be 3 finite numbers. Received (1.0, 2.0).",
        ),
    ],
)
def test_bad_reset_options_raise(env: ArmReachEnv, options: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        env.reset(seed=0, options=options)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"render_mode": "human"}, "`render_mode` must be one of [None, 'rgb_array']. Received 'human'."),
        ({"success_threshold": -1.0}, "`success_threshold` must be > 0. Received -1.0."),
        ({"success_threshold": 0.0}, "`success_threshold` must be > 0. Received 0.0."),
        ({"success_threshold": float("nan")}, "`success_threshold` must be > 0. Received nan."),
        ({"width": 0}, "`width` must be a positive int. Received 0."),
        ({"height": 12.5}, "`height` must be a positive int. Received 12.5."),
        ({"max_episode_steps": -3}, "`max_episode_steps` must be a positive int. Received -3."),
        ({"max_episode_steps": True}, "`max_episode_steps` must be a positive int. Received True."),
    ],
)
def test_bad_constructor_arguments_raise(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        ArmReachEnv(**kwargs)  # type: ignore[arg-type]


def test_render_without_render_mode_returns_none(env: ArmReachEnv) -> None:
    env.reset(seed=0)
    assert env.render() is None


@pytest.mark.render
@pytest.mark.usefixtures("rendering_available")
def test_render_returns_rgb_frame() -> None:
    environment = ArmReachEnv(render_mode="rgb_array")
    environment.reset(seed=0)
    frame = _frame(environment)
    assert frame.shape == (480, 480, 3)
    assert frame.dtype == np.uint8
    environment.close()
    environment.close()  # closing twice must be harmless


@pytest.mark.render
@pytest.mark.usefixtures("rendering_available")
def test_render_shows_the_target() -> None:
    environment = ArmReachEnv(render_mode="rgb_array", width=160, height=120)
    environment.reset(seed=0, options={"target_pos": (0.3, -0.3, 0.3)})
    first = _frame(environment).copy()
    environment.reset(seed=0, options={"target_pos": (0.3, 0.3, 0.5)})
    second = _frame(environment)
    assert first.shape == (120, 160, 3)
    assert not np.array_equal(first, second)
    environment.close()


@pytest.mark.render
@pytest.mark.usefixtures("rendering_available")
def test_render_frames_differ_for_different_seeds() -> None:
    environment = ArmReachEnv(render_mode="rgb_array")
    environment.reset(seed=0)
    first = _frame(environment).copy()
    environment.reset(seed=1)
    second = _frame(environment)
    assert not np.array_equal(first, second)
    environment.close()
