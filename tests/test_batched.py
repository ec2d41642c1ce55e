"""The batched engine (issue 15): each world bitwise equal to its single env, the VectorEnv's autoreset, errors."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np
import pytest
from conftest import reset_and_compare

import sim2real as s2r
from sim2real.batched import BatchedEnv, BatchedVectorEnv, make_batched, supports

# A short time limit (0.3 s = 15 control steps) so episodes end, and the next one starts, inside the test.
SHORT = {"time_limit": 0.3}
OPTIONS = {
    "dmc/reacher-easy": SHORT,
    "dmc/reacher-hard": SHORT,
    "sim2real/arm-reach": {"max_episode_steps": 15},
    "dmc/manipulator-bring_ball": {"time_limit": 0.15},  # 15 steps of 0.01 s
    "dmc/manipulator-bring_peg": {"time_limit": 0.15},
    "dmc/manipulator-insert_ball": {"time_limit": 0.15},
}
# Actions a little beyond the action space: both paths clamp them (MuJoCo's ctrlrange, arm-reach's MAX_DELTA).
ACTION_SCALE = {"sim2real/arm-reach": 0.08}


def _effects(kind: int) -> list:
    sets = [
        [],
        [s2r.Mass(scale=s2r.Uniform(0.7, 1.3)), s2r.Damping(scale=s2r.Uniform(0.5, 2.0))],
        [
            s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2)),
            s2r.Friction(scale=s2r.Uniform(0.5, 1.5)),
            s2r.Armature(add=s2r.Uniform(0.0, 0.01)),
            s2r.Gravity(add=s2r.Normal(0.0, 0.5)),
        ],
        [  # signal models: noise on both sides, a latency drawn per episode (physics steps), and a physics effect
            s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
            s2r.ObservationNoise(s2r.Gaussian(std=0.01), s2r.Bias(s2r.Uniform(-0.02, 0.02)), s2r.Scale(1.05)),
            s2r.ActionNoise(s2r.Gaussian(std=0.05)),
            s2r.ObservationLatency(steps=s2r.Choice([0, 10, 30])),
        ],
    ]
    return sets[kind]


def _compare(task: str, seed: int, kind: int, episodes: int, num: int = 3) -> int:
    """Steps the batched worlds and their single twins with the same actions; returns the steps compared."""
    effects = _effects(kind)
    options, scale = OPTIONS[task], ACTION_SCALE.get(task, 1.5)
    batched = make_batched(task, num, *effects, seed=seed, **options)
    singles = [s2r.wrap(s2r.make(task, **options), *effects, seed=(seed, i)) for i in range(num)]
    rng = np.random.default_rng(seed)
    compared = 0
    try:
        for episode in range(episodes):
            # First episode: explicit reset seeds; later ones: each world continues its own streams.
            seeds = [1000 * seed + i for i in range(num)] if episode == 0 else None
            obs, _ = reset_and_compare(batched, singles, seeds)
            ended = np.zeros(num, bool)
            while not ended.all():
                actions = rng.uniform(-scale, scale, (num, batched.action_dim)).astype(np.float32)
                obs, reward, terminated, truncated, diverged = batched.step(actions)
                for i, env in enumerate(singles):
                    o, r, te, tr, info = env.step(actions[i])
                    assert np.array_equal(o, obs[i]), (episode, i)
                    assert r == reward[i] and te == terminated[i] and tr == truncated[i]
                    assert bool(info["sim2real"]["diverged"]) == diverged[i]
                    if "is_success" in info:
                        assert info["is_success"] == terminated[i]
                    compared += 1
                # A world that ended keeps stepping here (its single twin too): the engine steps whole batches.
                ended |= terminated | truncated
            assert (batched.steps == 15).all()
    finally:
        batched.close()
        for env in singles:
            env.close()
    return compared


@pytest.mark.parametrize(
    ("task", "seed", "kind"),
    [
        ("dmc/reacher-easy", 0, 0),
        ("dmc/reacher-easy", 3, 1),
        ("dmc/reacher-hard", 11, 2),
        ("dmc/reacher-easy", 5, 2),
        ("sim2real/arm-reach", 0, 0),
        ("sim2real/arm-reach", 4, 1),
        ("sim2real/arm-reach", 9, 2),
        ("dmc/manipulator-bring_ball", 0, 0),
        ("dmc/manipulator-bring_ball", 2, 1),
        ("dmc/manipulator-bring_peg", 7, 2),
        ("dmc/manipulator-insert_ball", 8, 1),
        ("dmc/reacher-easy", 12, 3),
        ("dmc/reacher-hard", 13, 3),
        ("sim2real/arm-reach", 14, 3),
        ("dmc/manipulator-bring_ball", 15, 3),
    ],
)
def test_each_world_is_bitwise_its_single_env(task: str, seed: int, kind: int) -> None:
    assert _compare(task, seed, kind, episodes=2) == 2 * 3 * 15  # a seeded episode, then one continuing the streams


def test_reacher_rewards_are_bitwise_over_a_full_episode_that_reaches() -> None:
    # A proportional controller towards the target earns reward 1 on many steps: the sparse reward is compared
    # where it is not all zeros (a kernel that always returned 0 would fail here).
    effects = _effects(1)
    batched = make_batched("dmc/reacher-easy", 2, *effects, seed=2, time_limit=2.0)
    singles = [s2r.wrap(s2r.make("dmc/reacher-easy", time_limit=2.0), *effects, seed=(2, i)) for i in range(2)]
    obs, _ = batched.reset(seed=[4, 9])
    for i, env in enumerate(singles):
        env.reset(seed=[4, 9][i])
    total = np.zeros(2)
    for _ in range(100):
        actions = np.clip(5.0 * np.stack([obs[:, 2] * -obs[:, 0], obs[:, 3]], axis=1) - 0.5 * obs[:, 4:6], -1, 1)
        actions = actions.astype(np.float32)
        obs, reward, _, _, _ = batched.step(actions)
        for i, env in enumerate(singles):
            assert env.step(actions[i])[1] == reward[i]
        total += reward
    batched.close()
    assert total.max() > 0  # the reward was compared where it is not all zeros


def test_vector_env_autoresets_like_sync_vector_env() -> None:
    effects = _effects(1)
    ours = BatchedVectorEnv("dmc/reacher-easy", 3, *effects, seed=4, **SHORT)
    theirs = s2r.make_vec("dmc/reacher-easy", 3, *effects, seed=4, **SHORT)
    assert ours.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    assert ours.observation_space == theirs.observation_space and ours.action_space == theirs.action_space
    o1, i1 = ours.reset(seed=8)
    o2, i2 = theirs.reset(seed=8)
    assert np.array_equal(o1, o2)
    draws = {k: v for k, v in i2["sim2real"]["params"].items() if not k.startswith("_")}  # gymnasium's masks
    assert sorted(i1["sim2real"]["params"]) == sorted(draws)
    for key, values in draws.items():
        assert np.array_equal(i1["sim2real"]["params"][key], values)
    rng = np.random.default_rng(0)
    resets = 0
    for _ in range(40):  # 15-step episodes: two autoresets per world
        actions = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
        a = ours.step(actions)
        b = theirs.step(actions)
        for x, y in zip(a[:4], b[:4], strict=True):
            assert np.array_equal(x, y)
        if "sim2real" in a[4] and "reset" in a[4]["sim2real"]:
            resets += int(a[4]["sim2real"]["reset"].sum())
            for key, values in a[4]["sim2real"]["params"].items():  # the new episode's draws, as the sub-envs report
                assert np.array_equal(values, b[4]["sim2real"]["params"][key])
    assert resets == 6
    ours.close()
    theirs.close()


def test_close_restores_the_nominal_model() -> None:
    nominal = s2r.make("dmc/reacher-easy").unwrapped.physics.model.body_mass.copy()
    batched = make_batched("dmc/reacher-easy", 2, s2r.Mass(scale=s2r.Uniform(0.5, 0.6)), seed=0)
    batched.reset(seed=0)
    assert not np.array_equal(batched.models[0].body_mass, nominal)
    batched.close()
    assert np.array_equal(batched.models[0].body_mass, nominal)
    with pytest.raises(RuntimeError, match="closed"):
        batched.reset()


def test_errors_name_the_argument_and_what_is_allowed() -> None:
    with pytest.raises(ValueError, match=r"`task` and `effects` must be supported .*no batched kernel for task "
                       r"'dmc/jaco-reach_site'"):  # fmt: skip
        make_batched("dmc/jaco-reach_site", 2)
    assert supports("dmc/reacher-easy", s2r.ObservationNoise(s2r.Quantize(0.1))) == (
        "Quantize is not batched (only ['Gaussian', 'UniformNoise', 'Bias', 'Scale', 'Drift', 'Outlier'])"
    )
    assert supports("dmc/reacher-easy", s2r.SampleAndHold(steps=2)) == "SampleAndHold is not batched"
    assert "per-step" in str(supports("dmc/reacher-easy", s2r.Push(force=s2r.Uniform(0, 1), interval=10.0)))
    with pytest.raises(ValueError, match=r"`num_envs` must be an int >= 1. Received 0."):
        make_batched("dmc/reacher-easy", 0)
    batched = make_batched("dmc/reacher-easy", 2)
    batched.reset()
    with pytest.raises(ValueError, match=r"`actions` must have shape \(2, 2\). Received \(2,\)."):
        batched.step(np.zeros(2))
    with pytest.raises(ValueError, match=r"`seed` must be None, an int >= 0 or a sequence of one int >= 0 or None per "
                       r"reset world \(2\). Received 1 seeds: \[1\].$"):  # fmt: skip
        batched.reset(seed=[1])
    batched.close()


def _reach(obs: np.ndarray) -> np.ndarray:
    """A scripted numpy policy for reacher: Jacobian-transpose torques towards the target, damped."""
    q1, q2, e = obs[:, 0], obs[:, 1], obs[:, 2:4]
    s1, c1, s12, c12 = np.sin(q1), np.cos(q1), np.sin(q1 + q2), np.cos(q1 + q2)
    j1 = np.stack([-0.12 * s1 - 0.12 * s12, 0.12 * c1 + 0.12 * c12], axis=1)
    j2 = np.stack([-0.12 * s12, 0.12 * c12], axis=1)
    return np.clip(60.0 * np.stack([(j1 * e).sum(1), (j2 * e).sum(1)], axis=1) - 0.3 * obs[:, 4:6], -1, 1)


_reach.batched = True  # type: ignore[attr-defined]  # sim2real.agents.as_policy: takes a (B, obs_dim) batch


def test_evaluate_uses_the_engine_and_reports_byte_identical_results() -> None:
    from sim2real.evaluation import evaluate, nominal, randomized, sweep

    conditions = [
        nominal(),
        randomized([s2r.Mass(scale=s2r.Uniform(0.7, 1.3)), s2r.Damping(scale=s2r.Uniform(0.5, 2.0))]),
        randomized([s2r.ObservationNoise(s2r.Gaussian(std=0.01)), s2r.ObservationLatency(steps=2)], name="noisy"),
        randomized([s2r.ActionLatency(steps=2)], name="delayed"),
        *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 1.5]),
    ]
    kwargs = {"episodes": 5, "seed": 3, "max_steps": 60, "batch": 3, "task_options": {"time_limit": 1.0}}
    policies = {"reach": _reach, "still": lambda o: np.zeros(2)}  # a per-row callable too
    auto = evaluate(policies, "dmc/reacher-easy", conditions, **kwargs)
    per_env = evaluate(policies, "dmc/reacher-easy", conditions, engine="per-env", **kwargs)
    assert dict(auto.engines) == {
        "sim": "batched",
        "randomized": "batched",
        "noisy": "batched",
        "delayed": "batched",  # action latency too (tests/test_batched_latency.py)
        "ActuatorGain.scale=0.5": "batched",
        "ActuatorGain.scale=1": "batched",  # a sweep includes the nominal value
        "ActuatorGain.scale=1.5": "batched",
    }
    assert set(per_env.engines.values()) == {"per-env"}
    assert auto.to_json() == per_env.to_json()  # bitwise: returns, lengths, draws
    assert auto.returns["reach"]["sim"].sum() > 0  # the rewards compared are not all zero
    assert (auto.lengths["still"]["sim"] == 50).all()  # the 1 s limit (50 steps) ends before max_steps
    with pytest.raises(ValueError, match=r"`engine` must be one of \['auto', 'per-env'\]. Received 'gpu'."):
        evaluate(_reach, "dmc/reacher-easy", [nominal()], engine="gpu")


def test_evaluate_arm_reach_successes_and_early_ends_are_byte_identical() -> None:
    from sim2real.agents import ReachController
    from sim2real.evaluation import evaluate, nominal, randomized

    conditions = [
        nominal(),
        randomized([s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), s2r.Mass(scale=s2r.Uniform(0.8, 1.2))]),
    ]
    policies = {"reach": ReachController(), "zero": lambda o: np.zeros(3)}
    kwargs = {"episodes": 4, "seed": 1, "max_steps": 60, "batch": 3}
    auto = evaluate(policies, "sim2real/arm-reach", conditions, **kwargs)
    per_env = evaluate(policies, "sim2real/arm-reach", conditions, engine="per-env", **kwargs)
    assert set(auto.engines.values()) == {"batched"}
    assert auto.to_json() == per_env.to_json()
    # Episodes that succeed end early (terminated): lengths differ between worlds of one batch.
    assert auto.successes["reach"]["sim"].any() and not auto.successes["zero"]["sim"].any()
    assert len(set(auto.lengths["reach"]["sim"].tolist())) > 1


def test_noise_blocks_and_latency_rings_stay_per_world_when_worlds_step_unevenly() -> None:
    # Worlds stepped on random masks (as evaluation steps only unfinished worlds) for more than one noise block
    # (BLOCK = 256 rows), resetting when their episode ends: every world's noise rows, latency ring and lag
    # must stay its own. The single envs are stepped only when their world is.
    effects = _effects(3)
    num = 3
    batched = make_batched("dmc/reacher-easy", num, *effects, seed=21, time_limit=6.0)  # 300-step episodes
    singles = [s2r.wrap(s2r.make("dmc/reacher-easy", time_limit=6.0), *effects, seed=(21, i)) for i in range(num)]
    obs, params = batched.reset(seed=[1, 2, 3])
    lags, steps, resets = set(params["obs_latency_steps"].tolist()), np.zeros(num, int), 0
    for i, env in enumerate(singles):
        assert np.array_equal(env.reset(seed=i + 1)[0], obs[i])
    rng = np.random.default_rng(5)
    for _ in range(450):
        mask = rng.random(num) < 0.8
        actions = rng.uniform(-1, 1, (num, 2)).astype(np.float32)
        obs, reward, _, truncated, _ = batched.step(actions, mask=mask)
        for i in np.flatnonzero(mask):
            o, r, _, tr, _ = singles[i].step(actions[i])
            assert np.array_equal(o, obs[i]) and r == reward[i] and tr == truncated[i]
            steps[i] += 1
        ended = np.flatnonzero(truncated)
        if len(ended):
            obs, params = batched.reset(indices=ended)
            resets += len(ended)
            lags.update(params["obs_latency_steps"].tolist())
            for i in ended:
                o, info = singles[i].reset()
                assert np.array_equal(o, obs[i])
                assert info["sim2real"]["params"]["obs_latency_steps"] == params["obs_latency_steps"][i]
    # Past a block refill inside an episode, a world reset while the others ran on, different lags in play.
    assert steps.min() > 256 and resets >= 1 and len(lags) > 1
    batched.close()


def test_threads_do_not_change_results() -> None:
    effects = _effects(1)
    one = make_batched("dmc/manipulator-bring_ball", 5, *effects, seed=3, time_limit=0.1)
    two = make_batched("dmc/manipulator-bring_ball", 5, *effects, seed=3, time_limit=0.1, threads=2)
    assert np.array_equal(one.reset(seed=0)[0], two.reset(seed=0)[0])
    rng = np.random.default_rng(0)
    for _ in range(10):
        actions = rng.uniform(-1, 1, (5, one.action_dim))
        for x, y in zip(one.step(actions), two.step(actions), strict=True):
            assert np.array_equal(x, y)
    one.close()
    two.close()
    with pytest.raises(ValueError, match=r"`threads` must be an int >= 1. Received 0."):
        make_batched("dmc/reacher-easy", 2, threads=0)


@pytest.mark.parametrize(
    ("task", "effect"),
    [
        ("dmc/reacher-easy", s2r.ActuatorGain(scale=s2r.Constant(1e9))),
        ("dmc/manipulator-bring_ball", s2r.ActuatorGain(scale=s2r.Constant(1e9))),
        ("sim2real/arm-reach", s2r.Stiffness(set=s2r.Constant(1e14))),
    ],
)
def test_a_diverged_world_ends_its_episode_like_the_single_env(task: str, effect: object) -> None:
    # dm-control: PhysicsError -> truncated, reward 0, last observation; arm-reach (gymnasium): RandomizePhysics
    # ends the episode on MuJoCo's bad-state warnings. The engine sees both through the warning counters.
    options = OPTIONS.get(task, SHORT)
    batched = make_batched(task, 2, effect, seed=0, **options)
    singles = [s2r.wrap(s2r.make(task, **options), effect, seed=(0, i)) for i in range(2)]
    obs, _ = batched.reset(seed=[1, 2])
    for i, env in enumerate(singles):
        assert np.array_equal(env.reset(seed=i + 1)[0], obs[i])
    actions = np.full((2, batched.action_dim), 0.5 * ACTION_SCALE.get(task, 1.0), np.float32)
    obs, reward, terminated, truncated, diverged = batched.step(actions)
    assert diverged.all() and truncated.all()
    for i, env in enumerate(singles):
        o, r, te, tr, info = env.step(actions[i])
        assert np.array_equal(o, obs[i]) and r == reward[i] and te == terminated[i] and tr == truncated[i]
        assert info["sim2real"]["diverged"]
    batched.close()


def test_given_envs_are_released_through_every_layer() -> None:
    # evaluate reuses its envs across conditions: closing the worlds must peel the signal and the physics layers
    # and restore the nominal model, so the next condition starts from the same env.
    bases = [s2r.make("dmc/reacher-easy") for _ in range(2)]
    damping = bases[0].unwrapped.physics.model.dof_damping.copy()
    worlds = BatchedEnv("dmc/reacher-easy", 2, [*_effects(3)], envs=bases, stream_seeds=[0, 0])
    worlds.reset(seed=[1, 2])
    assert not np.array_equal(bases[0].unwrapped.physics.model.dof_damping, damping)
    worlds.close()
    assert np.array_equal(bases[0].unwrapped.physics.model.dof_damping, damping)
    again = BatchedEnv("dmc/reacher-easy", 2, [s2r.Mass(scale=s2r.Uniform(0.7, 1.3))], envs=bases, stream_seeds=[0, 0])
    assert [type(env).__name__ for env in again.envs] == ["RandomizePhysics", "RandomizePhysics"]
    assert again.envs[0].env is bases[0]
    again.close()
