"""Building a batched world cheaply changes nothing: the recorded constructor arguments, the lockstep step.

(The shared ``mj_setConst`` scratch is pinned in ``tests/test_setconst.py``.)"""

from __future__ import annotations

import pickle
from typing import Any

import numpy as np
import pytest

import sim2real as s2r
from sim2real.batched import make_batched
from sim2real.wrappers.gym import RandomizePhysics


def test_immutable_effects_are_recorded_as_they_are_and_anything_else_is_copied() -> None:
    effects = [s2r.Mass(scale=s2r.Uniform(0.7, 1.3)), s2r.Damping(scale=s2r.Uniform(0.5, 2.0), joints=["shoulder"])]
    env = RandomizePhysics(s2r.make("dmc/reacher-easy"), effects, seed=(0, 3))
    saved = env._saved_kwargs
    assert saved == {"effects": tuple(effects), "seed": (0, 3)}
    assert all(a is b for a, b in zip(saved["effects"], effects, strict=True))  # values: nothing to copy
    seed = [0, 3]  # a list may change after the call: recorded as a copy, as gymnasium records it
    env = RandomizePhysics(s2r.make("dmc/reacher-easy"), effects, seed=seed)
    seed.append(9)
    assert env._saved_kwargs["seed"] == [0, 3]
    assert env._saved_kwargs["effects"][0] is not effects[0]  # copied along with the seed, as before
    again = pickle.loads(pickle.dumps(env._saved_kwargs))
    assert again == {"effects": tuple(effects), "seed": [0, 3]}
    env.close()


def _twins(task: str, effects: list[Any], **options: Any) -> tuple[Any, Any]:
    return (make_batched(task, 4, *effects, seed=5, **options), make_batched(task, 4, *effects, seed=5, **options))


@pytest.mark.parametrize(
    ("task", "effects", "options"),
    [
        (
            "dmc/reacher-easy",
            [
                s2r.Mass(scale=s2r.Uniform(0.7, 1.3)),
                s2r.ObservationNoise(s2r.Gaussian(std=0.01)),
                s2r.ActionLatency(seconds=s2r.Choice((0.0, 0.012, 0.02))),
            ],
            {"time_limit": 0.3},
        ),
        ("sim2real/arm-reach", [s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], {"max_episode_steps": 12}),
        (
            "dmc/reacher-hard",
            [s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], delta=0.1, m=1, t_low=-1.0, t_high=0.5)],
            {"time_limit": 0.2},
        ),
    ],
    ids=["signals-latency", "arm-reach", "adr"],
)
def test_a_lockstep_step_is_bitwise_the_masked_step_of_every_world(
    task: str, effects: list[Any], options: dict
) -> None:
    # step(actions) takes the lockstep path; step(actions, mask=all True) the general one: the same arithmetic.
    lockstep, masked = _twins(task, effects, **options)
    rng = np.random.default_rng(0)
    for episode in range(2):
        seeds = [10 * episode + i for i in range(4)]
        a, b = lockstep.reset(seed=seeds), masked.reset(seed=seeds)
        assert np.array_equal(a[0], b[0])
        for _ in range(30):
            actions = rng.uniform(-0.08, 0.08, (4, lockstep.action_dim)).astype(np.float32)
            got = lockstep.step(actions)
            want = masked.step(actions, np.ones(4, bool))
            for x, y in zip(got, want, strict=True):
                assert x.dtype == y.dtype and x.tobytes() == y.tobytes()
            if got[3].any():
                break
    lockstep.close()
    masked.close()


def test_a_lockstep_step_after_a_diverged_reset_ends_that_world_as_the_masked_step_does() -> None:
    # A near-zero mass leaves reacher's reset diverged (its forward pass finds a singular inertia): that world's next
    # step ends its episode unstepped, on the general path; the others go on, on the lockstep path from then on.
    effects = [s2r.Mass(set=s2r.Choice((1e-300, 0.05)), shared=True)]
    lockstep, masked = _twins("dmc/reacher-easy", effects, time_limit=0.1)
    a, b = lockstep.reset(seed=[1, 2, 3, 4]), masked.reset(seed=[1, 2, 3, 4])
    assert np.array_equal(a[0], b[0])
    assert 0 < int(lockstep._reset_diverged.sum()) < 4 and lockstep._stuck
    rng = np.random.default_rng(1)
    for step in range(10):
        actions = rng.uniform(-1, 1, (4, 2)).astype(np.float32)
        got, want = lockstep.step(actions), masked.step(actions, np.ones(4, bool))
        for x, y in zip(got, want, strict=True):
            assert x.tobytes() == y.tobytes()
        if step == 0:
            assert got[4].any() and not lockstep._stuck  # the diverged resets ended on the first step
    lockstep.close()
    masked.close()
