"""The batched engine's lockstep paths (issue 15): worlds reset together and stepped unmasked read their noise row,
observation-latency slot and command slot as views shared by all worlds, refill their noise blocks in one pass,
and drop back to per-world gathers after a partial reset or a masked step. Every path must stay bitwise each
world's single env, on effect mixes the benchmark stack does not use (gains, drift, outliers, uniform noise,
per-world drawn lags, a fixed mid-step action latency) and past block refills."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import sim2real as s2r
from noise_models import ActionNoise, Gaussian, ObservationNoise, SignalCorruptor
from noise_models.processes import BLOCK
from noise_models.values import Layout
from sim2real.batched import make_batched
from tests.conftest import reset_and_compare


def _singles(task: str, effects: list[Any], seed: int, num: int, **options: Any) -> list[Any]:
    return [s2r.wrap(s2r.make(task, **options), *effects, seed=(seed, i)) for i in range(num)]


def _step_both(batched: Any, singles: list[Any], actions: np.ndarray, mask: np.ndarray | None = None) -> None:
    obs, reward, terminated, truncated, _ = batched.step(actions, mask=mask)
    for i, env in enumerate(singles):
        if mask is not None and not mask[i]:
            continue
        o, r, te, tr, _ = env.step(actions[i])
        assert np.array_equal(o, obs[i]), i
        assert r == reward[i] and (te, tr) == (terminated[i], truncated[i]), i


def _lined_up(batched: Any) -> bool:
    signals = batched._signals
    pipes = [*signals._obs, *signals._act]
    return all(p.common is not None for p in pipes) and signals._kc is not None


@pytest.mark.parametrize("drawn", [False, True])
def test_noise_and_observation_latency_stay_bitwise_through_lockstep_and_per_world_paths(drawn: bool) -> None:
    # Gains (not the add-only case), drift and outliers in the observation pipeline, uniform noise with a gain and
    # the actuator clip on the actions, an observation lag fixed (one slot for all worlds) or drawn per world
    # (lockstep counts, per-world lags).
    effects = [
        s2r.ObservationNoise(
            s2r.Gaussian(std=0.02),
            s2r.Scale(gain=s2r.Uniform(0.9, 1.1)),
            s2r.Drift(std=0.001),
            s2r.Outlier(probability=0.05, magnitude=0.5),
        ),
        s2r.ActionNoise(s2r.UniformNoise(half_width=0.3), s2r.Scale(gain=1.5)),
        s2r.ObservationLatency(steps=s2r.Choice([0, 1, 3]) if drawn else 2),
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
    ]
    num, seed = 4, 7
    batched = make_batched("dmc/reacher-easy", num, *effects, seed=seed)
    singles = _singles("dmc/reacher-easy", effects, seed, num)
    rng = np.random.default_rng(3)

    def actions() -> np.ndarray:
        return rng.uniform(-1.2, 1.2, (num, 2)).astype(np.float32)  # beyond the bounds: the clip acts

    try:
        _, params = reset_and_compare(batched, singles, [10, 11, 12, 13])
        lags = set(params["obs_latency_steps"].tolist())
        for _ in range(BLOCK + 20):  # lockstep through every world's block refill at row 256
            _step_both(batched, singles, actions())
        assert _lined_up(batched)
        assert not batched._signals._obs[0].all_unit  # the gain path
        # A partial reset: per-world rows and counts from here (the reset world's block starts over).
        reset_and_compare_some(batched, singles, [2])
        for _ in range(30):
            _step_both(batched, singles, actions())
        assert not _lined_up(batched)
        for t in range(40):  # masked steps: only the stepped worlds' noise and rings advance
            _step_both(batched, singles, actions(), mask=np.arange(num) % 2 == t % 2)
        # All worlds reset together: in lockstep again, through another refill.
        _, params = reset_and_compare(batched, singles, None)
        lags |= set(params["obs_latency_steps"].tolist())
        for _ in range(BLOCK + 5):
            _step_both(batched, singles, actions())
        assert _lined_up(batched)
        assert (batched._signals._lagc is None) == drawn
        assert len(lags) == (3 if drawn else 1)  # drawn: different lags in play in the lockstep path
    finally:
        batched.close()
        for env in singles:
            env.close()


def reset_and_compare_some(batched: Any, singles: list[Any], indices: list[int]) -> None:
    obs, params = batched.reset(indices=indices)
    for i in indices:
        o, info = singles[i].reset()
        assert np.array_equal(o, obs[i])
        for key, value in info["sim2real"]["params"].items():
            assert params[key][i] == value, key


@pytest.mark.parametrize("steps", [3, 13])
def test_a_fixed_mid_step_action_latency_shares_one_split_call_pair_in_lockstep(steps: int) -> None:
    # Manipulator: 10 physics steps per control step, so 3 and 13 physics steps arrive mid step (13: one whole
    # control step of lag first, during which the reset command holds). Every world drew the same latency: one
    # command slot per step.
    effects = [
        s2r.ActionLatency(steps=steps),
        s2r.ActionNoise(Gaussian(std=0.1)),
        s2r.Mass(scale=s2r.Uniform(0.8, 1.2)),
    ]
    num, seed = 3, 2
    options = {"time_limit": 0.2}
    batched = make_batched("dmc/manipulator-bring_ball", num, *effects, seed=seed, **options)
    singles = _singles("dmc/manipulator-bring_ball", effects, seed, num, **options)
    rng = np.random.default_rng(steps)
    try:
        for episode in range(2):
            reset_and_compare(batched, singles, [5, 6, 7] if episode == 0 else None)
            for t in range(20):
                mask = np.array([True, t % 3 != 1, True]) if episode == 1 and 8 <= t < 12 else None
                _step_both(batched, singles, rng.uniform(-1, 1, (num, batched.action_dim)), mask=mask)
                if t == 5:
                    assert batched._n_sub == 10 and batched._signals.command_common == divmod(steps, 10)
                if episode == 1 and t == 11:
                    assert batched._signals.command_common is None  # the masked steps broke the lockstep
    finally:
        batched.close()
        for env in singles:
            env.close()


def test_next_noise_block_hands_the_block_over_and_the_pipeline_draws_the_one_after() -> None:
    # The batched engine steps a block it took with next_noise_block itself; the corruptor's own next step must draw
    # the block after it (its stream's next), never reuse the rows the engine consumed.
    def corruptor() -> SignalCorruptor:
        c = SignalCorruptor([ObservationNoise(Gaussian(std=0.1)), ActionNoise(Gaussian(std=0.2))], seed=9)
        c.bind(obs=Layout(3), action=Layout(2, low=-np.ones(2), high=np.ones(2)), timestep=0.01, substeps=1)
        c.begin_episode()
        return c

    ours, twin = corruptor(), corruptor()
    zero = np.zeros(2, np.float32)
    first = ours.next_noise_block("action", 0)
    assert first.row == 0 and first.offsets.shape == (BLOCK, 2)
    expected = []
    for _ in range(2 * BLOCK):
        expected.append(twin.act(zero))
    assert np.array_equal(np.stack(expected[:BLOCK]), np.clip(first.offsets, -1, 1))
    # The next step of `ours` draws block 1, as the twin did at its step BLOCK.
    assert np.array_equal(ours.act(zero), expected[BLOCK])
    second = ours.next_noise_block("action", 0)  # then block 2, the block after the one its own step drew
    twin_rows = [twin.act(zero) for _ in range(BLOCK)]
    assert np.array_equal(np.stack(twin_rows), np.clip(second.offsets, -1, 1))


def test_next_noise_blocks_composes_many_corruptors_bitwise_their_own_blocks() -> None:
    # Gains and offsets per episode (scalars and per-entry arrays), a non-contiguous selection, drift and uniform
    # noise: the blocks composed at once equal each corruptor's next_noise_block, block after block.
    from noise_models import Bias, Drift, Scale, UniformNoise
    from randomizers import Uniform

    models = [
        ObservationNoise(
            Gaussian(std=Uniform(0.01, 0.1)),
            Scale(gain=Uniform(0.8, 1.2), select=[0, 2, 3]),
            Bias(Uniform(-0.1, 0.1)),
            Drift(std=0.01, select=[1, 4]),
            UniformNoise(half_width=0.05),
        )
    ]

    def corruptor(i: int) -> SignalCorruptor:
        c = SignalCorruptor(models, seed=(3, i))
        c.bind(obs=Layout(5), action=None, timestep=0.01, substeps=1)
        c.begin_episode()
        return c

    ours = [corruptor(i) for i in range(4)]
    twins = [corruptor(i) for i in range(4)]
    for _ in range(3):
        offsets, gains, unit = SignalCorruptor.next_noise_blocks(ours, "observation", 0)
        for i, twin in enumerate(twins):
            block = twin.next_noise_block("observation", 0)
            assert offsets.dtype == block.offsets.dtype and np.array_equal(offsets[i], block.offsets)
            assert block.gain is not None and not unit[i] and np.array_equal(gains[i], block.gain)
    assert len({float(g[0]) for g in gains}) == 4  # each corruptor its own episode draws


def test_next_noise_blocks_keep_the_sign_of_zero_noise_bitwise() -> None:
    # std 0: every draw times 0.0 is 0.0 or -0.0. A pipeline's own refill adds the draws to zeros (0.0 + -0.0 is
    # 0.0); the composition that draws straight into its array must give the same bits, or a -0.0 action would stay
    # -0.0 where the single env's is 0.0.
    def corruptor(i: int) -> SignalCorruptor:
        c = SignalCorruptor([ActionNoise(Gaussian(std=0.0))], seed=(5, i))
        c.bind(obs=Layout(3), action=Layout(2, low=-np.ones(2), high=np.ones(2)), timestep=0.01, substeps=1)
        c.begin_episode()
        return c

    ours = [corruptor(i) for i in range(3)]
    twins = [corruptor(i) for i in range(3)]
    offsets, _, _ = SignalCorruptor.next_noise_blocks(ours, "action", 0)
    for i, twin in enumerate(twins):
        block = twin.next_noise_block("action", 0)
        assert np.array_equal(offsets[i].view(np.uint32), block.offsets.view(np.uint32))
    assert not np.signbit(offsets).any()


@pytest.mark.parametrize("head", ["gaussian", "uniform"])
def test_next_noise_blocks_of_additive_pipelines_are_bitwise_their_own_blocks_across_chunks(head: str) -> None:
    # Pipelines without a gain are composed a few at a time with the + 0.0 moved after the sums: 13 pipelines of 5
    # entries are three chunks here, written into a transposed (BLOCK, P, size) buffer as the engine's. A first
    # process that draws every entry (Gaussian: drawn straight into the scratch) or not (UniformNoise), per-world
    # drawn scales and biases, a selection, and the sign of zero noise (std 0 plus a bias of -0.0: 0.0 either way).
    from noise_models import Bias, Drift, UniformNoise
    from noise_models.fused import _CHUNK_BYTES
    from randomizers import Uniform

    first = Gaussian(std=Uniform(0.01, 0.1)) if head == "gaussian" else UniformNoise(half_width=Uniform(0.01, 0.1))
    cases = [
        [
            ObservationNoise(
                first, Bias(Uniform(-0.1, 0.1)), Drift(std=0.01, select=[1, 4]), Gaussian(std=0.02, name="noise2")
            )
        ],
        [ObservationNoise(Gaussian(std=0.0) if head == "gaussian" else UniformNoise(half_width=0.0), Bias(-0.0))],
    ]
    num, size = 13, 5
    assert _CHUNK_BYTES // (BLOCK * size * 8) < num  # more than one chunk
    for models in cases:

        def corruptor(i: int, models: list[Any] = models) -> SignalCorruptor:
            c = SignalCorruptor(models, seed=(7, i))
            c.bind(obs=Layout(size), action=None, timestep=0.01, substeps=1, obs_dtype=np.float32)
            c.begin_episode()
            return c

        ours = [corruptor(i) for i in range(num)]
        twins = [corruptor(i) for i in range(num)]
        store = np.full((BLOCK, num, size), np.nan, np.float32)
        out = (store.transpose(1, 0, 2), np.zeros((num, size), np.float32), np.zeros(num, bool))
        for _ in range(2):
            offsets, gains, unit = SignalCorruptor.next_noise_blocks(ours, "observation", 0, out)
            assert offsets.base is store or offsets.base is store.base
            for i, twin in enumerate(twins):
                block = twin.next_noise_block("observation", 0)
                assert np.array_equal(offsets[i].view(np.uint32), block.offsets.view(np.uint32)), i
                assert block.gain is None and unit[i] and (gains[i] == 1.0).all()
        if models is cases[1]:
            assert not np.signbit(store).any() and not store.any()


@pytest.mark.parametrize("size", [2, 6])
@pytest.mark.parametrize("std", ["constant", "drawn", "zero"])
def test_next_noise_blocks_of_gaussian_heads_are_bitwise_their_own_blocks(size: int, std: str) -> None:
    # The usual noise (Gaussian of a keyed stream, then a Bias) is drawn by one generator set to each world's key and
    # counter in turn, scaled and biased in one pass a world (constant, drawn and zero std: the sign of zero noise
    # must survive); rows of two float32 (size 2) are cast into a chunk and moved as int64. 30 worlds: more than one
    # chunk either way; compared with each world's own single-pipeline block, bitwise.
    from noise_models import Bias
    from noise_models.fused import _CHUNK_BYTES
    from randomizers import Uniform

    value: Any = {"constant": 0.05, "drawn": Uniform(0.01, 0.1), "zero": 0.0}[std]
    models = [ObservationNoise(Gaussian(std=value), Bias(Uniform(-0.1, 0.1) if std != "zero" else -0.0))]
    num = 30
    assert _CHUNK_BYTES // (BLOCK * size * 8) < num

    def corruptor(i: int) -> SignalCorruptor:
        c = SignalCorruptor(models, seed=(3, i))
        c.bind(obs=Layout(size), action=None, timestep=0.01, substeps=1, obs_dtype=np.float32)
        c.begin_episode()
        return c

    ours = [corruptor(i) for i in range(num)]
    twins = [corruptor(i) for i in range(num)]
    store = np.full((BLOCK, num, size), np.nan, np.float32)
    out = (store.transpose(1, 0, 2), np.zeros((num, size), np.float32), np.zeros(num, bool))
    for _ in range(3):
        offsets, _, _ = SignalCorruptor.next_noise_blocks(ours, "observation", 0, out)
        fresh, _, _ = SignalCorruptor.next_noise_blocks(twins[num // 2 :], "observation", 0)  # no `out`: allocated
        for i, twin in enumerate(twins[: num // 2]):
            block = twin.next_noise_block("observation", 0)
            assert np.array_equal(offsets[i].view(np.uint32), block.offsets.view(np.uint32)), i
        for i in range(num // 2, num):
            assert np.array_equal(offsets[i].view(np.uint32), fresh[i - num // 2].view(np.uint32)), i
    if std == "zero":
        assert not np.signbit(store).any() and not store.any()
    else:
        assert np.isfinite(store).all() and len(np.unique(store)) > BLOCK * num * size // 2
