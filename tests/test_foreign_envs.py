"""Envs written the way other people write them (issue: wrap environments nobody here designed): a TorchRL
``EnvBase`` with nested Composite observations, envs without actuators."""

from __future__ import annotations

from typing import Any

import dm_env
import dm_env.specs
import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real as s2r
from noise_models import ActionLatency, ActionNoise, Bias, ControlJitter, Gaussian, ObservationLatency, ObservationNoise
from randomizers import Choice, Uniform

ARM_XML = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="link1"><joint name="j1" type="hinge" axis="0 0 1" damping="0.2"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.3"/>
      <body name="link2" pos="0.2 0 0"><joint name="j2" type="hinge" axis="0 0 1" damping="0.1"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.2"/></body></body>
  </worldbody>
  <actuator><motor name="m1" joint="j1"/><motor name="m2" joint="j2"/></actuator>
</mujoco>
"""


def _nested_torchrl_arm() -> Any:
    """A TorchRL env as users write one: ``EnvBase`` around MuJoCo, joint state nested under ``"robot"``."""
    import torch
    from tensordict import TensorDict
    from torchrl.data import Bounded, Composite, Unbounded
    from torchrl.envs import EnvBase

    class NestedArm(EnvBase):
        n_substeps = 4

        def __init__(self) -> None:
            super().__init__(device="cpu")
            self.model = mujoco.MjModel.from_xml_string(ARM_XML)
            self.data = mujoco.MjData(self.model)
            f64 = torch.float64
            self.observation_spec = Composite(
                robot=Composite(qpos=Unbounded((2,), dtype=f64), qvel=Unbounded((2,), dtype=f64)),
                tip=Unbounded((3,), dtype=torch.float32),
            )
            self.action_spec = Bounded(-1.0, 1.0, (2,), dtype=f64)
            self.reward_spec = Unbounded((1,))

        def _obs(self) -> dict[str, Any]:
            d = self.data
            robot = {"qpos": torch.tensor(d.qpos.copy()), "qvel": torch.tensor(d.qvel.copy())}
            return {"robot": robot, "tip": torch.tensor(d.xpos[2].astype(np.float32))}

        def _reset(self, td: Any) -> Any:
            mujoco.mj_resetData(self.model, self.data)
            mujoco.mj_forward(self.model, self.data)
            done = torch.zeros(1, dtype=torch.bool)
            return TensorDict({**self._obs(), "done": done, "terminated": done.clone()}, [])

        def _simulate(self, nstep: int) -> None:
            mujoco.mj_step(self.model, self.data, nstep=nstep)

        def _step(self, td: Any) -> Any:
            self.data.ctrl[:] = td["action"].numpy()
            self._simulate(self.n_substeps)
            done = torch.zeros(1, dtype=torch.bool)
            return TensorDict({**self._obs(), "reward": torch.zeros(1), "done": done, "terminated": done.clone()}, [])

        def _set_seed(self, seed: int | None) -> None:
            pass

    return NestedArm()


@pytest.mark.parametrize("physics", [False, True], ids=["signals", "fused"])
def test_noise_reaches_nested_torchrl_observations(physics: bool) -> None:
    from torchrl.envs.utils import check_env_specs

    effects = (s2r.Mass(scale=1.0),) if physics else ()
    env = s2r.wrap(_nested_torchrl_arm(), *effects, ObservationNoise(Bias(0.5)), seed=0)
    check_env_specs(env, seed=0)
    td = env.reset()
    bare = _nested_torchrl_arm().reset()
    for key in (("robot", "qpos"), ("robot", "qvel"), "tip"):  # the nested entries were left untouched before
        np.testing.assert_allclose(td[key].numpy(), bare[key].numpy() + 0.5)
        assert td[key].dtype == bare[key].dtype
    td = env.rand_step(td)
    assert td["next", "robot", "qvel"].dtype == bare["robot", "qvel"].dtype


def test_nested_torchrl_entries_are_selected_by_dotted_name_or_tuple_key() -> None:
    from torchrl.envs import TransformedEnv

    from sim2real.wrappers import CorruptSignalsTransform

    env = s2r.wrap(_nested_torchrl_arm(), ObservationNoise(Bias(0.5), select="robot.qv*"), seed=0)
    td = env.reset()
    np.testing.assert_array_equal(td["robot", "qpos"].numpy(), [0.0, 0.0])
    np.testing.assert_array_equal(td["robot", "qvel"].numpy(), [0.5, 0.5])
    transform = CorruptSignalsTransform([ObservationNoise(Bias(0.5))], seed=0, observation_keys=[("robot", "qpos")])
    td = TransformedEnv(_nested_torchrl_arm(), transform).reset()
    np.testing.assert_array_equal(td["robot", "qpos"].numpy(), [0.5, 0.5])
    np.testing.assert_array_equal(td["robot", "qvel"].numpy(), [0.0, 0.0])
    bad = CorruptSignalsTransform([ObservationNoise(Bias(0.5))], seed=0, observation_keys=[("robot", "x")])
    with pytest.raises(ValueError, match=r"^`observation_keys` names \[\('robot', 'x'\)\], which the env does not"):
        TransformedEnv(_nested_torchrl_arm(), bad).reset()


# -- envs without actuators --------------------------------------------------------------------------------------

BALL_XML = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 .1"/>
    <body name="ball" pos="0 0 1"><freejoint/><geom name="b" size="0.1" mass="1"/></body>
  </worldbody>
</mujoco>
"""


