"""The corruptor's public view for the batched engine (issue 15): NoiseBlock, next_noise_block, observation_lag."""

from __future__ import annotations

import numpy as np
import pytest

from noise_models import (
    ActionNoise,
    Bias,
    Gaussian,
    ObservationLatency,
    ObservationNoise,
    Quantize,
    Scale,
    SignalCorruptor,
)
from noise_models.processes import BLOCK
from noise_models.values import Layout


def _corruptor(*models: object, low: float | None = None) -> SignalCorruptor:
    c = SignalCorruptor(models, seed=4)  # type: ignore[arg-type]
    layout = Layout(3) if low is None else Layout(3, low=np.full(3, low), high=np.full(3, -low))
    c.bind(obs=layout, action=Layout(2, low=-np.ones(2), high=np.ones(2)), timestep=0.01, substeps=1)
    c.begin_episode()
    return c


def test_blocks_reproduce_the_pipelines_steps_bitwise() -> None:
    models = (ObservationNoise(Gaussian(std=0.1), Bias(0.5), Scale(1.1)), ActionNoise(Gaussian(std=0.3)))
    ours, twin = _corruptor(*models, low=-0.4), _corruptor(*models, low=-0.4)
    reset = np.array([0.1, -0.2, 0.3])
    first = twin.first_observation(reset)  # the reset sample takes the observation pipeline's first row
    ours.first_observation(reset)
    (obs_block,) = ours.noise_blocks("observation")
    (act_block,) = ours.noise_blocks("action")
    assert obs_block.row == 1 and act_block.row == BLOCK  # no action drawn yet: its block is still to draw
    assert np.array_equal(first, np.clip(reset * obs_block.gain + obs_block.offsets[0], -0.4, 0.4))
    rng = np.random.default_rng(0)
    clipped = 0
    obs_row, act_row = obs_block.row, act_block.row
    for t in range(BLOCK + 5):  # through refills: each block from the pipeline's own stream
        x = rng.uniform(-0.6, 0.6, 3)
        a = rng.uniform(-1.5, 1.5, 2).astype(np.float32)
        if obs_row == BLOCK:
            obs_block, obs_row = ours.next_noise_block("observation", 0), 0
        if act_row == BLOCK:
            act_block, act_row = ours.next_noise_block("action", 0), 0
        assert obs_block.gain is not None and act_block.gain is None
        w = x * obs_block.gain + obs_block.offsets[obs_row]
        obs_block.clip(x, w)
        v = a + act_block.offsets[act_row]
        act_block.clip(a, v)
        obs_row, act_row = obs_row + 1, act_row + 1
        clipped += int((np.abs(v) == 1.0).sum())
        assert np.array_equal(twin.act(a), v), t
        assert np.array_equal(twin.observe(x, now=t + 1), w), t
    assert clipped > 0  # the action bounds were exercised


def test_observation_lag_is_the_episodes_fixed_lag() -> None:
    assert _corruptor(ObservationLatency(steps=2)).observation_lag == 2
    assert SignalCorruptor([ObservationLatency(steps=2)], seed=0).observation_lag is None  # before any episode


def test_a_pipeline_that_is_not_affine_and_a_bad_side_are_refused() -> None:
    c = _corruptor(ObservationNoise(Gaussian(std=0.1), Quantize(0.01)))
    with pytest.raises(ValueError, match="is not one affine stage"):
        c.noise_blocks("observation")
    with pytest.raises(ValueError, match=r"`side` must be one of \['observation', 'action'\]. Received 'obs'."):
        c.noise_blocks("obs")
    assert c.pipeline_sizes("observation") == (3,) and c.pipeline_sizes("action") == ()
    assert c.observation_lag is None
