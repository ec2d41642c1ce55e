"""Envs written the way other people write them (wrap environments nobody here designed): envs without actuators,
a user's MujocoEnv subclass, envs that step MuJoCo themselves, rebuild their model in reset or reuse their observation
array, copies of wrapped envs. TorchRL's own shapes are in tests/test_foreign_torchrl.py."""

from __future__ import annotations

from typing import Any

import dm_env
import dm_env.specs
import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real as s2r
from noise_models import ActionLatency, ActionNoise, Bias, ControlJitter, Gaussian, ObservationLatency, ObservationNoise
from randomizers import Choice, Uniform

ARM_XML = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="link1"><joint name="j1" type="hinge" axis="0 0 1" damping="0.2"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.3"/>
      <body name="link2" pos="0.2 0 0"><joint name="j2" type="hinge" axis="0 0 1" damping="0.1"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.2"/></body></body>
  </worldbody>
  <actuator><motor name="m1" joint="j1"/><motor name="m2" joint="j2"/></actuator>
</mujoco>
"""


# -- envs without actuators --------------------------------------------------------------------------------------

BALL_XML = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 .1"/>
    <body name="ball" pos="0 0 1"><freejoint/><geom name="b" size="0.1" mass="1"/></body>
  </worldbody>
</mujoco>
"""


class DroppedBall(gym.Env):
    """A passive model (``nu = 0``): its action space is an empty Box, as gymnasium envs declare one."""

    frame_skip = 5

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(BALL_XML)
        self.data = mujoco.MjData(self.model)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (13,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (0,), np.float64)

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.data.qpos, self.data.qvel])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def _simulate(self, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self._simulate(self.frame_skip)
        return self._obs(), 0.0, False, False, {}


EMPTY_ACTION = (
    "{} need a non-empty action: this env's action has no entries, so nothing would be corrupted or delayed. "
    "Received an action of size 0."
)


@pytest.mark.parametrize(
    ("models", "names"),
    [
        ((ActionNoise(Gaussian(std=0.1)),), "ActionNoise"),  # an IndexError at the first reset before
        ((ActionLatency(steps=3),), "ActionLatency"),  # reported a latency of 0.03 s that delayed nothing
        ((ActionLatency(steps=3), ActionNoise(Gaussian(std=0.1))), "ActionLatency and ActionNoise"),
    ],
    ids=["noise", "latency", "both"],
)
@pytest.mark.parametrize("physics", [False, True], ids=["signals", "fused"])
def test_action_models_refuse_an_env_without_actuators(models: tuple[Any, ...], names: str, physics: bool) -> None:
    effects = (s2r.Mass(scale=1.0),) if physics else ()
    with pytest.raises(ValueError) as err:
        s2r.wrap(DroppedBall(), *effects, *models, seed=0)
    assert str(err.value) == EMPTY_ACTION.format(names)


class DroppedBallDm(dm_env.Environment):
    """The same ball as a plain ``dm_env.Environment`` with an empty action spec."""

    def __init__(self) -> None:
        self.gym = DroppedBall()

    def reset(self) -> dm_env.TimeStep:
        return dm_env.restart(self.gym.reset()[0])

    def step(self, action: Any) -> dm_env.TimeStep:
        return dm_env.transition(0.0, self.gym.step(action)[0])

    def observation_spec(self) -> Any:
        return dm_env.specs.Array((13,), np.float64, "state")

    def action_spec(self) -> Any:
        return dm_env.specs.BoundedArray((0,), np.float64, -1.0, 1.0, "action")


def test_action_models_refuse_an_empty_action_on_dm_env_and_torchrl() -> None:
    from torchrl.envs import GymWrapper

    with pytest.raises(ValueError) as err:
        s2r.wrap(DroppedBallDm(), ActionLatency(steps=3), seed=0)
    assert str(err.value) == EMPTY_ACTION.format("ActionLatency")
    with pytest.raises(ValueError) as err:
        s2r.wrap(GymWrapper(DroppedBall()), ActionNoise(Gaussian(std=0.1)), seed=0)
    assert str(err.value) == EMPTY_ACTION.format("ActionNoise")


def test_an_env_without_actuators_still_takes_physics_effects_and_observation_models() -> None:
    from gymnasium.utils.env_checker import check_env

    env = s2r.wrap(DroppedBall(), s2r.Mass(scale=2.0), ObservationNoise(Gaussian(std=0.01)), seed=0)
    _, info = env.reset(seed=0)
    assert info["sim2real"]["params"]["body_mass[ball]"] == 2.0
    check_env(env, skip_render_check=True)
    env.close()


# -- a user's MujocoEnv subclass ----------------------------------------------------------------------------------


def _user_mujoco_env(xml_path: str, frame_skip: int, mocap: bool = False) -> Any:
    """A user's ``MujocoEnv`` subclass with its own XML and ``frame_skip``; with ``mocap`` its action moves a mocap
    target (the model has no actuators)."""
    from gymnasium.envs.mujoco import MujocoEnv

    class UserArm(MujocoEnv):
        metadata = {  # noqa: RUF012 - gymnasium's own envs declare it so
            "render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"],
            "render_fps": 25 if mocap else 50,  # 1 / dt, which MujocoEnv checks
        }

        def __init__(self) -> None:
            obs = gym.spaces.Box(-np.inf, np.inf, (6 if mocap else 4,), np.float64)
            MujocoEnv.__init__(self, xml_path, frame_skip, observation_space=obs)
            if mocap:
                self.action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

        def _get_obs(self) -> np.ndarray:
            if mocap:
                return np.concatenate([self.data.body("hand").xpos, self.data.qvel[:3]])
            return np.concatenate([self.data.qpos, self.data.qvel])

        def step(self, action: Any) -> Any:
            if mocap:
                self.data.mocap_pos[0] = 0.05 * np.asarray(action, dtype=np.float64)
                action = np.zeros(0)
            self.do_simulation(action, self.frame_skip)
            return self._get_obs(), 0.0, False, False, {}

        def reset_model(self) -> np.ndarray:
            self.set_state(self.init_qpos, self.init_qvel)
            return self._get_obs()

    return UserArm()


