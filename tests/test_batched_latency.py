"""ActionLatency in the batched engine (issue 15): each world bitwise its single env, episode by episode."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest
from conftest import reset_and_compare

import sim2real as s2r
from sim2real.batched import BatchedVectorEnv, make_batched, supports

# Short episodes (15 control steps) so that later episodes, which continue each world's streams, are compared too.
OPTIONS = {
    "dmc/reacher-easy": {"time_limit": 0.3},
    "sim2real/arm-reach": {"max_episode_steps": 15},
    "dmc/manipulator-bring_ball": {"time_limit": 0.15},
}
ACTION_SCALE = {"sim2real/arm-reach": 0.08}


def _stack(kind: str) -> list:
    if kind == "fixed":
        return [s2r.ActionLatency(seconds=0.04)]
    if kind == "drawn":  # physics steps; on arm-reach (10 substeps) rounded to whole control steps (action path)
        return [s2r.ActionLatency(steps=s2r.Choice([0, 1, 2, 3, 20, 34]))]
    if kind == "mid-step":  # manipulator: 5 substeps per control step, so 3, 7 and 12 apply mid step
        return [s2r.ActionLatency(steps=s2r.Choice([0, 3, 5, 7, 12]))]
    # The study's twin: a delay, sensor noise and physics scales (and action noise before the delay).
    return [
        s2r.ActionLatency(seconds=s2r.Uniform(0.0, 0.06)),  # reacher: 0-3 physics steps; arm-reach: 0-3 control
        s2r.ObservationNoise(s2r.Gaussian(std=0.01), s2r.Bias(s2r.Uniform(-0.02, 0.02))),
        s2r.ActionNoise(s2r.Gaussian(std=0.05)),
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
        s2r.Mass(scale=s2r.Uniform(0.8, 1.2)),
    ]


def _compare(task: str, seed: int, kind: str, episodes: int = 3, num: int = 3) -> set[float]:
    """Steps the batched worlds and their single twins with the same actions through ``episodes`` episodes
    (the first seeded, the others continuing each world's streams); returns the latencies the worlds drew."""
    effects, options = _stack(kind), OPTIONS[task]
    scale = ACTION_SCALE.get(task, 1.5)
    batched = make_batched(task, num, *effects, seed=seed, **options)
    singles = [s2r.wrap(s2r.make(task, **options), *effects, seed=(seed, i)) for i in range(num)]
    rng = np.random.default_rng(seed)
    drawn: set[float] = set()
    try:
        for episode in range(episodes):
            seeds = [100 * seed + i for i in range(num)] if episode == 0 else None
            obs, params = reset_and_compare(batched, singles, seeds)
            drawn |= set(params["action_latency_steps"].tolist())
            for t in range(15):
                actions = rng.uniform(-scale, scale, (num, batched.action_dim)).astype(np.float32)
                obs, reward, terminated, truncated, _ = batched.step(actions)
                for i, env in enumerate(singles):
                    o, r, te, tr, _ = env.step(actions[i])
                    assert np.array_equal(o, obs[i]), (episode, t, i)
                    assert r == reward[i], (episode, t, i)
                    assert (te, tr) == (terminated[i], truncated[i])
    finally:
        batched.close()
        for env in singles:
            env.close()
    return drawn


@pytest.mark.parametrize(
    ("task", "seed", "kind"),
    [
        ("dmc/reacher-easy", 0, "fixed"),
        ("dmc/reacher-easy", 1, "drawn"),
        ("dmc/reacher-easy", 2, "twin"),
        ("dmc/reacher-easy", 3, "twin"),
        ("sim2real/arm-reach", 0, "fixed"),
        ("sim2real/arm-reach", 4, "drawn"),
        ("sim2real/arm-reach", 5, "twin"),
        ("dmc/manipulator-bring_ball", 6, "mid-step"),
    ],
)
def test_each_world_is_bitwise_its_single_env_with_action_latency(task: str, seed: int, kind: str) -> None:
    drawn = _compare(task, seed, kind)
    if kind == "fixed":
        assert drawn == ({20.0} if task == "sim2real/arm-reach" else {2.0})  # 0.04 s in physics steps
    elif kind in ("drawn", "mid-step", "twin"):
        assert len(drawn) > 1  # the worlds drew different delays (per world, per episode)
    if kind == "mid-step":
        assert {d % 5 for d in drawn} - {0}  # some delay applied its command mid control step


def test_reset_command_holds_until_the_first_delayed_command_arrives() -> None:
    # Reacher: 1 substep of 0.02 s. With 3 steps of delay the first 3 steps run the reset command (zero torque):
    # the same trajectory as zero actions; the 4th step differs.
    delayed = make_batched("dmc/reacher-easy", 1, s2r.ActionLatency(steps=3), seed=0)
    still = make_batched("dmc/reacher-easy", 1, seed=0)
    a, _ = delayed.reset(seed=0)
    b, _ = still.reset(seed=0)
    for t in range(4):
        a = delayed.step(np.ones((1, 2), np.float32))[0]
        b = still.step(np.zeros((1, 2), np.float32))[0]
        assert np.array_equal(a, b) == (t < 3), t
    delayed.close()
    still.close()


def test_vector_env_autoresets_with_action_latency_like_the_single_envs() -> None:
    effects = _stack("twin")
    ours = BatchedVectorEnv("dmc/reacher-easy", 2, *effects, seed=7, time_limit=0.2)  # 10-step episodes
    singles = [s2r.wrap(s2r.make("dmc/reacher-easy", time_limit=0.2), *effects, seed=(7, i)) for i in range(2)]
    obs, _ = ours.reset(seed=[3, 4])
    for i, env in enumerate(singles):
        assert np.array_equal(env.reset(seed=[3, 4][i])[0], obs[i])
    rng = np.random.default_rng(0)
    ended = np.zeros(2, bool)
    resets = 0
    for _ in range(34):  # 10 steps and the reset step: three autoresets per world
        actions = rng.uniform(-1, 1, (2, 2)).astype(np.float32)
        obs, reward, terminated, truncated, info = ours.step(actions)
        for i, env in enumerate(singles):
            if ended[i]:  # next-step autoreset: this step reset the world, the action is ignored
                o, single_info = env.reset()
                assert reward[i] == 0.0
                for key, value in single_info["sim2real"]["params"].items():
                    assert info["sim2real"]["params"][key][i] == value, key
                resets += 1
            else:
                o, r, te, tr, _ = env.step(actions[i])
                assert r == reward[i] and (te, tr) == (terminated[i], truncated[i])
            assert np.array_equal(o, obs[i])
        ended = terminated | truncated
    ours.close()
    assert resets == 6


def test_jitter_keeps_the_per_env_path_and_says_why() -> None:
    assert supports("dmc/reacher-easy", s2r.ActionLatency(steps=2)) is None
    assert supports("sim2real/arm-reach", s2r.ActionLatency(seconds=s2r.Uniform(0.0, 0.05))) is None
    assert (
        supports("dmc/reacher-easy", s2r.ActionLatency(steps=2, jitter=s2r.Uniform(0, 2)))
        == "ActionLatency with jitter is not batched"
    )


def test_evaluate_runs_action_latency_batched_and_byte_identical() -> None:
    from sim2real.evaluation import evaluate, nominal, randomized, sweep

    conditions = [
        nominal(),
        randomized(_stack("twin"), name="twin"),
        *sweep({"type": "ActionLatency", "steps": 0}, "steps", [1, 3]),
    ]
    policies = {"still": lambda o: np.zeros(2), "wave": lambda o: np.clip(o[:2] * -3.0, -1, 1)}
    kwargs = {"episodes": 4, "seed": 2, "max_steps": 40, "batch": 2, "task_options": {"time_limit": 0.5}}
    auto = evaluate(policies, "dmc/reacher-easy", conditions, **kwargs)
    per_env = evaluate(policies, "dmc/reacher-easy", conditions, engine="per-env", **kwargs)
    assert set(auto.engines.values()) == {"batched"}
    assert set(per_env.engines.values()) == {"per-env"}
    assert auto.to_json() == per_env.to_json()  # bitwise: returns, lengths, draws


def test_torchrl_env_with_action_latency_is_bitwise_the_single_envs() -> None:
    torch = pytest.importorskip("torch")
    from tensordict import TensorDict

    from sim2real.batched.torchrl_env import BatchedTorchRLEnv

    effects = _stack("twin")
    env = BatchedTorchRLEnv("dmc/reacher-easy", 3, *effects, seed=8, time_limit=0.3)
    singles = [s2r.wrap(s2r.make("dmc/reacher-easy", time_limit=0.3), *effects, seed=(8, i)) for i in range(3)]
    env.set_seed(40)
    td = env.reset()
    for i, single in enumerate(singles):
        obs, info = single.reset(seed=40 + i)
        assert np.array_equal(td["observation"][i].numpy(), obs)
        assert td["sim2real_params"][i].tolist() == [info["sim2real"]["params"][k] for k in env.param_names]
    assert "action_latency_steps" in env.param_names
    rng = np.random.default_rng(3)
    for _ in range(15):
        actions = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
        out = env.step(TensorDict({"action": torch.as_tensor(actions)}, batch_size=[3]))["next"]
        assert out["reward"].shape == (3, 1) and out["reward"].dtype == torch.float32
        for i, single in enumerate(singles):
            obs, reward, terminated, truncated, _ = single.step(actions[i])
            assert np.array_equal(out["observation"][i].numpy(), obs)
            assert float(out["reward"][i]) == reward
            assert bool(out["done"][i]) == (terminated or truncated) and bool(out["truncated"][i]) == truncated
    # A partial reset: world 2's new draws reach the params of the steps that follow (not the old episode's).
    td = env.reset(TensorDict({"_reset": torch.tensor([[False], [False], [True]])}, batch_size=[3]))
    _, info = singles[2].reset()
    expected = [info["sim2real"]["params"][k] for k in env.param_names]
    assert td["sim2real_params"][2].tolist() == expected
    out = env.step(TensorDict({"action": torch.zeros(3, 2)}, batch_size=[3]))["next"]
    assert out["sim2real_params"][2].tolist() == expected
    env.close()


def test_threads_and_uneven_steps_keep_each_worlds_command_ring() -> None:
    # Worlds split over threads, and a mask that steps some worlds and not others: each world's ring advances only
    # with its own steps, as its single env's does when only the masked-in worlds are stepped.
    effects = _stack("mid-step")
    options = OPTIONS["dmc/manipulator-bring_ball"]
    singles = [s2r.wrap(s2r.make("dmc/manipulator-bring_ball", **options), *effects, seed=(1, i)) for i in range(5)]
    expected = [[env.reset(seed=i)[0]] for i, env in enumerate(singles)]
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (12, 5, 5)).astype(np.float32)
    masks = [np.arange(5) % 2 == t % 2 if t < 6 else np.ones(5, bool) for t in range(12)]
    for t in range(12):
        for i, env in enumerate(singles):
            expected[i].append(env.step(actions[t, i])[0] if masks[t][i] else expected[i][-1])
    for threads in (1, 2):
        envs = make_batched("dmc/manipulator-bring_ball", 5, *effects, seed=1, threads=threads, **options)
        obs, params = envs.reset(seed=0)
        assert len(set(params["action_latency_steps"].tolist())) > 1
        for t in range(12):
            obs = envs.step(actions[t], mask=masks[t])[0]
            for i in range(5):
                assert np.array_equal(obs[i], expected[i][t + 1]), (threads, t, i)
        envs.close()


