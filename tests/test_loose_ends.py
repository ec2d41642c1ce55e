"""Loose ends of earlier sessions, each pinned by a test that failed before its fix."""

from __future__ import annotations

import warnings
from typing import Any

import dm_env
import numpy as np
import pytest
from dm_env import specs
from gymnasium.utils.env_checker import check_env

from sim2real.adapters import DmEnvToGym


class _Drift(dm_env.Environment):
    """A hand-written dm_env (no dm-control): a point drifting by its action; optionally noisy."""

    def __init__(self, rng: Any = None) -> None:
        self.x = np.zeros(2)
        if rng is not None:
            self._rng = rng

    def reset(self) -> dm_env.TimeStep:
        self.x = np.zeros(2) if not hasattr(self, "_rng") else self._rng.normal(size=2)
        self.t = 0
        return dm_env.restart(self.x.copy())

    def step(self, action: Any) -> dm_env.TimeStep:
        self.x = self.x + np.asarray(action, dtype=np.float64)
        self.t += 1
        if self.t >= 5:
            return dm_env.truncation(-float(self.x @ self.x), self.x.copy())
        return dm_env.transition(-float(self.x @ self.x), self.x.copy())

    def observation_spec(self) -> specs.Array:
        return specs.Array((2,), np.float64, name="x")

    def action_spec(self) -> specs.BoundedArray:
        return specs.BoundedArray((2,), np.float64, -1.0, 1.0, name="push")


def test_a_deterministic_dm_env_takes_a_seed_and_passes_check_env() -> None:
    env = DmEnvToGym(_Drift())
    obs, info = env.reset(seed=3)  # "`seed` cannot be honoured: _Drift exposes no RandomState" before
    assert obs.tolist() == [0.0, 0.0] and info == {}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # accepted without a warning: there is nothing to re-seed
        env.reset(seed=4)
    check_env(env, skip_render_check=True)


@pytest.mark.parametrize(
    ("rng", "kind"),
    [
        (np.random.default_rng(0), "numpy.random.Generator"),
        (np.random.RandomState(0), "numpy.random.RandomState"),
    ],
)
def test_a_dm_env_with_randomness_it_keeps_to_itself_refuses_a_seed(rng: Any, kind: str) -> None:
    env = DmEnvToGym(_Drift(rng))
    with pytest.raises(ValueError) as err:
        env.reset(seed=3)
    assert str(err.value) == (
        f"`seed` cannot be honoured: _Drift draws from env._rng ({kind}), which DmEnvToGym cannot re-seed. "
        "Keep the env's randomness in a numpy RandomState named `random_state` (re-seeded in place, as for "
        "composer envs), or seed the env in its factory and call reset() without a seed. Received seed=3."
    )
    obs, _ = env.reset()  # unseeded resets still work
    assert obs.shape == (2,)


def test_a_dm_env_exposing_random_state_is_reseeded_in_place() -> None:
    inner = _Drift(np.random.RandomState(0))
    inner.random_state = inner._rng  # the name composer envs use
    env = DmEnvToGym(inner)
    first, _ = env.reset(seed=7)
    env.reset()
    again, _ = env.reset(seed=7)
    assert first.tobytes() == again.tobytes() and np.abs(first).sum() > 0


def test_a_dm_control_suite_env_is_still_reseeded_and_passes_check_env() -> None:
    from dm_control import suite

    env = DmEnvToGym(suite.load("reacher", "easy"))
    first, _ = env.reset(seed=11)
    other, _ = env.reset(seed=12)
    again, _ = env.reset(seed=11)
    assert first.tobytes() == again.tobytes() and first.tobytes() != other.tobytes()
    check_env(env, skip_render_check=True)
