"""Signal models inside environments: latency exactness at physics rate on probe envs, resets, the
shared contract (single, composed, vector, seed twin, bitwise) and each API's own checker."""

from __future__ import annotations

from typing import Any

import dm_env
import gymnasium as gym
import mujoco
import numpy as np
import pytest
from dm_env import specs

import sim2real as s2r
from noise_models import (
    BLOCK,
    ActionLatency,
    ActionNoise,
    Bias,
    ControlJitter,
    Drift,
    Dropout,
    Gaussian,
    ObservationLatency,
    ObservationNoise,
    Outlier,
    Quantize,
    SampleAndHold,
    Saturate,
    Scale,
    Sticky,
    Stuck,
    UniformNoise,
    stream,
)
from randomizers import Choice, Uniform

PROBE_XML = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody><body><joint name="slide" type="slide"/><geom size="0.1" mass="1"/></body></worldbody>
  <actuator><motor joint="slide" ctrlrange="-1000 1000"/></actuator>
</mujoco>
"""


class ProbeEnv(gym.Env):
    """Observes its physics step index; logs the ctrl applied at every physics step."""

    def __init__(self, substeps: int = 4) -> None:
        self.model = mujoco.MjModel.from_xml_string(PROBE_XML)
        self.data = mujoco.MjData(self.model)
        self.n_substeps = substeps
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float64)
        self.action_space = gym.spaces.Box(-1000.0, 1000.0, (1,), np.float64)
        self.applied: list[float] = []

    def _index(self) -> np.ndarray:
        return np.array([round(self.data.time / self.model.opt.timestep)], dtype=np.float64)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self.applied = []
        return self._index(), {}

    def _simulate(self, nstep: int) -> None:
        for _ in range(nstep):
            self.applied.append(float(self.data.ctrl[0]))
            mujoco.mj_step(self.model, self.data)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.data.ctrl[0] = float(np.asarray(action)[0])
        self._simulate(self.n_substeps)
        return self._index(), 0.0, False, False, {}


class CountingEnv(gym.Env):
    """No MuJoCo: observes the control step index and echoes the last action it got."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.action_space = gym.spaces.Box(-1000.0, 1000.0, (1,), np.float64)
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        self.t = 0
        return np.array([0.0, 0.0]), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.t += 1
        return np.array([float(self.t), float(np.asarray(action)[0])]), 0.0, False, False, {}


# -- latency exactness ----------------------------------------------------------------------------


@pytest.mark.parametrize("k", [0, 1, 3, 4, 6, 9])
def test_action_applied_exactly_k_physics_steps_late(k: int) -> None:
    env = s2r.wrap(ProbeEnv(substeps=4), ActionLatency(steps=k), seed=0)
    env.reset(seed=0)
    for t in range(12):
        env.step(np.array([t + 1.0]))  # command t + 1 sent at physics step 4t
    applied = env.unwrapped.applied
    expected = [max((t + 1 for t in range(12) if 4 * t + k <= s), default=0.0) for s in range(48)]
    assert applied == expected


def test_action_latency_in_seconds_and_reported() -> None:
    env = s2r.wrap(ProbeEnv(substeps=4), ActionLatency(seconds=0.05), seed=0)
    _, info = env.reset(seed=0)
    assert info["sim2real"]["params"]["action_latency_steps"] == 5
    assert info["sim2real"]["params"]["action_latency"] == pytest.approx(0.05)
    for t in range(3):
        env.step(np.array([t + 1.0]))
    assert env.unwrapped.applied == [0.0] * 5 + [1.0] * 4 + [2.0] * 3


