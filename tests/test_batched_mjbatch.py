"""The batched engine on ``mujoco.batch`` (issue 15): long rollouts with contacts and joint limits bitwise the single
env's at 1 and 2 threads, ``datas[i]`` holding the batch's whole state, and divergence seen episode after episode."""

from __future__ import annotations

import io
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np
import pytest

import sim2real as s2r
from sim2real.batched import make_batched

LIMIT = mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT


@pytest.mark.parametrize(
    ("task", "options", "steps"),
    [
        ("dmc/manipulator-bring_ball", {"time_limit": 2.0}, 200),  # contacts (ball, floor, fingers), arm limits
        ("dmc/reacher-easy", {}, 1000),  # a whole episode; the wrist's range is hit under large actions
    ],
)
def test_long_rollouts_with_contacts_and_limits_are_bitwise_at_one_and_two_threads(
    task: str, options: dict, steps: int
) -> None:
    effects = [s2r.Mass(scale=s2r.Uniform(0.7, 1.3)), s2r.Damping(scale=s2r.Uniform(0.3, 2.0))]
    n = 3
    one = make_batched(task, n, *effects, seed=5, threads=1, **options)
    two = make_batched(task, n, *effects, seed=5, threads=2, **options)
    assert (one.threads, two.threads) == (1, 2)
    singles = [s2r.wrap(s2r.make(task, **options), *effects, seed=(5, i)) for i in range(n)]
    obs1, _ = one.reset(seed=10)
    obs2, _ = two.reset(seed=10)
    assert np.array_equal(obs1, obs2)
    for i, env in enumerate(singles):
        assert np.array_equal(env.reset(seed=10 + i)[0], obs1[i])
    rng = np.random.default_rng(0)
    contacts = limits = 0
    for t in range(steps):
        actions = rng.uniform(-1.5, 1.5, (n, one.action_dim))
        out1, out2 = one.step(actions), two.step(actions)
        for x, y in zip(out1, out2, strict=True):
            assert np.array_equal(x, y), t
        for i, env in enumerate(singles):
            o, r, te, tr, _ = env.step(actions[i])
            assert np.array_equal(o, out1[0][i]) and r == out1[1][i] and te == out1[2][i] and tr == out1[3][i], (t, i)
        for i, env in enumerate(singles):
            theirs = s2r.physics.find_physics(env).data  # type: ignore[union-attr]
            contacts += theirs.ncon > 0
            limits += bool((theirs.efc_type[: theirs.nefc] == LIMIT).any())
            if t % 10 == 0:  # datas[i]: the batch's whole MjData, the same as the single env's (constraints too)
                mine = one.datas[i]
                assert np.array_equal(mine.qacc_warmstart, theirs.qacc_warmstart)
                assert (mine.ncon, mine.nefc) == (theirs.ncon, theirs.nefc)
                assert np.array_equal(mine.efc_force[: mine.nefc], theirs.efc_force[: theirs.nefc])
    if task.startswith("dmc/manipulator"):
        assert contacts > 0
    assert limits > 0  # the comparisons above ran with the constraint solver (and its warm start) at work
    for env in (one, two, *singles):
        env.close()


def test_a_world_diverges_again_in_its_next_episode() -> None:
    # Each reset loads a fresh MjData into the batch (zero warning counters): MuJoCo counts a divergence as 1 after
    # resetting the data, so a counter carried over from the last episode would hide the second one.
    effect = s2r.ActuatorGain(scale=s2r.Constant(1e9))
    batched = make_batched("dmc/reacher-easy", 2, effect, seed=0, time_limit=0.3)
    single = s2r.wrap(s2r.make("dmc/reacher-easy", time_limit=0.3), effect, seed=(0, 1))
    actions = np.full((2, batched.action_dim), 0.5)
    for episode in range(3):
        obs, _ = batched.reset(seed=[episode, 100 + episode])
        assert np.array_equal(single.reset(seed=100 + episode)[0], obs[1])
        obs, reward, _, truncated, diverged = batched.step(actions)
        o, r, _, tr, info = single.step(actions[1])
        assert diverged.all() and truncated.all(), episode
        assert info["sim2real"]["diverged"] and tr and r == reward[1] == 0.0
        assert np.array_equal(o, obs[1])
    batched.close()


def test_threads_default_to_the_idle_cores_and_never_more_than_the_worlds(monkeypatch: pytest.MonkeyPatch) -> None:
    from sim2real.batched import worlds
    from sim2real.batched.worlds import CpuReadings, busy_cores, default_threads

    # Only this thread runnable: every core, whatever the (lagging) load average says.
    idle = CpuReadings(cores=2, running=(1, 1, 1, 1), load=None)
    assert busy_cores(idle) == 0 and default_threads(64, idle) == 2
    # A task on the other core at every reading (a busy loop started seconds ago, load average still below 2).
    other = CpuReadings(cores=2, running=(2, 2, 3, 2), load=None)
    assert busy_cores(other) == 1 and default_threads(64, other) == 1
    # A burst over by one reading is not a busy core.
    burst = CpuReadings(cores=2, running=(2, 1, 2, 2), load=None)
    assert busy_cores(burst) == 0 and default_threads(64, burst) == 2
    # More busy than cores: 1; fewer worlds than idle cores: one thread per world.
    crowded = CpuReadings(cores=8, running=(12, 11, 13, 12), load=None)
    assert busy_cores(crowded) == 10 and default_threads(64, crowded) == 1
    half = CpuReadings(cores=8, running=(5, 5, 6, 5), load=None)
    assert default_threads(64, half) == 4 and default_threads(3, half) == 3 and default_threads(1, half) == 1
    # Without /proc/loadavg: the one-minute load above 1 (this process), rounded down; without either: every core.
    assert busy_cores(CpuReadings(cores=4, running=(), load=2.7)) == 1
    assert default_threads(64, CpuReadings(cores=4, running=(), load=2.7)) == 3
    assert default_threads(64, CpuReadings(cores=4, running=(), load=None)) == 4

    # read_cpu parses /proc/loadavg's runnable count at each of its readings, and falls back to the load average.
    lines = iter([b"0.52 0.58 0.59 2/345 6789\n", b"1.10 0.58 0.59 3/345 6790\n"] * worlds.SAMPLES)

    class Loadavg(io.BytesIO):
        def __init__(self, *_: object) -> None:
            super().__init__(next(lines))

    monkeypatch.setattr(worlds, "open", Loadavg, raising=False)
    got = worlds.read_cpu()
    assert got.running == (2, 3, 2, 3)[: worlds.SAMPLES] and got.load is None and got.cores >= 1
    assert busy_cores(got) == 1

    def missing(*_: object) -> None:
        raise FileNotFoundError("/proc/loadavg")

    monkeypatch.setattr(worlds, "open", missing, raising=False)
    monkeypatch.setattr(worlds.os, "getloadavg", lambda: (2.5, 0.0, 0.0))
    assert worlds.read_cpu() == CpuReadings(cores=got.cores, running=(), load=2.5)

    # make_batched asks default_threads when given no count.
    cores = got.cores
    monkeypatch.setattr(worlds, "read_cpu", lambda: CpuReadings(cores=cores, running=(1,), load=None))
    many = make_batched("dmc/reacher-easy", 5, seed=0)
    assert many.threads == min(cores, 5)
    one = make_batched("dmc/reacher-easy", 1, seed=0)
    assert one.threads == 1
    for env in (many, one):
        env.close()
