"""Distributions: values, supports, immutability, reproducibility; keyed streams."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from randomizers import Choice, Constant, LogUniform, Normal, StreamFactory, TruncatedNormal, Uniform, stream
from randomizers.distributions import distribution_from_config

N = 200_000


def test_moments_match_within_tolerance() -> None:
    rng = np.random.default_rng(0)
    u = Uniform(0.5, 1.5).sample(rng, N)
    assert abs(u.mean() - 1.0) < 0.005 and abs(u.var() - 1 / 12) < 0.002
    n = Normal(2.0, 0.5).sample(rng, N)
    assert abs(n.mean() - 2.0) < 0.005 and abs(n.std() - 0.5) < 0.005
    lu = LogUniform(0.1, 10.0).sample(rng, N)
    assert abs(np.log(lu).mean()) < 0.02 and lu.min() >= 0.1 and lu.max() < 10.0
    c = Choice((1.0, 2.0, 3.0), p=(0.2, 0.3, 0.5)).sample(rng, N)
    np.testing.assert_allclose([np.mean(c == v) for v in (1.0, 2.0, 3.0)], [0.2, 0.3, 0.5], atol=0.005)
    assert Constant(3.0).sample(rng) == 3.0


def test_truncated_normal_matches_scipy() -> None:
    from scipy import stats

    d = TruncatedNormal(1.0, 0.5, low=0.5, high=2.0)
    x = d.sample(np.random.default_rng(1), N)
    ref = stats.truncnorm((0.5 - 1.0) / 0.5, (2.0 - 1.0) / 0.5, loc=1.0, scale=0.5)
    assert abs(x.mean() - ref.mean()) < 0.005 and abs(x.std() - ref.std()) < 0.005
    assert stats.kstest(x[:5000], ref.cdf).pvalue > 0.01


@given(st.floats(-100, 100), st.floats(0, 100), st.integers(0, 2**32 - 1))
def test_uniform_draws_stay_in_support_and_repeat(low: float, width: float, seed: int) -> None:
    d = Uniform(low, low + width)
    a = d.sample(np.random.default_rng(seed), 8)
    b = d.sample(np.random.default_rng(seed), 8)
    assert a.tobytes() == b.tobytes()
    lo, hi = d.support
    assert ((a >= lo) & (a <= hi)).all()


def test_equality_repr_and_config_round_trip() -> None:
    for d in (
        Constant(1.0),
        Uniform(0, 1),
        LogUniform(0.1, 1),
        Normal(0, 1),
        TruncatedNormal(0, 1, -1, 1),
        Choice((1, 2)),
    ):
        assert d == eval(repr(d))
        assert distribution_from_config(d.to_config()) == d


def test_streams_are_keyed_not_positional() -> None:
    factory = StreamFactory(seed=9)
    gen = factory.generator("A")
    factory.start(gen, "A", episode=2)
    first = gen.uniform(size=4)
    factory.start(gen, "A", episode=2)
    assert gen.uniform(size=4).tobytes() == first.tobytes()
    assert stream(9, "A", 2).uniform(size=4).tobytes() == first.tobytes()
    assert stream(9, "B", 2).uniform(size=4).tobytes() != first.tobytes()
    assert stream(9, "A", 3).uniform(size=4).tobytes() != first.tobytes()
    assert stream(9, "A", 2, resample=1).uniform(size=4).tobytes() != first.tobytes()


def test_global_numpy_random_is_untouched() -> None:
    import sim2real as s2r

    np.random.seed(1234)
    expected = np.random.random_sample(3)
    np.random.seed(1234)
    env = s2r.wrap(s2r.make("sim2real/arm-reach"), s2r.Mass(scale=s2r.Uniform(0.5, 1.5)), seed=0)
    env.reset(seed=0)
    env.step(np.zeros(3, np.float32))
    assert np.random.random_sample(3).tobytes() == expected.tobytes()


@pytest.mark.parametrize("bad", [Uniform(0, 1), 1.5, None])
def test_choice_rejects_non_sequences(bad: object) -> None:
    with pytest.raises(ValueError, match="`values` of Choice must be a non-empty sequence of numbers"):
        Choice(bad)  # type: ignore[arg-type]