@pytest.mark.parametrize(("k", "substeps"), [(0, 1), (3, 1), (5, 1), (4, 4), (8, 4), (3, 4), (6, 4)])
def test_observation_delayed_by_k_physics_steps(k: int, substeps: int) -> None:
    env = s2r.wrap(ProbeEnv(substeps=substeps), ObservationLatency(steps=k), seed=0)
    obs, _ = env.reset(seed=0)
    seen = [obs[0]] + [env.step(np.zeros(1))[0][0] for _ in range(10)]
    now = substeps * np.arange(11)
    # Samples exist at control boundaries: the newest one measured at or before now - k.
    expected = np.maximum(substeps * np.floor((now - k) / substeps), 0)
    assert np.array_equal(seen, expected)
    if k % substeps == 0:
        assert np.array_equal(seen, np.maximum(now - k, 0))


def test_without_mujoco_time_counts_control_steps() -> None:
    env = s2r.wrap(CountingEnv(), ObservationLatency(steps=2), ActionLatency(steps=3), seed=0)
    env.reset(seed=0)
    seen = [env.step(np.array([10.0 + t]))[0] for t in range(8)]
    assert [o[0] for o in seen] == [0, 0, 1, 2, 3, 4, 5, 6]  # step index delayed by 2
    # The action echoed at step t (observed 2 steps later) is the one sent 3 steps earlier (0 before).
    assert [o[1] for o in seen] == [0, 0, 0, 0, 0, 10, 11, 12]


def test_seconds_without_a_timestep_is_rejected() -> None:
    with pytest.raises(ValueError) as info:
        s2r.wrap(CountingEnv(), ObservationLatency(seconds=0.1), seed=0)
    assert str(info.value) == (
        "ObservationLatency(seconds=...) needs the environment's timestep to count steps, and this environment "
        "exposes none (no MuJoCo model, no `dt`/`control_timestep`); give `steps=` instead."
    )


def test_control_jitter_varies_substeps_and_keeps_latency_exact() -> None:
    env = s2r.wrap(ProbeEnv(substeps=4), ControlJitter(delta=Choice((-1, 0, 1))), ActionLatency(steps=2), seed=0)
    env.reset(seed=0)
    boundaries = [0]
    for t in range(40):
        env.step(np.array([t + 1.0]))
        boundaries.append(len(env.unwrapped.applied))
    lengths = np.diff(boundaries)
    assert set(lengths.tolist()) == {3, 4, 5}
    applied = env.unwrapped.applied
    expected = [max((t + 1 for t in range(40) if boundaries[t] + 2 <= s), default=0.0) for s in range(len(applied))]
    assert applied == expected


_SERVO_XML = """
<mujoco><option timestep="0.002"/>
  <worldbody><body><joint name="j" type="hinge" axis="0 0 1"/><geom type="capsule" size="0.02" fromto="0 0 0 0.2 0 0"/>
  </body></worldbody>
  <actuator><position name="s" joint="j" kp="5" ctrlrange="-1 1"/></actuator>
</mujoco>
"""


class _PeriodDmEnv(dm_env.Environment):  # type: ignore[misc]
    """A dm_env written by hand around mujoco that says its control period only by ``control_timestep()`` (5 physics
    steps of 2 ms, stepped through ``_simulate``): no frame_skip, n_substeps or _n_sub_steps attribute."""

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(_SERVO_XML)
        self.data = mujoco.MjData(self.model)
        self.commands: list[float] = []  # data.ctrl at every physics step

    def reset(self) -> Any:
        mujoco.mj_resetData(self.model, self.data)
        return dm_env.restart({"q": self.data.qpos.copy()})

    def step(self, action: Any) -> Any:
        self.data.ctrl[:] = action
        self._simulate(5)
        return dm_env.transition(0.0, {"q": self.data.qpos.copy()})

    def _simulate(self, nstep: int) -> None:
        for _ in range(nstep):
            self.commands.append(float(self.data.ctrl[0]))
            mujoco.mj_step(self.model, self.data)

    def control_timestep(self) -> float:
        return 0.01

    def observation_spec(self) -> Any:
        return {"q": specs.Array((1,), np.float64, "q")}

    def action_spec(self) -> Any:
        return specs.BoundedArray((1,), np.float64, -1.0, 1.0, "action")


