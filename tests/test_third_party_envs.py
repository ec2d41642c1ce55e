"""Wrappers on envs nobody here tuned for (issue 16 §2-§3): spec'd gymnasium envs and recreation,
observation bounds that are stale, mocap-driven arms, tasks whose own reset writes a randomised
field, divergence during reset, and wrong-shaped actions."""

from __future__ import annotations

import pickle
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real as s2r
from noise_models import ActionLatency, ActionNoise, Bias, Gaussian, ObservationLatency, ObservationNoise
from randomizers import Uniform

# -- spec'd envs: gymnasium's checker and recreation ------------------------------------------------


@pytest.mark.parametrize(
    "effects",
    [
        (s2r.Friction(scale=Uniform(0.5, 1.5)),),
        (ObservationNoise(Gaussian(std=0.01)), ActionLatency(steps=2)),
        (s2r.Mass(scale=Uniform(0.8, 1.2)), ObservationNoise(Gaussian(std=0.01)), ActionNoise(Gaussian(std=0.1))),
    ],
    ids=["physics", "signals", "both"],
)
def test_check_env_passes_on_a_spec_d_env(effects: tuple[Any, ...]) -> None:
    from gymnasium.utils.env_checker import check_env

    env = s2r.wrap(s2r.make("gym/Reacher-v5"), *effects, seed=0)
    assert env.spec is not None and env.spec.additional_wrappers
    check_env(env, skip_render_check=True)
    env.close()


def test_spec_d_env_is_recreated_with_the_same_effects() -> None:
    effects = (s2r.Damping(scale=Uniform(0.5, 2.0)), ObservationNoise(Bias(0.25)))
    env = s2r.wrap(s2r.make("gym/Reacher-v5"), *effects, seed=3)
    spec = pickle.loads(pickle.dumps(env.spec))  # effects are values: the spec pickles
    twin = spec.make()
    assert type(twin) is type(env) and type(twin.env) is type(env.env)
    # Physics and signals in one layer (sim2real.wrappers.fused) since issue 15; its spec records both lists.
    assert twin.randomizer.effects == env.randomizer.effects
    assert twin.corruptor.models == env.corruptor.models
    obs, info = env.reset(seed=1)
    obs2, info2 = twin.reset(seed=1)
    assert info["sim2real"]["params"] == info2["sim2real"]["params"]
    np.testing.assert_array_equal(obs, obs2)
    env.close()
    twin.close()


# -- observation bounds that are stale ---------------------------------------------------------------

STALE_XML = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody><body><joint name="slide" type="slide"/><geom size="0.1" mass="1"/></body></worldbody>
  <actuator><motor joint="slide"/></actuator>
