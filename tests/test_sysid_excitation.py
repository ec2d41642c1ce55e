"""Excitation signals (limits, spectra, switching, seeding, errors) and the D-optimal experiment-design helper."""

from __future__ import annotations

import re

import mujoco
import numpy as np
import pytest
from conftest import assert_same_model, model_arrays

from sysid.design import candidate_grid, design_experiment, fisher_information, parameter_space
from sysid.excitation import (
    EXCITATIONS,
    PRBS,
    ActuatorLimits,
    Chirp,
    ExcitationPolicy,
    Multisine,
    RandomSteps,
    lfsr_sequence,
    make_excitation,
)

# A motor with an asymmetric range, a position servo with a control range, and a servo limited only by its
# joint's range (no ctrlrange): three ways limits reach the excitation.
ARM = """
<mujoco>
  <compiler angle="radian"/>
  <option timestep="0.005"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" axis="0 1 0" damping="0.3"/>
      <geom type="capsule" size=".02" fromto="0 0 0 0 0 -.3" mass=".5"/>
      <body name="fore" pos="0 0 -.3">
        <joint name="elbow" axis="0 1 0" range="-1 1.5" damping="0.1"/>
        <geom type="capsule" size=".02" fromto="0 0 0 0 0 -.3" mass=".3"/>
        <body name="hand" pos="0 0 -.3">
          <joint name="wrist" axis="0 1 0" range="-0.5 0.5" damping="0.05"/>
          <geom type="sphere" size=".03" mass=".1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="shoulder" joint="shoulder" ctrlrange="-1 3"/>
    <position name="elbow" joint="elbow" kp="5" ctrlrange="-0.8 1.2"/>
    <position name="wrist" joint="wrist" kp="2"/>
  </actuator>
</mujoco>
"""

PENDULUM = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="link">
      <joint name="hinge" axis="0 1 0" damping="0.2"/>
      <geom type="capsule" size=".02" fromto="0 0 0 0 0 -.3" mass=".5"/>
    </body>
  </worldbody>
  <actuator><motor name="motor" joint="hinge" ctrlrange="-1 1"/></actuator>
  <sensor><jointpos name="angle" joint="hinge"/></sensor>
