"""PPO collection through the batched engine (issue 15, P5): the path chosen and why, the keyed-stream promise per
world, bitwise-reproducible training, the fallbacks (ADR, unbatched signal models, env objects)."""

from __future__ import annotations

import numpy as np
import pytest

import sim2real as s2r
from sim2real.agents import PPOConfig, train
from sim2real.agents.collect import Collection, choose_collection, make_collection_env, worlds_for
from sim2real.agents.config import replace

REACHER = "dmc/reacher-easy"
TINY = PPOConfig(
    frames=400, frames_per_batch=200, epochs=2, minibatch_size=100, hidden_sizes=(16,), obs_norm_frames=100,
    num_envs=4,
)  # fmt: skip


def _effects() -> list:
    return [
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
        s2r.Mass(scale=s2r.Uniform(0.8, 1.2), bodies="*"),
        s2r.ObservationNoise(s2r.Gaussian(std=0.01)),
        s2r.ActionNoise(s2r.Gaussian(std=0.05)),
        s2r.ObservationLatency(steps=1),
    ]


# --------------------------------------------------------------------------- which path, and why


def test_worlds_divide_the_batch() -> None:
    assert [worlds_for(f, 20) for f in (1000, 4000, 200, 97, 30)] == [20, 20, 20, 1, 15]
    assert worlds_for(1000, 16) == 10 and worlds_for(8, 20) == 8


def test_choose_collection_batched_and_its_description() -> None:
    chosen = choose_collection(REACHER, _effects(), PPOConfig(frames_per_batch=1000, num_envs=16))
    assert chosen == Collection("batched", 10, None, 100)
    assert str(chosen) == "batched engine, 10 worlds x 100 steps per batch"


@pytest.mark.parametrize(
    ("source", "effects", "config", "reason"),
    [
        (REACHER, [], PPOConfig(engine="per-env"), "engine='per-env' was asked for"),
        (
            REACHER,
            [s2r.ActionLatency(steps=1, jitter=s2r.Uniform(0.0, 2.0))],
            PPOConfig(),
            "ActionLatency with jitter is not batched",
        ),
        ("dmc/jaco-reach_site", [], PPOConfig(), "no batched kernel for task 'dmc/jaco-reach_site'"),
        (
            REACHER,
            [s2r.Damping(scale=s2r.Uniform(0.5, 2.0), schedule=s2r.Interval(10))],
            PPOConfig(),
            "Damping acts during the episode (per-step effects are not batched)",
        ),
    ],
)
def test_choose_collection_falls_back_with_the_reason(source, effects, config, reason) -> None:
    assert choose_collection(source, effects, config) == Collection("per-env", 1, reason)
    assert str(choose_collection(source, effects, config)) == f"per-env (one TorchRL env): {reason}"


def test_env_objects_fall_back_and_adr_is_batched() -> None:
    env = s2r.make(REACHER)
    try:
        chosen = choose_collection(env, [], PPOConfig())
    finally:
        env.close()
    assert chosen.engine == "per-env" and chosen.reason is not None
    assert chosen.reason.startswith("an env object (") and "builds its worlds from a task id" in chosen.reason
    adr = s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], delta=0.1, t_low=0.2, t_high=0.8)
    chosen = choose_collection(REACHER, [adr], PPOConfig())  # ADR is batched (sim2real.batched.adr)
    assert chosen == Collection("batched", 20, None, 50)


def test_config_engine_and_num_envs() -> None:
    with pytest.raises(ValueError, match=r"`engine` must be one of \['auto', 'per-env'\]\. Received 'gpu'\."):
        PPOConfig(engine="gpu")
    with pytest.raises(ValueError, match=r"`num_envs` must be a positive int\. Received 0\."):
        PPOConfig(num_envs=0)
    # Defaults stay out of the stored form (checkpoints and the study's manifests written before they existed).
    assert "engine" not in PPOConfig().to_dict() and "num_envs" not in PPOConfig().to_dict()
    custom = PPOConfig(engine="per-env", num_envs=8)
    assert custom.to_dict()["engine"] == "per-env" and PPOConfig.from_yaml(custom.to_yaml()) == custom


# --------------------------------------------------------------------------- the keyed-stream promise per world


def test_world_i_is_the_single_env_with_seed_seed_i() -> None:
    """Each world of the collection env draws, observes and is rewarded as ``wrap(make(task), *effects,
    seed=(seed, i))`` reset with ``seed + i`` (the first reset; later ones continue its streams)."""
    import torch

    seed, n, steps = 7, 3, 12
    env = make_collection_env(REACHER, _effects(), seed, Collection("batched", n, None, steps))
    actions = torch.as_tensor(np.random.default_rng(0).uniform(-1, 1, (steps, n, 2)), dtype=torch.float32)
    step = iter(range(steps))

    def policy(td):
        td["action"] = actions[next(step)]
        return td

    try:
        data = env.rollout(steps, policy, break_when_any_done=False)
        names = env.base_env.param_names
    finally:
        env.close()
    for i in range(n):
        single = s2r.wrap(s2r.make(REACHER), *_effects(), seed=(seed, i))
        try:
            obs, info = single.reset(seed=seed + i)
            draws = info["sim2real"]["params"]
            np.testing.assert_array_equal(data["observation"][i, 0].numpy(), obs)
            for k, name in enumerate(names):
                assert data["sim2real_params"][i, 0, k].item() == pytest.approx(draws[name], rel=0, abs=0), name
            for t in range(steps):
                obs, reward, *_ = single.step(actions[t, i].numpy())
                np.testing.assert_array_equal(data["next", "observation"][i, t].numpy(), obs)
                assert data["next", "reward"][i, t].item() == np.float32(reward)
        finally:
            single.close()