</mujoco>
"""


class StaleBoundsEnv(gym.Env):
    """Declares every observation inside [-1, 1], but its goal (entry 2) is at 5: the bounds are stale."""

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(STALE_XML)
        self.data = mujoco.MjData(self.model)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float64)

    def _obs(self) -> np.ndarray:
        return np.array([0.5, 0.9, 5.0])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        return self._obs(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.data.ctrl[:] = action
        mujoco.mj_step(self.model, self.data)
        return self._obs(), 0.0, False, False, {}


def test_zero_noise_leaves_a_stale_observation_unchanged() -> None:
    env = s2r.wrap(StaleBoundsEnv(), ObservationNoise(Gaussian(std=0.0)), seed=0)
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(obs, [0.5, 0.9, 5.0])  # the goal was clipped to 1.0 before
    obs, *_ = env.step(np.zeros(1))
    np.testing.assert_array_equal(obs, [0.5, 0.9, 5.0])


def test_unselected_entries_are_never_clipped_and_selected_ones_are() -> None:
    env = s2r.wrap(StaleBoundsEnv(), ObservationNoise(Bias(0.3), select=[1]), seed=0)
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(obs, [0.5, 1.0, 5.0])  # 0.9 + 0.3 clipped to the bound, goal untouched


def test_noise_on_an_entry_already_outside_its_bounds_is_not_clipped() -> None:
    env = s2r.wrap(StaleBoundsEnv(), ObservationNoise(Bias(0.25)), seed=0)
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(obs, [0.75, 1.0, 5.25])


def test_clip_false_turns_observation_clipping_off() -> None:
    model = ObservationNoise(Bias(0.3), clip=False)
    assert repr(model) == "ObservationNoise(Bias(offset=0.3), clip=False)"
    assert model.to_config()["clip"] is False
    assert model != ObservationNoise(Bias(0.3))
    env = s2r.wrap(StaleBoundsEnv(), model, seed=0)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs, [0.8, 1.2, 5.3])


def test_clip_must_be_a_bool() -> None:
    with pytest.raises(TypeError, match=r"^`clip` must be a bool\. Received 1\.$"):
        ObservationNoise(Bias(0.3), clip=1)  # type: ignore[arg-type]


# -- wrong-shaped actions ------------------------------------------------------------------------------

SHAPE_MESSAGE = "`action` must have the shape of the env's action space, (2,). Received an array of shape {}."


@pytest.mark.parametrize("action", [np.zeros(3), [0.0], np.zeros((2, 1)), 0.0], ids=["3", "1", "2x1", "scalar"])
@pytest.mark.parametrize("model", [ActionNoise(Gaussian(std=0.1)), ActionLatency(steps=3)], ids=["noise", "latency"])
def test_wrong_shaped_action_names_expected_and_received_shape(action: Any, model: Any) -> None:
    env = s2r.wrap(s2r.make("dmc/reacher-easy"), model, seed=0)
    env.reset(seed=0)
    with pytest.raises(ValueError) as err:
        env.step(action)
    assert str(err.value) == SHAPE_MESSAGE.format(np.shape(action))
    env.close()


def test_wrong_shaped_action_on_dm_env() -> None:
    from dm_control import suite

    env = s2r.wrap(suite.load("reacher", "easy"), ActionLatency(steps=1), seed=0)
    env.reset()
    with pytest.raises(ValueError) as err:
        env.step(np.zeros(3))
    assert str(err.value) == SHAPE_MESSAGE.format((3,))
    env.close()


def test_wrong_shaped_action_on_torchrl() -> None:
    import torch
    from torchrl.envs import DMControlEnv

    env = s2r.wrap(DMControlEnv("reacher", "easy"), ActionNoise(Gaussian(std=0.1)), seed=0)
    td = env.reset()
    td["action"] = torch.zeros(3, dtype=torch.float64)
    with pytest.raises(ValueError) as err:
        env.step(td)
    assert str(err.value) == SHAPE_MESSAGE.format((3,))


def test_wrong_shaped_action_to_the_engine() -> None:
    from noise_models import Layout, SignalCorruptor

    c = SignalCorruptor([ActionNoise(Gaussian(std=0.1))], seed=0)
    c.bind(obs=None, action=Layout(2), timestep=0.01)
    c.begin_episode()
    with pytest.raises(ValueError) as err:
        c.act(np.zeros((1, 2)))
    assert str(err.value) == (
        "`action` must be a flat array of shape (2,) (the action layout). Received an array of shape (1, 2)."
    )


def test_observation_latency_still_passes_any_action() -> None:
    # Only layers that read the action check its shape; the env validates the rest.
    env = s2r.wrap(s2r.make("dmc/reacher-easy"), ObservationLatency(steps=2), seed=0)
    env.reset(seed=0)
    env.step([0.0, 0.0])
    env.close()


# -- mocap-driven arms ---------------------------------------------------------------------------------

MOCAP_XML = """
<mujoco>
  <option timestep="0.002" gravity="0 0 0"/>
  <worldbody>
    <body name="hand_target" mocap="true"/>
    <body name="hand">
      <freejoint/>
      <geom type="box" size="0.02 0.02 0.02" mass="0.5"/>
      <body name="finger" pos="0.03 0 0">
        <joint name="grip" type="slide" axis="1 0 0" range="0 0.05"/>
        <geom type="box" size="0.01 0.01 0.01" mass="0.05"/>
      </body>
    </body>
  </worldbody>
  <equality><weld body1="hand_target" body2="hand" solref="0.02 1"/></equality>
  <actuator>{actuators}</actuator>
