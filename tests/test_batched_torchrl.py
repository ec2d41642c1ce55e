"""The batched engine as a TorchRL env (issue 15): specs, bitwise equality with the single envs, partial resets,
signal-model draws. Kept apart from tests/test_batched.py because importing torch and check_env_specs dominate."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest

import sim2real as s2r

SHORT = {"time_limit": 0.3}  # 15 control steps: episodes end inside the test


def _effects(kind: int) -> list:
    """kind 1: physics draws; kind 3: physics draws with noise on both sides and a per-episode latency."""
    if kind == 1:
        return [s2r.Mass(scale=s2r.Uniform(0.7, 1.3)), s2r.Damping(scale=s2r.Uniform(0.5, 2.0))]
    return [
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
        s2r.ObservationNoise(s2r.Gaussian(std=0.01), s2r.Bias(s2r.Uniform(-0.02, 0.02)), s2r.Scale(1.05)),
        s2r.ActionNoise(s2r.Gaussian(std=0.05)),
        s2r.ObservationLatency(steps=s2r.Choice([0, 10, 30])),
    ]


def test_torchrl_env_passes_check_env_specs_and_matches_the_single_envs() -> None:
    torch = pytest.importorskip("torch")
    from tensordict import TensorDict
    from torchrl.envs.utils import check_env_specs

    from sim2real.batched.torchrl_env import BatchedTorchRLEnv

    effects = _effects(1)
    env = BatchedTorchRLEnv("dmc/reacher-easy", 3, *effects, seed=6, **SHORT)
    check_env_specs(env, seed=0)
    singles = [s2r.wrap(s2r.make("dmc/reacher-easy", **SHORT), *effects, seed=(6, i)) for i in range(3)]
    env.set_seed(20)
    td = env.reset()
    for i, single in enumerate(singles):
        obs, info = single.reset(seed=20 + i)
        assert np.array_equal(td["observation"][i].numpy(), obs)
        params = info["sim2real"]["params"]
        assert td["sim2real_params"][i].tolist() == [params[name] for name in env.param_names]
    rng = np.random.default_rng(1)
    for _ in range(15):
        actions = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
        td = env.step(TensorDict({"action": torch.as_tensor(actions)}, batch_size=[3]))["next"]
        for i, single in enumerate(singles):
            obs, reward, _, truncated, _ = single.step(actions[i])
            assert np.array_equal(td["observation"][i].numpy(), obs)
            assert float(td["reward"][i]) == reward and bool(td["truncated"][i]) == truncated
    assert td["done"].all()  # 15 steps: every world's episode ended
    # A partial reset starts a new episode in world 1 only, continuing its streams like the single env's reset().
    td = env.reset(TensorDict({"_reset": torch.tensor([[False], [True], [False]])}, batch_size=[3]))
    obs, info = singles[1].reset()
    assert np.array_equal(td["observation"][1].numpy(), obs)
    assert env.engine.steps.tolist() == [15, 0, 15]  # worlds 0 and 2 were left alone
    assert td["sim2real_params"][1].tolist() == [info["sim2real"]["params"][n] for n in env.param_names]
    env.close()
    for single in singles:
        single.close()


def test_torchrl_env_with_signal_models_reports_their_draws() -> None:
    pytest.importorskip("torch")
    from torchrl.envs.utils import check_env_specs

    from sim2real.batched.torchrl_env import BatchedTorchRLEnv

    env = BatchedTorchRLEnv("dmc/reacher-easy", 2, *_effects(3), seed=2, **SHORT)
    check_env_specs(env, seed=0)
    assert "obs_latency_steps" in env.param_names and "dof_damping[shoulder]" in env.param_names
    single = s2r.wrap(s2r.make("dmc/reacher-easy", **SHORT), *_effects(3), seed=(2, 1))
    env.set_seed(30)
    td = env.reset()
    obs, info = single.reset(seed=31)
    assert np.array_equal(td["observation"][1].numpy(), obs)
    column = env.param_names.index("obs_latency_steps")
    assert float(td["sim2real_params"][1, column]) == info["sim2real"]["params"]["obs_latency_steps"]
    env.close()
