"""Loose ends of earlier sessions, each pinned by a test that failed before its fix."""

from __future__ import annotations

import random
import warnings
import zlib
from pathlib import Path
from typing import Any

import dm_env
import numpy as np
import pytest
from dm_env import specs
from gymnasium.utils.env_checker import check_env

from sim2real.adapters import DmEnvToGym


class _Drift(dm_env.Environment):
    """A hand-written dm_env (no dm-control): a point drifting by its action; optionally noisy."""

    def __init__(self, rng: Any = None) -> None:
        self.x = np.zeros(2)
        if rng is not None:
            self._rng = rng

    def reset(self) -> dm_env.TimeStep:
        self.x = np.zeros(2) if not hasattr(self, "_rng") else self._rng.normal(size=2)
        self.t = 0
        return dm_env.restart(self.x.copy())

    def step(self, action: Any) -> dm_env.TimeStep:
        self.x = self.x + np.asarray(action, dtype=np.float64)
        self.t += 1
        if self.t >= 5:
            return dm_env.truncation(-float(self.x @ self.x), self.x.copy())
        return dm_env.transition(-float(self.x @ self.x), self.x.copy())

    def observation_spec(self) -> specs.Array:
        return specs.Array((2,), np.float64, name="x")

    def action_spec(self) -> specs.BoundedArray:
        return specs.BoundedArray((2,), np.float64, -1.0, 1.0, name="push")


def test_a_deterministic_dm_env_takes_a_seed_and_passes_check_env() -> None:
    env = DmEnvToGym(_Drift())
    obs, info = env.reset(seed=3)  # "`seed` cannot be honoured: _Drift exposes no RandomState" before
    assert obs.tolist() == [0.0, 0.0] and info == {}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # accepted without a warning: there is nothing to re-seed
        env.reset(seed=4)
    check_env(env, skip_render_check=True)


@pytest.mark.parametrize(
    "make_rng",
    [np.random.default_rng, np.random.RandomState, lambda s: np.random.Generator(np.random.Philox(s)), random.Random],
    ids=["Generator", "RandomState", "Philox", "random.Random"],
)
def test_a_dm_env_keeping_its_own_generator_is_reseeded_in_place(make_rng: Any) -> None:
    class Noisy(_Drift):
        def reset(self) -> dm_env.TimeStep:
            rng = self._rng
            self.x = np.array([rng.gauss(0, 1), rng.gauss(0, 1)]) if isinstance(rng, random.Random) else None
            if self.x is None:
                self.x = rng.normal(size=2) if hasattr(rng, "normal") else rng.standard_normal(2)
            self.t = 0
            return dm_env.restart(self.x.copy())

    rng = make_rng(0)
    env = DmEnvToGym(Noisy(rng))
    # "`seed` cannot be honoured: _Drift draws from env._rng (...), which DmEnvToGym cannot re-seed" before
    first, _ = env.reset(seed=3)
    other, _ = env.reset(seed=4)
    env.reset()  # an unseeded reset draws on from where the stream is
    again, _ = env.reset(seed=3)
    assert first.tobytes() == again.tobytes() != other.tobytes()
    assert env.dm_env._rng is rng  # the user's own generator, re-seeded in place, not replaced
    twin, _ = DmEnvToGym(Noisy(make_rng(99))).reset(seed=3)  # whatever it was built with
    assert twin.tobytes() == first.tobytes()
    check_env(env, skip_render_check=True)