def test_an_env_that_declares_its_period_by_control_timestep_gets_the_latency_it_reports() -> None:
    # 13 ms on a 2 ms timestep is 7 physics steps (reported 14 ms); the env's 5 physics steps per control step are
    # found from its control_timestep(), so the command of control step 0 reaches ctrl at physics step 7, in
    # control step 1. (The clock took 1 physics step per control step: the command came 7 control steps late.)
    from sim2real.physics import find_physics

    inner = _PeriodDmEnv()
    assert find_physics(inner).substeps == 5  # type: ignore[union-attr]
    env = s2r.wrap(inner, ActionLatency(seconds=0.013), seed=0)
    env.reset()
    assert (env.current_params["action_latency_steps"], env.current_params["action_latency"]) == (7, 0.014)
    for k in range(3):
        env.step(np.array([0.1 * (k + 1)]))
    assert inner.commands == [0.0] * 7 + [0.1] * 5 + [0.2] * 3
    env.close()


class _MixedDtypeDmEnv(_PeriodDmEnv):
    """Observation keys of three dtypes: float64 ``q``, an int32 scalar ``count``, float32 ``f32``."""

    def _observation(self) -> Any:
        return {
            "q": self.data.qpos.copy(),
            "count": np.int32(len(self.commands)),
            "f32": np.array([self.data.qvel[0], 0.5], dtype=np.float32),
        }

    def reset(self) -> Any:
        mujoco.mj_resetData(self.model, self.data)
        return dm_env.restart(self._observation())

    def step(self, action: Any) -> Any:
        self.data.ctrl[:] = action
        self._simulate(5)
        return dm_env.transition(0.0, self._observation())

    def observation_spec(self) -> Any:
        return {
            "q": specs.Array((1,), np.float64, "q"),
            "count": specs.Array((), np.int32, "count"),
            "f32": specs.Array((2,), np.float32, "f32"),
        }


@pytest.mark.parametrize("physics", [False, True])
def test_dm_env_observation_keys_keep_their_spec_dtype(physics: bool) -> None:
    # The models work on one float64 vector; each key leaves with its spec's dtype (an int32 counter no model
    # selects stays int32, exactly; a float32 key stays float32), and an integer key that noise selects becomes
    # float64, as the wrapper's observation_spec then says. (Every key came back float64 and failed its spec.)
    effects = (s2r.Damping(scale=Uniform(0.5, 2.0)),) if physics else ()
    models = (ObservationNoise(Gaussian(std=0.1), select="q"), ObservationLatency(steps=1))
    env = s2r.wrap(_MixedDtypeDmEnv(), *effects, *models, seed=0)
    spec = env.observation_spec()
    assert {k: v.dtype for k, v in spec.items()} == {"q": np.float64, "count": np.int32, "f32": np.float32}
    timesteps = [env.reset()] + [env.step(np.array([0.2])) for _ in range(3)]
    for ts in timesteps:
        for k, v in ts.observation.items():
            spec[k].validate(v)
    assert [int(ts.observation["count"]) for ts in timesteps] == [0, 0, 5, 10]  # one step late, exact
    env.close()
    noisy = s2r.wrap(_MixedDtypeDmEnv(), *effects, ObservationNoise(Gaussian(std=0.1), select="count"), seed=0)
    assert noisy.observation_spec()["count"].dtype == np.float64
    count = noisy.step(np.array([0.2])).observation["count"]  # (the first step resets)
    assert count.dtype == np.float64 and count != 0.0
    noisy.close()