class DroppedBall(gym.Env):
    """A passive model (``nu = 0``): its action space is an empty Box, as gymnasium envs declare one."""

    frame_skip = 5

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(BALL_XML)
        self.data = mujoco.MjData(self.model)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (13,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (0,), np.float64)

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.data.qpos, self.data.qvel])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def _simulate(self, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self._simulate(self.frame_skip)
        return self._obs(), 0.0, False, False, {}


EMPTY_ACTION = (
    "{} need a non-empty action: this env's action has no entries, so nothing would be corrupted or delayed. "
    "Received an action of size 0."
)


@pytest.mark.parametrize(
    ("models", "names"),
    [
        ((ActionNoise(Gaussian(std=0.1)),), "ActionNoise"),  # an IndexError at the first reset before
        ((ActionLatency(steps=3),), "ActionLatency"),  # reported a latency of 0.03 s that delayed nothing
        ((ActionLatency(steps=3), ActionNoise(Gaussian(std=0.1))), "ActionLatency and ActionNoise"),
    ],
    ids=["noise", "latency", "both"],
)
@pytest.mark.parametrize("physics", [False, True], ids=["signals", "fused"])
def test_action_models_refuse_an_env_without_actuators(models: tuple[Any, ...], names: str, physics: bool) -> None:
    effects = (s2r.Mass(scale=1.0),) if physics else ()
    with pytest.raises(ValueError) as err:
        s2r.wrap(DroppedBall(), *effects, *models, seed=0)
    assert str(err.value) == EMPTY_ACTION.format(names)


class DroppedBallDm(dm_env.Environment):
    """The same ball as a plain ``dm_env.Environment`` with an empty action spec."""

    def __init__(self) -> None:
        self.gym = DroppedBall()

    def reset(self) -> dm_env.TimeStep:
        return dm_env.restart(self.gym.reset()[0])

    def step(self, action: Any) -> dm_env.TimeStep:
        return dm_env.transition(0.0, self.gym.step(action)[0])

    def observation_spec(self) -> Any:
        return dm_env.specs.Array((13,), np.float64, "state")

    def action_spec(self) -> Any:
        return dm_env.specs.BoundedArray((0,), np.float64, -1.0, 1.0, "action")


def test_action_models_refuse_an_empty_action_on_dm_env_and_torchrl() -> None:
    from torchrl.envs import GymWrapper

    with pytest.raises(ValueError) as err:
        s2r.wrap(DroppedBallDm(), ActionLatency(steps=3), seed=0)
    assert str(err.value) == EMPTY_ACTION.format("ActionLatency")
    with pytest.raises(ValueError) as err:
        s2r.wrap(GymWrapper(DroppedBall()), ActionNoise(Gaussian(std=0.1)), seed=0).reset()  # binds on first use
    assert str(err.value) == EMPTY_ACTION.format("ActionNoise")


def test_an_env_without_actuators_still_takes_physics_effects_and_observation_models() -> None:
    from gymnasium.utils.env_checker import check_env

    env = s2r.wrap(DroppedBall(), s2r.Mass(scale=2.0), ObservationNoise(Gaussian(std=0.01)), seed=0)
    _, info = env.reset(seed=0)
    assert info["sim2real"]["params"]["body_mass[ball]"] == 2.0
    check_env(env, skip_render_check=True)
    env.close()


# -- TorchRL's own action repeat (GymWrapper(..., frame_skip=k)) -------------------------------------------------


def _user_mujoco_env(xml_path: str, frame_skip: int, mocap: bool = False) -> Any:
    """A user's ``MujocoEnv`` subclass with its own XML and ``frame_skip``; with ``mocap`` its action moves a mocap
    target (the model has no actuators)."""
    from gymnasium.envs.mujoco import MujocoEnv

    class UserArm(MujocoEnv):
        metadata = {  # noqa: RUF012 - gymnasium's own envs declare it so
            "render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"],
            "render_fps": 25 if mocap else 50,  # 1 / dt, which MujocoEnv checks
        }

        def __init__(self) -> None:
            obs = gym.spaces.Box(-np.inf, np.inf, (6 if mocap else 4,), np.float64)
            MujocoEnv.__init__(self, xml_path, frame_skip, observation_space=obs)
            if mocap:
                self.action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

        def _get_obs(self) -> np.ndarray:
            if mocap:
                return np.concatenate([self.data.body("hand").xpos, self.data.qvel[:3]])
            return np.concatenate([self.data.qpos, self.data.qvel])

        def step(self, action: Any) -> Any:
            if mocap:
                self.data.mocap_pos[0] = 0.05 * np.asarray(action, dtype=np.float64)
                action = np.zeros(0)
            self.do_simulation(action, self.frame_skip)
            return self._get_obs(), 0.0, False, False, {}

        def reset_model(self) -> np.ndarray:
            self.set_state(self.init_qpos, self.init_qvel)
            return self._get_obs()

    return UserArm()


