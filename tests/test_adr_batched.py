"""ADR on the batched engine (sim2real.batched.adr): each world bitwise its single ADR env, one shared controller.

The reference is N single envs ``wrap(make(task), adr, *effects, seed=(0, i))`` sharing one controller, stepped one
after the other (world order) and the finished ones reset after the step, as the collector's partial reset does.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

import sim2real as s2r
from sim2real.agents import PPOConfig, train
from sim2real.agents.collect import Collection, choose_collection
from sim2real.batched import make_batched, supports

ARM = "sim2real/arm-reach"
REACHER = "dmc/reacher-easy"


def _controller(metric: str, t_low: float, t_high: float) -> s2r.ADR:
    return s2r.ADR(
        [s2r.Damping(scale=s2r.Uniform(0.0, 5.0)), s2r.ActuatorGain(scale=s2r.Uniform(0.25, 2.0))],
        delta=0.25, m=1, p_boundary=0.75, t_low=t_low, t_high=t_high, metric=metric,
        # Started wide, so failing pinned episodes narrow a boundary too (narrowing stops at the initial range).
        initial={"Damping[joints=*]": (0.5, 3.0), "ActuatorGain[actuators=*]": (0.5, 1.5)},
    )  # fmt: skip


def _lockstep(
    task: str, n: int, adr: s2r.ADR, others: list[Any], actions: np.ndarray, options: dict[str, Any]
) -> list[tuple[Any, ...]]:
    """Every step's (obs, reward, terminated, truncated) and every reset's (world, params) of N single envs."""
    envs = [s2r.wrap(s2r.make(task, textures=False, **options), adr, *others, seed=(0, i)) for i in range(n)]
    out: list[tuple[Any, ...]] = []
    try:
        for i, env in enumerate(envs):
            _, info = env.reset(seed=i)
            out.append(("reset", i, info["sim2real"]["params"]))
        for act in actions:
            step = [env.step(a) for env, a in zip(envs, act, strict=True)]  # world order: reports in that order
            out.append(("step", *(np.array([s[k] for s in step]) for k in range(4))))
            for i, s in enumerate(step):
                if s[2] or s[3]:
                    _, info = envs[i].reset()
                    out.append(("reset", i, info["sim2real"]["params"]))
    finally:
        for env in envs:
            env.close()
    return out


def _batched(
    task: str, n: int, adr: s2r.ADR, others: list[Any], actions: np.ndarray, options: dict[str, Any]
) -> list[tuple[Any, ...]]:
    envs = make_batched(task, n, adr, *others, seed=0, **options)
    out: list[tuple[Any, ...]] = []
    try:
        _, params = envs.reset(seed=0)
        out += [("reset", i, {k: v[i] for k, v in params.items()}) for i in range(n)]
        for act in actions:
            obs, reward, terminated, truncated, _ = envs.step(act)
            out.append(("step", obs, reward, terminated, truncated))
            done = np.flatnonzero(terminated | truncated)
            if len(done):
                _, params = envs.reset(indices=done)
                out += [("reset", int(i), {k: v[i] for k, v in params.items()}) for i in done]
    finally:
        envs.close()
    return out


def _assert_same(ours: list[tuple[Any, ...]], theirs: list[tuple[Any, ...]]) -> None:
    assert len(ours) == len(theirs)
    for a, b in zip(ours, theirs, strict=True):
        assert a[0] == b[0]
        if a[0] == "reset":
            assert a[1] == b[1] and sorted(a[2]) == sorted(b[2])
            for key, value in a[2].items():
                assert value == b[2][key], key  # bitwise, the same draw (a pinned boundary included)
        else:
            assert np.array_equal(a[1].astype(np.float32), b[1])  # the engine's observations are float32
            for k in (2, 3, 4):
                assert np.array_equal(a[k], b[k])


@pytest.mark.parametrize(
    ("task", "n", "steps", "options", "metric", "t_low", "t_high", "signals"),
    [
        # Success metric on arm-reach: about half the episodes succeed at once (terminated after 1 step), the others
        # run to the 15-step limit, so the worlds end and reset at different steps.
        (ARM, 3, 60, {"max_episode_steps": 15, "success_threshold": 0.6}, "success", 0.3, 0.7, False),
        # Return metric, thresholds around the random policy's return, a Mass outside ADR and noisy observations.
        (ARM, 4, 48, {"max_episode_steps": 8}, "return", -5.5, -4.8, True),
    ],
)
def test_each_world_and_the_controller_are_bitwise_the_lockstep_single_envs(
    task: str, n: int, steps: int, options: dict[str, Any], metric: str, t_low: float, t_high: float, signals: bool
) -> None:
    others: list[Any] = []
    if signals:
        others = [s2r.Mass(scale=s2r.Uniform(0.8, 1.2), bodies="*"), s2r.ObservationNoise(s2r.Gaussian(0.01))]
    actions = np.random.default_rng(7).uniform(-0.05, 0.05, (steps, n, 3)).astype(np.float32)
    ref_adr, adr = _controller(metric, t_low, t_high), _controller(metric, t_low, t_high)
    theirs = _lockstep(task, n, ref_adr, others, actions, options)
    ours = _batched(task, n, adr, others, actions, options)
    _assert_same(theirs, ours)
    assert adr.state() == ref_adr.state()  # ranges, buffers, frames, stale results and the whole history
    assert 0 < adr.frames <= steps * n  # the steps of the finished episodes
    moves = np.diff(np.array(adr.history.low), axis=0), np.diff(np.array(adr.history.high), axis=0)
    assert (moves[0] < 0).any() or (moves[1] > 0).any(), "no boundary widened"
    assert (moves[0] > 0).any() or (moves[1] < 0).any(), "no boundary narrowed"


def test_reacher_episodes_report_their_return_and_no_success() -> None:
    def controller(seen: list[s2r.Episode]) -> s2r.ADR:
        def metric(episode: s2r.Episode) -> float:
            seen.append(episode)
            return episode.episode_return

        return s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], delta=0.1, m=1, t_low=-1.0, t_high=0.5,
                       metric=metric)  # fmt: skip

    ours_seen: list[s2r.Episode] = []
    theirs_seen: list[s2r.Episode] = []
    adr, ref = controller(ours_seen), controller(theirs_seen)
    actions = np.random.default_rng(3).uniform(-1, 1, (1000, 2, 2)).astype(np.float32)
    _assert_same(_lockstep(REACHER, 2, ref, [], actions, {}), _batched(REACHER, 2, adr, [], actions, {}))
    assert ours_seen == theirs_seen and [e.length for e in ours_seen] == [1000, 1000]
    assert {e.success for e in ours_seen} == {None}  # dm-control reacher reports no success flag
    assert adr.state() == ref.state() and adr.frames == 2000


def test_supports_checks_the_controllers_effects() -> None:
    adr = s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], delta=0.1, t_low=0.2, t_high=0.8)
    assert supports(REACHER, adr) is None
    per_step = s2r.ADR(
        [s2r.Damping(scale=s2r.Uniform(0.5, 2.0), schedule=s2r.Interval(10))], delta=0.1, t_low=0.2, t_high=0.8
    )
    assert supports(REACHER, per_step) == "Damping acts during the episode (per-step effects are not batched)"


def test_ppo_with_adr_collects_batched_and_is_deterministic() -> None:
    # 5 worlds x (40 normaliser + 2 x 100 collected) steps: every world ends at least one 200-step episode.
    cfg = PPOConfig(frames=1000, frames_per_batch=500, minibatch_size=250, epochs=1, obs_norm_frames=200, num_envs=5)

    def run() -> Any:
        adr = s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.2, 4.0))], delta=0.2, t_low=-200.0, t_high=-50.0, m=1,
                      p_boundary=1.0)  # fmt: skip
        return train(ARM, cfg, effects=[adr], seed=3, progress=False, logger=None)

    assert choose_collection(ARM, [_controller("return", 0.0, 1.0)], cfg) == Collection("batched", 5, None, 100)
    first, second = run(), run()
    assert first.collection == Collection("batched", 5, None, 100)
    assert first.adr == second.adr and first.metrics == second.metrics
    state = s2r.ADR.from_state(first.adr)
    assert state.frames >= 5 * 200 and len(state.history.frames) > 1  # every world reported; a boundary moved
    per_env = train(ARM, replace(cfg, engine="per-env"), effects=[_controller("return", 0.0, 1.0)], seed=3,
                    progress=False, logger=None)  # fmt: skip
    assert per_env.collection is not None and per_env.collection.engine == "per-env"