def test_composer_env_latency_per_substep() -> None:
    # Composer steps physics one substep at a time, and recompiles on reset: the command must still
    # arrive exactly two control steps late, episode after episode.
    twin = s2r.make("dmc/jaco-reach_site")
    n = s2r.find_physics(twin).substeps
    env = s2r.wrap(s2r.make("dmc/jaco-reach_site"), ActionLatency(steps=2 * n), seed=0)
    rng = np.random.default_rng(0)
    for episode in range(2):
        twin.reset(seed=episode)
        _, info = env.reset(seed=episode)
        assert info["sim2real"]["params"]["action_latency_steps"] == 2 * n
        initial = np.array(s2r.find_physics(env).data.ctrl)
        sent, applied = [], []
        for _ in range(4):
            action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            twin.step(action)
            sent.append(np.array(s2r.find_physics(twin).data.ctrl))
            env.step(action)
            applied.append(np.array(s2r.find_physics(env).data.ctrl))
        assert np.array_equal(applied[0], initial) and np.array_equal(applied[1], initial)
        assert np.array_equal(applied[2], sent[0]) and np.array_equal(applied[3], sent[1])
    env.close()


def test_reset_clears_buffers_on_an_env() -> None:
    env = s2r.wrap(ProbeEnv(substeps=2), ObservationLatency(steps=6), ActionLatency(steps=5), seed=0)
    env.reset(seed=0)
    for t in range(20):
        env.step(np.array([50.0 + t]))
    obs, _ = env.reset()
    assert obs.tolist() == [0.0]
    assert env.step(np.array([1.0]))[0].tolist() == [0.0]  # nothing from the last episode arrives
    assert env.unwrapped.applied == [0.0, 0.0]  # the reset command, not a stale one


# -- the shared contract over every model ------------------------------------------------------------

TASK = "sim2real/arm-reach"
MODELS: dict[str, Any] = {
    "Gaussian": ObservationNoise(Gaussian(std=Uniform(0.001, 0.01))),
    "UniformNoise": ObservationNoise(UniformNoise(half_width=0.01)),
    "Bias": ObservationNoise(Bias(Uniform(-0.02, 0.02))),
    "Drift": ObservationNoise(Drift(std=0.001, timescale=Uniform(10, 50))),
    "Quantize": ObservationNoise(Quantize(Uniform(0.001, 0.01))),
    "Dropout": ObservationNoise(Dropout(Uniform(0.0, 0.2))),
    "Stuck": ObservationNoise(Stuck(0.01, Uniform(2, 8))),
    "Outlier": ObservationNoise(Outlier(Uniform(0.0, 0.05), Uniform(0.1, 0.5))),
    "Saturate": ObservationNoise(Saturate(-1.0, Uniform(0.5, 1.0))),
    "Scale": ObservationNoise(Scale(Uniform(0.9, 1.1))),
    "ActionNoise": ActionNoise(Gaussian(std=Uniform(0.0, 0.01)), Sticky(Uniform(0.0, 0.2))),
    "ObservationLatency": ObservationLatency(steps=Choice((0, 5, 10, 20)), jitter=Uniform(0, 5)),
    "ActionLatency": ActionLatency(seconds=Uniform(0.0, 0.05)),
    "SampleAndHold": SampleAndHold(steps=Uniform(10, 40)),
    "ControlJitter": ControlJitter(delta=Choice((-2, 0, 2))),
}
IDS = list(MODELS)


def rollout(env: gym.Env, steps: int = 30, seed: int = 0) -> tuple[np.ndarray, dict[str, float]]:
    obs, info = env.reset(seed=seed)
    params = info["sim2real"]["params"]
    rng = np.random.default_rng(123)
    out = [obs]
    for _ in range(steps):
        obs, _, _term, _trunc, info = env.step(rng.uniform(-0.05, 0.05, 3))
        assert info["sim2real"]["params"] == params
        out.append(obs)
    return np.array(out), params


