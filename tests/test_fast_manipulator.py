"""The manipulator fast path (issue 15): ``dmc/manipulator-*`` read their observation and reward by cached index,
bitwise what dm-control's own ``Bring.get_observation`` / ``get_reward`` give, over many random states (in-bounds,
margin and far distances included) of all four tasks, and along rollouts against a pristine ``suite.load`` env."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import pytest

import sim2real as s2r
from sim2real.tasks.fast_manipulator import fast_bring

TASKS = ["bring_ball", "bring_peg", "insert_ball", "insert_peg"]


def _same_observation(a: Any, b: Any) -> None:
    assert list(a) == list(b)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], strict=True)  # values, shape and dtype
        assert a[key].shape == b[key].shape and a[key].dtype == b[key].dtype


def _reference(task: Any, physics: Any) -> tuple[Any, float]:
    from dm_control.suite import manipulator

    return manipulator.Bring.get_observation(task, physics), manipulator.Bring.get_reward(task, physics)


@pytest.mark.parametrize("name", TASKS)
def test_random_states_match_dm_control_bitwise(name: str) -> None:
    env = s2r.make(f"dmc/manipulator-{name}", textures=False)
    env.reset(seed=0)
    dm = env.unwrapped.dm_env
    physics, task = dm.physics, dm.task
    assert type(task) is fast_bring()
    model, data = physics.model.ptr, physics.data.ptr
    rng = np.random.default_rng(TASKS.index(name))
    obj = "peg" if name.endswith("peg") else "ball"
    target = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "target_peg" if obj == "peg" else "target_ball")
    obj_joints = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{obj}_{d}") for d in "xz"]
    rewards = []
    for k in range(300):
        data.qpos[:] = rng.uniform(-np.pi, np.pi, model.nq)
        data.qvel[:] = rng.normal(0.0, 5.0, model.nv)
        if k % 3 == 0:  # the object near the target: distances inside the bounds and in the margin
            mujoco.mj_forward(model, data)
            offset = rng.choice([0.0, 0.004, 0.009, 0.015, 0.03]) * rng.uniform(-1, 1, 2)
            for j, axis, off in zip(obj_joints, (0, 2), offset, strict=True):
                data.qpos[model.jnt_qposadr[j]] += (
                    data.site_xpos[target, axis]
                    - data.site_xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, obj), axis]
                    + off
                )
        physics.forward()
        obs, reward = task.get_observation(physics), task.get_reward(physics)
        ref_obs, ref_reward = _reference(task, physics)
        _same_observation(obs, ref_obs)
        assert type(reward) is type(ref_reward) and (
            reward == ref_reward or (np.isnan(reward) and np.isnan(ref_reward))
        )
        rewards.append(reward)
    values = np.array(rewards)
    # A distance inside the bounds (a term of 1.0: ball reward 1, peg reward >= 0.5), one in the margin, far ones.
    inside = (values == 1.0).any() if obj == "ball" else (values >= 0.5).any()
    assert inside and ((values > 1e-3) & (values < 1.0) & (values != 0.5)).any() and (values < 1e-6).any()
    env.close()


@pytest.mark.parametrize("name", ["bring_ball", "insert_peg"])
def test_rollouts_match_a_pristine_suite_env(name: str) -> None:
    from dm_control import suite

    from sim2real.adapters import DmEnvToGym

    fast = s2r.make(f"dmc/manipulator-{name}")
    ref = DmEnvToGym(suite.load("manipulator", name))
    assert type(ref.dm_env.task).__name__ == "Bring"
    actions = np.random.default_rng(3).uniform(-1, 1, (60, *fast.action_space.shape)).astype(np.float32)
    for seed in (0, 1):
        a, _ = fast.reset(seed=seed)
        b, _ = ref.reset(seed=seed)
        np.testing.assert_array_equal(a, b, strict=True)
        for action in actions:
            a, ra, *_ = fast.step(action)
            b, rb, *_ = ref.step(action)
            np.testing.assert_array_equal(a, b, strict=True)
            assert ra == rb
    fast.close()
    ref.close()


def test_partially_observable_task_keeps_dm_controls_keys() -> None:
    from dm_control.suite import manipulator

    env = s2r.make("dmc/manipulator-bring_ball", flatten=False)
    env.reset(seed=2)
    dm = env.unwrapped.dm_env
    task = dm.task
    task._fully_observable = False
    obs = task.get_observation(dm.physics)
    assert list(obs) == ["arm_pos", "arm_vel", "touch"]
    _same_observation(obs, manipulator.Bring.get_observation(task, dm.physics))
