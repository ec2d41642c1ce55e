"""Building a batched world cheaply changes nothing: the recorded constructor arguments.

(The shared ``mj_setConst`` scratch is pinned in ``tests/test_setconst.py``.)"""

from __future__ import annotations

import pickle

import sim2real as s2r
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