MOCAP_XML = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <body name="target" mocap="true"/>
    <body name="hand"><freejoint/><geom type="box" size="0.02 0.02 0.02" mass="0.5"/></body>
  </worldbody>
  <equality><weld body1="target" body2="hand" solref="0.02 1"/></equality>
</mujoco>
"""


# -- copies ---------------------------------------------------------------------------------------------------------


def _copies() -> list[Any]:
    import copy
    import pickle

    return [copy.deepcopy, lambda env: pickle.loads(pickle.dumps(env))]


@pytest.mark.parametrize("physics", [False, True], ids=["signals", "fused"])
def test_an_env_with_signal_models_refuses_copies_and_says_what_to_do(physics: bool) -> None:
    from dm_control import suite
    from torchrl.envs import GymWrapper

    effects = (s2r.Mass(scale=1.5),) if physics else ()
    models = (ObservationNoise(Gaussian(std=0.1)), ActionLatency(steps=2))
    envs = [
        s2r.wrap(gym.make("InvertedPendulum-v5"), *effects, *models, seed=0),
        s2r.wrap(suite.load("cartpole", "balance"), *effects, *models, seed=0),
        s2r.wrap(GymWrapper(gym.make("InvertedPendulum-v5")), *effects, *models, seed=0),
    ]
    for env in envs:
        env.reset()
        for copy in _copies():
            # Before: "cannot pickle 'memoryview' object" / "Can't pickle local object 'Gaussian.compile.<locals>...'";
            # a deep copy that got past them would have shared the original's noise closures and physics-step hook.
            with pytest.raises(TypeError, match=r"cannot be pickled or deep-copied: .*gymnasium\.make\(env\.spec\)"):
                copy(env)
        env.close()


def test_a_physics_only_env_is_copied_with_a_model_of_its_own() -> None:
    env = s2r.wrap(gym.make("InvertedPendulum-v5"), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=0)
    model = env.unwrapped.model
    nominal = model.body_mass.copy()
    obs, info = env.reset(seed=3)
    for copy in _copies():
        twin = copy(env)
        assert twin.unwrapped.model is not model
        obs2, info2 = twin.reset(seed=3)
        np.testing.assert_array_equal(obs2, obs)
        assert info2["sim2real"]["params"] == info["sim2real"]["params"]
        twin.close()
        np.testing.assert_array_equal(twin.unwrapped.model.body_mass, nominal)
    assert not np.array_equal(model.body_mass, nominal)  # the original keeps its draws until it closes
    env.close()
    np.testing.assert_array_equal(model.body_mass, nominal)


def test_a_make_vec_sub_env_is_recreated_from_its_spec() -> None:
    envs = s2r.make_vec("gym/InvertedPendulum-v5", 2, s2r.Mass(scale=Uniform(0.5, 2.0)), seed=4)
    sub: Any = envs.envs[1]  # type: ignore[attr-defined]
    twin: Any = gym.make(sub.spec)  # "_ReportAtReset wrapper does not inherit from RecordConstructorArgs" before
    assert type(twin) is type(sub) and type(twin.env) is type(sub.env)
    obs, info = sub.reset(seed=2)
    obs2, info2 = twin.reset(seed=2)
    np.testing.assert_array_equal(obs2, obs)
    assert info2["sim2real"]["params"] == info["sim2real"]["params"]
    assert "sim2real" not in twin.step(twin.action_space.sample())[4]  # still reports at resets only
    twin.close()
    envs.close()


# -- envs that step MuJoCo themselves ---------------------------------------------------------------------------


def _pd_arm(xml_path: str) -> Any:
    """A user's MujocoEnv that runs its own PD loop with ``mujoco.mj_step``, never through ``do_simulation``."""
    env = _user_mujoco_env(xml_path, 4)

    def step(action: Any) -> Any:
        for _ in range(env.frame_skip):
            env.data.ctrl[:] = 5.0 * (np.asarray(action) - env.data.qpos) - 0.5 * env.data.qvel
            mujoco.mj_step(env.model, env.data)
        return env._get_obs(), 0.0, False, False, {}

    env.step = step
    return env