MOCAP_XML = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <body name="target" mocap="true"/>
    <body name="hand"><freejoint/><geom type="box" size="0.02 0.02 0.02" mass="0.5"/></body>
  </worldbody>
  <equality><weld body1="target" body2="hand" solref="0.02 1"/></equality>
</mujoco>
"""


def _torchrl_path(env: Any, actions: np.ndarray) -> tuple[dict[str, float], np.ndarray]:
    import torch

    td = env.reset()
    out = []
    for a in actions:
        td["action"] = torch.as_tensor(a, dtype=env.action_spec.dtype)
        td = env.step(td)["next"]
        out.append(td["observation"].numpy().copy())
    return dict(zip(env.transform.param_names, td["sim2real_signal_params"].tolist(), strict=True)), np.array(out)


def _reference(env: Any, actions: np.ndarray, repeat: int, action_lag: int = 0, obs_lag: int = 0) -> np.ndarray:
    """The bare env stepped by hand: ctrl applied ``action_lag`` physics steps late; an observation taken at
    physics step t arrives at t + ``obs_lag`` (the reset one at once) and the newest arrived one is seen."""
    env.reset(seed=0)
    model, data = env.unwrapped.model, env.unwrapped.data
    per_step = repeat * env.unwrapped.frame_skip
    taken, seen, t = [(0, env.unwrapped._get_obs())], [], 0
    for _ in actions:
        for _ in range(repeat):
            for _ in range(env.unwrapped.frame_skip):
                source = t - action_lag
                data.ctrl[:] = actions[source // per_step] if source >= 0 else 0.0
                mujoco.mj_step(model, data)
                t += 1
            mujoco.mj_rnePostConstraint(model, data)
        taken.append((t, env.unwrapped._get_obs()))
        seen.append([obs for stamp, obs in taken if stamp == 0 or stamp + obs_lag <= t][-1])
    return np.array(seen)


@pytest.mark.parametrize("repeat", [1, 2])
@pytest.mark.parametrize(
    ("model", "lags"),
    [(ActionLatency(steps=8), (8, 0)), (ActionLatency(steps=6), (6, 0)), (ObservationLatency(steps=6), (0, 6))],
    ids=["action-whole-steps", "action-mid-step", "observation"],
)
def test_physics_rate_latency_under_torchrl_frame_skip_is_what_is_reported(
    tmp_path: Any, repeat: int, model: Any, lags: tuple[int, int]
) -> None:
    from torchrl.envs import GymWrapper

    path = str(tmp_path / "arm.xml")
    with open(path, "w") as f:
        f.write(ARM_XML)
    env = s2r.wrap(GymWrapper(_user_mujoco_env(path, 4), frame_skip=repeat), model, seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (10, 2)).astype(np.float32)  # the env's action dtype
    params, seen = _torchrl_path(env, actions)
    side = "action" if isinstance(model, ActionLatency) else "obs"
    assert params[f"{side}_latency_steps"] == max(lags)
    # With frame_skip=2, a latency of whole control steps delayed the command by 2 TorchRL steps for the first half of
    # each step and not at all for the second, and the observation by 2 TorchRL steps (16 physics steps, not 6).
    np.testing.assert_array_equal(seen, _reference(_user_mujoco_env(path, 4), actions, repeat, *lags))


def test_mocap_action_latency_under_torchrl_frame_skip_counts_torchrl_steps(tmp_path: Any) -> None:
    from torchrl.envs import GymWrapper

    path = str(tmp_path / "mocap.xml")
    with open(path, "w") as f:
        f.write(MOCAP_XML)
    actions = np.random.default_rng(1).uniform(-1, 1, (6, 3)).astype(np.float32)
    env = s2r.wrap(
        GymWrapper(_user_mujoco_env(path, 20, mocap=True), frame_skip=2), ActionLatency(seconds=0.08), seed=0
    )
    params, seen = _torchrl_path(env, actions)
    assert env.transform.action_latency_path == "action"
    # 0.08 s is one TorchRL step of 2 x 20 physics steps (it was applied as 2 steps, 0.16 s, and reported as 0.08 s)
    assert (params["action_latency"], params["action_latency_steps"], params["action_latency_control_steps"]) == (
        0.08,
        40.0,
        1.0,
    )
    late = GymWrapper(_user_mujoco_env(path, 20, mocap=True), frame_skip=2)
    _, expected = _torchrl_path_bare(late, np.vstack([np.zeros((1, 3), np.float32), actions[:-1]]))
    np.testing.assert_array_equal(seen, expected)


def _torchrl_path_bare(env: Any, actions: np.ndarray) -> tuple[None, np.ndarray]:
    import torch

    td = env.reset()
    out = []
    for a in actions:
        td["action"] = torch.as_tensor(a)
        td = env.step(td)["next"]
        out.append(td["observation"].numpy().copy())
    return None, np.array(out)


# -- copies ---------------------------------------------------------------------------------------------------------


def _copies() -> list[Any]:
    import copy
    import pickle

    return [copy.deepcopy, lambda env: pickle.loads(pickle.dumps(env))]


@pytest.mark.parametrize("physics", [False, True], ids=["signals", "fused"])
def test_an_env_with_signal_models_refuses_copies_and_says_what_to_do(physics: bool) -> None:
    from dm_control import suite
    from torchrl.envs import GymWrapper

    effects = (s2r.Mass(scale=1.5),) if physics else ()
    models = (ObservationNoise(Gaussian(std=0.1)), ActionLatency(steps=2))
    envs = [
        s2r.wrap(gym.make("InvertedPendulum-v5"), *effects, *models, seed=0),
        s2r.wrap(suite.load("cartpole", "balance"), *effects, *models, seed=0),
        s2r.wrap(GymWrapper(gym.make("InvertedPendulum-v5")), *effects, *models, seed=0),
    ]
    for env in envs:
        env.reset()
        for copy in _copies():
            # Before: "cannot pickle 'memoryview' object" / "Can't pickle local object 'Gaussian.compile.<locals>...'";
            # a deep copy that got past them would have shared the original's noise closures and physics-step hook.
            with pytest.raises(TypeError, match=r"cannot be pickled or deep-copied: .*gymnasium\.make\(env\.spec\)"):
                copy(env)
        env.close()


def test_a_physics_only_env_is_copied_with_a_model_of_its_own() -> None:
    env = s2r.wrap(gym.make("InvertedPendulum-v5"), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=0)
    model = env.unwrapped.model
    nominal = model.body_mass.copy()
    obs, info = env.reset(seed=3)
    for copy in _copies():
        twin = copy(env)
        assert twin.unwrapped.model is not model
        obs2, info2 = twin.reset(seed=3)
        np.testing.assert_array_equal(obs2, obs)
        assert info2["sim2real"]["params"] == info["sim2real"]["params"]
        twin.close()
        np.testing.assert_array_equal(twin.unwrapped.model.body_mass, nominal)
    assert not np.array_equal(model.body_mass, nominal)  # the original keeps its draws until it closes
    env.close()
    np.testing.assert_array_equal(model.body_mass, nominal)


def test_a_make_vec_sub_env_is_recreated_from_its_spec() -> None:
    envs = s2r.make_vec("gym/InvertedPendulum-v5", 2, s2r.Mass(scale=Uniform(0.5, 2.0)), seed=4)
    sub = envs.envs[1]
    twin = gym.make(sub.spec)  # "_ReportAtReset wrapper does not inherit from RecordConstructorArgs" before
    assert type(twin) is type(sub) and type(twin.env) is type(sub.env)
    obs, info = sub.reset(seed=2)
    obs2, info2 = twin.reset(seed=2)
    np.testing.assert_array_equal(obs2, obs)
    assert info2["sim2real"]["params"] == info["sim2real"]["params"]
    assert "sim2real" not in twin.step(twin.action_space.sample())[4]  # still reports at resets only
    twin.close()
    envs.close()


# -- envs that step MuJoCo themselves ---------------------------------------------------------------------------


def _pd_arm(xml_path: str) -> Any:
    """A user's MujocoEnv that runs its own PD loop with ``mujoco.mj_step``, never through ``do_simulation``."""
    env = _user_mujoco_env(xml_path, 4)

    def step(action: Any) -> Any:
        for _ in range(env.frame_skip):
            env.data.ctrl[:] = 5.0 * (np.asarray(action) - env.data.qpos) - 0.5 * env.data.qvel
            mujoco.mj_step(env.model, env.data)
        return env._get_obs(), 0.0, False, False, {}

    env.step = step
    return env


