"""sim2real.agents.sac: the hand-written SAC update against a textbook computation, the replay buffer, and the
SAC training loop (determinism, env paths, no per-step pandas probing)."""

from __future__ import annotations

import copy
import importlib.util
import math

import numpy as np
import pytest
import torch
from torch import nn

from sim2real.agents import SACConfig, as_policy
from sim2real.agents.nets import actor_normalizer, build_actor, build_qvalue
from sim2real.agents.sac import LOSS_KEYS, ReplayBuffer, SACUpdate

ARM = "sim2real/arm-reach"
TINY_SAC = SACConfig(
    frames=400, frames_per_batch=100, init_random_frames=200, batch_size=32, hidden_sizes=(16,), obs_norm_frames=100
)


def _update(obs_dim: int = 5, act_dim: int = 2, seed: int = 0) -> SACUpdate:
    torch.manual_seed(seed)
    actor = build_actor("sac", obs_dim, [-0.5] * act_dim, [0.5] * act_dim, (32, 32), "relu")
    norm = actor_normalizer(actor)
    norm.set_stats(torch.linspace(-1, 1, obs_dim), torch.linspace(0.5, 2, obs_dim))
    qvalues = [build_qvalue(obs_dim, act_dim, (32, 32), "relu", norm) for _ in range(2)]
    return SACUpdate(actor, qvalues, lr=1e-3, gamma=0.9, tau=0.1, alpha_init=0.3)


def _batch(obs_dim: int = 5, act_dim: int = 2, n: int = 64) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(7)
    term = (torch.rand(n, generator=g) < 0.3).float()
    return (torch.randn(n, obs_dim, generator=g), torch.rand(n, act_dim, generator=g) * 2 - 1,
            torch.randn(n, generator=g), torch.randn(n, obs_dim, generator=g), term)  # fmt: skip


def _textbook(update: SACUpdate, batch: tuple[torch.Tensor, ...], seed: int) -> tuple[list[float], list[torch.Tensor]]:
    """The SAC losses written from the paper with torch.distributions, on deep copies of the update's modules:
    (loss values, gradients of actor then critic then log_alpha parameters)."""
    obs, act, rew, nxt, term = batch
    norm, mlp, extractor = (copy.deepcopy(m) for m in (update.norm, update.mlp, update.extractor))
    qs = [copy.deepcopy(q.mlp) for q in update.qnets]
    targets = [copy.deepcopy(t) for t in update.targets]
    log_alpha = nn.Parameter(update.log_alpha.detach().clone())
    torch.manual_seed(seed)
    eps_next = torch.randn(obs.shape[0], update.act_dim)
    eps = torch.randn(obs.shape[0], update.act_dim)

    def sample(o: torch.Tensor, e: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc, scale = extractor(mlp(norm(o)))
        u = loc + scale * e
        a = torch.tanh(u)
        logp = torch.distributions.Normal(loc, scale).log_prob(u) - torch.log(1 - a.double() ** 2).float()
        return a, logp.sum(-1)

    alpha = log_alpha.detach().exp()
    with torch.no_grad():
        a2, logp2 = sample(nxt, eps_next)
        x2 = torch.cat((norm(nxt), a2), -1)
        y = rew + 0.9 * (1 - term) * (torch.min(targets[0](x2), targets[1](x2)).squeeze(-1) - alpha * logp2)
    x = torch.cat((norm(obs), act), -1)
    loss_q = 0.5 * sum(((q(x).squeeze(-1) - y) ** 2).mean() for q in qs)
    a, logp = sample(obs, eps)
    for q in qs:
        q.requires_grad_(False)
    xa = torch.cat((norm(obs), a), -1)
    loss_actor = (alpha * logp - torch.min(qs[0](xa), qs[1](xa)).squeeze(-1)).mean()
    for q in qs:
        q.requires_grad_(True)
    loss_alpha = -(log_alpha * (logp.detach() - update.act_dim)).mean()
    (loss_actor + loss_q + loss_alpha).backward()
    grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in [*mlp.parameters(),
             *(p for q in qs for p in q.parameters()), log_alpha]]  # fmt: skip
    return [float(v.detach()) for v in (loss_actor, loss_q, loss_alpha, alpha)], grads


def test_sac_update_matches_the_textbook_losses_and_gradients() -> None:
    update = _update()
    batch = _batch()
    expected, grads = _textbook(update, batch, seed=11)
    torch.manual_seed(11)
    losses = update.step(*batch)
    np.testing.assert_allclose(losses.numpy(), expected, rtol=1e-5, atol=1e-6)
    params = [*update.actor_params, *update._sources, update.log_alpha]
    for p, g in zip(params, grads, strict=True):
        torch.testing.assert_close(p.grad, g, rtol=1e-4, atol=1e-6)


def test_sac_update_moves_targets_by_polyak_and_keeps_alpha_positive() -> None:
    update = _update()
    before = [p.detach().clone() for p in update._target_params]
    update.step(*_batch())
    for old, new, src in zip(before, update._target_params, update._sources, strict=True):
        torch.testing.assert_close(new, old + 0.1 * (src.detach() - old))
    assert dict(zip(LOSS_KEYS, update.step(*_batch()).tolist(), strict=True))["alpha"] > 0