UNREACHED = (
    "{module}._user_mujoco_env.<locals>.UserArm advanced its physics without calling do_simulation(ctrl, n_frames), so {names} (acting inside "
    "that call) would be reported but not applied. Step MuJoCo through do_simulation(ctrl, n_frames) in the env's "
    "`step`."
)


@pytest.mark.parametrize(
    ("models", "names"),
    [
        ((ActionLatency(steps=8),), "ActionLatency"),
        ((ControlJitter(Choice((-2.0, 2.0))), ObservationNoise(Gaussian(std=0.1))), "ControlJitter"),
    ],
    ids=["latency", "jitter"],
)
@pytest.mark.parametrize("api", ["gymnasium", "fused", "torchrl"])
def test_a_physics_rate_model_refuses_an_env_that_steps_mujoco_itself(
    tmp_path: Any, models: tuple[Any, ...], names: str, api: str
) -> None:
    path = str(tmp_path / "arm.xml")
    with open(path, "w") as f:
        f.write(ARM_XML)
    message = UNREACHED.format(module=__name__, names=names)
    if api == "torchrl":
        import torch
        from torchrl.envs import GymWrapper

        env = s2r.wrap(GymWrapper(_pd_arm(path)), *models, seed=0)
        td = env.reset()
        td["action"] = torch.zeros(2, dtype=env.action_spec.dtype)
        with pytest.raises(TypeError) as err:
            env.step(td)
    else:
        effects = (s2r.Mass(scale=1.0),) if api == "fused" else ()
        env = s2r.wrap(_pd_arm(path), *effects, *models, seed=0)
        env.reset(seed=0)
        # Before: the wrapped env stepped bitwise as the bare one while reporting the latency / jitter as applied.
        with pytest.raises(TypeError) as err:
            env.step(np.zeros(2))
    assert str(err.value) == message


def test_the_first_step_check_leaves_an_env_that_steps_through_its_hook_alone(tmp_path: Any) -> None:
    path = str(tmp_path / "arm.xml")
    with open(path, "w") as f:
        f.write(ARM_XML)
    env = s2r.wrap(_user_mujoco_env(path, 4), ActionLatency(steps=8), seed=0)
    assert "step" in vars(env)  # the one-shot check
    env.reset(seed=0)
    env.step(np.zeros(2))
    assert "step" not in vars(env)  # later steps are the class's own
    env.close()