UNREACHED = (
    "{module}._user_mujoco_env.<locals>.UserArm advanced its physics without calling do_simulation(ctrl, n_frames), so {names} (acting inside "
    "that call) would be reported but not applied. Step MuJoCo through do_simulation(ctrl, n_frames) in the env's "
    "`step`."
)


@pytest.mark.parametrize(
    ("models", "names"),
    [
        ((ActionLatency(steps=8),), "ActionLatency"),
        ((ControlJitter(Choice((-2.0, 2.0))), ObservationNoise(Gaussian(std=0.1))), "ControlJitter"),
    ],
    ids=["latency", "jitter"],
)
@pytest.mark.parametrize("api", ["gymnasium", "fused", "torchrl"])
def test_a_physics_rate_model_refuses_an_env_that_steps_mujoco_itself(
    tmp_path: Any, models: tuple[Any, ...], names: str, api: str
) -> None:
    path = str(tmp_path / "arm.xml")
    with open(path, "w") as f:
        f.write(ARM_XML)
    message = UNREACHED.format(module=__name__, names=names)
    if api == "torchrl":
        import torch
        from torchrl.envs import GymWrapper

        env = s2r.wrap(GymWrapper(_pd_arm(path)), *models, seed=0)
        td = env.reset()
        td["action"] = torch.zeros(2, dtype=env.action_spec.dtype)
        with pytest.raises(TypeError) as err:
            env.step(td)
    else:
        effects = (s2r.Mass(scale=1.0),) if api == "fused" else ()
        env = s2r.wrap(_pd_arm(path), *effects, *models, seed=0)
        env.reset(seed=0)
        # Before: the wrapped env stepped bitwise as the bare one while reporting the latency / jitter as applied.
        with pytest.raises(TypeError) as err:
            env.step(np.zeros(2))
    assert str(err.value) == message


