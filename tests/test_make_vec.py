"""make_vec (issue 15): draws reported when they are made (reset, autoreset, divergence), not merged every step."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np

import sim2real as s2r

TASK = "dmc/reacher-easy"
SHORT = {"time_limit": 0.1}  # 5 control steps per episode


def test_draws_come_with_resets_and_autoresets_only() -> None:
    effects = [s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), s2r.ObservationNoise(s2r.Bias(s2r.Uniform(-0.1, 0.1)))]
    envs = s2r.make_vec(TASK, 2, *effects, seed=3, **SHORT)
    singles = [s2r.wrap(s2r.make(TASK, **SHORT), *effects, seed=(3, i)) for i in range(2)]
    obs, info = envs.reset(seed=5)
    for i, env in enumerate(singles):
        o, single = env.reset(seed=5 + i)
        assert np.array_equal(o, obs[i])
        for key, value in single["sim2real"]["params"].items():
            assert info["sim2real"]["params"][key][i] == value
    zero = np.zeros((2, 2), np.float32)
    with_report = []
    for t in range(12):  # episodes of 5 steps: sub-envs autoreset in steps 5 and 11
        obs, _, _, truncated, info = envs.step(zero)
        assert bool(truncated.all()) == (t in (4, 10))
        if "sim2real" in info:
            with_report.append(t)
            for i, env in enumerate(singles):  # the new episodes' draws, bitwise the single envs' next reset
                _, single = env.reset()
                assert (
                    info["sim2real"]["params"]["dof_damping[shoulder]"][i]
                    == single["sim2real"]["params"]["dof_damping[shoulder]"]
                )
                assert info["sim2real"]["params"]["obs_bias[0]"][i] == single["sim2real"]["params"]["obs_bias[0]"]
        else:
            assert sorted(info) == []  # nothing merged on ordinary steps
    assert with_report == [5, 11]
    envs.close()


def test_a_diverged_step_still_reports() -> None:
    envs = s2r.make_vec(TASK, 2, s2r.ActuatorGain(scale=s2r.Constant(1e9)), seed=0)
    envs.reset(seed=1)
    _, _, _, truncated, info = envs.step(np.full((2, 2), 0.5, np.float32))
    assert truncated.all()
    assert info["sim2real"]["diverged"].tolist() == [True, True]
    envs.close()


def test_effects_that_act_during_an_episode_keep_the_per_step_report() -> None:
    push = s2r.Push(bodies="arm", force=s2r.Uniform(0.0, 0.01), interval=2.0)
    envs = s2r.make_vec(TASK, 2, push, seed=0)
    envs.reset(seed=1)
    _, _, _, _, info = envs.step(np.zeros((2, 2), np.float32))
    assert "events" in info["sim2real"]  # pushes so far, on every step
    envs.close()


def test_physics_only_sub_envs_are_one_layer_that_reports_at_reset_like_wrap() -> None:
    # Physics effects only (or none): each sub-env is one RandomizePhysics layer that reports at resets, autoresets
    # and divergence only; its observations, rewards and reports are bitwise wrap()'s single env's.
    from sim2real.wrappers import RandomizePhysics

    for effects in ([], [s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), s2r.Mass(scale=s2r.Uniform(0.8, 1.2))]):
        envs = s2r.make_vec(TASK, 2, *effects, seed=3, **SHORT)
        subs = envs.envs  # type: ignore[attr-defined]
        assert all(isinstance(sub, RandomizePhysics) and not isinstance(sub.env, RandomizePhysics) for sub in subs)
        singles = [s2r.wrap(s2r.make(TASK, **SHORT), *effects, seed=(3, i)) for i in range(2)]
        obs, info = envs.reset(seed=5)
        for i, env in enumerate(singles):
            o, single = env.reset(seed=5 + i)
            assert np.array_equal(o, obs[i])
            assert info["sim2real"]["episode"][i] == single["sim2real"]["episode"] == 0
            assert info["sim2real"]["diverged"][i] is np.False_ and info["sim2real"]["reapplied"][i] == ()
            assert sorted(k for k in info["sim2real"]["params"] if k[0] != "_") == sorted(single["sim2real"]["params"])
            for key, value in single["sim2real"]["params"].items():
                assert info["sim2real"]["params"][key][i] == value
        actions = np.random.default_rng(0).uniform(-1, 1, (7, 2, 2)).astype(np.float32)
        for t in range(7):  # episodes of 5 steps: both sub-envs autoreset in step 5
            obs, reward, _, truncated, info = envs.step(actions[t])
            if t == 5:
                assert info["sim2real"]["episode"].tolist() == [1, 1]
                for i, env in enumerate(singles):
                    o, single = env.reset()
                    assert np.array_equal(o, obs[i])
                    for key, value in single["sim2real"]["params"].items():
                        assert info["sim2real"]["params"][key][i] == value
                continue
            assert sorted(info) == []  # nothing on ordinary steps
            for i, env in enumerate(singles):
                o, r, _, tr, single_info = env.step(actions[t, i])
                assert np.array_equal(o, obs[i]) and r == reward[i] and tr == truncated[i]
                assert single_info["sim2real"]["diverged"] is False
        envs.close()
        for env in singles:
            env.close()