</mujoco>
"""
GRIPPER = '<position name="grip" joint="grip" kp="100"/>'
WRISTS = "".join(f'<motor name="wrist{i}" joint="grip" gear="0"/>' for i in range(3))


class MocapArmEnv(gym.Env):
    """A hand moved through a mocap weld, as manipulation suites do: ``step`` writes ``mocap_pos`` from
    action[:3] and the gripper's ``ctrl`` from action[3], then calls ``mj_step`` itself (no hook).

    With ``action_is_ctrl`` the model also has three inert actuators, so the action's size equals
    ``model.nu`` and the env writes the whole action to ``ctrl`` too: only the weld reveals the mocap."""

    frame_skip = 10

    def __init__(self, action_is_ctrl: bool = False) -> None:
        actuators = (WRISTS + GRIPPER) if action_is_ctrl else GRIPPER
        self.model = mujoco.MjModel.from_xml_string(MOCAP_XML.format(actuators=actuators))
        self.data = mujoco.MjData(self.model)
        self.action_is_ctrl = action_is_ctrl
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (4,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float64)

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.data.body("hand").xpos, self.data.qpos[7:8]])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.data.mocap_pos[0] = 0.1 * np.asarray(action[:3])
        if self.action_is_ctrl:
            self.data.ctrl[:] = action
        else:
            self.data.ctrl[0] = action[3]
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        return self._obs(), 0.0, False, False, {}


def _hand_path(env: gym.Env, actions: np.ndarray) -> np.ndarray:
    env.reset(seed=0)
    return np.array([env.step(a)[0] for a in actions])


@pytest.mark.parametrize("action_is_ctrl", [False, True], ids=["size-differs", "mocap-weld"])
def test_action_latency_delays_a_mocap_driven_hand_by_what_it_reports(action_is_ctrl: bool) -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, (12, 4))
    env = s2r.wrap(MocapArmEnv(action_is_ctrl), ActionLatency(steps=20), seed=0)
    _, info = env.reset(seed=0)
    report = info["sim2real"]
    assert report["action_latency_path"] == "action" == env.action_latency_path
    params = report["params"]
    assert (params["action_latency_steps"], params["action_latency_control_steps"]) == (20, 2)
    assert params["action_latency"] == pytest.approx(0.04)
    wrapped = _hand_path(env, actions)
    bare = _hand_path(MocapArmEnv(action_is_ctrl), actions)
    delayed = _hand_path(MocapArmEnv(action_is_ctrl), np.vstack([np.zeros((2, 4)), actions[:-2]]))
    assert not np.allclose(wrapped[:, :3], bare[:, :3])  # before: the hand moved exactly as without latency
    np.testing.assert_array_equal(wrapped, delayed)  # hand and gripper, 2 control steps = 20 physics steps late


def test_mocap_latency_is_rounded_to_whole_control_steps_and_reported_as_applied() -> None:
    env = s2r.wrap(MocapArmEnv(), ActionLatency(steps=14), seed=0)
    _, info = env.reset(seed=0)
    params = info["sim2real"]["params"]
    assert (params["action_latency_steps"], params["action_latency_control_steps"]) == (10, 1)
    actions = np.random.default_rng(1).uniform(-1, 1, (5, 4))
    delayed = _hand_path(MocapArmEnv(), np.vstack([np.zeros((1, 4)), actions[:-1]]))
    np.testing.assert_array_equal(_hand_path(env, actions), delayed)


def test_ctrl_driven_env_keeps_physics_rate_latency() -> None:
    env = s2r.wrap(s2r.make("dmc/reacher-easy"), ActionLatency(steps=3), seed=0)
    _, info = env.reset(seed=0)
    assert info["sim2real"]["action_latency_path"] == "ctrl"
    assert "action_latency_control_steps" not in info["sim2real"]["params"]
    env.close()


def test_dm_env_reports_the_latency_path() -> None:
    from dm_control import suite

    dm = s2r.wrap(suite.load("reacher", "easy"), ActionLatency(steps=3), seed=0)
    assert dm.action_latency_path == "ctrl"
    dm.close()


# -- reported draws are what the model holds -------------------------------------------------------------

DRAW_EFFECTS = (
    s2r.Damping(scale=Uniform(5.0, 50.0)),  # finger-spin's reset writes hinge damping = 0.03
    s2r.Mass(scale=Uniform(0.5, 2.0)),
    s2r.Friction(scale=Uniform(0.5, 1.5)),
)


def _held(model: mujoco.MjModel, address: str) -> float:
    """The live model's value at ``address``, read independently of randomizers (the test's oracle)."""
    field, element, *index = address.replace("]", "").split("[")
    kind = {"dof": mujoco.mjtObj.mjOBJ_JOINT, "body": mujoco.mjtObj.mjOBJ_BODY, "geom": mujoco.mjtObj.mjOBJ_GEOM}
    prefix = field.split("_")[0]
    i = mujoco.mj_name2id(model, kind[prefix], element)
    row = model.jnt_dofadr[i] if prefix == "dof" else i
    value = getattr(model, field)[row]
    return float(value[int(index[0])] if index else value)


def _assert_model_holds(model: mujoco.MjModel, params: dict[str, float]) -> None:
    assert params
    wrong = {a: (v, _held(model, a)) for a, v in params.items() if _held(model, a) != v}
    assert not wrong, f"reported != held: {wrong}"


SUITE_TASKS = [("finger", "spin"), ("cartpole", "swingup"), ("cheetah", "run")]


@pytest.mark.parametrize(("domain", "task"), SUITE_TASKS)
def test_gymnasium_reports_what_the_model_holds_after_reset(domain: str, task: str) -> None:
    from dm_control import suite

    from sim2real.adapters import DmEnvToGym

    env = s2r.wrap(DmEnvToGym(suite.load(domain, task)), *DRAW_EFFECTS, seed=0)
    model = s2r.find_physics(env).model
    for episode in range(3):
        obs, info = env.reset(seed=episode)
        _assert_model_holds(model, info["sim2real"]["params"])
        _assert_model_holds(model, env.current_params)
        np.testing.assert_array_equal(obs, env.unwrapped.observe())  # consistent with the model as applied
        assert bool(info["sim2real"]["reapplied"]) == (domain == "finger")
    if domain == "finger":
        assert info["sim2real"]["reapplied"] == ("dof_damping[hinge]",)
    env.close()


@pytest.mark.parametrize(("domain", "task"), SUITE_TASKS)
def test_dm_env_reports_what_the_model_holds_after_reset(domain: str, task: str) -> None:
    from dm_control import suite

    env = s2r.wrap(suite.load(domain, task), *DRAW_EFFECTS, seed=0)
    for _ in range(3):
        env.reset()
        _assert_model_holds(env.physics.model.ptr, env.current_params)
    env.close()


@pytest.mark.parametrize(("domain", "task"), SUITE_TASKS)
def test_torchrl_reports_what_the_model_holds_after_reset(domain: str, task: str) -> None:
    from torchrl.envs import DMControlEnv

    env = s2r.wrap(DMControlEnv(domain, task), *DRAW_EFFECTS, seed=0)
    transform = env.transform
    for _ in range(3):
        td = env.reset()
        model = transform._bound().model
        _assert_model_holds(model, dict(zip(transform.param_names, td["sim2real_params"].tolist(), strict=True)))
    env.close()


def test_gymnasium_mujoco_env_reports_what_the_model_holds() -> None:
    env = s2r.wrap(s2r.make("gym/Reacher-v5"), *DRAW_EFFECTS, seed=0)
    _, info = env.reset(seed=0)
    _assert_model_holds(env.unwrapped.model, info["sim2real"]["params"])
    assert info["sim2real"]["reapplied"] == ()
    env.close()


def test_composer_task_reports_what_each_recompiled_model_holds() -> None:
    env = s2r.wrap(s2r.make("dmc/jaco-reach_site"), s2r.Damping(scale=Uniform(0.5, 2.0)), seed=0)
    for episode in range(2):
        _, info = env.reset(seed=episode)
        _assert_model_holds(s2r.find_physics(env).model, info["sim2real"]["params"])
    env.close()


# -- divergence during reset ---------------------------------------------------------------------------

STIFF = s2r.Stiffness(set=1e9)  # cheetah settles its physics inside reset: this blows up there


def test_gymnasium_flags_a_reset_that_diverges_and_truncates_next_step() -> None:
    from dm_control import suite

    from sim2real.adapters import DmEnvToGym

    env = s2r.wrap(DmEnvToGym(suite.load("cheetah", "run")), STIFF, seed=0)
    obs, info = env.reset(seed=0)  # dm-control's PhysicsError before
    report = info["sim2real"]
    assert report["diverged"] is True and "diverged" not in info
    assert report["params"]["jnt_stiffness[rootz]"] == 1e9  # the draws that caused it
    assert np.isfinite(obs).all()
    obs2, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert (reward, terminated, truncated, info["sim2real"]["diverged"]) == (0.0, False, True, True)
    np.testing.assert_array_equal(obs2, obs)
    env.close()


def test_dm_env_flags_a_reset_that_diverges() -> None:
    import dm_env
    from dm_control import suite

    env = s2r.wrap(suite.load("cheetah", "run"), STIFF, seed=0)
    timestep = env.reset()
    assert timestep.step_type == dm_env.StepType.FIRST and env.diverged
    assert env.current_params["jnt_stiffness[rootz]"] == 1e9
    timestep = env.step(np.zeros(6))
    assert (timestep.step_type, timestep.discount, timestep.reward) == (dm_env.StepType.LAST, 1.0, 0.0)
    env.close()


def test_torchrl_flags_a_reset_that_diverges() -> None:
    from torchrl.envs import DMControlEnv

    env = s2r.wrap(DMControlEnv("cheetah", "run"), STIFF, seed=0)
    td = env.reset()
    assert td["sim2real_diverged"].tolist() == [True]
    td = env.rand_step(td)
    assert td["next", "truncated"].tolist() == [True] and td["next", "sim2real_diverged"].tolist() == [True]


def test_a_healthy_reset_is_not_flagged() -> None:
    env = s2r.wrap(s2r.make("dmc/reacher-easy"), s2r.Stiffness(set=1.0), seed=0)
    _, info = env.reset(seed=0)
    assert info["sim2real"]["diverged"] is False
    assert env.step(np.zeros(2))[3] is False
    env.close()


# -- env shapes ActionLatency refuses ------------------------------------------------------------------


class DictActionEnv(gym.Env):
    observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float64)
    action_space = gym.spaces.Dict({"arm": gym.spaces.Box(-1.0, 1.0, (2,), np.float64)})

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        return np.zeros(1), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        return np.zeros(1), 0.0, False, False, {}


class UnreachableStepEnv(StaleBoundsEnv):
    """Its action is its ctrl, but it steps MuJoCo from plain Python: no hook to delay ctrl at physics rate."""

    def __init__(self) -> None:
        super().__init__()
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float64)


def test_action_latency_refuses_a_dict_action_space() -> None:
    with pytest.raises(TypeError) as err:
        s2r.wrap(DictActionEnv(), ActionLatency(steps=1), seed=0)
    assert str(err.value) == f"action models need a Box action space. Received {DictActionEnv.action_space!r}."


def test_action_latency_refuses_an_unreachable_physics_step() -> None:
    with pytest.raises(TypeError) as err:
        s2r.wrap(UnreachableStepEnv(), ActionLatency(steps=1), seed=0)
    assert str(err.value) == (
        f"{UnreachableStepEnv.__module__}.UnreachableStepEnv steps MuJoCo without a hook sim2real can intercept "
        "(gymnasium's MujocoEnv._step_mujoco_simulation, a `_simulate(nstep)` method, or dm-control's "
        "Physics.step), so physics-rate action latency and ControlJitter cannot reach it. Give the env a "
        "`_simulate(nstep)` method that calls mujoco.mj_step."
    )
