"""Envs written the way other people write them (issue: wrap environments nobody here designed): a TorchRL
``EnvBase`` with nested Composite observations, envs without actuators."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import pytest

import sim2real as s2r
from noise_models import Bias, ObservationNoise

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
