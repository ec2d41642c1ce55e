"""Adding an effect never shifts another's draws: stream names come from an effect's content, not its position."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from noise_models import Gaussian, ObservationNoise, SignalCorruptor
from noise_models.values import Layout
from randomizers import Mass, PhysicsRandomizer, Uniform

# -- physics effects ----------------------------------------------------------------------------------------


def _torso_masses(effects: list[Any]) -> list[tuple[float, float]]:
    from dm_control import suite

    physics = suite.load("cheetah", "run").physics
    model, data = physics.model.ptr, physics.data.ptr
    r = PhysicsRandomizer(effects, seed=7)
    r.bind(model, data)
    torso = model.body("torso").id
    out = []
    for episode in range(3):
        r.begin_episode(seed=11) if episode == 0 else r.begin_episode()
        r.apply()
        out.append((r.current_params["body_mass[torso]"], float(model.body_mass[torso])))
    return out


def test_inserting_a_same_kind_effect_before_another_keeps_its_draws_bitwise() -> None:
    scale = Mass(scale=Uniform(0.5, 1.5), bodies="torso")
    alone = _torso_masses([scale])
    inserted = _torso_masses([Mass(add=Uniform(-0.5, 0.5), bodies="torso"), scale])
    # The scale effect is applied last, so it decides what torso holds: the same numbers, bitwise
    # (before: its stream became "Mass[bodies=torso]#1" and the torso mass moved).
    assert inserted == alone
    assert all(reported == held for reported, held in alone)


def test_stream_names_are_the_effects_own_keys() -> None:
    r = PhysicsRandomizer(
        [Mass(add=Uniform(-0.1, 0.1), bodies="torso"), Mass(scale=Uniform(0.5, 1.5), bodies="torso")], seed=0
    )
    assert r.stream_names == ("Mass[bodies=torso,op=add]", "Mass[bodies=torso]")
    assert Mass(set=Uniform(1.0, 2.0), bodies="torso", name="payload").key == "payload"


def test_two_effects_with_one_stream_are_refused() -> None:
    with pytest.raises(ValueError) as err:
        PhysicsRandomizer([Mass(scale=Uniform(0.5, 1.5)), Mass(scale=Uniform(0.9, 1.1))], seed=0)
    assert str(err.value) == (
        "`effects[1]` and `effects[0]` would share the random stream 'Mass[bodies=*]' "
        "(Mass(scale=Uniform(low=0.9, high=1.1), bodies='*') and Mass(scale=Uniform(low=0.5, high=1.5), "
        "bodies='*')); pass a distinct `name=` to one of them."
    )
    PhysicsRandomizer([Mass(scale=Uniform(0.5, 1.5)), Mass(scale=Uniform(0.9, 1.1), name="second")], seed=0)


# -- noise models --------------------------------------------------------------------------------------------


def _noisy(models: list[Any]) -> tuple[dict[str, float], np.ndarray]:
    c = SignalCorruptor(models, seed=3)
    c.bind(obs=Layout(4), action=None, timestep=None, physics=False)
    params, rows = {}, []
    for episode in range(3):
        c.begin_episode(seed=5) if episode == 0 else c.begin_episode()
        params.update({f"{episode}:{k}": v for k, v in c.current_params.items()})
        rows.append(c.first_observation(np.zeros(4)))
        rows.extend(c.observe(np.zeros(4)) for _ in range(5))
    return params, np.array(rows)


def test_inserting_a_noise_model_before_another_keeps_its_draws_and_report_keys() -> None:
    existing = ObservationNoise(Gaussian(std=Uniform(0.0, 1.0)), select=[2, 3])
    alone_params, alone_obs = _noisy([existing])
    params, obs = _noisy([ObservationNoise(Gaussian(std=Uniform(0.0, 1.0)), select=[0, 1]), existing])
    assert sorted(alone_params) == [f"{e}:obs_noise_std[{i}]" for e in range(3) for i in (2, 3)]
    # before: the existing model's keys became obs_noise#1_std[2], obs_noise#1_std[3] and its draws moved
    assert {k: params[k] for k in alone_params} == alone_params
    assert obs[:, 2:].tobytes() == alone_obs[:, 2:].tobytes()


def test_noise_models_that_would_share_a_stream_or_report_keys_are_refused() -> None:
    with pytest.raises(ValueError) as err:
        SignalCorruptor([ObservationNoise(Gaussian(std=0.1)), ObservationNoise(Gaussian(std=0.2))], seed=0)
    assert str(err.value) == (
        "`models[1]` and `models[0]` would share the random stream 'obs_noise' (same process name and "
        "selection); pass a distinct `name=` to one of the processes, e.g. Gaussian(..., name='noise2')."
    )
    c = SignalCorruptor([ObservationNoise(Gaussian(std=0.1)), ObservationNoise(Gaussian(std=0.2), select=0)], seed=0)
    with pytest.raises(ValueError) as err:
        c.bind(obs=Layout(4), action=None, timestep=None, physics=False)
    assert str(err.value) == (
        "The processes of streams 'obs_noise' and 'obs_noise[0]' act on overlapping entries, so both would "
        "report 'obs_noise' for them; pass a distinct `name=` to one of the processes."
    )
    named = ObservationNoise(Gaussian(std=0.2, name="imu_noise"), select=0)
    c = SignalCorruptor([ObservationNoise(Gaussian(std=0.1)), named], seed=0)
    c.bind(obs=Layout(4), action=None, timestep=None, physics=False)
    assert c.stream_names == ("obs_noise", "obs_imu_noise[0]")


def test_philox_key_draws_what_start_starts_on_any_generator() -> None:
    # next_blocks draws many worlds' noise with one generator set to each world's key and counter in turn.
    from noise_models.seeding import StreamFactory

    factory = StreamFactory(seed=(4, 2))
    own = factory.generator("obs_noise[0]")
    factory.start(own, "obs_noise[0]", episode=3, resample=5)
    expected = own.standard_normal(7)
    other = np.random.Generator(np.random.Philox(key=np.zeros(2, np.uint64)))
    other.standard_normal(3)  # a used generator: a partial buffer, another key
    key = factory.philox_key("obs_noise[0]")
    assert len(key) == 2 and all(type(k) is int for k in key)
    other.bit_generator.state = {
        "bit_generator": "Philox",
        "state": {"counter": [0, 0, 5, 3], "key": key},
        "buffer": [0, 0, 0, 0],
        "buffer_pos": 4,
        "has_uint32": 0,
        "uinteger": 0,
    }
    assert np.array_equal(other.standard_normal(7), expected)
    assert not np.array_equal(factory.philox_key("obs_noise[1]"), key)
