"""sim2real.metrics: hand-computed values, known distributions, interval coverage, reproducibility, warnings, errors."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy import stats

from sim2real import metrics as m
from sim2real.metrics import Estimate, FewSamplesWarning

# --------------------------------------------------------------------------------------------------------------------
# Hand-computed values


def test_mean_hand_computed():
    returns = [[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [6.0, 60.0]] * 3  # 12 runs
    a, b = m.mean(returns, rng=0)
    assert a.value == pytest.approx(3.0) and b.value == pytest.approx(30.0)
    assert a.n == 12 and a.confidence == 0.95 and a.method == "percentile bootstrap"
    assert 1.0 <= a.low < 3.0 < a.high <= 6.0


def test_iqm_hand_computed_and_matches_rliable_trim_mean():
    # 8 runs: floor(8 / 4) = 2 cut from each end -> mean(3, 4, 5, 6) = 4.5, the outlier 100 is ignored
    column = [7.0, 1.0, 100.0, 3.0, 5.0, 2.0, 6.0, 4.0]
    with pytest.warns(FewSamplesWarning):
        (est,) = m.iqm(np.array(column)[:, None], rng=0)
    assert est.value == pytest.approx(4.5)
    data = np.random.default_rng(3).gamma(2.0, size=(37, 4))
    values = [e.value for e in m.iqm(data, rng=0)]
    np.testing.assert_allclose(values, stats.trim_mean(data, 0.25, axis=0), rtol=1e-12)


# Matrices of returns as users have them: any run count (most not divisible by 4), ties, mixed magnitudes and signs.
_RETURNS = hnp.arrays(
    np.float64,
    st.tuples(st.integers(1, 41), st.integers(1, 5)),
    elements=st.one_of(
        st.floats(-1e3, 1e3, allow_nan=False, width=64),
        st.sampled_from([0.0, 1.0, -2.5, 0.1, 1e-9]),  # repeated values
        st.floats(-1e9, 1e9, allow_nan=False, width=64),
    ),
)


@pytest.mark.parametrize("layout", [np.ascontiguousarray, np.asfortranarray])
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(returns=_RETURNS)
def test_iqm_point_is_bitwise_rliable_trim_mean(returns: np.ndarray, layout):
    returns = layout(returns)  # numpy's sums depend on the memory layout; the same data is the same array
    expected = stats.trim_mean(returns, 0.25, axis=0)  # what rliable's IQM computes
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FewSamplesWarning)
        estimates = m.iqm(returns, rng=0, num_resamples=20)
        (pooled,) = (m.aggregate(returns, statistic="iqm", rng=0, num_resamples=20),)
    assert np.array_equal(np.array([e.value for e in estimates]), expected)  # bitwise, not approximately
    assert np.array_equal(m.iqm_point(returns), expected)
    assert pooled.value == stats.trim_mean(returns, 0.25, axis=None)  # rliable's aggregate IQM
    for e in estimates:  # the interval is still the bootstrap's, around the same window of runs
        assert e.low <= e.high and e.method == "percentile bootstrap" and e.n == returns.shape[0]
        rounding = 1e-12 * np.abs(returns).max()
        assert returns.min() - rounding <= e.low and e.high <= returns.max() + rounding


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(hnp.arrays(np.float64, st.tuples(st.integers(2, 41), st.just(2)), elements=st.floats(-1e3, 1e3)))
def test_iqm_gaps_start_from_the_trim_mean_points(returns: np.ndarray):
    ref, tgt = stats.trim_mean(returns, 0.25, axis=0)  # = iqm(returns), so a gap is the difference of two IQMs
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FewSamplesWarning)
        paired = m.gap(returns, statistic="iqm", rng=0, num_resamples=20)
        unpaired = m.unpaired_gap(returns[:, 0], returns[1:, 1], statistic="iqm", rng=0, num_resamples=20)
    assert paired.absolute.value == ref - tgt
    # a vector of runs is one condition, shape (num_runs, 1), as everywhere in sim2real.metrics
    (alone,) = stats.trim_mean(returns[:, :1], 0.25, axis=0)
    assert unpaired.absolute.value == alone - stats.trim_mean(returns[1:, 1:], 0.25, axis=0)[0]


def test_iqm_point_errors():
    with pytest.raises(ValueError) as caught:
        m.iqm_point([1.0, 2.0])
    assert (
        str(caught.value) == "`returns` must be a 2-D array of shape (num_runs, num_conditions). Received shape (2,)."
    )
    with pytest.raises(ValueError) as caught:
        m.iqm_point([[1.0], [math.inf]])
    assert str(caught.value) == "`returns` must be finite. Received inf at run 1, column 0."


def test_cvar_hand_computed_fractional_tail():
    returns = np.array([4.0, 9.0, 1.0, 7.0, 3.0, 10.0, 2.0, 8.0, 6.0, 5.0])[:, None]  # 1..10, order irrelevant
    returns = np.column_stack([returns, returns * 2])
    a25, b25 = m.cvar(returns, alpha=0.25, rng=0)
    assert a25.value == pytest.approx((1 + 2 + 0.5 * 3) / 2.5)  # 1.8
    assert b25.value == pytest.approx(3.6)
    (a10, _) = m.cvar(returns, alpha=0.1, rng=0)
    (a05, _) = m.cvar(returns, alpha=0.05, rng=0)
    (a_half, _) = m.cvar(returns, alpha=0.5, rng=0)
    assert a10.value == pytest.approx(1.0)
    assert a05.value == pytest.approx(1.0)  # half a run of the worst one, divided by half a run
    assert a_half.value == pytest.approx(3.0)  # mean of 1..5


def test_cvar_default_alpha_on_a_known_distribution():
    # CVaR_0.1 of N(0, 1) (lower tail) is -pdf(q_0.1) / 0.1 = -1.7550
    data = np.random.default_rng(8).normal(size=(20000, 1))
    (est,) = m.cvar(data, rng=0, num_resamples=1000)
    truth = -stats.norm.pdf(stats.norm.ppf(0.1)) / 0.1
    assert est.low < truth < est.high
    assert est.value == pytest.approx(truth, abs=0.05)


def test_worst_case():
    np.testing.assert_array_equal(m.worst_case([[3.0, -1.0], [2.0, 5.0], [4.0, 0.0]]), [2.0, -1.0])


def test_aggregate_pools_all_conditions():
    data = np.random.default_rng(4).normal(size=(15, 3)) + np.array([0.0, 5.0, 10.0])
    est = m.aggregate(data, statistic="iqm", rng=0)
    assert est.value == pytest.approx(stats.trim_mean(data.ravel(), 0.25))
    assert est.n == 45
    assert m.aggregate(data, statistic="mean", rng=0).value == pytest.approx(data.mean())


def test_bootstrap_is_the_plain_resample_bootstrap():
    """The count-based machinery equals resampling runs explicitly with the same generator draws."""
    data = np.random.default_rng(9).exponential(size=(23, 2))
    est_mean = m.mean(data, rng=5, num_resamples=1000)
    est_iqm = m.iqm(data, rng=5, num_resamples=1000)
    est_cvar = m.cvar(data, alpha=0.2, rng=5, num_resamples=1000)
    gen = np.random.default_rng(5)
    for j in range(2):
        idx = gen.integers(0, 23, size=(1000, 23))
        res = np.sort(data[idx, j], axis=1)
        for est, boots in (
            (est_mean[j], res.mean(axis=1)),
            (est_iqm[j], stats.trim_mean(res, 0.25, axis=1)),
            # alpha * n = 4.6: four worst runs fully, the fifth with weight 0.6
            (est_cvar[j], (res[:, :4].sum(axis=1) + 0.6 * res[:, 4]) / 4.6),
        ):
            low, high = np.quantile(boots, [0.025, 0.975])
            assert est.low == pytest.approx(low, rel=1e-12)
            assert est.high == pytest.approx(high, rel=1e-12)


# --------------------------------------------------------------------------------------------------------------------
# Wilson


@pytest.mark.parametrize(
    ("k", "n", "low", "high"),
    # Newcombe (1998), Stat. Med. 17:857, Table I, method 3 (Wilson score, no continuity correction)
    [(81, 263, 0.2553, 0.3662), (15, 148, 0.0624, 0.1605), (0, 20, 0.0, 0.1611), (1, 29, 0.0061, 0.1718)],
)
def test_wilson_textbook_values(k, n, low, high):
    outcomes = np.zeros((n, 1), dtype=bool)
    outcomes[:k] = True
    (est,) = m.success_rate(outcomes)
    assert est.value == pytest.approx(k / n)
    assert (round(est.low, 4), round(est.high, 4)) == (low, high)
    assert est.method == "wilson" and est.n == n


def test_success_rate_from_returns_with_threshold():
    returns = [[5.0, 0.0], [1.0, 3.0], [3.0, 2.0], [2.0, 9.0]]
    a, b = m.success_rate(returns, threshold=3.0)
    assert (a.value, b.value) == (0.5, 0.5)
    (c,) = m.success_rate([[0.0], [1.0], [1.0], [1.0]], confidence=0.9)
    z = stats.norm.ppf(0.95)
    centre = (0.75 + z * z / 8) / (1 + z * z / 4)
    half = z / (1 + z * z / 4) * math.sqrt(0.75 * 0.25 / 4 + z * z / 64)
    assert (c.low, c.high) == pytest.approx((centre - half, centre + half))


@pytest.mark.parametrize(("n", "p"), [(50, 0.3), (100, 0.5), (200, 0.1)])
def test_wilson_exact_coverage(n, p):
    """Exact coverage under Binomial(n, p), summed over every possible outcome."""
    outcomes = (np.arange(n)[:, None] < np.arange(n + 1)[None, :]).astype(float)  # column k has k successes
    ests = m.success_rate(outcomes)
    covered = np.array([e.low <= p <= e.high for e in ests])
    coverage = stats.binom.pmf(np.arange(n + 1), n, p)[covered].sum()
    assert 0.93 <= coverage <= 0.97


# --------------------------------------------------------------------------------------------------------------------
# Gap, probability of improvement


def test_gap_hand_computed_and_pairing():
    ref = np.array([10.0, 12.0, 14.0, 16.0] * 3)
    target = ref - 4.0  # every paired run loses exactly 4
    returns = np.column_stack([ref, np.zeros_like(ref), target])
    paired = m.gap(returns, reference=0, target=2, paired=True, rng=0)
    assert paired.absolute.value == pytest.approx(4.0)
    assert paired.relative.value == pytest.approx(4.0 / 13.0)
    # paired resampling sees the constant difference: no uncertainty at all
    assert (paired.absolute.low, paired.absolute.high) == pytest.approx((4.0, 4.0))
    unpaired = m.gap(returns, reference=0, target=2, paired=False, rng=0)
    assert unpaired.absolute.value == pytest.approx(4.0)
    assert unpaired.absolute.low < 3.0 and unpaired.absolute.high > 5.0
    assert (paired.reference, paired.target, paired.paired, unpaired.paired) == (0, 2, True, False)
    assert paired.absolute.n == 24


def test_gap_iqm_and_zero_reference():
    returns = np.column_stack([np.r_[np.arange(1.0, 12.0), 1000.0], np.arange(12.0)])
    g = m.gap(returns, statistic="iqm", rng=0)
    # 12 runs: 3 cut from each end -> IQM(1..11, 1000) = mean(4..9) = 6.5, IQM(0..11) = mean(3..8) = 5.5
    assert g.absolute.value == pytest.approx(1.0)
    assert g.statistic == "iqm"
    zero = m.gap(np.column_stack([np.zeros(12), np.ones(12)]), rng=0)
    assert math.isnan(zero.relative.value) and zero.absolute.value == -1.0


def test_probability_of_improvement_hand_computed():
    with pytest.warns(FewSamplesWarning):
        assert m.probability_of_improvement([[2.0], [4.0]], [[1.0], [3.0]], rng=0).value == pytest.approx(0.75)
        # ties count a half: (0.5 + 0 + 1 + 0.5) / 4
        assert m.probability_of_improvement([[1.0], [2.0]], [[1.0], [2.0]], rng=0).value == pytest.approx(0.5)
        # averaged over conditions
        two = m.probability_of_improvement([[2.0, 0.0], [4.0, 0.0]], [[1.0, 1.0], [3.0, 1.0]], rng=0)
    assert two.value == pytest.approx((0.75 + 0.0) / 2)


def test_probability_of_improvement_matches_mann_whitney_and_known_distribution():
    rng = np.random.default_rng(21)
    x = np.round(rng.normal(1.0, 1.0, size=(30, 3)), 1)  # rounded: ties happen
    y = np.round(rng.normal(0.0, 1.0, size=(25, 3)), 1)
    expected = np.mean([stats.mannwhitneyu(x[:, j], y[:, j]).statistic / (30 * 25) for j in range(3)])
    assert m.probability_of_improvement(x, y, rng=0).value == pytest.approx(expected)
    # P(X > Y) for X ~ N(1, 1), Y ~ N(0, 1) is Phi(1 / sqrt(2)) = 0.760
    big_x = rng.normal(1.0, 1.0, size=(400, 1))
    big_y = rng.normal(0.0, 1.0, size=(400, 1))
    est = m.probability_of_improvement(big_x, big_y, rng=0, num_resamples=1000)
    truth = stats.norm.cdf(1 / math.sqrt(2))
    assert est.low < truth < est.high
    assert est.high - est.low < 0.1


# --------------------------------------------------------------------------------------------------------------------
# Robustness radius


def test_robustness_radius_one_sided():
    grid = [0.0, 0.1, 0.2, 0.3, 0.4]
    returns = np.tile([100.0, 98.0, 94.0, 86.0, 70.0], (12, 1))
    r = m.robustness_radius(grid, returns, rng=0)
    # threshold 90 crossed between 94 (0.2) and 86 (0.3): 0.2 + 4 / 8 * 0.1
    assert r.radius.value == pytest.approx(0.25)
    assert (r.radius.low, r.radius.high) == pytest.approx((0.25, 0.25))  # no run-to-run noise
    assert (r.censored, r.nominal, r.nominal_return, r.fraction) == (False, 0.0, 100.0, 0.9)
    on_grid = m.robustness_radius(grid, returns, interpolate=False, rng=0)
    assert on_grid.radius.value == pytest.approx(0.2)
    assert m.robustness_radius(grid, returns, fraction=0.5, rng=0).censored is True  # 70 >= 50 everywhere
    assert m.robustness_radius(grid, returns, fraction=0.5, rng=0).radius.value == pytest.approx(0.4)


def test_robustness_radius_two_sided_scale_grid():
    grid = [0.8, 0.9, 1.0, 1.1, 1.2]
    returns = np.tile([80.0, 95.0, 100.0, 96.0, 85.0], (12, 1))
    r = m.robustness_radius(grid, returns, nominal=1.0, rng=0)
    left = 0.1 + (95 - 90) / (95 - 80) * 0.1  # 0.1333
    right = 0.1 + (96 - 90) / (96 - 85) * 0.1  # 0.1545
    assert r.radius.value == pytest.approx(min(left, right))
    assert r.censored is False
    # the short side binds when nothing fails: censored at its extent
    r = m.robustness_radius([-0.1, 0.0, 0.1, 0.2, 0.3], np.full((12, 5), 50.0), rng=0)
    assert (r.radius.value, r.censored) == (pytest.approx(0.1), True)


def test_robustness_radius_interval_from_noise():
    rng = np.random.default_rng(2)
    grid = np.linspace(0.0, 1.0, 11)
    curve = 100.0 - 40.0 * grid**2  # 90 % of 100 is reached at sqrt(0.25) = 0.5
    returns = curve + rng.normal(0.0, 5.0, size=(60, 11))
    r = m.robustness_radius(grid, returns, rng=0, num_resamples=1000)
    assert r.radius.low < 0.5 < r.radius.high
    assert r.radius.high - r.radius.low < 0.4


# --------------------------------------------------------------------------------------------------------------------
# Sim vs real across policies


SIM = np.array([0.2, 0.5, 0.9, 0.7])
REAL = np.array([0.1, 0.4, 0.3, 0.6])


def test_mmrv_hand_example():
    # disagreements: (policy 2, policy 3) by |0.4 - 0.3| = 0.1 and (policy 3, policy 4) by |0.3 - 0.6| = 0.3;
    # per-policy maxima 0, 0.1, 0.3, 0.3 -> MMRV = 0.7 / 4
    est = m.mmrv(np.tile(SIM, (12, 1)), np.tile(REAL, (12, 1)), rng=0)
    assert est.value == pytest.approx(0.175)
    assert (est.low, est.high) == pytest.approx((0.175, 0.175))  # constant runs: nothing to resample
    assert m.mmrv(np.tile(SIM, (12, 1)), np.tile(SIM * 3, (12, 1)), rng=0).value == 0.0


def test_srcc_hand_example():
    sim, real = np.tile(SIM, (12, 1)), np.tile(REAL, (12, 1))
    # SRCC is Spearman: ranks (1, 2, 4, 3) vs (1, 3, 2, 4): sum d^2 = 6 -> 1 - 6 * 6 / (4 * 15) = 0.4
    assert m.srcc(sim, real, rng=0).value == pytest.approx(0.4)
    assert m.srcc(sim, real, rng=0).value == pytest.approx(stats.spearmanr(SIM, REAL).statistic)
    # Pearson is its own, named function: centred sim (-0.375, -0.075, 0.325, 0.125), real (-0.25, 0.05, -0.05, 0.25)
    assert m.pearson(sim, real, rng=0).value == pytest.approx(0.105 / math.sqrt(0.2675 * 0.13))
    assert m.pearson(sim, real, rng=0) == m.srcc(sim, real, method="pearson", rng=0)
    assert m.pearson(sim, real, rng=0).value == pytest.approx(stats.pearsonr(SIM, REAL).statistic)


def test_correlation_of_noisy_means_keeps_its_point_inside_the_interval():
    # The quick study's case: 4 policies far apart, 4 noisy episodes each. A resample adds a second helping of
    # sampling noise to every policy's mean, so the replicates of a near-1 correlation sit below the estimate and the
    # plain percentile interval missed it (0.9963 [-0.4158, 0.9836]); the interval is now bias-corrected.
    rng = np.random.default_rng(3)
    means = np.array([525.0, 680.0, 720.0, 815.0])
    sim = means + rng.normal(0.0, 120.0, (4, 4))
    real = means + rng.normal(0.0, 120.0, (4, 4))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FewSamplesWarning)
        for est in (m.pearson(sim, real, rng=0), m.srcc(sim, real, rng=0), m.mmrv(sim, real, rng=0)):
            assert est.low <= est.value <= est.high
        plain = m.pearson(sim, real, rng=0)
    assert -1.0 <= plain.low <= plain.value <= plain.high <= 1.0


_SMALL = hnp.arrays(
    np.float64,
    st.tuples(st.integers(2, 12), st.integers(3, 4)),
    elements=st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, width=32),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sim=_SMALL, shift=st.floats(-50.0, 50.0), spread=st.floats(0.0, 3.0), seed=st.integers(0, 2**16))
def test_every_reported_statistic_contains_its_point_estimate(sim, shift, spread, seed):
    """The report's statistics: mean, IQM, CVaR, gaps (paired and not, absolute and relative), P(x > y), Spearman,
    Pearson, MMRV and the robustness radius; every finite estimate lies inside its interval."""
    noise = np.random.default_rng(seed).normal(0.0, 1.0 + spread * 100.0, sim.shape)
    real = sim - shift + noise
    found: list[Estimate] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FewSamplesWarning)
        options = dict(rng=seed, num_resamples=200)
        found += m.mean(sim, **options) + m.iqm(sim, **options) + m.cvar(sim, alpha=0.25, **options)
        gaps = [m.gap(np.column_stack([sim[:, 0], real[:, 0]]), paired=p, **options) for p in (True, False)]
        found += [e for g in gaps for e in (g.absolute, g.relative)]
        found.append(m.probability_of_improvement(sim[:, :1], real[:, :1], **options))
        for fn in (m.srcc, m.pearson):
            with contextlib.suppress(ValueError):  # every policy scores the same: undefined, and said so
                found.append(fn(sim, real, **options))
        found.append(m.mmrv(sim, real, **options))
        curve = np.sort(np.abs(sim) + 1.0, axis=1)[:, ::-1]  # returns falling away from the nominal (column 0)
        grid = np.arange(sim.shape[1], dtype=np.float64)
        found.append(m.robustness_radius(grid, curve, fraction=0.8, paired=True, **options).radius)
        found.append(
            m.robustness_radius(grid, curve, fraction=0.8, reference=np.abs(real[:, 0]) + 1.0, **options).radius
        )
    for e in found:
        if math.isfinite(e.value) and math.isfinite(e.low):
            assert e.low <= e.value <= e.high, e
        else:  # undefined (a relative gap from 0, or from a reference that is 0 in too many resamples)
            assert math.isnan(e.low) and math.isnan(e.high), e
            assert math.isnan(e.value) or any(e is g.relative for g in gaps), e


def test_relative_gap_from_a_mostly_zero_reference_has_no_interval():
    # 4 episodes, 3 of them 0 in sim: the relative gap of the resamples whose sim return is not 0 is always
    # 13 / 13 (a conditional, zero-width interval, like the quick study's 16.9% [16.9%, 16.9%])
    returns = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [13.0, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FewSamplesWarning)
        g = m.gap(returns, paired=True, rng=0)
    assert g.relative.value == 1.0 and math.isnan(g.relative.low) and math.isnan(g.relative.high)
    assert g.absolute.low <= g.absolute.value <= g.absolute.high


def test_radius_against_a_reference_return():
    grid = np.array([0.0, 1.0, 2.0, 3.0])
    curve = np.tile([100.0, 90.0, 70.0, 50.0], (20, 1))
    own = m.robustness_radius(grid, curve, fraction=0.8, rng=0)
    assert own.nominal_return == 100.0 and own.radius.value == pytest.approx(1.5) and not own.censored
    # trained in a sim that returned 120: 96 is crossed 0.4 of the way from 100 to 90
    trained = m.robustness_radius(grid, curve, fraction=0.8, reference=np.full(20, 120.0), paired=True, rng=0)
    assert trained.nominal_return == 120.0 and trained.radius.value == pytest.approx(0.4) and not trained.censored
    # trained in a sim that returned 130: 104 is missed already at the nominal point -> radius 0
    missed = m.robustness_radius(grid, curve, fraction=0.8, reference=np.full(20, 130.0), rng=0)
    assert missed.radius.value == 0.0 and not missed.censored
    # a weak training sim (60): 48 is never crossed on the sweep -> censored at the sweep end (3)
    weak = m.robustness_radius(grid, curve, fraction=0.8, reference=np.full(20, 60.0), rng=0)
    assert weak.radius.value == 3.0 and weak.censored
    with pytest.raises(ValueError, match=r"`returns` of `reference` must have a positive mean .* Received -1."):
        m.robustness_radius(grid, curve, reference=np.full(20, -1.0), rng=0)


def test_srcc_mmrv_bootstrap_over_runs():
    rng = np.random.default_rng(6)
    true_sim = np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    sim = (rng.random((200, 5)) < true_sim).astype(float)  # successes
    real = (rng.random((40, 5)) < true_sim * 0.8).astype(float)
    corr = m.srcc(sim, real, rng=0)
    assert corr.low < corr.value <= corr.high <= 1.0 and corr.value > 0.8
    assert corr.n == sim.size + real.size
    viol = m.mmrv(sim, real, rng=0)
    assert 0.0 <= viol.low <= viol.value <= viol.high


# --------------------------------------------------------------------------------------------------------------------
# Interval coverage on synthetic normal data (each column is an independent dataset)


def test_mean_bootstrap_coverage():
    data = np.random.default_rng(2024).normal(5.0, 2.0, size=(100, 2000))
    ests = m.mean(data, rng=1, num_resamples=1000)
    coverage = np.mean([e.low <= 5.0 <= e.high for e in ests])
    assert 0.93 <= coverage <= 0.97


def test_iqm_bootstrap_coverage():
    # the IQM of a symmetric distribution is its centre
    data = np.random.default_rng(2025).normal(-3.0, 1.0, size=(100, 1000))
    ests = m.iqm(data, rng=2, num_resamples=1000)
    coverage = np.mean([e.low <= -3.0 <= e.high for e in ests])
    assert 0.93 <= coverage <= 0.97


@pytest.mark.slow
@pytest.mark.parametrize("paired", [False, True])
def test_gap_bootstrap_coverage(paired):
    rng = np.random.default_rng(7 + paired)
    hits = []
    for i in range(1000):
        shared = rng.normal(10.0, 3.0, size=80)
        target = (shared if paired else rng.normal(10.0, 3.0, size=80)) - 2.0 + rng.normal(0.0, 1.0, size=80)
        g = m.gap(np.column_stack([shared, target]), paired=paired, rng=i, num_resamples=1000)
        hits.append(g.absolute.low <= 2.0 <= g.absolute.high)
    assert 0.93 <= np.mean(hits) <= 0.97


# --------------------------------------------------------------------------------------------------------------------
# Randomness: the generator is honoured, the global RNG is not touched


def _all_bootstrapped(rng):
    data = np.random.default_rng(10).normal(size=(20, 3))
    other = np.random.default_rng(11).normal(size=(20, 3))
    return (
        m.mean(data, rng=rng),
        m.iqm(data, rng=rng),
        m.cvar(data, rng=rng),
        m.aggregate(data, rng=rng),
        m.gap(data, paired=True, rng=rng),
        m.gap(data, paired=False, rng=rng),
        m.probability_of_improvement(data, data + 0.3, rng=rng),
        m.robustness_radius([0.0, 1.0, 2.0], data + np.array([10.0, 9.0, 7.0]), rng=rng),
        m.pearson(data, other, rng=rng),  # Spearman over 3 policies takes 4 values: its ends sit on them
        m.mmrv(data, other, rng=rng),
        m.srcc(data, other, rng=rng),
    )


def _intervals(results):
    flat = []
    for item in results:
        for est in item if isinstance(item, tuple) else (item,):
            if isinstance(est, m.Gap):
                flat += [est.absolute, est.relative]
            elif isinstance(est, m.RobustnessRadius):
                flat.append(est.radius)
            else:
                flat.append(est)
    return [(e.low, e.high) for e in flat]


def test_same_seed_is_bitwise_reproducible():
    first = _all_bootstrapped(np.random.default_rng(123))
    again = _all_bootstrapped(np.random.default_rng(123))
    assert first == again  # dataclass equality on floats: bitwise
    assert _all_bootstrapped(123) == _all_bootstrapped(123)
    data = np.random.default_rng(0).normal(size=(20, 2))
    assert m.iqm(data, rng=7) == m.iqm(data, rng=np.random.default_rng(7))  # an int seeds default_rng


def test_different_seeds_differ_and_generator_is_consumed():
    a = _all_bootstrapped(np.random.default_rng(1))
    b = _all_bootstrapped(np.random.default_rng(2))
    # every metric's intervals move (a single end may sit on the same data atom, e.g. a CVaR's lowest run)
    assert all(_intervals([x]) != _intervals([y]) for x, y in zip(a[:-1], b[:-1], strict=True))
    assert sum(x != y for x, y in zip(_intervals(a), _intervals(b), strict=True)) >= len(_intervals(a)) - 2
    gen = np.random.default_rng(3)
    data = np.random.default_rng(0).normal(size=(20, 1))
    assert m.mean(data, rng=gen) != m.mean(data, rng=gen)  # the same generator moves on


def test_global_rng_untouched():
    np.random.seed(77)
    before = np.random.get_state()
    results = _all_bootstrapped(5)
    after = np.random.get_state()
    assert before[0] == after[0] and np.array_equal(before[1], after[1]) and before[2:] == after[2:]
    np.random.seed(0)  # a different global state changes nothing
    assert _all_bootstrapped(5) == results


# --------------------------------------------------------------------------------------------------------------------
# Few-samples warning


def test_minimum_runs_rule():
    assert [m.minimum_runs(c) for c in (0.5, 0.9, 0.95, 0.98, 0.99, 0.999)] == [10, 10, 10, 25, 50, 500]


def test_few_runs_warn_and_point_at_the_caller():
    data = np.random.default_rng(0).normal(size=(9, 2))
    message = "mean: 9 runs in a stratum are too few for a 0.95 bootstrap interval (need >= 10)"
    with pytest.warns(FewSamplesWarning, match=re.escape(message)) as record:
        m.mean(data, rng=0)
    assert record[0].filename == __file__
    with pytest.warns(FewSamplesWarning, match=r"probability_of_improvement: 5 runs"):
        m.probability_of_improvement(np.ones((30, 1)), np.ones((5, 1)), rng=0)
    with pytest.warns(FewSamplesWarning, match=r"need >= 50"):
        m.iqm(np.random.default_rng(0).normal(size=(20, 1)), rng=0, confidence=0.99, num_resamples=5000)
    with pytest.warns(FewSamplesWarning, match=re.escape("use num_resamples >= 1000")) as record:
        m.gap(np.ones((20, 2)), rng=0, num_resamples=500)
    assert record[0].filename == __file__
    assert issubclass(FewSamplesWarning, UserWarning)


def test_enough_samples_do_not_warn():
    data = np.random.default_rng(0).normal(size=(10, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m.mean(data, rng=0)
        m.gap(data, rng=0, num_resamples=1000)
        m.success_rate(np.ones((3, 1)))  # Wilson has no resampling rule


# --------------------------------------------------------------------------------------------------------------------
# Errors and result objects


@pytest.mark.parametrize(
    ("call", "error", "message"),
    [
        (lambda: m.mean([1.0, 2.0], rng=0), ValueError,
         "`returns` must be a 2-D array of shape (num_runs, num_conditions). Received shape (2,)."),
        (lambda: m.mean(np.zeros((0, 3)), rng=0), ValueError,
         "`returns` must hold at least one run and one column. Received shape (0, 3)."),
        (lambda: m.mean([[1.0], [np.nan]], rng=0), ValueError,
         "`returns` must be finite. Received nan at run 1, column 0."),
        (lambda: m.mean([["a"]], rng=0), TypeError, "`returns` must be a numeric array. Received dtype <U1."),
        (lambda: m.mean([[1.0, 2.0], [3.0]], rng=0), ValueError,
         "`returns` must be a 2-D array of shape (num_runs, num_conditions). Received a ragged sequence."),
        (lambda: m.mean(np.ones((20, 1)), rng=0, confidence=1.5), ValueError,
         "`confidence` must be in (0, 1). Received 1.5."),
        (lambda: m.success_rate(np.ones((20, 1)), confidence=0.0), ValueError,
         "`confidence` must be in (0, 1). Received 0.0."),
        (lambda: m.cvar(np.ones((20, 1)), alpha=1.0, rng=0), ValueError, "`alpha` must be in (0, 1). Received 1.0."),
        (lambda: m.cvar(np.ones((20, 1)), alpha="x", rng=0), TypeError,  # type: ignore[arg-type]
         "`alpha` must be a number in (0, 1). Received 'x'."),
        (lambda: m.mean(np.ones((20, 1)), rng=np.random.RandomState(0)), TypeError,  # type: ignore[arg-type]
         "`rng` must be a numpy.random.Generator or a non-negative int seed. Received RandomState."),
        (lambda: m.mean(np.ones((20, 1)), rng=-1), ValueError,
         "`rng` must be a numpy.random.Generator or a non-negative int seed. Received -1."),
        (lambda: m.mean(np.ones((20, 1)), rng=0, num_resamples=0), ValueError,
         "`num_resamples` must be a positive int. Received 0."),
        (lambda: m.aggregate(np.ones((20, 1)), statistic="median", rng=0), ValueError,  # type: ignore[arg-type]
         "`statistic` must be one of 'mean', 'iqm'. Received 'median'."),
        (lambda: m.success_rate([[0.0], [0.5]]), ValueError,
         "`successes` must hold only 0/1 or booleans (or pass `threshold`). Received 0.5 at run 1, column 0."),
        (lambda: m.gap(np.ones((20, 2)), target=2, rng=0), ValueError,
         "`target` must be a condition index in [0, 2). Received 2."),
        (lambda: m.gap(np.ones((20, 2)), target=0, rng=0), ValueError,
         "`target` must differ from `reference`. Received 0 for both."),
        (lambda: m.probability_of_improvement(np.ones((20, 2)), np.ones((20, 3)), rng=0), ValueError,
         "`x` and `y` must have the same number of conditions (columns). Received 2 and 3."),
        (lambda: m.robustness_radius([0.0, 0.2, 0.1], np.ones((20, 3)), rng=0), ValueError,
         "`grid` must be finite and strictly increasing. Received [0.0, 0.2, 0.1]."),
        (lambda: m.robustness_radius([0.0, 0.1], np.ones((20, 3)), rng=0), ValueError,
         "`grid` must have one value per condition (column) of `returns` (3). Received 2."),
        (lambda: m.robustness_radius([0.5, 1.0, 2.0], np.ones((20, 3)), rng=0), ValueError,
         "`nominal` must be one of the grid values [0.5, 1.0, 2.0]. Received 0.0."),
        (lambda: m.robustness_radius([0.0, 1.0], np.ones((20, 2)), fraction=0.0, rng=0), ValueError,
         "`fraction` must be in (0, 1]. Received 0.0."),
        (lambda: m.robustness_radius([0.0, 1.0], -np.ones((20, 2)), rng=0), ValueError,
         "`returns` at the nominal grid value must have a positive mean to keep a fraction of it "
         "(shift the returns so that 0 is the worst acceptable). Received -1."),
        (lambda: m.srcc(np.ones((20, 3)), np.ones((20, 4)), rng=0), ValueError,
         "`sim` and `real` must have the same number of policies (columns). Received 3 and 4."),
        (lambda: m.srcc(np.ones((20, 2)), np.ones((20, 2)), rng=0), ValueError,
         "`sim` and `real` must cover at least 3 policies. Received 2."),
        (lambda: m.srcc(np.ones((20, 3)), np.ones((20, 3)), method="kendall", rng=0), ValueError,  # type: ignore[arg-type]
         "`method` must be one of 'pearson', 'spearman'. Received 'kendall'."),
        (lambda: m.srcc(np.ones((20, 3)), np.arange(60.0).reshape(20, 3), rng=0), ValueError,
         "`sim` and `real` must not score every policy the same: the correlation is undefined."),
        (lambda: m.mmrv([1.0, 2.0], np.ones((20, 2)), rng=0), ValueError,
         "`sim` must be a 2-D array of shape (num_runs, num_policies). Received shape (2,)."),
    ],
)  # fmt: skip
def test_error_messages(call, error, message):
    with pytest.raises(error, match=re.escape(message)):
        call()


def test_results_are_frozen_dataclasses():
    est = m.mean(np.ones((20, 1)), rng=0)[0]
    assert (est.value, est.low, est.high) == (1.0, 1.0, 1.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        est.value = 2.0
    g = m.gap(np.ones((20, 2)), rng=0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.paired = True
    assert dataclasses.asdict(g)["absolute"]["method"] == "percentile bootstrap"
    assert str(Estimate(0.5, 0.25, 0.75, 0.9, 10, "wilson")) == "0.5 [0.25, 0.75] (90% wilson, n=10)"


def test_module_imports_no_heavy_dependencies():
    path = Path(m.__file__)
    code = (
        "import importlib.util, sys\n"
        f"spec = importlib.util.spec_from_file_location('metrics_alone', {str(path)!r})\n"
        "mod = importlib.util.module_from_spec(spec); sys.modules['metrics_alone'] = mod; spec.loader.exec_module(mod)\n"
        "heavy = [k for k in ('torch', 'gymnasium', 'mujoco', 'dm_control', 'torchrl') if k in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