@pytest.mark.parametrize("name", IDS)
def test_single_env_reports_and_bitwise_determinism(name: str) -> None:
    a, pa = rollout(s2r.wrap(s2r.make(TASK), MODELS[name], seed=0))
    b, pb = rollout(s2r.wrap(s2r.make(TASK), MODELS[name], seed=0))
    c, pc = rollout(s2r.wrap(s2r.make(TASK), MODELS[name], seed=1))
    assert pa == pb and a.tobytes() == b.tobytes()
    assert pa and all(isinstance(v, (int, float)) for v in pa.values())
    assert a.tobytes() != c.tobytes() or pa != pc or name in ("Saturate",)


def test_seed_twin_on_an_env() -> None:
    std = Uniform(0.001, 0.01)
    env = s2r.wrap(s2r.make(TASK), ObservationNoise(Gaussian(std=std)), seed=4)
    raw = s2r.make(TASK)
    for episode, reset_seed in enumerate((None, None)):
        obs, info = env.reset(seed=reset_seed) if episode else env.reset(seed=9)
        clean, _ = raw.reset(seed=9) if episode == 0 else (None, None)
        root = (4, 0x5EED5EED, 9)
        draws = std.sample(stream(root, "obs_noise", episode, 0), 16)
        assert [info["sim2real"]["params"][f"obs_noise_std[{i}]"] for i in range(16)] == draws.tolist()
        if episode == 0:
            noise = (stream(root, "obs_noise", 0, 1).standard_normal((BLOCK, 16)) * draws)[0]
            assert np.array_equal(obs, clean + noise.astype(obs.dtype))


def test_composed_models_and_physics_do_not_shift_each_other() -> None:
    alone = s2r.wrap(s2r.make(TASK), MODELS["Gaussian"], seed=0)
    both = s2r.wrap(
        s2r.make(TASK),
        s2r.Damping(scale=Uniform(0.5, 2.0)),
        MODELS["Bias"],
        MODELS["Gaussian"],
        MODELS["ActionLatency"],
        seed=0,
    )
    _, ia = alone.reset(seed=3)
    _, ib = both.reset(seed=3)
    pa, pb = ia["sim2real"]["params"], ib["sim2real"]["params"]
    assert all(pb[k] == v for k, v in pa.items())
    assert any(k.startswith("dof_damping") for k in pb) and any(k.startswith("obs_bias") for k in pb)


def test_vector_env_independent_and_reproducible() -> None:
    models = [MODELS["Gaussian"], MODELS["ObservationLatency"]]
    envs = s2r.make_vec(TASK, 3, *models, seed=0)
    _, info = envs.reset()
    stds = info["sim2real"]["params"]["obs_noise_std[0]"]
    assert len(set(stds.tolist())) == 3
    again = s2r.make_vec(TASK, 3, *models, seed=0)
    _, info2 = again.reset()
    assert (info2["sim2real"]["params"]["obs_noise_std[0]"] == stds).all()
    envs.close()
    again.close()


def test_declared_spaces_stay_truthful() -> None:
    env = s2r.wrap(s2r.make(TASK), ObservationNoise(Gaussian(std=10.0)), ActionNoise(Gaussian(std=1.0)), seed=0)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    for _ in range(20):
        obs, *_ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)


def test_key_selection_on_flattened_dm_control_observations() -> None:
    env = s2r.wrap(s2r.make("dmc/reacher-easy"), ObservationNoise(Gaussian(std=1.0), select="velocity"), seed=0)
    raw = s2r.make("dmc/reacher-easy")
    obs, info = env.reset(seed=2)
    clean, _ = raw.reset(seed=2)
    assert sorted(info["sim2real"]["params"]) == ["obs_noise_std[velocity]"]
    assert np.array_equal(obs[:4], clean[:4]) and not np.array_equal(obs[4:], clean[4:])


# -- each API's own checker ------------------------------------------------------------------------


ALL = [
    MODELS[n]
    for n in (
        "Gaussian",
        "Bias",
        "Dropout",
        "ActionNoise",
        "ObservationLatency",
        "ActionLatency",
        "SampleAndHold",
        "ControlJitter",
    )
]