def test_two_generators_of_one_env_get_different_streams_and_a_shared_one_is_seeded_once() -> None:
    class Two(_Drift):
        def reset(self) -> dm_env.TimeStep:
            self.x = np.array([self._rng.normal(), self._other.normal()])
            self.t = 0
            return dm_env.restart(self.x.copy())

    inner = Two(np.random.default_rng(0))
    inner._other = np.random.default_rng(0)
    obs, _ = DmEnvToGym(inner).reset(seed=5)
    assert obs[0] != obs[1]  # each from the seed and its own attribute path
    shared = Two(np.random.default_rng(0))
    shared._other = shared._rng  # one generator under two names: re-seeded once, drawn twice
    obs, _ = DmEnvToGym(shared).reset(seed=5)
    expected = np.random.Generator(
        np.random.PCG64(np.random.SeedSequence(5, spawn_key=(zlib.crc32(b"env._rng"),)))
    ).normal(size=2)
    assert obs.tolist() == expected.astype(np.float32).tolist()  # (DmEnvToGym observations are float32)


def test_a_dm_env_exposing_random_state_is_reseeded_in_place() -> None:
    inner = _Drift(np.random.RandomState(0))
    inner.random_state = inner._rng  # the name composer envs use
    env = DmEnvToGym(inner)
    first, _ = env.reset(seed=7)
    env.reset()
    again, _ = env.reset(seed=7)
    assert first.tobytes() == again.tobytes() and np.abs(first).sum() > 0


def test_a_dm_control_suite_env_is_still_reseeded_and_passes_check_env() -> None:
    from dm_control import suite

    env = DmEnvToGym(suite.load("reacher", "easy"))
    first, _ = env.reset(seed=11)
    other, _ = env.reset(seed=12)
    again, _ = env.reset(seed=11)
    assert first.tobytes() == again.tobytes() and first.tobytes() != other.tobytes()
    check_env(env, skip_render_check=True)


@pytest.mark.parametrize(
    ("task_id", "options"),
    [
        ("dmc/reacher-easy", {}),
        ("dmc/manipulator-bring_ball", {"time_limit": 2.0, "flatten": False, "textures": False}),
        ("sim2real/arm-reach", {"max_episode_steps": 20}),
    ],
)
def test_a_task_env_has_a_spec_that_gymnasium_make_recreates(task_id: str, options: dict[str, Any]) -> None:
    import gymnasium as gym

    import sim2real as s2r

    env: Any = s2r.make(task_id, **options)
    assert env.spec is not None  # None before: gym.make(env.spec) raised
    assert env.spec.id == task_id and env.spec.entry_point == "sim2real.tasks:make"
    assert env.spec.kwargs == {"task_id": task_id, **options}
    twin = gym.make(env.spec)
    assert type(twin) is type(env) and twin.spec == env.spec  # no checker/order/time-limit layers added
    first, _ = env.reset(seed=5)
    again, _ = twin.reset(seed=5)
    flat = (lambda o: np.concatenate([np.ravel(v) for v in o.values()])) if isinstance(first, dict) else np.ravel
    assert flat(first).tobytes() == flat(again).tobytes()
    action = np.full(env.action_space.shape or (), 0.3, np.float32)
    assert flat(env.step(action)[0]).tobytes() == flat(twin.step(action)[0]).tobytes()


def test_a_calibrated_task_spec_recreates_the_calibration() -> None:
    import gymnasium as gym

    import sim2real as s2r

    env: Any = s2r.make("dmc/reacher-easy", params={"body_mass[arm]": 0.5})
    twin: Any = gym.make(env.spec)
    assert env.spec is not None and env.spec.kwargs["params"] == {"body_mass[arm]": 0.5}
    arm = twin.unwrapped.physics.model.body("arm").id
    assert twin.unwrapped.physics.model.body_mass[arm] == 0.5 == env.unwrapped.physics.model.body_mass[arm]