</mujoco>
"""

KWARGS = {
    "multisine": {"band": (0.5, 5.0)},
    "chirp": {"f0": 0.5, "f1": 5.0, "duration": 4.0},
    "prbs": {"switch_period": 0.04},
    "random": {"hold": 0.03},
}


@pytest.fixture(scope="module")
def arm() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(ARM)


@pytest.fixture(scope="module")
def pendulum() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(PENDULUM)


def test_limits_from_model(arm: mujoco.MjModel) -> None:
    limits = ActuatorLimits.from_model(arm)
    assert limits.names == ("shoulder", "elbow", "wrist")
    np.testing.assert_array_equal(limits.low, [-1.0, -0.8, -0.5])
    np.testing.assert_array_equal(limits.high, [3.0, 1.2, 0.5])
    np.testing.assert_allclose(limits.center, [1.0, 0.2, 0.0], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(limits.servo, [False, True, True])


@pytest.mark.parametrize("kind", sorted(EXCITATIONS))
def test_signals_stay_within_limits_and_swing_around_the_centre(arm: mujoco.MjModel, kind: str) -> None:
    policy = make_excitation(kind, arm, amplitude=1.0, seed=0, **KWARGS[kind])
    assert isinstance(policy, EXCITATIONS[kind]) and isinstance(policy, ExcitationPolicy)
    u = policy.signal(4000, 0.005)
    limits = policy.limits
    assert u.shape == (4000, 3)
    assert np.all(u >= limits.low) and np.all(u <= limits.high)
    # A full-amplitude signal uses the whole swing available around its centre ...
    swing = np.abs(u - limits.center).max(axis=0)
    assert np.all(swing > 0.9 * limits.half_range)
    # ... and half the amplitude stays within half of it (position servos keep clear of the joint limits).
    half = make_excitation(kind, arm, amplitude=0.5, seed=0, **KWARGS[kind]).signal(4000, 0.005)
    assert np.all(np.abs(half - limits.center) <= 0.5 * limits.half_range + 1e-12)


def test_custom_centre_for_position_servos(arm: mujoco.MjModel) -> None:
    home = [1.0, 0.9, -0.2]
    policy = Multisine(arm, amplitude=1.0, band=(0.5, 5.0), center=home, seed=0)
    u = policy.signal(2000, 0.005)
    np.testing.assert_allclose(policy.limits.half_range, [2.0, 0.3, 0.3])
    assert np.all(np.abs(u - home) <= policy.limits.half_range + 1e-12)
    np.testing.assert_allclose(u.mean(axis=0), home, atol=0.05)  # whole periods of zero-mean sines


@pytest.mark.parametrize("kind", sorted(EXCITATIONS))
def test_same_seed_is_bitwise_identical_and_seeds_differ(arm: mujoco.MjModel, kind: str) -> None:
    state = np.random.get_state()[1].copy()
    a = make_excitation(kind, arm, seed=7, **KWARGS[kind]).signal(1500, 0.005)
    b = make_excitation(kind, arm, seed=7, **KWARGS[kind]).signal(1500, 0.005)
    c = make_excitation(kind, arm, seed=8, **KWARGS[kind]).signal(1500, 0.005)
    assert a.tobytes() == b.tobytes()
    assert not np.array_equal(a, c)
    # An explicit Generator is honoured: a twin generator gives the same signal.
    g1, g2 = np.random.default_rng(3), np.random.default_rng(3)
    d = make_excitation(kind, arm, seed=g1, **KWARGS[kind]).signal(1500, 0.005)
    e = make_excitation(kind, arm, seed=g2, **KWARGS[kind]).signal(1500, 0.005)
    assert d.tobytes() == e.tobytes()
    assert np.array_equal(np.random.get_state()[1], state), "the global np.random state must stay untouched"


@pytest.mark.parametrize("kind", sorted(EXCITATIONS))
def test_per_step_calls_match_the_block_signal(arm: mujoco.MjModel, kind: str) -> None:
    block = make_excitation(kind, arm, seed=1, **KWARGS[kind]).signal(300, 0.01)
    stepper = make_excitation(kind, arm, seed=1, **KWARGS[kind])
    # Queried backwards on purpose: random steps must not depend on query order.
    rows = np.array([stepper(k * 0.01) for k in reversed(range(300))])[::-1]
    np.testing.assert_allclose(rows, block, rtol=0, atol=1e-12)


def test_multisine_puts_its_energy_on_the_requested_frequencies() -> None:
    limits = ActuatorLimits.explicit(low=[-1.0, -2.0, 0.0], high=[1.0, 2.0, 1.0])
    policy = Multisine(limits, amplitude=0.8, band=(0.5, 6.0), period=4.0, seed=2)
    dt, n = 0.01, 800  # exactly two periods: every harmonic falls on an FFT bin
    u = policy.signal(n, dt) - limits.center
    spectrum = np.abs(np.fft.rfft(u, axis=0)) ** 2
    freqs = np.fft.rfftfreq(n, dt)
    owned: list[set[float]] = []
    for j, wanted in enumerate(policy.frequencies):
        assert np.all((wanted >= 0.5) & (wanted <= 6.0))
        bins = np.searchsorted(freqs, wanted)
        np.testing.assert_allclose(freqs[bins], wanted)
        assert spectrum[bins, j].sum() > 0.999 * spectrum[1:, j].sum()
        assert spectrum[bins, j].min() > 0.5 * spectrum[bins, j].max()  # flat amplitude spectrum
        owned.append(set(np.round(wanted, 9).tolist()))
    # Interleaved: each actuator owns its own harmonics, together covering the band on the 1/period grid.
    assert not (owned[0] & owned[1]) and not (owned[0] & owned[2]) and not (owned[1] & owned[2])
    assert sorted(owned[0] | owned[1] | owned[2]) == [k / 4.0 for k in range(2, 25)]


def test_schroeder_phases_lower_the_crest_factor() -> None:
    limits = ([-1.0], [1.0])
    schroeder = Multisine(limits, band=(0.2, 6.0), period=5.0, seed=0)
    random = Multisine(limits, band=(0.2, 6.0), period=5.0, phases="random", seed=0)
    assert schroeder.crest_factor[0] < 2.0 < random.crest_factor[0]


@pytest.mark.parametrize("method", ["linear", "log"])
def test_chirp_instantaneous_frequency(method: str) -> None:
    chirp = Chirp(([-1.0], [1.0]), amplitude=1.0, f0=1.0, f1=8.0, duration=5.0, method=method, seed=0)
    dt = 0.0005
    u = chirp.signal(10000, dt)[:, 0]
    # Zero crossings sit half a cycle apart; the mean frequency over each half cycle is the instantaneous
    # frequency at its midpoint (to second order in the sweep rate).
    k = np.flatnonzero(np.signbit(u[:-1]) != np.signbit(u[1:]))
    crossings = (k - u[k] / (u[k + 1] - u[k])) * dt
    measured = 0.5 / np.diff(crossings)
    mid = 0.5 * (crossings[1:] + crossings[:-1])
    assert measured.size > 20
    np.testing.assert_allclose(measured, chirp.instantaneous_frequency(mid), rtol=0.01)
    expected_end = 8.0 if method == "linear" else 1.0 * 8.0 ** (4.999 / 5.0)
    assert chirp.instantaneous_frequency(np.array([4.999]))[0] == pytest.approx(expected_end, rel=1e-3)


def test_prbs_switches_only_on_its_clock_and_is_maximal_length() -> None:
    prbs = PRBS(([-2.0, 0.0], [2.0, 4.0]), amplitude=0.5, switch_period=0.05, order=6, seed=4)
    dt = 0.01
    u = prbs.signal(63 * 5 * 2, dt)  # two full periods of the 63-clock sequence
    centred = u - prbs.limits.center
    np.testing.assert_array_equal(np.unique(np.abs(centred)), [1.0])  # only ±amplitude * half_range
    switches = np.flatnonzero(np.any(np.diff(u, axis=0) != 0, axis=1)) + 1
    assert switches.size > 20
    np.testing.assert_array_equal(switches % 5, 0)  # on multiples of switch_period / dt
    bits = centred[::5] > 0
    np.testing.assert_array_equal(bits[:63], bits[63:])  # period 2**6 - 1 clocks
    np.testing.assert_array_equal(bits[:63].sum(axis=0), [32, 32])  # an m-sequence has one more 1 than 0
    assert not np.array_equal(bits[:, 0], bits[:, 1])  # actuators run shifted copies
    assert PRBS(([-1.0], [1.0]), f_max=2.0).switch_period == pytest.approx(0.443 / 2.0)


@pytest.mark.parametrize("order", range(3, 19))
def test_lfsr_taps_give_maximal_length(order: int) -> None:
    seq = lfsr_sequence(order, 1).astype(np.int64)
    n = (1 << order) - 1
    assert seq.shape == (n,) and seq.sum() == (n + 1) // 2
    wrapped = np.concatenate([seq, seq[: order - 1]])
    windows = sum(wrapped[i : i + n] << i for i in range(order))
    assert np.unique(windows).size == n  # every non-zero register state appears once per period


def test_random_steps_hold_their_value() -> None:
    steps = RandomSteps(([-1.0], [1.0]), hold=0.05, seed=0)
    u = steps.signal(1000, 0.01)[:, 0]
    np.testing.assert_array_equal(np.flatnonzero(np.diff(u)) % 5, 4)
    assert -1.0 <= u.min() < -0.5 and 0.5 < u.max() <= 1.0


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: Multisine(([-1.0], [1.0]), amplitude=1.5), "`amplitude` must be in (0, 1]. Received 1.5."),
        (lambda: PRBS(([-1.0], [1.0]), amplitude=0.0), "`amplitude` must be in (0, 1]. Received 0.0."),
        (
            lambda: Multisine(([-1.0], [1.0]), band=(0.0, 1.0)),
            "`band` of Multisine must be (f_low, f_high) in Hz with 0 < f_low < f_high. Received (0.0, 1.0).",
        ),
        (
            lambda: Multisine(([-1.0], [1.0]), band=(1.0, 2.0), period=0.5),
            "`period` of Multisine must be >= 1 / band[0] = 1.0 s so the lowest frequency fits. Received 0.5.",
        ),
        (lambda: Chirp(([-1.0], [1.0]), f0=-1.0), "`f0` of Chirp must be a finite number > 0. Received -1.0."),
        (
            lambda: PRBS(([-1.0], [1.0]), switch_period=0.1, f_max=1.0),
            "PRBS needs exactly one of `switch_period` (s) or `f_max` (Hz). Received switch_period=0.1, f_max=1.0.",
        ),
        (lambda: PRBS(([-1.0], [1.0]), order=2), "`order` of PRBS must be an int in [3, 18]. Received 2."),
        (
            lambda: RandomSteps(([-1.0], [1.0]), hold=0),
            "`hold` of RandomSteps must be a finite number > 0. Received 0.",
        ),
        (
            lambda: make_excitation("sweep", ([-1.0], [1.0])),
            "`policy` must be one of ['chirp', 'multisine', 'prbs', 'random']. Received 'sweep'.",
        ),
        (
            lambda: Multisine(([-1.0], [1.0]), center=[2.0]),
            "`center` must lie strictly inside (low, high) for every actuator. Received center=[2.0], low=[-1.0], "
            "high=[1.0].",
        ),
        (
            lambda: Multisine(([-1.0, -1.0], [1.0, 1.0]), amplitude=[0.5]),
            "`amplitude` must be a number or a sequence of 2 numbers (one per actuator). Received [0.5].",
        ),
        (lambda: Chirp(([-1.0], [1.0])).signal(10, 0.0), "`dt` of signal must be a finite number > 0. Received 0.0."),
        (
            lambda: Chirp(([-1.0], [1.0]), seed=-3),
            "`seed` must be None, a non-negative int, a sequence of them or a numpy.random.Generator. Received -3.",
        ),
    ],
)
def test_bad_arguments_are_named(build, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=re.escape(message)):
        build()


def test_unlimited_actuator_needs_explicit_limits() -> None:
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body></worldbody>'
        '<actuator><motor name="free_motor" joint="j"/></actuator></mujoco>'
    )
    with pytest.raises(ValueError, match=re.escape("actuator 'free_motor' has no control limits")):
        Multisine(model)
    u = Multisine(ActuatorLimits.explicit(-0.3, 0.3), seed=0).signal(10, 0.01)
    assert np.all(np.abs(u) <= 0.3)


# --- experiment design ---------------------------------------------------------------------------------------


def test_zero_excitation_scores_below_a_multisine(pendulum: mujoco.MjModel) -> None:
    multisine = Multisine(pendulum, amplitude=0.5, band=(0.5, 3.0), seed=0)
    result = design_experiment(pendulum, "dof_damping[*]", candidates=[np.zeros((300, 1)), multisine], n_steps=300)
    assert result.params == ("dof_damping[hinge]",)
    assert result.scores[0] < result.scores[1]
    assert np.isfinite(result.scores[1])
    assert result.best is multisine and result.best_index == 1
    assert result.logdet == result.scores[1]
    assert np.all(np.isfinite(result.crlb_sd)) and np.all(result.crlb_sd > 0)


def test_logdet_grows_with_amplitude_for_damping(pendulum: mujoco.MjModel) -> None:
    amplitudes = (0.1, 0.3, 0.6, 1.0)
    result = design_experiment(
        pendulum, ["dof_damping[hinge]"], n_steps=300, amplitudes=amplitudes, bands=((0.5, 3.0),), seed=0
    )
    assert len(result.candidates) == 4
    assert np.all(np.diff(result.scores) > 0)
    assert result.best_index == 3 and result.best.amplitude.tolist() == [1.0]
    # More excitation shrinks the Cramér–Rao bound.
    small = fisher_information(pendulum, "dof_damping[*]", result.candidates[0].signal(300, 0.005))
    assert np.sqrt(1 / small[0, 0]) > result.crlb_sd[0]


def test_design_grid_over_several_parameters(arm: mujoco.MjModel) -> None:
    params = "dof_damping[*], dof_armature[shoulder], actuator_gain[shoulder]"
    before = model_arrays(arm)
    result = design_experiment(arm, params, n_steps=200, amplitudes=(0.3, 1.0), bands=((0.5, 2.0), (0.5, 6.0)))
    assert result.params == (
        "dof_damping[shoulder]",
        "dof_damping[elbow]",
        "dof_damping[wrist]",
        "dof_armature[shoulder]",
        "actuator_gain[shoulder]",
    )
    assert result.fisher.shape == (4, 5, 5) and result.scores.shape == (4,)
    np.testing.assert_allclose(result.fisher, np.swapaxes(result.fisher, 1, 2))
    assert result.best_index == int(np.argmax(result.scores))
    assert result.controls().shape == (200, 3)
    assert_same_model(before, arm)  # perturbations go to copies (armature even runs mj_setConst there)


def test_sensitivities_match_a_python_step_loop(pendulum: mujoco.MjModel) -> None:
    """The batched rollout Jacobian equals central differences of a plain ``mj_step`` loop."""
    controls = Multisine(pendulum, amplitude=0.7, band=(0.5, 3.0), seed=1).signal(150, 0.01)
    fisher = fisher_information(pendulum, "dof_damping[hinge]", controls, n_substeps=2, noise_std=0.01)

    def trajectory(damping: float) -> np.ndarray:
        model = mujoco.MjModel.from_xml_string(PENDULUM)
        model.dof_damping[0] = damping
        data = mujoco.MjData(model)
        out = []
        for u in controls:
            data.ctrl[:] = u
            mujoco.mj_step(model, data)
            mujoco.mj_step(model, data)
            out.append(data.qpos[0])
        return np.array(out)

    h = 0.2 * 1e-4
    jac = (trajectory(0.2 + h) - trajectory(0.2 - h)) / (2 * h) / 0.01
    assert fisher[0, 0] == pytest.approx(jac @ jac, rel=1e-6)


def test_sensor_measurement_design(pendulum: mujoco.MjModel) -> None:
    controls = Multisine(pendulum, amplitude=0.7, band=(0.5, 3.0), seed=1).signal(200, 0.005)
    by_qpos = fisher_information(pendulum, "dof_damping[*]", controls, measure="qpos")
    by_sensor = fisher_information(pendulum, "dof_damping[*]", controls, measure="sensordata")
    # The jointpos sensor reads qpos; it misses only the last row (never evaluated by the rollout).
    assert by_sensor[0, 0] == pytest.approx(by_qpos[0, 0], rel=0.05)
    assert by_sensor[0, 0] < by_qpos[0, 0]


def test_candidate_grid_maps_bands_per_kind(pendulum: mujoco.MjModel) -> None:
    grid = {
        kind: candidate_grid(kind, pendulum, amplitudes=(0.5,), bands=((0.5, 4.0),), duration=3.0)[0]
        for kind in EXCITATIONS
    }
    assert grid["multisine"].band == (0.5, 4.0)
    assert (grid["chirp"].f0, grid["chirp"].f1, grid["chirp"].duration) == (0.5, 4.0, 3.0)
    assert grid["prbs"].f_max == pytest.approx(4.0)
    assert grid["random"].hold == pytest.approx(0.443 / 4.0)


def test_zero_nominal_parameter_needs_no_bounds_for_design() -> None:
    model = mujoco.MjModel.from_xml_string(PENDULUM.replace('damping="0.2"', 'damping="0"'))
    space = parameter_space(model, "dof_damping[hinge]", need_bounds=False)
    assert space.nominal.tolist() == [0.0]
    controls = Multisine(model, band=(0.5, 3.0), seed=0).signal(100, 0.005)
    assert fisher_information(model, space, controls)[0, 0] > 0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"candidates": [np.zeros((5, 2))]}, "`candidates[0]` must be an ExcitationPolicy or a finite array of shape"),
        ({"measure": "force"}, "`measure` must be one of ['qpos', 'qvel', 'state', 'sensordata']. Received 'force'."),
        (
            {"noise_std": -1.0},
            "`noise_std` must be a number > 0 or 1 of them (one per measured channel). Received -1.0.",
        ),
        ({"n_steps": 1}, "`n_steps` must be an int >= 2. Received 1."),
        ({"params": "dof_damping[knee]"}, "`joints` pattern 'knee' matches no joint in the model."),
        ({"candidates": []}, "`candidates` must hold at least one design. Received an empty sequence."),
    ],
)
def test_design_errors(pendulum: mujoco.MjModel, kwargs: dict, message: str) -> None:  # type: ignore[type-arg]
    args = {"params": "dof_damping[*]", "n_steps": 100, **kwargs}
    with pytest.raises(ValueError, match=re.escape(message)):
        design_experiment(pendulum, **args)