def test_the_first_step_check_leaves_an_env_that_steps_through_its_hook_alone(tmp_path: Any) -> None:
    path = str(tmp_path / "arm.xml")
    with open(path, "w") as f:
        f.write(ARM_XML)
    env = s2r.wrap(_user_mujoco_env(path, 4), ActionLatency(steps=8), seed=0)
    assert "step" in vars(env)  # the one-shot check
    env.reset(seed=0)
    env.step(np.zeros(2))
    assert "step" not in vars(env)  # later steps are the class's own
    env.close()


class SelfSteppingDm(dm_env.Environment):
    """A plain dm_env around MuJoCo that has a ``_simulate`` method but steps with ``mujoco.mj_step`` itself."""

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(ARM_XML)
        self.data = mujoco.MjData(self.model)
        self.n_substeps = 4

    def _simulate(self, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def reset(self) -> dm_env.TimeStep:
        mujoco.mj_resetData(self.model, self.data)
        return dm_env.restart(self.data.qpos.copy())

    def step(self, action: Any) -> dm_env.TimeStep:
        self.data.ctrl[:] = action
        mujoco.mj_step(self.model, self.data, nstep=self.n_substeps)
        return dm_env.transition(0.0, self.data.qpos.copy())

    def observation_spec(self) -> Any:
        return dm_env.specs.Array((2,), np.float64, "qpos")

    def action_spec(self) -> Any:
        return dm_env.specs.BoundedArray((2,), np.float64, -1.0, 1.0, "action")


@pytest.mark.parametrize("physics", [False, True], ids=["signals", "fused"])
def test_a_dm_env_that_steps_mujoco_itself_is_refused_at_its_first_step(physics: bool) -> None:
    effects = (s2r.Mass(scale=1.0),) if physics else ()
    env = s2r.wrap(SelfSteppingDm(), *effects, ActionLatency(steps=6), seed=0)
    env.reset()
    with pytest.raises(TypeError, match=r"^tests?[\w.]*SelfSteppingDm advanced its physics without calling _simulate"):
        env.step(np.zeros(2))


# -- TorchRL envs whose action entry is not "action" -----------------------------------------------------------


def _keyed_torchrl_arm() -> Any:
    """A TorchRL env whose action is ``("arm", "torque")``."""
    import torch
    from tensordict import TensorDict
    from torchrl.data import Bounded, Composite, Unbounded
    from torchrl.envs import EnvBase

    class KeyedArm(EnvBase):
        def __init__(self) -> None:
            super().__init__(device="cpu")
            self.model = mujoco.MjModel.from_xml_string(ARM_XML)
            self.data = mujoco.MjData(self.model)
            self.n_substeps = 4
            self.observation_spec = Composite(qpos=Unbounded((2,), dtype=torch.float64))
            self.action_spec = Composite(arm=Composite(torque=Bounded(-1.0, 1.0, (2,), dtype=torch.float64)))
            self.reward_spec = Unbounded((1,))

        def _out(self, **extra: Any) -> Any:
            done = torch.zeros(1, dtype=torch.bool)
            qpos = torch.tensor(self.data.qpos.copy())
            return TensorDict({"qpos": qpos, "done": done, "terminated": done.clone(), **extra}, [])

        def _reset(self, td: Any) -> Any:
            mujoco.mj_resetData(self.model, self.data)
            return self._out()

        def _simulate(self, nstep: int) -> None:
            mujoco.mj_step(self.model, self.data, nstep=nstep)

        def _step(self, td: Any) -> Any:
            self.data.ctrl[:] = td["arm", "torque"].numpy()
            self._simulate(self.n_substeps)
            return self._out(reward=torch.zeros(1))

        def _set_seed(self, seed: int | None) -> None:
            pass

    return KeyedArm()


def test_signal_models_use_a_torchrl_envs_own_action_key() -> None:
    import torch
    from torchrl.envs.utils import check_env_specs

    for models in ((ObservationNoise(Gaussian(std=0.1)),), (ActionNoise(Bias(0.25)), ActionLatency(steps=4))):
        env = s2r.wrap(_keyed_torchrl_arm(), *models, seed=0)  # KeyError: 'action' before, whatever the models
        check_env_specs(env, seed=0)
    data = s2r.find_physics(env).data
    td = env.reset()
    td["arm", "torque"] = torch.tensor([0.1, -0.2], dtype=torch.float64)
    env.step(td)
    env.step(td)
    np.testing.assert_allclose(data.ctrl, [0.35, 0.05])  # the noisy command, one control step (4 physics steps) late


# -- envs that compile a new model in every reset -----------------------------------------------------------------

SLIDER_XML = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody>
    <body name="box" pos="0 0 {height}"><joint name="lift" type="slide" axis="0 0 1" damping="1"/>
      <geom size="0.1" mass="1"/></body>
  </worldbody>
  <actuator><motor name="push" joint="lift"/></actuator>
</mujoco>
"""


class RebuiltScene(gym.Env):
    """A procedural scene: every reset compiles a new model (the box at a height drawn from the reset's seed)."""

    frame_skip = 2

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float64)
        self._build()

    def _build(self) -> None:
        height = float(self.np_random.uniform(0.0, 1.0))
        self.model = mujoco.MjModel.from_xml_string(SLIDER_XML.format(height=height))
        self.data = mujoco.MjData(self.model)

    def _simulate(self, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.data.qpos, self.data.qvel])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        self._build()
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.data.ctrl[:] = action
        self._simulate(self.frame_skip)
        return self._obs(), 0.0, False, False, {}