def test_gymnasium_make_of_a_wrapped_task_spec_recreates_the_wrapper_stack() -> None:
    import gymnasium as gym

    import sim2real as s2r
    from noise_models import Gaussian, ObservationLatency, ObservationNoise
    from randomizers import Friction, Mass, Uniform

    base = s2r.make("dmc/reacher-easy", time_limit=1.0)
    physics = s2r.wrap(base, Mass(scale=Uniform(0.5, 1.5)), seed=4)
    env = s2r.wrap(physics, ObservationNoise(Gaussian(std=0.01)), ObservationLatency(steps=2), seed=9)
    fused = s2r.wrap(
        s2r.make("dmc/reacher-easy"), Friction(scale=Uniform(0.5, 1.5)), ObservationLatency(steps=1), seed=2
    )
    for original in (env, fused):
        twin = gym.make(original.spec)
        assert [type(e) for e in _layers(twin)] == [type(e) for e in _layers(original)]
        first, info = original.reset(seed=3)
        again, twin_info = twin.reset(seed=3)
        assert first.tobytes() == again.tobytes()
        assert info["sim2real"]["params"] == twin_info["sim2real"]["params"]
        for _ in range(3):
            action = original.action_space.sample()
            assert original.step(action)[0].tobytes() == twin.step(action)[0].tobytes()
    vec = gym.make_vec(env.spec, num_envs=2, vectorization_mode="sync")  # rebuilds its sub-envs from the spec
    obs, _ = vec.reset(seed=3)
    assert obs.shape == (2, 6)


def _layers(env: Any) -> list[Any]:
    out = [env]
    while hasattr(out[-1], "env"):
        out.append(out[-1].env)
    return out


@pytest.mark.render
def test_a_pixel_task_spec_recreates_the_pixel_env_and_its_wrappers() -> None:
    import gymnasium as gym

    import sim2real as s2r
    from randomizers import Mass, Uniform

    env = s2r.wrap(s2r.make("dmc/reacher-easy", pixels=True, size=(24, 32)), Mass(scale=Uniform(0.5, 1.5)), seed=1)
    twin = gym.make(env.spec)
    assert [type(e).__name__ for e in _layers(twin)] == ["RandomizePhysics", "PixelObservation", "DmEnvToGym"]
    first, _ = env.reset(seed=3)
    again, _ = twin.reset(seed=3)
    assert first.shape == (24, 32, 3) and first.tobytes() == again.tobytes()
    env.close()
    twin.close()


def test_a_calibrated_gymnasium_task_keeps_its_spec_and_the_calibration() -> None:
    import gymnasium as gym

    import sim2real as s2r

    env: Any = s2r.make("gym/Reacher-v5", params={"body_mass[body0]": 0.5})
    assert env.spec is not None and env.spec.id == "Reacher-v5" and env.spec.max_episode_steps == 50
    twin: Any = gym.make(env.spec)  # an uncalibrated Reacher before: gymnasium's spec does not know the params
    assert [type(e).__name__ for e in _layers(twin)] == [type(e).__name__ for e in _layers(env)]
    body = twin.unwrapped.model.body("body0").id
    assert twin.unwrapped.model.body_mass[body] == 0.5 == env.unwrapped.model.body_mass[body]
    assert twin.spec == env.spec
    assert (
        getattr(s2r.make("gym/Reacher-v5").spec, "entry_point", None) == "gymnasium.envs.mujoco.reacher_v5:ReacherEnv"
    )


ARM_XML = """<mujoco><option timestep="0.005"/><worldbody><body name="upper">
<joint name="shoulder" axis="0 1 0" range="-1.5 1.5" damping="0.3"/>
<geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="1"/></body></worldbody>
<actuator><motor joint="shoulder" ctrlrange="-1 1"/></actuator></mujoco>"""

FACTORIES = """
from dm_control import suite


def dm_reacher():
    return suite.load("reacher", "easy")
"""


