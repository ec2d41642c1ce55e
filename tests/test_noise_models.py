"""noise_models on its own (no env): statistics of every process, seed twins, buffers, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from noise_models import (
    BLOCK,
    ActionLatency,
    ActionNoise,
    Bias,
    ControlJitter,
    Deadzone,
    Drift,
    Dropout,
    Gaussian,
    Layout,
    ObservationLatency,
    ObservationNoise,
    Outlier,
    Quantize,
    SampleAndHold,
    Saturate,
    Scale,
    SignalCorruptor,
    Sticky,
    Stuck,
    UniformNoise,
    stream,
)
from noise_models.timing import CommandDelay
from randomizers import Choice, Normal, Uniform

N = 20_000  # steps per statistical test: relative SE of a std estimate ~ 1/sqrt(2N) = 0.5%


def run_obs(models: list, signal: np.ndarray | None = None, size: int = 4, steps: int = N, seed: int = 0) -> tuple:
    """Corrupts a constant (or given) signal for ``steps`` steps; returns (outputs, params)."""
    c = SignalCorruptor(models, seed=seed)
    c.bind(obs=Layout(size), action=Layout(size), timestep=0.01)
    c.begin_episode()
    x = np.zeros(size) if signal is None else signal
    out = [c.first_observation(x)]
    out += [c.observe(x, t) for t in range(1, steps)]
    return np.array(out), c.current_params


def run_act(models: list, action: np.ndarray, steps: int = N) -> np.ndarray:
    c = SignalCorruptor(models, seed=0)
    c.bind(
        obs=None,
        action=Layout(action.size, low=np.full(action.size, -10.0), high=np.full(action.size, 10.0)),
        timestep=0.01,
        physics=False,
    )
    c.begin_episode()
    return np.array([c.act(action) for _ in range(steps)])


# -- statistics (fixed seeds; tolerances are several standard errors wide) -------------------------


def test_gaussian_std_and_mean() -> None:
    out, params = run_obs([ObservationNoise(Gaussian(std=0.05))])
    assert params == {"obs_noise_std": 0.05}
    assert np.allclose(out.std(axis=0), 0.05, rtol=0.03)
    assert np.all(np.abs(out.mean(axis=0)) < 4 * 0.05 / math.sqrt(N))


def test_gaussian_std_drawn_per_element_is_reported_and_used() -> None:
    out, params = run_obs([ObservationNoise(Gaussian(std=Uniform(0.01, 0.1)))])
    stds = np.array([params[f"obs_noise_std[{i}]"] for i in range(4)])
    assert len(set(stds.tolist())) == 4 and ((stds >= 0.01) & (stds < 0.1)).all()
    assert np.allclose(out.std(axis=0), stds, rtol=0.03)


def test_uniform_noise_std_and_support() -> None:
    out, _ = run_obs([ObservationNoise(UniformNoise(half_width=0.3))])
    assert np.allclose(out.std(axis=0), 0.3 / math.sqrt(3), rtol=0.03)
    assert out.min() >= -0.3 and out.max() < 0.3


def test_bias_is_constant_per_episode_and_equals_report() -> None:
    out, params = run_obs([ObservationNoise(Bias(Uniform(-0.02, 0.02)))], steps=50)
    bias = np.array([params[f"obs_bias[{i}]"] for i in range(4)])
    assert (out == bias).all()


def test_random_walk_increments_and_variance_growth() -> None:
    out, _ = run_obs([ObservationNoise(Drift(std=0.01))], size=200, steps=400)
    inc = np.diff(out, axis=0)
    assert np.isclose(inc.std(), 0.01, rtol=0.03)
    # Var(x_t) = t * std^2 across the 200 independent elements.
    assert np.isclose(out[399].var() / (399 * 0.01**2), 1.0, atol=0.3)


def test_ornstein_uhlenbeck_stationary_std_and_correlation() -> None:
    out, params = run_obs([ObservationNoise(Drift(std=0.1, timescale=20.0))], size=8, steps=40_000)
    assert params["obs_drift_timescale"] == 20.0
    tail = out[2000:]
    assert np.allclose(tail.std(axis=0), 0.1, rtol=0.15)
    lag1 = np.mean([np.corrcoef(tail[:-1, i], tail[1:, i])[0, 1] for i in range(8)])
    assert np.isclose(lag1, math.exp(-1 / 20.0), atol=0.01)


def test_quantize_levels() -> None:
    signal = np.linspace(-1, 1, 7)
    out, _ = run_obs([ObservationNoise(Gaussian(std=0.3), Quantize(0.125))], signal=signal, size=7, steps=2000)
    assert np.allclose(out / 0.125, np.round(out / 0.125), atol=1e-12)
    assert len(np.unique(out)) > 10


def test_dropout_rate_hold_and_zero() -> None:
    ramp = np.arange(1, 5, dtype=float)
    c = SignalCorruptor([ObservationNoise(Gaussian(std=1.0), Dropout(0.2, mode="zero"))], seed=0)
    c.bind(obs=Layout(4), action=None, timestep=None, physics=False)
    c.begin_episode()
    out = np.array([c.observe(ramp, t) for t in range(N)])
    assert np.isclose((out == 0).mean(), 0.2, atol=0.01)
    out, _ = run_obs([ObservationNoise(Gaussian(std=1.0), Dropout(0.3))])
    repeats = (np.diff(out, axis=0) == 0).mean()
    assert np.isclose(repeats, 0.3, atol=0.01)


def test_stuck_freezes_for_the_drawn_duration() -> None:
    out, _ = run_obs([ObservationNoise(Gaussian(std=1.0), Stuck(probability=0.01, duration=10))], size=4)
    same = np.diff(out, axis=0) == 0
    # Each event freezes 10 steps; onsets happen only while not stuck: fraction = 10p / (1 + 10p).
    assert np.isclose(same.mean(), 0.1 / 1.1, atol=0.02)
    runs = []
    for i in range(4):
        count = 0
        for s in same[:, i]:
            if s:
                count += 1
            elif count:
                runs.append(count)
                count = 0
    assert max(runs) % 10 == 0 and np.mean(np.array(runs) % 10 == 0) > 0.95


def test_outlier_rate_and_magnitude() -> None:
    out, _ = run_obs([ObservationNoise(Outlier(probability=0.05, magnitude=3.0))])
    assert set(np.unique(out).tolist()) <= {-3.0, 0.0, 3.0}
    assert np.isclose((out != 0).mean(), 0.05, atol=0.005)
    assert np.isclose((out > 0).mean(), 0.025, atol=0.004)


def test_saturate_and_scale() -> None:
    out, params = run_obs(
        [ObservationNoise(Scale(gain=Uniform(0.9, 1.1)), Saturate(-1.05, 1.05))], signal=np.full(4, 1.0), steps=10
    )
    gains = np.array([params[f"obs_scale[{i}]"] for i in range(4)])
    assert np.allclose(out[0], np.minimum(gains, 1.05))


def test_deadzone_and_sticky_on_actions() -> None:
    out = run_act([ActionNoise(Deadzone(0.5))], np.array([0.4, -0.6]), steps=3)
    assert out[0].tolist() == [0.0, -0.6]
    rng = np.random.default_rng(1)
    c = SignalCorruptor([ActionNoise(Sticky(0.25))], seed=0)
    c.bind(obs=None, action=Layout(1), timestep=None, physics=False)
    c.begin_episode()
    out = np.array([c.act(rng.normal(size=1)) for _ in range(N)])
    assert np.isclose((np.diff(out[:, 0]) == 0).mean(), 0.25, atol=0.01)


def test_action_noise_is_clipped_to_the_action_space() -> None:
    out = run_act([ActionNoise(Gaussian(std=5.0))], np.zeros(2), steps=2000)
    assert out.min() >= -10 and out.max() <= 10 and (np.abs(out) == 10).any()


# -- seeding contract -------------------------------------------------------------------------------


def test_seed_twin_gaussian_matches_bare_stream() -> None:
    std = Uniform(0.01, 0.1)
    c = SignalCorruptor([ObservationNoise(Gaussian(std=std))], seed=7)
    c.bind(obs=Layout(3), action=None, timestep=None, physics=False)
    for episode in range(2):
        c.begin_episode()
        out = np.array([c.first_observation(np.zeros(3))] + [c.observe(np.zeros(3), t) for t in range(1, 300)])
        draws = std.sample(stream(7, "obs_noise", episode, 0), 3)
        assert [c.current_params[f"obs_noise_std[{i}]"] for i in range(3)] == draws.tolist()
        first = stream(7, "obs_noise", episode, 1).standard_normal((BLOCK, 3)) * draws
        second = stream(7, "obs_noise", episode, 2).standard_normal((BLOCK, 3)) * draws
        assert np.array_equal(out, np.concatenate([first, second])[:300])


def test_seed_twin_latency_matches_bare_stream() -> None:
    steps = Choice((1, 2, 3, 4, 5))
    c = SignalCorruptor([ObservationLatency(steps=steps)], seed=3)
    c.bind(obs=Layout(1), action=None, timestep=None, physics=False)
    for episode in range(4):
        c.begin_episode()
        assert c.current_params["obs_latency_steps"] == int(steps.sample(stream(3, "obs_latency", episode, 0)))


def test_composed_models_do_not_shift_each_other() -> None:
    alone, _ = run_obs([ObservationNoise(Gaussian(std=0.1))], steps=500)
    both, params = run_obs(
        [
            ObservationNoise(Bias(Uniform(-1, 1)), Gaussian(std=0.1)),
            ActionNoise(Gaussian(std=1.0)),
            ObservationLatency(steps=Uniform(1, 4)),
        ],
        steps=500,
    )
    bias = np.array([params[f"obs_bias[{i}]"] for i in range(4)])
    lag = params["obs_latency_steps"]
    assert lag >= 1
    assert np.allclose(both[lag:] - bias, alone[: 500 - lag], rtol=0, atol=1e-12)
    assert np.allclose(both[:lag] - bias, alone[0], rtol=0, atol=1e-12)


def test_same_seed_bitwise_and_reset_seed_rerooting() -> None:
    models = [ObservationNoise(Gaussian(std=Uniform(0.1, 1)), Drift(0.1), Outlier(0.1, Uniform(0.5, 2.0)))]
    a, _ = run_obs(models, steps=600, seed=5)
    b, _ = run_obs(models, steps=600, seed=5)
    c, _ = run_obs(models, steps=600, seed=6)
    assert a.tobytes() == b.tobytes() and a.tobytes() != c.tobytes()
    eng = SignalCorruptor(models, seed=5)
    eng.bind(obs=Layout(4), action=None, timestep=None, physics=False)
    eng.begin_episode(seed=11)
    x = eng.first_observation(np.zeros(4))
    eng.begin_episode()
    eng.begin_episode(seed=11)
    assert eng.first_observation(np.zeros(4)).tobytes() == x.tobytes()


def test_duplicate_processes_get_distinct_streams() -> None:
    c = SignalCorruptor(
        [
            ObservationNoise(Gaussian(std=Uniform(0, 1)), select=0),
            ObservationNoise(Gaussian(std=Uniform(0, 1)), select=1),
        ],
        seed=0,
    )
    assert c.stream_names == ("obs_noise[0]", "obs_noise[1]")


# -- buffers ------------------------------------------------------------------------------------------


def test_command_delay_with_jitter_keeps_newest_sent() -> None:
    d = CommandDelay(capacity=8, size=1)
    d.reset(np.zeros(1))
    d.push(np.array([1.0]), arrival=7)  # sent first, arrives late
    d.push(np.array([2.0]), arrival=5)  # sent later, arrives first
    pieces = [(float(c[0]), n) for c, n in d.segments(4, 6)]
    assert pieces == [(0.0, 1), (2.0, 5)]  # command 1 is never applied


def test_observation_latency_jitter_never_goes_back_in_time() -> None:
    c = SignalCorruptor([ObservationLatency(steps=2, jitter=Uniform(0, 4))], seed=0)
    c.bind(obs=Layout(1), action=None, timestep=None, physics=False)
    c.begin_episode()
    seen = [c.first_observation(np.zeros(1))[0]] + [c.observe(np.array([float(t)]), t)[0] for t in range(1, 500)]
    ages = np.arange(500) - np.array(seen)
    assert (np.diff(seen) >= 0).all() and ages[10:].min() >= 2 and ages[10:].max() <= 6


def test_begin_episode_clears_buffers() -> None:
    c = SignalCorruptor([ObservationLatency(steps=5), ObservationNoise(Drift(std=1.0))], seed=0)
    c.bind(obs=Layout(1), action=None, timestep=None, physics=False)
    c.begin_episode()
    c.first_observation(np.zeros(1))
    for t in range(1, 50):
        c.observe(np.array([100.0 + t]), t)
    c.begin_episode()
    first = c.first_observation(np.array([-7.0]))
    assert first.tolist() == [-7.0]  # fresh drift state (0) and nothing stale in the delay line
    assert c.observe(np.array([3.0]), 1).tolist() == [-7.0]


def test_sample_and_hold_updates_on_period() -> None:
    c = SignalCorruptor([SampleAndHold(steps=3)], seed=0)
    c.bind(obs=Layout(1), action=None, timestep=None, physics=False)
    c.begin_episode()
    seen = [c.first_observation(np.zeros(1))[0]] + [c.observe(np.array([float(t)]), t)[0] for t in range(1, 10)]
    assert seen == [0, 0, 0, 3, 3, 3, 6, 6, 6, 9]


def test_control_jitter_draws() -> None:
    c = SignalCorruptor([ControlJitter(delta=Choice((-1, 0, 1)))], seed=0)
    c.bind(obs=None, action=None, timestep=0.002, substeps=5)
    c.begin_episode()
    n = []
    for _ in range(3000):
        c.act(np.zeros(0))
        n.append(c.substeps(5))
    counts = np.bincount(n)
    assert set(np.flatnonzero(counts).tolist()) == {4, 5, 6} and np.allclose(counts[4:] / 3000, 1 / 3, atol=0.03)


# -- bad input: pinned messages ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("build", "error", "message"),
    [
        (lambda: Gaussian(std=-1.0), ValueError, "`std` must be >= 0. Received -1.0."),
        (
            lambda: Gaussian(std=Uniform(-1, 1)),
            ValueError,
            "`std` must be >= 0, but Uniform(low=-1.0, high=1.0) can draw values in [-1, 1]. "
            "Received Uniform(low=-1.0, high=1.0).",
        ),
        (
            lambda: Gaussian(std="big"),
            TypeError,
            "`std` must be a number or a distribution with sample(rng, size) (e.g. randomizers.Uniform). "
            "Received 'big' of type str.",
        ),
        (lambda: Dropout(probability=1.5), ValueError, "`probability` must be in [0, 1]. Received 1.5."),
        (lambda: Outlier(probability=-0.1, magnitude=1), ValueError, "`probability` must be in [0, 1]. Received -0.1."),
        (
            lambda: ObservationLatency(steps=5000),
            ValueError,
            "`steps` (plus `jitter`) of ObservationLatency can reach 5000 steps, more than the buffer holds "
            "(`max_steps`=1000). Raise `max_steps` or shorten the latency. Received steps=5000.0, jitter=None.",
        ),
        (
            lambda: ObservationLatency(steps=Normal(3, 1)),
            ValueError,
            "`steps` must be >= 0, but Normal(mean=3.0, std=1.0) can draw values in [-inf, inf]. "
            "Received Normal(mean=3.0, std=1.0).",
        ),
        (
            lambda: ActionLatency(),
            ValueError,
            "ActionLatency takes exactly one of `steps` and `seconds`. Received steps=None, seconds=None.",
        ),
        (
            lambda: ObservationNoise(Sticky(0.1)),
            ValueError,
            "`processes[0]` of ObservationNoise is Sticky, which does not apply to observations (Deadzone and Sticky "
            "act on actions only). Received Sticky(probability=0.1).",
        ),
        (
            lambda: ObservationNoise(),
            ValueError,
            "ObservationNoise needs at least one process, e.g. ObservationNoise(Gaussian(std=0.01)).",
        ),
    ],
)
def test_bad_input_messages(build, error, message) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(error) as info:
        build()
    assert str(info.value) == message


def test_latency_in_seconds_longer_than_buffer_is_rejected_at_bind() -> None:
    c = SignalCorruptor([ActionLatency(seconds=0.5, max_steps=100)], seed=0)
    with pytest.raises(ValueError) as info:
        c.bind(obs=None, action=Layout(2), timestep=0.002, substeps=5)
    assert str(info.value) == (
        "`seconds` (plus `jitter`) of ActionLatency can reach 250 steps, more than the buffer holds (`max_steps`=100). "
        "Raise `max_steps` or shorten the latency. Received seconds=0.5, jitter=None."
    )


def test_unknown_keys_are_listed() -> None:
    layout = Layout(6, keys=(("position", slice(0, 3), (3,)), ("velocity", slice(3, 6), (3,))))
    c = SignalCorruptor([ObservationNoise(Gaussian(std=0.1), select="velocty")], seed=0)
    with pytest.raises(ValueError) as info:
        c.bind(obs=layout, action=None, timestep=None, physics=False)
    assert str(info.value) == (
        "`select` names key 'velocty', which the signal does not have. Known keys: 'position', 'velocity'. "
        "Close matches: 'velocity'."
    )


def test_models_are_immutable_values() -> None:
    g = Gaussian(std=0.1)
    with pytest.raises(AttributeError):
        g.std = 0.2  # type: ignore[misc]
    assert g == Gaussian(std=0.1) and hash(g) == hash(Gaussian(std=0.1)) and g != Gaussian(std=0.2)
    assert ObservationLatency(steps=3) == ObservationLatency(steps=3.0)


def test_any_object_with_sample_rng_is_a_distribution() -> None:
    class Coin:
        def sample(self, rng: np.random.Generator) -> float:
            return float(rng.integers(0, 2)) * 0.1

    out, params = run_obs([ObservationNoise(Gaussian(std=Coin()))], steps=2000)
    stds = [params[f"obs_noise_std[{i}]"] for i in range(4)]
    assert set(stds) <= {0.0, 0.1}
    assert np.allclose(out.std(axis=0), stds, atol=0.01)


def test_yaml_round_trip_of_every_model() -> None:
    from randomizers import Damping
    from randomizers.config import dump_config, load_config

    models = [
        Damping(scale=Uniform(0.5, 2.0)),
        ObservationNoise(Gaussian(std=Uniform(0.0, 0.1)), Bias(0.01), Drift(0.001, timescale=20.0), select="velocity"),
        ObservationNoise(Quantize(0.01), Dropout(0.1, mode="zero"), Stuck(0.01, 5), Outlier(0.01, 1.0),
                         Saturate(-1.0, 1.0), Scale(Uniform(0.9, 1.1)), UniformNoise(0.01), select=(0, 1)),
        ActionNoise(Gaussian(std=0.05), Deadzone(0.01), Sticky(0.1), clip=False),
        ObservationLatency(steps=Choice((1, 2, 3)), jitter=Uniform(0, 2)),
        ActionLatency(seconds=0.02, max_steps=50),
        SampleAndHold(seconds=0.05, phase=0.01),
        ControlJitter(delta=Choice((-1, 0, 1))),
    ]
    assert load_config(dump_config(models)) == models


def test_yaml_signal_errors_name_the_key(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from randomizers.config import load_config

    path = tmp_path / "bad.yaml"
    path.write_text("signals:\n  - type: ObservationNoise\n    processes:\n      - {type: Gaussian, std: -1}\n")
    with pytest.raises(ValueError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: signals[0].processes[0]: `std` must be >= 0. Received -1.0."
