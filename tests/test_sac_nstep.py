"""n-step returns and the entropy target of SAC (sim2real.agents.sac.NStepWriter, SACConfig.n_step and
SACConfig.target_entropy), each against a computation written out from its definition."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sim2real.agents import SACConfig
from sim2real.agents.nets import actor_normalizer, build_actor, build_qvalue
from sim2real.agents.sac import NStepWriter, ReplayBuffer, SACUpdate

ARM = "sim2real/arm-reach"


def _textbook_nstep(rewards: list[float], ends: list[str], n: int, gamma: float) -> list[tuple[float, int, int, bool]]:
    """For every step t: (R_t = sum_{k<m} gamma^k r_{t+k}, index of the bootstrap observation t+m, m, terminated),
    with m = min(n, steps left in t's episode); ``ends[t]`` is "" / "terminated" / "truncated"."""
    out = []
    for t in range(len(rewards)):
        end = next(i for i in range(t, len(rewards)) if ends[i])
        m = min(n, end - t + 1)
        ret = sum(gamma**k * rewards[t + k] for k in range(m))
        out.append((ret, t + m, m, ends[end] == "terminated" and t + m == end + 1))
    return out


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_nstep_writer_matches_the_definition(n: int) -> None:
    rng = np.random.default_rng(n)
    rewards = rng.normal(size=17).tolist()
    # three episodes: 6 steps ending in a terminal state, 2 steps truncated, 9 steps terminated
    ends = ["" for _ in range(17)]
    ends[5], ends[7], ends[16] = "terminated", "truncated", "terminated"
    gamma = 0.9
    buffer = ReplayBuffer(64, 1, 1, seed=0)
    writer = NStepWriter(buffer, n=n, gamma=gamma)
    obs = np.zeros(1, dtype=np.float32)
    for t, (r, end) in enumerate(zip(rewards, ends, strict=True)):
        # observation t carries its index; the env hands out the same array every step (some wrappers do)
        nxt = np.full(1, t + 1, dtype=np.float32)
        writer.add(obs, np.full(1, -t, dtype=np.float32), r, nxt, end == "terminated", end == "truncated")
        obs[:] = t + 1
    expected = _textbook_nstep(rewards, ends, n, gamma)
    assert len(buffer) == 17
    order = np.argsort(buffer.obs[:17, 0].numpy())  # written in the order steps complete, not taken
    assert buffer.obs[:17, 0][order].tolist() == list(range(17))
    np.testing.assert_allclose(buffer.reward[:17][order].numpy(), [e[0] for e in expected], rtol=1e-6)
    assert buffer.next_obs[:17, 0][order].tolist() == [e[1] for e in expected]
    assert buffer.steps[:17][order].tolist() == [e[2] for e in expected]
    assert buffer.terminated[:17][order].tolist() == [float(e[3]) for e in expected]
    assert buffer.action[:17, 0][order].tolist() == [-t for t in range(17)]


def test_nstep_writer_rejects_a_bad_n() -> None:
    with pytest.raises(ValueError, match=r"^`n` must be a positive int\. Received 0\.$"):
        NStepWriter(ReplayBuffer(4, 1, 1, seed=0), n=0, gamma=0.9)


def _update(gamma: float, target_entropy: float | None = None) -> SACUpdate:
    torch.manual_seed(0)
    actor = build_actor("sac", 4, [-1.0, -1.0], [1.0, 1.0], (16,), "relu")
    norm = actor_normalizer(actor)
    qvalues = [build_qvalue(4, 2, (16,), "relu", norm) for _ in range(2)]
    return SACUpdate(actor, qvalues, lr=1e-3, gamma=gamma, tau=0.1, alpha_init=0.5, target_entropy=target_entropy)


def _batch(n: int = 32) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(3)
    return (torch.randn(n, 4, generator=g), torch.rand(n, 2, generator=g) * 2 - 1, torch.randn(n, generator=g),
            torch.randn(n, 4, generator=g), (torch.rand(n, generator=g) < 0.2).float())  # fmt: skip


def test_sac_update_discounts_an_m_step_transition_by_gamma_to_the_m() -> None:
    """steps = 2 with gamma 0.9 is the update of gamma 0.81; steps = 1 is the one-step update, bitwise."""
    batch = _batch()
    runs = []
    for gamma, steps in ((0.9, torch.full((32,), 2.0)), (0.81, None), (0.9, torch.ones(32)), (0.9, None)):
        update = _update(gamma)
        torch.manual_seed(5)
        obs, act, rew, nxt, term = batch
        losses = update.step(obs, act, rew, nxt, term, steps)
        runs.append((losses, [p.detach().clone() for p in update._sources]))
    torch.testing.assert_close(runs[0][0], runs[1][0], rtol=1e-6, atol=1e-7)
    assert torch.equal(runs[2][0], runs[3][0])
    assert all(torch.equal(a, b) for a, b in zip(runs[2][1], runs[3][1], strict=True))
    assert not torch.allclose(runs[0][0], runs[3][0])


def test_target_entropy_sets_the_temperature_gradient() -> None:
    """d loss_alpha / d log_alpha = -(mean log pi + target_entropy): raising the target by 1 lowers it by 1."""
    grads = []
    for target in (None, -1.0):
        update = _update(0.9, target)
        torch.manual_seed(5)
        update.step(*_batch())
        assert update.log_alpha.grad is not None
        grads.append(float(update.log_alpha.grad))
    assert update.target_entropy == -1.0 and _update(0.9).target_entropy == -2.0
    assert grads[0] - grads[1] == pytest.approx(1.0, abs=1e-5)


def test_sac_config_n_step_and_target_entropy() -> None:
    cfg = SACConfig(n_step=3, target_entropy=-1.5)
    assert SACConfig.from_yaml(cfg.to_yaml()) == cfg
    assert "n_step: 3" in cfg.to_yaml() and "target_entropy: -1.5" in cfg.to_yaml()
    # at their defaults they stay out of the stored form, so older checkpoints' configs are unchanged
    assert "n_step" not in SACConfig().to_dict() and "target_entropy" not in SACConfig().to_dict()
    with pytest.raises(ValueError, match=r"^`n_step` must be a positive int\. Received 0\.$"):
        SACConfig(n_step=0)
    with pytest.raises(ValueError, match=r"^`target_entropy` must be None or a finite number\. Received 'high'\.$"):
        SACConfig(target_entropy="high")  # type: ignore[arg-type]


def test_train_sac_with_n_step_returns_is_deterministic() -> None:
    from sim2real.agents import train

    cfg = SACConfig(frames=400, frames_per_batch=100, init_random_frames=200, batch_size=32, hidden_sizes=(16,),
                    obs_norm_frames=100, n_step=3, target_entropy=-1.0)  # fmt: skip
    first = train(ARM, cfg, seed=1, progress=False, logger=None)
    second = train(ARM, cfg, seed=1, progress=False, logger=None)
    a, b = first.policy.state_dict(), second.policy.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a) and first.metrics == second.metrics
    one_step = train(ARM, SACConfig.from_dict({**cfg.to_dict(), "n_step": 1}), seed=1, progress=False, logger=None)
    assert first.metrics["loss_qvalue"] != one_step.metrics["loss_qvalue"]