class SelfSteppingDm(dm_env.Environment):
    """A plain dm_env around MuJoCo that has a ``_simulate`` method but steps with ``mujoco.mj_step`` itself."""

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(ARM_XML)
        self.data = mujoco.MjData(self.model)
        self.n_substeps = 4

    def _simulate(self, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def reset(self) -> dm_env.TimeStep:
        mujoco.mj_resetData(self.model, self.data)
        return dm_env.restart(self.data.qpos.copy())

    def step(self, action: Any) -> dm_env.TimeStep:
        self.data.ctrl[:] = action
        mujoco.mj_step(self.model, self.data, nstep=self.n_substeps)
        return dm_env.transition(0.0, self.data.qpos.copy())

    def observation_spec(self) -> Any:
        return dm_env.specs.Array((2,), np.float64, "qpos")

    def action_spec(self) -> Any:
        return dm_env.specs.BoundedArray((2,), np.float64, -1.0, 1.0, "action")


@pytest.mark.parametrize("physics", [False, True], ids=["signals", "fused"])
def test_a_dm_env_that_steps_mujoco_itself_is_refused_at_its_first_step(physics: bool) -> None:
    effects = (s2r.Mass(scale=1.0),) if physics else ()
    env = s2r.wrap(SelfSteppingDm(), *effects, ActionLatency(steps=6), seed=0)
    env.reset()
    with pytest.raises(TypeError, match=r"^tests?[\w.]*SelfSteppingDm advanced its physics without calling _simulate"):
        env.step(np.zeros(2))


# -- envs that compile a new model in every reset -----------------------------------------------------------------

SLIDER_XML = """
<mujoco>
  <option timestep="0.01"/>
  <worldbody>
    <body name="box" pos="0 0 {height}"><joint name="lift" type="slide" axis="0 0 1" damping="1"/>
      <geom size="0.1" mass="1"/></body>
  </worldbody>
  <actuator><motor name="push" joint="lift"/></actuator>
</mujoco>
"""


class RebuiltScene(gym.Env):
    """A procedural scene: every reset compiles a new model (the box at a height drawn from the reset's seed)."""

    frame_skip = 2

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float64)
        self._build()

    def _build(self) -> None:
        height = float(self.np_random.uniform(0.0, 1.0))
        self.model = mujoco.MjModel.from_xml_string(SLIDER_XML.format(height=height))
        self.data = mujoco.MjData(self.model)

    def _simulate(self, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.data.qpos, self.data.qvel])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        self._build()
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.data.ctrl[:] = action
        self._simulate(self.frame_skip)
        return self._obs(), 0.0, False, False, {}


def _held_by(model: mujoco.MjModel) -> dict[str, float]:
    return {"body_mass[box]": float(model.body_mass[1]), "dof_damping[lift]": float(model.dof_damping[0])}


@pytest.mark.parametrize("signals", [False, True], ids=["physics", "fused"])
def test_draws_reach_a_model_the_env_compiles_in_its_reset(signals: bool) -> None:
    effects = (s2r.Mass(scale=Uniform(0.5, 2.0)), s2r.Damping(scale=Uniform(2.0, 3.0)))
    models = (ObservationNoise(Bias(0.0)),) if signals else ()
    env = s2r.wrap(RebuiltScene(), *effects, *models, seed=0)
    for episode in range(3):
        obs, info = env.reset(seed=episode)
        params = {k: v for k, v in info["sim2real"]["params"].items() if k in ("body_mass[box]", "dof_damping[lift]")}
        assert params == _held_by(env.unwrapped.model)  # the draws stayed in the first model before
        np.testing.assert_array_equal(obs, env.unwrapped._obs())
    model = env.unwrapped.model
    env.close()
    assert _held_by(model) == {"body_mass[box]": 1.0, "dof_damping[lift]": 1.0}  # the current model's nominal


def test_physics_rate_latency_follows_a_rebuilt_model() -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, (6, 1))
    env = s2r.wrap(RebuiltScene(), ActionLatency(steps=2), seed=0)
    for episode in range(2):  # the second episode runs on a model compiled after wrap
        env.reset(seed=episode)
        seen = np.array([env.step(a)[0] for a in actions])
        late = RebuiltScene()
        late.reset(seed=episode)
        expected = np.array([late.step(a)[0] for a in np.vstack([np.zeros((1, 1)), actions[:-1]])])
        np.testing.assert_array_equal(seen, expected)  # 2 physics steps = one control step late


# -- envs that reuse their observation buffer -------------------------------------------------------------------