def test_sac_update_rejects_foreign_networks() -> None:
    update = _update()
    with pytest.raises(TypeError, match=r"^`actor` must be a SAC actor made by build_actor\. Received Linear\.$"):
        SACUpdate(nn.Linear(2, 2), update.qnets, lr=1e-3, gamma=0.9, tau=0.1, alpha_init=1.0)
    actor = build_actor("sac", 5, [-1.0], [1.0], (8,), "relu")
    with pytest.raises(ValueError, match=r"^`qvalues` must hold at least 2 critics\. Received 1\.$"):
        SACUpdate(actor, update.qnets[:1], lr=1e-3, gamma=0.9, tau=0.1, alpha_init=1.0)


def test_replay_buffer_is_a_ring_and_samples_from_its_seed() -> None:
    buf = ReplayBuffer(4, 2, 1, seed=3)
    for i in range(6):
        buf.add(np.full(2, i), np.full(1, -i), float(i), np.full(2, i + 1), i == 5)
    assert len(buf) == 4
    assert buf.reward.tolist() == [4.0, 5.0, 2.0, 3.0]  # rows 0 and 1 overwritten by transitions 4 and 5
    assert buf.terminated.tolist() == [0.0, 1.0, 0.0, 0.0]
    again = ReplayBuffer(4, 2, 1, seed=3)
    for i in range(6):
        again.add(np.full(2, i), np.full(1, -i), float(i), np.full(2, i + 1), i == 5)
    first, second = buf.sample(16), again.sample(16)
    assert all(torch.equal(a, b) for a, b in zip(first, second, strict=True))
    obs, act, rew, nxt, _, steps = first
    assert torch.equal(obs[:, 0], rew) and torch.equal(nxt[:, 0], rew + 1) and torch.equal(act[:, 0], -rew)
    assert torch.equal(steps, torch.ones(16))  # one-step transitions unless an NStepWriter says otherwise


def test_train_sac_is_bitwise_deterministic() -> None:
    from sim2real.agents import train

    first = train(ARM, TINY_SAC, seed=2, progress=False, logger=None)
    second = train(ARM, TINY_SAC, seed=2, progress=False, logger=None)
    a, b = first.policy.state_dict(), second.policy.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert first.metrics == second.metrics
    assert set(LOSS_KEYS) <= set(first.metrics) and first.metrics["frames"] == (100.0, 200.0, 300.0, 400.0)
    other = train(ARM, TINY_SAC, seed=3, progress=False, logger=None).policy.state_dict()
    assert not all(torch.equal(a[k], other[k]) for k in a)


def test_train_sac_on_a_torchrl_env() -> None:
    from torchrl.envs import GymWrapper

    import sim2real
    from sim2real.agents import train

    res = train(GymWrapper(sim2real.make(ARM)), TINY_SAC, seed=0, progress=False, logger=None)
    assert res.frames == 400 and math.isfinite(res.metrics["loss_qvalue"][-1])
    actions = as_policy(res)(np.zeros((2, 16), dtype=np.float32))
    assert actions.shape == (2, 3) and np.all(np.abs(actions) <= 0.05)


def test_train_sac_never_probes_for_pandas(monkeypatch: pytest.MonkeyPatch) -> None:
    from sim2real.agents import train

    probes: list[str] = []
    real = importlib.util.find_spec

    def spy(name: str, *args: object, **kwargs: object) -> object:
        if name == "pandas":
            probes.append(name)
        return real(name, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(importlib.util, "find_spec", spy)
    train(ARM, TINY_SAC, seed=0, progress=False, logger=None)
    assert probes == []


def test_train_sac_refuses_an_unbounded_action_space() -> None:
    import gymnasium as gym

    from sim2real.agents import train

    class Unbounded(gym.Env):
        observation_space = gym.spaces.Box(-1, 1, (3,))
        action_space = gym.spaces.Box(-np.inf, np.inf, (2,))

    with pytest.raises(TypeError, match=r"^the env's action space must be a bounded Box\. Received Box\("):
        train(Unbounded(), TINY_SAC, progress=False, logger=None)


def test_the_checkpointed_policy_acts_with_the_mean_the_update_trains() -> None:
    """as_policy (the deterministic TorchRL TanhNormal) gives mid + half * tanh(loc): the noise-free action of
    the squashed Gaussian SACUpdate samples from."""
    from sim2real.agents.sac import _actor_parts

    torch.manual_seed(0)
    actor = build_actor("sac", 5, [-0.05, 0.0, -2.0], [0.05, 1.0, 3.0], (16,), "relu")
    norm, mlp, extractor = _actor_parts(actor)
    obs = torch.randn(9, 5) * 2
    with torch.no_grad():
        loc, _ = extractor(mlp(norm(obs)))
    low, high = torch.tensor([-0.05, 0.0, -2.0]), torch.tensor([0.05, 1.0, 3.0])
    expected = (high + low) / 2 + (high - low) / 2 * torch.tanh(loc)
    np.testing.assert_allclose(as_policy(actor)(obs.numpy()), expected.numpy(), rtol=1e-6, atol=1e-6)