def test_user_models_and_factories_get_a_spec_that_recreates_them(tmp_path: Any, monkeypatch: Any) -> None:
    import gymnasium as gym

    import sim2real as s2r
    from randomizers import Damping, Uniform

    path = tmp_path / "my arm-v2.xml"
    path.write_text(ARM_XML)
    (tmp_path / "loose_end_factories.py").write_text(FACTORIES)
    monkeypatch.syspath_prepend(str(tmp_path))
    cases: list[tuple[str, dict[str, Any], str]] = [
        (f"model:{path}", {}, "sim2real/model-my_arm_v2"),
        ("env:loose_end_factories:dm_reacher", {}, "sim2real/env-dm_reacher"),
    ]
    for task_id, options, spec_id in cases:
        env: Any = s2r.wrap(s2r.make(task_id, **options), Damping(scale=Uniform(0.5, 2.0)), seed=1)
        assert env.spec is not None and env.spec.id == spec_id  # None before: gym.make(env.spec) raised
        twin: Any = gym.make(env.spec)
        assert type(twin.unwrapped) is type(env.unwrapped)
        first, info = env.reset(seed=2)
        again, twin_info = twin.reset(seed=2)
        assert first.tobytes() == again.tobytes() and info["sim2real"] == twin_info["sim2real"]
        action = np.full(env.action_space.shape or (), 0.2, np.float32)
        assert env.step(action)[0].tobytes() == twin.step(action)[0].tobytes()


class _Repeat(dm_env.Environment):
    """A user's dm_env wrapper that does not forward ``task`` (action repeat 2), optionally with its own rng."""

    def __init__(self, env: dm_env.Environment, rng: Any = None) -> None:
        self._env = env
        if rng is not None:
            self._rng = rng

    def reset(self) -> dm_env.TimeStep:
        return self._env.reset()

    def step(self, action: Any) -> dm_env.TimeStep:
        self._env.step(action)
        return self._env.step(action)

    def observation_spec(self) -> Any:
        return self._env.observation_spec()

    def action_spec(self) -> Any:
        return self._env.action_spec()


def test_a_suite_env_inside_a_users_dm_env_wrapper_is_reseeded() -> None:
    from dm_control import suite

    env = DmEnvToGym(_Repeat(suite.load("reacher", "easy")))
    first, _ = env.reset(seed=11)  # refused before: env._env._task._random was taken for randomness out of reach
    other, _ = env.reset(seed=12)
    again, _ = env.reset(seed=11)
    assert first.tobytes() == again.tobytes() and first.tobytes() != other.tobytes()
    # The wrapper's own generator is re-seeded too (refused before: "draws from env._rng (numpy.random.Generator),
    # which DmEnvToGym cannot re-seed"); the task's RandomState is seeded as without it.
    noisy = DmEnvToGym(_Repeat(suite.load("reacher", "easy"), np.random.default_rng(0)))
    obs, _ = noisy.reset(seed=11)
    draw = noisy.dm_env._rng.normal()
    noisy.reset(seed=12)
    assert noisy.dm_env._rng.normal() != draw
    again, _ = noisy.reset(seed=11)
    assert noisy.dm_env._rng.normal() == draw and obs.tobytes() == again.tobytes() == first.tobytes()


def test_a_relative_model_path_in_a_spec_rebuilds_the_same_file_from_another_folder(
    tmp_path: Any, monkeypatch: Any
) -> None:
    """``make("model:arm.xml")`` kept the relative path in its spec: ``gym.make(spec)`` from another working folder
    built whatever ``arm.xml`` was there (here a twin with another damping), silently, or failed."""
    import gymnasium as gym

    import sim2real as s2r

    ours, elsewhere = tmp_path / "ours", tmp_path / "elsewhere"
    ours.mkdir(), elsewhere.mkdir()
    (ours / "arm.xml").write_text(ARM_XML)
    (elsewhere / "arm.xml").write_text(ARM_XML.replace('damping="0.3"', 'damping="9.0"'))
    monkeypatch.chdir(ours)
    env: Any = s2r.make("model:arm.xml")
    assert env.spec.id == "sim2real/model-arm"
    (key,) = env.spec.kwargs
    assert key == "task_id" and Path(env.spec.kwargs[key].removeprefix("model:")).samefile(ours / "arm.xml")
    monkeypatch.chdir(elsewhere)
    twin: Any = gym.make(env.spec)
    assert twin.unwrapped.model.dof_damping[0] == 0.3 == env.unwrapped.model.dof_damping[0]
