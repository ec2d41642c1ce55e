"""SAC's mean-action episodes (``SACConfig.mean_action_every``): which episodes act with the actor's mean, and
that the default leaves training as it was.

The env is not one of ours: 5-step episodes, a 3-entry observation, actions in [-2, 2] x [0, 1].
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from sim2real.agents import SACConfig, sac_loop
from sim2real.agents.sac import NStepWriter

LOW, HIGH = np.array([-2.0, 0.0], np.float32), np.array([2.0, 1.0], np.float32)


class FiveSteps(gym.Env):
    """Five steps per episode; reward = -|action - 0.5|."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-10.0, 10.0, (3,), np.float32)
        self.action_space = gym.spaces.Box(LOW, HIGH, dtype=np.float32)
        self._t = 0

    def reset(self, *, seed=None, options=None):  # type: ignore[no-untyped-def]
        super().reset(seed=seed)
        self._t = 0
        return self.np_random.normal(size=3).astype(np.float32), {}

    def step(self, action):  # type: ignore[no-untyped-def]
        self._t += 1
        obs = self.np_random.normal(size=3).astype(np.float32)
        return obs, -float(np.abs(action - 0.5).sum()), False, self._t >= 5, {}


def _cfg(**kw: object) -> SACConfig:
    base = dict(frames=60, frames_per_batch=10, init_random_frames=20, batch_size=8, hidden_sizes=(8,),
                obs_norm_frames=10, utd_ratio=0.5)  # fmt: skip
    base.update(kw)
    return SACConfig(**base)  # type: ignore[arg-type]


def _collected(monkeypatch: pytest.MonkeyPatch, cfg: SACConfig) -> list[np.ndarray]:
    """The normalised actions stored, in order, with the sampled policy playing +0.25 and the mean -0.75."""
    seen: list[np.ndarray] = []
    add = NStepWriter.add

    def record(self, obs, action, *rest):  # type: ignore[no-untyped-def]
        seen.append(np.array(action))
        return add(self, obs, action, *rest)

    monkeypatch.setattr(NStepWriter, "add", record)
    monkeypatch.setattr(sac_loop, "_explorer", lambda update, act_dim: lambda obs: torch.full((act_dim,), 0.25))
    monkeypatch.setattr(sac_loop, "_mean_actor", lambda update: lambda obs: torch.full((2,), -0.75))
    torch.manual_seed(0)
    sac_loop.train_sac(FiveSteps(), cfg, effects=(), seed=3, progress=False, log=None)
    return seen


@pytest.mark.parametrize("every", [0, 1, 3])
def test_every_kth_episode_after_the_warm_up_plays_the_mean(monkeypatch: pytest.MonkeyPatch, every: int) -> None:
    actions = _collected(monkeypatch, _cfg(mean_action_every=every))
    assert len(actions) == 60
    for frame, action in enumerate(actions):
        episode = frame // 5
        if frame < 20:  # the warm-up's uniform draws, whatever the option
            assert np.all(np.abs(action) <= 1.0) and not np.isin(action, (0.25, -0.75)).any(), frame
        elif every and episode % every == every - 1:
            assert action.tolist() == [-0.75, -0.75], frame
        else:
            assert action.tolist() == [0.25, 0.25], frame


def test_the_mean_actor_is_tanh_of_the_policy_mean() -> None:
    from sim2real.agents.nets import actor_normalizer, build_actor, build_qvalue
    from sim2real.agents.sac import SACUpdate

    torch.manual_seed(1)
    actor = build_actor("sac", 3, LOW.tolist(), HIGH.tolist(), (8,), "relu", 0.0)
    norm = actor_normalizer(actor)
    update = SACUpdate(actor, [build_qvalue(3, 2, (8,), "relu", norm) for _ in range(2)], lr=1e-3, gamma=0.99,
                       tau=0.005, alpha_init=0.1, target_entropy=None)  # fmt: skip
    obs = np.array([0.3, -1.0, 2.0], np.float32)
    loc, _ = update.extractor(update.mlp(update.norm(torch.from_numpy(obs))))
    before = torch.get_rng_state()
    mean = sac_loop._mean_actor(update)(obs)
    assert torch.equal(mean, torch.tanh(loc).detach())
    assert torch.equal(torch.get_rng_state(), before)  # no draw: the sampled episodes' noise is not shifted


def test_default_leaves_training_bitwise_and_the_config_form() -> None:
    """``mean_action_every=0`` is the loop as it was: same weights as a config that never mentions it."""
    assert "mean_action_every" not in SACConfig().to_dict()
    cfg = SACConfig.from_yaml("algo: sac\nmean_action_every: 4\n")
    assert cfg.mean_action_every == 4 and SACConfig.from_yaml(cfg.to_yaml()) == cfg
    with pytest.raises(ValueError, match=r"^`mean_action_every` must be an int >= 0\. Received -1\.$"):
        SACConfig(mean_action_every=-1)

    def weights(c: SACConfig) -> list[torch.Tensor]:
        torch.manual_seed(0)
        actor, _, _ = sac_loop.train_sac(FiveSteps(), c, effects=(), seed=3, progress=False, log=None)
        return [p.detach().clone() for p in actor.parameters()]

    plain, zero, two = weights(_cfg()), weights(_cfg(mean_action_every=0)), weights(_cfg(mean_action_every=2))
    assert all(torch.equal(a, b) for a, b in zip(plain, zero, strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(plain, two, strict=True))  # the option does change training
