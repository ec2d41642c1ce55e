"""`PhysicsHandle` under TorchRL wrappers: the handle's owner is the env that holds the model, so ``substeps`` is
the control period's (not the wrapper's own ``frame_skip``) and step interception reaches the real stepping code."""

from __future__ import annotations

from typing import Any

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


def test_torchrl_set_seed_restarts_the_streams_as_gymnasium_reset_seed_does() -> None:
    """``env.set_seed(s)`` on a wrapped TorchRL env (which TorchRL hands only to the base env) makes the next reset
    draw from the streams of ``(wrap seed, s)``: the draws of gymnasium's ``reset(seed=s)`` on the same wrap, the
    same again for the same seed, and different draws for the workers of a ``SerialEnv``, which gets one seed each."""
    import numpy as np
    from torchrl.envs import GymWrapper, SerialEnv

    from noise_models import Bias, ObservationNoise

    def effects() -> tuple[object, ...]:
        return (s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), ObservationNoise(Bias(s2r.Uniform(-1.0, 1.0))))

    def make() -> object:
        return s2r.wrap(GymWrapper(s2r.make("dmc/reacher-easy")), *effects(), seed=3)

    def draws(td: object) -> np.ndarray:
        return np.concatenate([td["sim2real_params"].numpy(), td["sim2real_signal_params"].numpy()], axis=-1)

    env = make()
    env.set_seed(5)
    first, following = draws(env.reset()), draws(env.reset())
    env.set_seed(5)
    again = draws(env.reset())
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, following)  # without a new seed the streams go on, as in gymnasium
    gym_env = s2r.wrap(s2r.make("dmc/reacher-easy"), *effects(), seed=3)
    _, info = gym_env.reset(seed=5)
    np.testing.assert_array_equal(first, np.array(list(info["sim2real"]["params"].values())))
    env.close()
    gym_env.close()

    serial = SerialEnv(2, make)
    serial.set_seed(10)
    workers = draws(serial.reset())
    serial.set_seed(10)
    assert not np.array_equal(workers[0], workers[1])  # one seed per worker: independent draws
    np.testing.assert_array_equal(workers, draws(serial.reset()))
    serial.close()


@pytest.mark.parametrize("fused", [False, True], ids=["physics", "physics+signals"])
@pytest.mark.parametrize("own_setting", [True, False])
def test_close_gives_dm_control_physics_back_its_warnings_cause_exception(fused: bool, own_setting: bool) -> None:
    from noise_models import Gaussian, ObservationNoise
    from randomizers import Mass, Uniform

    base = torchrl_envs.DMControlEnv("reacher", "easy")
    physics = base._env.physics
    physics._warnings_cause_exception = own_setting
    effects = [Mass(scale=Uniform(0.8, 1.2))] + ([ObservationNoise(Gaussian(std=0.01))] if fused else [])
    env = s2r.wrap(base, *effects, seed=0)
    env.rollout(3)
    assert physics._warnings_cause_exception is False  # while wrapped: divergences are read from the warnings
    env.close()
    assert physics._warnings_cause_exception is own_setting  # stayed False after close before


def test_close_restores_the_setting_of_a_composer_envs_current_physics() -> None:
    from randomizers import Mass, Uniform

    gym_env: Any = s2r.make("dmc/jaco-reach_site")  # TorchRL's DMControlWrapper takes suite envs only
    env = s2r.wrap(torchrl_envs.GymWrapper(gym_env), Mass(scale=Uniform(0.8, 1.2)), seed=0)
    env.reset()
    first = gym_env.unwrapped.physics
    env.reset()  # recompiled: a new physics each reset
    current = gym_env.unwrapped.physics
    assert current is not first
    assert current._warnings_cause_exception is False
    env.transform.close()  # the env closing first frees its physics: nothing is left to restore then
    assert current._warnings_cause_exception is True  # dm-control's default, as the env built it
    env.close()  # and closing the env after its physics is freed is fine


@pytest.mark.parametrize("fused", [False, True], ids=["physics", "physics+signals"])
def test_close_takes_the_set_seed_relay_off_the_base_env(fused: bool) -> None:
    from noise_models import Gaussian, ObservationNoise
    from randomizers import Mass, Uniform

    base = torchrl_envs.DMControlEnv("reacher", "easy")
    assert "_set_seed" not in base.__dict__
    effects = [Mass(scale=Uniform(0.8, 1.2))] + ([ObservationNoise(Gaussian(std=0.01))] if fused else [])
    env = s2r.wrap(base, *effects, seed=0)
    env.set_seed(3)
    env.rollout(2)
    assert "_set_seed" in base.__dict__  # set_seed reaches the transforms while they are on the env
    env.close()
    assert "_set_seed" not in base.__dict__  # stayed after close before, holding the closed transforms
