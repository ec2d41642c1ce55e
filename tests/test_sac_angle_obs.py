"""SACConfig.angle_obs: the policy-side sine/cosine features of angle observations (issue #14, reacher-easy's
unbounded shoulder). The env is unchanged; the features live in the networks' normaliser and travel with the
checkpoint, while checkpoints trained without them load and act bitwise as before."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from sim2real.agents import SACConfig, as_policy, load_checkpoint, train
from sim2real.agents.nets import Normalize, actor_dims, actor_normalizer, build_actor, build_qvalue
from sim2real.agents.policy import _tanh_normal_fast_path

REACHER = "dmc/reacher-easy"
TINY = SACConfig(
    frames=200, frames_per_batch=100, init_random_frames=100, batch_size=32, hidden_sizes=(16,), obs_norm_frames=100,
    angle_obs=(0, 1),
)  # fmt: skip


def test_normalize_features_are_sin_cos_and_periodic() -> None:
    norm = Normalize(4, angles=(2, 0))
    norm.set_stats(torch.tensor([9.0, 1.0, 9.0, -1.0]), torch.tensor([9.0, 2.0, 9.0, 0.5]))
    x = torch.tensor([[0.3, 5.0, -2.0, 1.0]])
    out = norm(x)
    assert norm.out_dim == 6 and out.shape == (1, 6)
    # angle entries: sin in place (stats ignored), cos appended in the order of `angles`; the others normalised
    expected = [math.sin(0.3), 2.0, math.sin(-2.0), 4.0, math.cos(-2.0), math.cos(0.3)]
    assert out[0].tolist() == pytest.approx(expected, abs=1e-6)
    turned = x + torch.tensor([[2 * math.pi, 0.0, -4 * math.pi, 0.0]])
    assert torch.allclose(norm(turned), out, atol=1e-5)
    assert set(norm.state_dict()) == {"loc", "scale"}  # the same keys as a normaliser without angles


@pytest.mark.parametrize("angles", [(6,), (1, 1), (-1,)])
def test_bad_angle_index_names_the_argument(angles: tuple[int, ...]) -> None:
    with pytest.raises(ValueError) as err:
        build_actor("sac", 6, [-1.0, -1.0], [1.0, 1.0], (8,), "relu", angle_obs=angles)
    assert str(err.value) == (
        "`angle_obs` must hold distinct observation indices in [0, 6) (the observation has 6 entries). "
        f"Received {list(angles)}."
    )


def test_config_round_trip_and_old_form() -> None:
    cfg = SACConfig.from_yaml("algo: sac\nangle_obs: [0, 1]\n")
    assert cfg.angle_obs == (0, 1)
    assert cfg.to_dict()["angle_obs"] == [0, 1]
    assert SACConfig.from_yaml(cfg.to_yaml()) == cfg
    assert "angle_obs" not in SACConfig().to_dict()  # configs without it keep the form stored before it existed
    with pytest.raises(ValueError, match=r"`angle_obs` must be a tuple of distinct ints >= 0\. Received \(0, 0\)\."):
        SACConfig(angle_obs=(0, 0))
    with pytest.raises(ValueError, match=r"`angle_obs` must be a tuple of distinct ints >= 0\. Received 'x'\."):
        SACConfig(angle_obs="x")  # type: ignore[arg-type]


def test_networks_widen_but_report_the_observation_size() -> None:
    actor = build_actor("sac", 6, [-1.0, -1.0], [1.0, 1.0], (8,), "relu", angle_obs=(0, 1))
    first = next(m for m in actor.modules() if isinstance(m, torch.nn.Linear))
    assert first.in_features == 8
    assert actor_dims(actor) == (6, [-1.0, -1.0], [1.0, 1.0])
    q = build_qvalue(6, 2, (8,), "relu", actor_normalizer(actor))
    assert q.module(torch.zeros(3, 6), torch.zeros(3, 2)).shape == (3, 1)


def test_trained_checkpoint_round_trip_and_shoulder_turn(tmp_path) -> None:
    result = train(REACHER, TINY, seed=0, progress=False, logger=None)
    path = tmp_path / "angles.pt"
    result.save(path)
    ckpt = load_checkpoint(path, task=REACHER)
    assert ckpt.config.angle_obs == (0, 1)
    obs = np.random.default_rng(0).normal(size=(16, 6)).astype(np.float32)
    trained, loaded = as_policy(result.policy), as_policy(ckpt.policy)
    assert np.array_equal(trained(obs), loaded(obs))
    # the fast numpy path of as_policy still applies (it probes with the observation's width, not the MLP's)
    assert _tanh_normal_fast_path(ckpt.policy, "observation", "action", torch.float32) is not None
    turned = obs.copy()
    turned[:, 0] += 2 * np.pi  # the shoulder one turn further: the same arm, the same action
    np.testing.assert_allclose(loaded(turned), loaded(obs), atol=1e-4)
    # without the features the same network does not see the turn as the same state
    torch.manual_seed(0)
    plain = build_actor("sac", 6, [-1.0, -1.0], [1.0, 1.0], (16,), "relu")
    assert not np.allclose(as_policy(plain)(turned), as_policy(plain)(obs), atol=1e-4)
    assert "angle_obs" not in dataclasses.replace(TINY, angle_obs=()).to_dict()