class BufferedObservation(gym.Env):
    """Writes every observation into one preallocated array and returns it (no allocation per step)."""

    def __init__(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(SLIDER_XML.format(height=0.0))
        self.data = mujoco.MjData(self.model)
        self.frame_skip = 1
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float64)
        self._buffer = np.zeros(2)

    def _obs(self) -> np.ndarray:
        self._buffer[0], self._buffer[1] = self.data.qpos[0], self.data.qvel[0]
        return self._buffer

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        return self._obs(), {}

    def _simulate(self, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.data.ctrl[:] = action
        self._simulate(self.frame_skip)
        return self._obs(), 0.0, False, False, {}


@pytest.mark.parametrize(
    "latency",
    [ObservationLatency(steps=3), ObservationLatency(steps=3, jitter=Choice((0.0, 1.0)))],
    ids=["fixed", "jittered"],
)
def test_observation_latency_delays_an_env_that_reuses_its_observation_array(latency: Any) -> None:
    env = s2r.wrap(BufferedObservation(), latency, seed=0)
    first = env.reset(seed=0)[0].copy()
    seen = np.array([env.step(np.ones(1))[0].copy() for _ in range(8)])
    bare = BufferedObservation()
    truth = np.array([first, *(bare.step(np.ones(1))[0].copy() for _ in range(8))])
    taken = [int(np.flatnonzero((truth == row).all(axis=1))[-1]) for row in seen]  # the physics step observed
    # At physics step k + 1 the newest sample that has arrived was taken at k + 1 - 3 or before (the reset sample
    # until then). Before: every "delayed" observation was the env's live buffer, the current state.
    assert all(t == 0 or k + 1 - t >= 3 for k, t in enumerate(taken)), taken
    if latency.jitter is None:
        assert taken == [0, 0, 0, 1, 2, 3, 4, 5]


class AlternatingScenes(RebuiltScene):
    """Keeps two compiled scenes and switches between them at every reset (a pool of pre-built variants)."""

    def __init__(self) -> None:
        super().__init__()
        self._pool = [mujoco.MjModel.from_xml_string(SLIDER_XML.format(height=h)) for h in (0.2, 0.8)]
        self._next = 0

    def _build(self) -> None:
        if not hasattr(self, "_pool"):
            return super()._build()
        self.model = self._pool[self._next % 2]
        self.data = mujoco.MjData(self.model)
        self._next += 1


def test_draws_never_compound_on_a_model_the_env_comes_back_to() -> None:
    env = s2r.wrap(AlternatingScenes(), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=0)
    for episode in range(6):
        _, info = env.reset(seed=episode)
        mass = info["sim2real"]["params"]["body_mass[box]"]
        assert 0.5 <= mass < 2.0 and mass == env.unwrapped.model.body_mass[1]  # scaled from 1.0, never from a draw
    env.close()
    assert [float(m.body_mass[1]) for m in env.unwrapped._pool] == [1.0, 1.0]


PUSHABLE_XML = """
<mujoco>
  <worldbody>
    <body name="target" mocap="true"/>
    <body name="shelf" pos="0 0 0.5"><geom type="box" size="0.2 0.2 0.01"/></body>
    <body name="box" pos="0 0 1"><freejoint/><geom size="0.1" mass="1"/></body>
  </worldbody>
</mujoco>
"""


def test_push_never_picks_a_body_that_cannot_move() -> None:
    from randomizers import PhysicsRandomizer

    model = mujoco.MjModel.from_xml_string(PUSHABLE_XML)
    randomizer = PhysicsRandomizer([s2r.Push(force=1.0, interval=1)], seed=0)
    randomizer.bind(model, mujoco.MjData(model))
    randomizer.begin_episode()
    randomizer.apply()
    for _ in range(40):
        randomizer.step()
    # Before: the mocap target and the shelf welded to the world were pushed too, and the pushes reported.
    assert {event.body for event in randomizer.events} == {"box"}
    with pytest.raises(ValueError) as err:
        s2r.Push(force=1.0, interval=1, bodies=["target", "shelf"]).bind(model)
    assert str(err.value) == (
        "`bodies` of Push selects only bodies that cannot move (welded to the world or mocap): 'target', 'shelf'. "
        "Received ['target', 'shelf']."
    )