def _held_by(model: mujoco.MjModel) -> dict[str, float]:
    return {"body_mass[box]": float(model.body_mass[1]), "dof_damping[lift]": float(model.dof_damping[0])}


@pytest.mark.parametrize("signals", [False, True], ids=["physics", "fused"])
def test_draws_reach_a_model_the_env_compiles_in_its_reset(signals: bool) -> None:
    effects = (s2r.Mass(scale=Uniform(0.5, 2.0)), s2r.Damping(scale=Uniform(2.0, 3.0)))
    models = (ObservationNoise(Bias(0.0)),) if signals else ()
    env = s2r.wrap(RebuiltScene(), *effects, *models, seed=0)
    for episode in range(3):
        obs, info = env.reset(seed=episode)
        params = {k: v for k, v in info["sim2real"]["params"].items() if k in ("body_mass[box]", "dof_damping[lift]")}
        assert params == _held_by(env.unwrapped.model)  # the draws stayed in the first model before
        np.testing.assert_array_equal(obs, env.unwrapped._obs())
    model = env.unwrapped.model
    env.close()
    assert _held_by(model) == {"body_mass[box]": 1.0, "dof_damping[lift]": 1.0}  # the current model's nominal


def test_torchrl_draws_reach_a_rebuilt_model() -> None:
    from torchrl.envs import GymWrapper

    env = s2r.wrap(GymWrapper(RebuiltScene()), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=0)
    for _ in range(2):
        td = env.reset()
        (mass,) = td["sim2real_params"].tolist()
        assert mass == s2r.find_physics(env).model.body_mass[1] != 1.0