def test_gymnasium_check_env_full_stack() -> None:
    from gymnasium.utils.env_checker import check_env

    check_env(s2r.wrap(s2r.make(TASK), s2r.Friction(scale=Uniform(0.5, 1.5)), *ALL, seed=0), skip_render_check=True)
    check_env(s2r.wrap(s2r.make("dmc/reacher-easy", flatten=False), *ALL, seed=0), skip_render_check=True)


def test_torchrl_check_env_specs_full_stack() -> None:
    from torchrl.envs import DMControlEnv, GymWrapper
    from torchrl.envs.utils import check_env_specs

    env = s2r.wrap(GymWrapper(s2r.make(TASK)), s2r.Damping(scale=Uniform(0.5, 2.0)), *ALL, seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(5)
    names = env.transform.signal_param_names  # one fused transform since issue 15 (was the Compose's second)
    assert td["sim2real_signal_params"].shape == (5, len(names)) and "action_latency_steps" in names
    env = s2r.wrap(DMControlEnv("reacher", "easy"), *ALL, seed=0)
    check_env_specs(env, seed=0)


def _dm_env_tests() -> type:
    import unittest

    from dm_control import suite
    from dm_env import test_utils

    class CorruptedReacherTest(test_utils.EnvironmentTestMixin, unittest.TestCase):
        def make_object_under_test(self):  # type: ignore[no-untyped-def]
            return s2r.wrap(suite.load("reacher", "easy"), s2r.Damping(scale=Uniform(0.5, 2.0)), *ALL, seed=0)

    return CorruptedReacherTest


TestDmEnvSignalsContract = _dm_env_tests()


def test_dm_env_reports_key_names_and_closes_cleanly() -> None:
    from dm_control import suite

    env = s2r.wrap(
        suite.load("reacher", "easy"),
        ObservationNoise(Gaussian(std=Uniform(0, 1)), select="position"),
        ActionLatency(steps=2),
        seed=0,
    )
    env.reset()
    assert sorted(env.current_params) == [
        "action_latency",
        "action_latency_steps",
        "obs_noise_std[position][0]",
        "obs_noise_std[position][1]",
    ]
    physics = env.physics
    env.step(np.zeros(2))
    env.close()
    assert "step" not in vars(physics)  # the physics-step interception is removed


def test_mid_step_latency_on_dm_control_costs_no_extra_pass_and_is_exact() -> None:
    # manipulator runs 10 substeps per control step; 5 steps of latency splits every control step.
    from sim2real.physics import _DmRunner

    def trajectory(fast: bool) -> np.ndarray:
        env = s2r.wrap(s2r.make("dmc/manipulator-bring_ball"), ActionLatency(steps=5), seed=0)
        env.reset(seed=0)
        original = _DmRunner.__init__

        def init(self, physics, step):  # type: ignore[no-untyped-def]
            original(self, physics, step)
            self.fast = self.fast and fast

        _DmRunner.__init__ = init  # type: ignore[method-assign]
        try:
            env.clock._remove()
            env.clock._remove = env.clock.handle.intercept_step(env.clock._stepper)
        finally:
            _DmRunner.__init__ = original  # type: ignore[method-assign]
        rng = np.random.default_rng(0)
        states = []
        for _ in range(20):
            env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
            data = env.clock.handle.data
            states.append(np.concatenate([data.qpos, data.qvel]))
        env.close()
        return np.array(states)

    fast, plain = trajectory(True), trajectory(False)
    assert fast.tobytes() == plain.tobytes()


def test_dm_env_current_params_include_the_physics_draws() -> None:
    from dm_control import suite

    import sim2real as s2r

    env = s2r.wrap(
        suite.load("reacher", "easy"), s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), s2r.ObservationLatency(steps=2), seed=0
    )
    env.reset()
    params = env.current_params
    assert params["obs_latency_steps"] == 2
    assert 0.005 <= params["dof_damping[shoulder]"] <= 0.02