# --------------------------------------------------------------------------- training on the batched engine


@pytest.fixture(scope="module")
def batched_run():
    return train(REACHER, TINY, effects=_effects(), seed=5, progress=False, logger=None)


def test_batched_training_is_bitwise_reproducible(batched_run) -> None:
    import torch

    again = train(REACHER, TINY, effects=_effects(), seed=5, progress=False, logger=None)
    assert batched_run.collection == again.collection == Collection("batched", 4, None, 50)
    first, second = batched_run.policy.state_dict(), again.policy.state_dict()
    assert all(torch.equal(first[k], second[k]) for k in first)
    assert batched_run.metrics == again.metrics
    assert batched_run.frames == 400 and batched_run.metrics["frames"] == (200.0, 400.0)
    other = train(REACHER, TINY, effects=_effects(), seed=6, progress=False, logger=None)
    assert not torch.equal(other.policy.state_dict()[k := next(iter(first))], first[k])


def test_per_env_path_is_what_it_was_and_reported(batched_run) -> None:
    import torch

    per_env = train(REACHER, replace(TINY, engine="per-env"), effects=_effects(), seed=5, progress=False, logger=None)
    assert per_env.collection == Collection("per-env", 1, "engine='per-env' was asked for")
    assert per_env.frames == 400 and set(per_env.metrics) == set(batched_run.metrics)
    # Different collection paths are different runs (the draws are spread over 4 worlds, not one env).
    first = next(iter(per_env.policy.state_dict()))
    assert not torch.equal(per_env.policy.state_dict()[first], batched_run.policy.state_dict()[first])


def test_adr_training_runs_batched_and_keeps_working() -> None:
    adr = s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.2, 4.0))], delta=0.2, t_low=-1e9, t_high=-1e8, m=1,
                  p_boundary=1.0)  # fmt: skip
    res = train(REACHER, replace(TINY, frames=200), effects=[adr], seed=0, progress=False, logger=None)
    assert res.collection is not None and res.collection.engine == "batched"  # tests/test_adr_batched.py
    assert res.adr is not None and '"history"' in res.adr


def test_csv_logger_records_the_collection(tmp_path) -> None:
    res = train(REACHER, replace(TINY, frames=200), seed=0, progress=False, log_dir=tmp_path)
    assert res.log_dir is not None
    text = "\n".join(p.read_text() for p in res.log_dir.rglob("*") if p.is_file())
    assert "batched engine, 4 worlds x 50 steps per batch" in text


def test_train_env_carries_the_tasks_success_flag_and_adr_scores_it() -> None:
    """arm-reach reports info["is_success"]; TorchRL's GymWrapper dropped it, so ADR's 'auto'/'success' metric
    saw no success flag on the training env (a 'success' metric raised, 'auto' silently scored the return)."""
    import torch

    from randomizers import ADR
    from sim2real.agents import PPOConfig, train
    from sim2real.agents.baselines import ReachController
    from sim2real.agents.collect import make_train_env

    env = make_train_env("sim2real/arm-reach", [], 3)
    controller = ReachController(kp=5.0)
    td = env.reset()
    flags, dones = [], []
    for _ in range(200):
        obs = td["observation"].numpy()
        td.set("action", torch.as_tensor(controller(obs), dtype=torch.float32))
        td = env.step(td)
        flags.append(bool(td["next", "is_success"]))
        dones.append(bool(td["next", "terminated"]))
        if dones[-1]:
            break
        td = td["next"]
    env.close()
    assert flags[-1] and dones[-1] and not any(flags[:-1]), (flags, dones)  # success ends the episode
    assert "is_success" not in make_train_env("dmc/reacher-easy", [], 0).rollout(2)["next"]

    adr = """
effects:
  - {type: Damping, scale: [0.2, 5.0]}
delta: 0.1
t_low: -1.0
t_high: 0.0
m: 1
p_boundary: 1.0
metric: success
"""
    # Per env: this checks the TorchRL training env's flag (the batched engine's: tests/test_adr_batched.py).
    cfg = PPOConfig(frames=400, frames_per_batch=200, minibatch_size=100, epochs=1, obs_norm_frames=0, adr=adr,
                    engine="per-env")  # fmt: skip
    result = train("sim2real/arm-reach", cfg, seed=0, progress=False, logger=None)
    state = ADR.from_state(result.adr)
    assert state.frames == 400
    # Every finished episode is scored on its success flag (a 'success' metric raised before: no flag) and, with
    # t_high 0, widens its pinned boundary: the nominal point plus one change per 200-step episode.
    assert len(state.history.frames) == 3
