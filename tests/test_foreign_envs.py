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
from noise_models import ActionLatency, ActionNoise, Bias, Gaussian, ObservationNoise

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
