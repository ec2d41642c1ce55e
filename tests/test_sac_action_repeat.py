"""SAC's training-time action repeat (``SACConfig.action_repeat``): each decision is held for ``k`` env steps and
stored as one transition whose reward is the block's sum; blocks restart at an episode's end.

The env is not one of ours: 5-step episodes (so a block of 2 or 3 is cut short at the end), a 3-entry observation
that counts steps, actions in [-2, 2] x [0, 1], reward = the step's index in its episode.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from sim2real.agents import SACConfig, sac_loop
from sim2real.agents.sac import NStepWriter

LOW, HIGH = np.array([-2.0, 0.0], np.float32), np.array([2.0, 1.0], np.float32)


class CountingSteps(gym.Env):
    """obs = (t, episode, 0); reward = t after the step; truncated at t = 5. Records the actions it receives."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-1e6, 1e6, (3,), np.float32)
        self.action_space = gym.spaces.Box(LOW, HIGH, dtype=np.float32)
        self._t = 0
        self._episode = -1
        self.received: list[tuple[int, int, tuple[float, ...]]] = []  # (episode, t before the step, action)

    def _obs(self) -> np.ndarray:
        return np.array([self._t, self._episode, 0.0], np.float32)

    def reset(self, *, seed=None, options=None):  # type: ignore[no-untyped-def]
        super().reset(seed=seed)
        self._t = 0
        self._episode += 1
        return self._obs(), {}

    def step(self, action):  # type: ignore[no-untyped-def]
        self.received.append((self._episode, self._t, tuple(np.asarray(action, float).round(6))))
        self._t += 1
        return self._obs(), float(self._t), False, self._t >= 5, {}


def _run(monkeypatch: pytest.MonkeyPatch, k: int) -> tuple[CountingSteps, list[tuple]]:
    stored: list[tuple] = []
    add = NStepWriter.add

    def record(self, obs, action, reward, next_obs, terminated, truncated):  # type: ignore[no-untyped-def]
        stored.append((obs.tolist(), np.array(action).tolist(), reward, next_obs.tolist(), terminated, truncated))
        return add(self, obs, action, reward, next_obs, terminated, truncated)

    monkeypatch.setattr(NStepWriter, "add", record)
    env = CountingSteps()
    cfg = SACConfig(frames=40, frames_per_batch=10, init_random_frames=15, batch_size=4, hidden_sizes=(8,),
                    obs_norm_frames=0, utd_ratio=0.5, reward_scale=2.0, action_repeat=k)  # fmt: skip
    sac_loop.train_sac(env, cfg, effects=(), seed=3, progress=False, log=None)
    return env, stored


@pytest.mark.parametrize("k", [1, 2, 3])
def test_each_decision_is_held_for_k_steps_and_stored_once(monkeypatch: pytest.MonkeyPatch, k: int) -> None:
    env, stored = _run(monkeypatch, k)
    assert len(env.received) == 40  # frames count env steps, whatever k
    blocks = [(0, 2, 4), (0, 3), (0,)]  # where blocks start within a 5-step episode (t before the step), k = 1, 2, 3
    starts = tuple(range(0, 5, k))
    assert starts == {1: (0, 1, 2, 3, 4), 2: blocks[0], 3: blocks[1]}[k]
    # the env sees each decision k times in a row, a new one at each block start (and at each episode's start)
    decisions = []
    for episode, t, action in env.received:
        if t in starts:
            decisions.append(action)
        else:
            assert action == decisions[-1], (episode, t)
    # one stored transition per block: from the decision's obs, summed (scaled) rewards, to the obs after the block
    assert len(stored) == 8 * len(starts)
    for j, (obs, _, reward, next_obs, terminated, truncated) in enumerate(stored):
        episode, block = divmod(j, len(starts))
        t0 = starts[block]
        t1 = min(t0 + k, 5)
        assert obs == [t0, episode, 0.0] and next_obs == [t1, episode, 0.0]
        assert reward == 2.0 * sum(range(t0 + 1, t1 + 1))
        assert terminated is False and truncated is (t1 == 5)
    # the stored action is the one the env received (in the normalised box)
    mid, half = (HIGH + LOW) / 2, (HIGH - LOW) / 2
    for j, (_, action, *_) in enumerate(stored):
        episode, block = divmod(j, len(starts))
        sent = np.array(env.received[episode * 5 + starts[block]][2])
        np.testing.assert_allclose(mid + half * np.array(action), sent, atol=1e-5)


def test_action_repeat_is_validated_and_omitted_at_its_default() -> None:
    with pytest.raises(ValueError, match=r"`action_repeat` must be .*Received 0"):
        SACConfig(action_repeat=0)
    assert "action_repeat" not in SACConfig().to_dict()
    assert SACConfig(action_repeat=4).to_dict()["action_repeat"] == 4
