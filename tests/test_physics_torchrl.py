"""`PhysicsHandle` under TorchRL wrappers: the handle's owner is the env that holds the model, so ``substeps`` is
the control period's (not the wrapper's own ``frame_skip``) and step interception reaches the real stepping code."""

from __future__ import annotations

import gymnasium as gym
import pytest

import sim2real as s2r
from sim2real.mjcf_env import MjcfEnv
from sysid.synthetic import generate_arm

torchrl_envs = pytest.importorskip("torchrl.envs")


def _arm() -> MjcfEnv:
    return MjcfEnv(xml=generate_arm(dof=6, seed=8, actuators="position"), control_timestep=0.02)


def test_substeps_of_a_torchrl_gym_wrapper_are_the_wrapped_envs() -> None:
    inner = _arm()
    env = torchrl_envs.GymWrapper(inner)
    assert env.frame_skip == 1  # TorchRL's own action repeat, which the handle must not answer with
    handle = s2r.find_physics(env)
    assert handle is not None
    assert handle.owner is inner
    assert handle.model is inner.model
    assert handle.substeps == inner.n_substeps == round(0.02 / inner.model.opt.timestep)
    transformed = torchrl_envs.TransformedEnv(torchrl_envs.GymWrapper(_arm()), torchrl_envs.StepCounter())
    deep = s2r.find_physics(transformed)
    assert deep is not None and deep.substeps == 10 and isinstance(deep.owner, MjcfEnv)


def test_a_gymnasium_frame_skip_under_torchrl_is_found_and_interception_reaches_it() -> None:
    base = gym.make("Reacher-v5")
    env = torchrl_envs.GymWrapper(base)
    handle = s2r.find_physics(env)
    assert handle is not None
    assert handle.owner is base.unwrapped
    assert handle.substeps == base.unwrapped.frame_skip == 2
    calls: list[int] = []

    def stepper(run, nstep: int, runner) -> None:  # type: ignore[no-untyped-def]
        calls.append(nstep)
        run(nstep)

    remove = handle.intercept_step(stepper)
    env.reset()
    env.rand_step()
    remove()
    assert calls == [2]  # the TorchRL step went through the wrapped env's patched _step_mujoco_simulation
    env.rand_step()
    assert calls == [2]
    env.close()


def test_plain_gymnasium_and_dm_control_handles_are_unchanged() -> None:
    env = gym.make("Reacher-v5")
    handle = s2r.find_physics(env)
    assert handle is not None and handle.owner is env.unwrapped and handle.substeps == 2
    dm = s2r.find_physics(s2r.make("dmc/reacher-easy"))
    assert dm is not None and dm.source == "dm_control.suite" and dm.substeps == 1  # reacher: one 0.02 s step