def test_ppo_collection_with_action_latency_is_batched_and_each_world_its_single_env() -> None:
    """PPO's collector now takes the engine for a delayed actuator: each world draws, observes and is rewarded as
    ``wrap(make(task), *effects, seed=(seed, i))`` reset with ``seed + i``."""
    torch = pytest.importorskip("torch")
    from sim2real.agents import PPOConfig
    from sim2real.agents.collect import Collection, choose_collection, make_collection_env

    effects = _stack("twin")
    assert choose_collection("dmc/reacher-easy", effects, PPOConfig(num_envs=4)).engine == ("batched")
    seed, n, steps = 3, 3, 12
    env = make_collection_env("dmc/reacher-easy", effects, seed, Collection("batched", n, None, steps))
    actions = torch.as_tensor(np.random.default_rng(1).uniform(-1, 1, (steps, n, 2)), dtype=torch.float32)
    step = iter(range(steps))

    def policy(td: object) -> object:
        td["action"] = actions[next(step)]  # type: ignore[index]
        return td

    try:
        data = env.rollout(steps, policy, break_when_any_done=False)
    finally:
        env.close()
    for i in range(n):
        single = s2r.wrap(s2r.make("dmc/reacher-easy"), *effects, seed=(seed, i))
        obs, _ = single.reset(seed=seed + i)
        assert np.array_equal(data["observation"][i, 0].numpy(), obs)
        for t in range(steps):
            obs, reward, *_ = single.step(actions[t, i].numpy())
            assert np.array_equal(data["next", "observation"][i, t].numpy(), obs), (i, t)
            assert data["next", "reward"][i, t].item() == np.float32(reward)
        single.close()