def test_physics_rate_latency_follows_a_rebuilt_model() -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, (6, 1))
    env = s2r.wrap(RebuiltScene(), ActionLatency(steps=2), seed=0)
    for episode in range(2):  # the second episode runs on a model compiled after wrap
        env.reset(seed=episode)
        seen = np.array([env.step(a)[0] for a in actions])
        late = RebuiltScene()
        late.reset(seed=episode)
        expected = np.array([late.step(a)[0] for a in np.vstack([np.zeros((1, 1)), actions[:-1]])])
        np.testing.assert_array_equal(seen, expected)  # 2 physics steps = one control step late


# -- envs that reuse their observation buffer -------------------------------------------------------------------


class BufferedObservation(gym.Env):
    """Writes every observation into one preallocated array and returns it (no allocation per step)."""

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(SLIDER_XML.format(height=0.0))
        self.data = mujoco.MjData(self.model)
        self.frame_skip = 1
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float64)
        self._buffer = np.zeros(2)

    def _obs(self) -> np.ndarray:
        self._buffer[0], self._buffer[1] = self.data.qpos[0], self.data.qvel[0]
        return self._buffer

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        return self._obs(), {}

    def _simulate(self, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.data.ctrl[:] = action
        self._simulate(self.frame_skip)
        return self._obs(), 0.0, False, False, {}


@pytest.mark.parametrize(
    "latency",
    [ObservationLatency(steps=3), ObservationLatency(steps=3, jitter=Choice((0.0, 1.0)))],
    ids=["fixed", "jittered"],
)
def test_observation_latency_delays_an_env_that_reuses_its_observation_array(latency: Any) -> None:
    env = s2r.wrap(BufferedObservation(), latency, seed=0)
    first = env.reset(seed=0)[0].copy()
    seen = np.array([env.step(np.ones(1))[0].copy() for _ in range(8)])
    bare = BufferedObservation()
    truth = np.array([first, *(bare.step(np.ones(1))[0].copy() for _ in range(8))])
    taken = [int(np.flatnonzero((truth == row).all(axis=1))[-1]) for row in seen]  # the physics step observed
    # At physics step k + 1 the newest sample that has arrived was taken at k + 1 - 3 or before (the reset sample
    # until then). Before: every "delayed" observation was the env's live buffer, the current state.
    assert all(t == 0 or k + 1 - t >= 3 for k, t in enumerate(taken)), taken
    if latency.jitter is None:
        assert taken == [0, 0, 0, 1, 2, 3, 4, 5]


def test_a_batched_torchrl_env_is_refused_with_the_per_worker_recipe() -> None:
    from torchrl.envs import GymEnv, SerialEnv

    for effects in ((ObservationNoise(Gaussian(std=0.1)),), (s2r.Mass(scale=Uniform(0.5, 2.0)),)):
        # Before: a RecursionError (signals: TorchRL's batched __getattr__) or "has no MuJoCo model" (physics).
        with pytest.raises(TypeError, match=r"^`env` is a batched TorchRL env \(SerialEnv, batch_size \[2\]\): wrap"):
            s2r.wrap(SerialEnv(2, lambda: GymEnv("InvertedPendulum-v5")), *effects, seed=0)
    recipe = SerialEnv(
        2,
        [
            lambda i=i: s2r.wrap(GymEnv("InvertedPendulum-v5"), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=(0, i))
            for i in range(2)
        ],
    )
    first, second = recipe.reset()["sim2real_params"].tolist()
    assert first != second
    recipe.close()


@pytest.mark.parametrize("repeat", [1, 2])
def test_torchrl_reports_the_substeps_control_jitter_applied(repeat: int) -> None:
    from torchrl.envs import GymWrapper
    from torchrl.envs.utils import check_env_specs

    jitter = ControlJitter(Choice((-2.0, 0.0, 3.0)))
    env = s2r.wrap(GymWrapper(gym.make("InvertedPendulum-v5"), frame_skip=repeat), jitter, seed=0)
    check_env_specs(env, seed=0)  # the per-step draw was in no TensorDict key before
    data = s2r.find_physics(env).data
    td = env.reset()
    applied, reported = [], []
    for _ in range(12):
        start = data.time
        td = env.rand_step(td)["next"]
        applied.append(round((data.time - start) / 0.02))  # InvertedPendulum-v5: 0.02 s per physics step
        reported.append(int(td["sim2real_substeps"]))
    assert reported == applied and len(set(applied)) > 1


@pytest.mark.parametrize("signals", [False, True], ids=["physics", "fused"])
def test_torchrl_reports_the_pushes_each_step_applied(signals: bool) -> None:
    from torchrl.envs import GymEnv
    from torchrl.envs.utils import check_env_specs

    push = s2r.Push(force=Uniform(1.0, 2.0), interval=Uniform(2.0, 3.0), bodies="object")
    models = (ObservationNoise(Gaussian(std=0.01)),) if signals else ()
    env = s2r.wrap(GymEnv("Pusher-v5"), push, *models, seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(12)
    rows = td["next", "sim2real_pushes"][:, 0].numpy()  # the pushes were in no TensorDict key before
    physics = env.transform.physics if signals else env.transform
    events = physics.randomizer.events
    body = s2r.find_physics(env).model.body("object").id
    assert len(events) >= 3
    for event in events:
        np.testing.assert_array_equal(rows[event.step - 1], [body, *event.force])
    started = {event.step - 1 for event in events}
    assert all(rows[k, 0] == -1.0 for k in range(12) if k not in started)
