"""User journey 5, "the batched engine on my own env": envs nobody here designed, through the public API only.

Two users: one brings a bare MJCF arm (``sim2real.make("model:<path>")``, what ``--model robot.xml`` runs), the
other a gymnasium ``MujocoEnv`` subclass of their own, registered under an id with its ``EnvSpec``. The engine
batches the first (world ``i`` bitwise ``wrap(make(task), *effects, seed=(seed, i))``, episode by episode,
autoresets and reported draws included) and refuses the second with the reason, which ``evaluate`` reports when
it falls back. All models are generated here.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from conftest import reset_and_compare

import sim2real as s2r
from sim2real.batched import BatchedVectorEnv, make_batched, supports
from sim2real.evaluation import episode_seed, evaluate, nominal, randomized, real, sweep

# Five hinges under gravity with joint limits and position servos, a tip site with a position sensor and a home
# keyframe; 0.005 s physics steps, so MjcfEnv's 50 Hz control is 4 physics steps (the MujocoEnv's frame_skip).
ARM = """
<mujoco model="journey5_arm">
  <option timestep="0.005" gravity="0 0 -9.81"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="base" pos="0 0 0.4">
      <joint name="yaw" type="hinge" axis="0 0 1" range="-2.5 2.5" damping="0.6"/>
      <geom type="cylinder" size="0.04 0.03" mass="0.8"/>
      <body name="upper" pos="0 0 0.03">
        <joint name="shoulder" type="hinge" axis="0 1 0" range="-1.6 1.6" damping="0.4"/>
        <geom type="capsule" fromto="0 0 0 0.22 0 0" size="0.025" mass="0.5"/>
        <body name="fore" pos="0.22 0 0">
          <joint name="elbow" type="hinge" axis="0 1 0" range="-2.2 2.2" damping="0.3"/>
          <geom type="capsule" fromto="0 0 0 0.18 0 0" size="0.02" mass="0.35"/>
          <body name="wrist" pos="0.18 0 0">
            <joint name="wrist_pitch" type="hinge" axis="0 1 0" range="-1.2 1.2" damping="0.1"/>
            <geom type="capsule" fromto="0 0 0 0.06 0 0" size="0.015" mass="0.1"/>
            <body name="hand" pos="0.06 0 0">
              <joint name="wrist_roll" type="hinge" axis="1 0 0" range="-1.5 1.5" damping="0.05"/>
              <geom name="hand" type="box" size="0.02 0.03 0.01" mass="0.08"/>
              <site name="tip" pos="0.02 0 0" size="0.01"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="yaw" joint="yaw" kp="25" ctrlrange="-2.5 2.5"/>
    <position name="shoulder" joint="shoulder" kp="30" ctrlrange="-1.6 1.6"/>
    <position name="elbow" joint="elbow" kp="20" ctrlrange="-2.2 2.2"/>
    <position name="wrist_pitch" joint="wrist_pitch" kp="6" ctrlrange="-1.2 1.2"/>
    <position name="wrist_roll" joint="wrist_roll" kp="3" ctrlrange="-1.5 1.5"/>
  </actuator>
  <sensor><framepos name="tip_pos" objtype="site" objname="tip"/></sensor>
  <keyframe><key name="home" qpos="0 0.4 -0.8 0.3 0" ctrl="0 0.4 -0.8 0.3 0"/></keyframe>
</mujoco>
"""
GYM_ID = "Journey5ServoArm-v0"
STEPS = 12  # control steps per episode here: several episodes, and their autoresets, inside each test


@pytest.fixture(scope="module")
def arm_path(tmp_path_factory: pytest.TempPathFactory) -> str:
    path = tmp_path_factory.mktemp("journey5") / "robot.xml"
    path.write_text(ARM)
    return str(path)


@pytest.fixture(scope="module")
def gym_task(arm_path: str) -> str:
    """The second user's env: a ``MujocoEnv`` subclass over the same arm, registered with gymnasium."""
    from gymnasium.envs.mujoco import MujocoEnv

    class ServoArmEnv(MujocoEnv):
        """Reach a fixed point with the tip: observation ``[qpos, qvel, tip sensor]``, reward the negative distance
        less an action cost, terminated when the tip is within 3 cm or touches the floor."""

        metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 50}  # noqa: RUF012

        def __init__(self, xml_path: str, **kwargs: object) -> None:
            space = gym.spaces.Box(-np.inf, np.inf, shape=(5 + 5 + 3,), dtype=np.float64)
            MujocoEnv.__init__(self, xml_path, 4, observation_space=space, **kwargs)  # type: ignore[arg-type]
            self.goal = np.array([0.3, 0.1, 0.35])

        def _obs(self) -> np.ndarray:
            return np.concatenate([self.data.qpos, self.data.qvel, self.data.sensordata])

        def step(self, action: np.ndarray) -> tuple:
            self.do_simulation(action, self.frame_skip)
            obs = self._obs()
            tip = self.data.sensordata[:3]
            distance = float(np.linalg.norm(tip - self.goal))
            reward = -distance - 1e-3 * float(np.square(action).sum())
            return obs, reward, bool(distance < 0.03 or tip[2] < 0.02), False, {"distance": distance}

        def reset_model(self) -> np.ndarray:
            noise = self.np_random.uniform(-0.05, 0.05, self.model.nq)
            self.set_state(self.init_qpos + noise, self.init_qvel)
            return self._obs()

    gym.register(GYM_ID, entry_point=ServoArmEnv, kwargs={"xml_path": arm_path}, max_episode_steps=STEPS)
    yield f"gym/{GYM_ID}"
    gym.registry.pop(GYM_ID, None)


def _signals_and_physics() -> list:
    """Physics draws, noise on both sides, a per-episode observation latency in control steps' worth of physics steps
    and an action latency that lands mid control step (2 of 4 physics steps) or after whole ones."""
    return [
        s2r.Mass(scale=s2r.Uniform(0.7, 1.3)),
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
        s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2)),
        s2r.Gravity(add=s2r.Normal(0.0, 0.5)),
        s2r.ObservationNoise(s2r.Gaussian(std=0.01), s2r.Bias(s2r.Uniform(-0.02, 0.02))),
        s2r.ActionNoise(s2r.Gaussian(std=0.05)),
        s2r.ObservationLatency(steps=s2r.Choice([0, 4, 8])),
        s2r.ActionLatency(steps=s2r.Choice([0, 2, 4, 6, 9])),
    ]


# -- the bare MJCF arm on the engine --------------------------------------------------------------------------------


@pytest.mark.parametrize(("seed", "physics_only"), [(0, False), (5, False), (9, True)])
def test_each_mjcf_world_is_bitwise_its_single_env(arm_path: str, seed: int, physics_only: bool) -> None:
    task = f"model:{arm_path}"
    effects = _signals_and_physics()[:4] if physics_only else _signals_and_physics()
    n, options = 3, {"max_episode_steps": STEPS}
    batched = make_batched(task, n, *effects, seed=seed, **options)
    singles = [s2r.wrap(s2r.make(task, **options), *effects, seed=(seed, i)) for i in range(n)]
    rng = np.random.default_rng(seed)
    compared = 0
    try:
        assert batched.observation_dim == 10 and batched.action_dim == 5
        for episode in range(3):  # a seeded episode, then two continuing each world's own streams
            seeds = [100 * seed + i for i in range(n)] if episode == 0 else None
            _, params = reset_and_compare(batched, singles, seeds)
            assert params["dof_damping[elbow]"].shape == (n,) and len(set(params["dof_damping[elbow]"])) == n
            for _ in range(STEPS):
                actions = rng.uniform(-3.0, 3.0, (n, 5)).astype(np.float32)  # beyond the ctrlrange: both clip
                obs, reward, terminated, truncated, diverged = batched.step(actions)
                for i, env in enumerate(singles):
                    o, r, te, tr, info = env.step(actions[i])
                    assert np.array_equal(o, obs[i]), (episode, i)
                    assert r == reward[i] and te == terminated[i] and tr == truncated[i], (episode, i)
                    assert bool(info["sim2real"]["diverged"]) == diverged[i]
                    compared += 1
            assert truncated.all() and not terminated.any()
    finally:
        batched.close()
        for env in singles:
            env.close()
    assert compared == 3 * n * STEPS


def test_vector_env_autoresets_the_mjcf_arm_like_gymnasium(arm_path: str) -> None:
    # One world in three draws a servo gain that blows the arm up on its first step: its episode ends early, so the
    # worlds autoreset at different steps (gymnasium 1.x next-step rule), with rings and noise blocks per world.
    task = f"model:{arm_path}"
    effects = [*_signals_and_physics()[:2], s2r.ActuatorGain(scale=s2r.Choice([1.0, 1.0, 1e7]))]
    effects += _signals_and_physics()[4:]
    options = {"max_episode_steps": 6}
    ours = BatchedVectorEnv(task, 3, *effects, seed=2, **options)
    theirs = s2r.make_vec(task, 3, *effects, seed=2, **options)
    try:
        assert ours.observation_space == theirs.observation_space and ours.action_space == theirs.action_space
        o1, i1 = ours.reset(seed=40)
        o2, i2 = theirs.reset(seed=40)
        assert np.array_equal(o1, o2)
        for key, values in i2["sim2real"]["params"].items():
            if not key.startswith("_"):  # gymnasium's masks
                assert np.array_equal(i1["sim2real"]["params"][key], values), key
        rng = np.random.default_rng(1)
        resets, diverged, ends = 0, 0, set()
        for t in range(30):
            actions = rng.uniform(-1, 1, (3, 5)).astype(np.float32)
            a, b = ours.step(actions), theirs.step(actions)
            for x, y in zip(a[:4], b[:4], strict=True):
                assert np.array_equal(x, y), t
            if "reset" in a[4].get("sim2real", {}):
                reset = a[4]["sim2real"]["reset"]
                resets += int(reset.sum())
                ends.add(tuple(reset.tolist()))
                for key, values in a[4]["sim2real"]["params"].items():  # the new episodes' draws, per world
                    assert np.array_equal(values[reset], b[4]["sim2real"]["params"][key][reset]), (t, key)
            if "diverged" in a[4].get("sim2real", {}):
                diverged += int(a[4]["sim2real"]["diverged"].sum())
        assert diverged >= 1 and resets >= 9
        assert len(ends) > 1  # worlds did not all restart together
    finally:
        ours.close()
        theirs.close()


def test_torchrl_env_of_the_mjcf_arm_passes_check_env_specs(arm_path: str) -> None:
    torch = pytest.importorskip("torch")
    from torchrl.envs.utils import check_env_specs

    from sim2real.batched.torchrl_env import BatchedTorchRLEnv

    task = f"model:{arm_path}"
    effects = _signals_and_physics()
    env = BatchedTorchRLEnv(task, 3, *effects, seed=4, max_episode_steps=STEPS)
    try:
        check_env_specs(env, seed=0)
        env.set_seed(7)
        td = env.rollout(STEPS + 2, break_when_any_done=False)
        assert td.batch_size == torch.Size([3, STEPS + 2])
        singles = [s2r.wrap(s2r.make(task, max_episode_steps=STEPS), *effects, seed=(4, i)) for i in range(3)]
        for i, single in enumerate(singles):
            obs, info = single.reset(seed=7 + i)
            assert np.array_equal(td["observation"][i, 0].numpy(), obs)
            draws = td["sim2real_params"][i, 0].numpy()
            for name, value in info["sim2real"]["params"].items():
                assert draws[env.param_names.index(name)] == value, name
            for t in range(STEPS):
                obs, reward, _, truncated, _ = single.step(td["action"][i, t].numpy())
                assert np.array_equal(td["next", "observation"][i, t].numpy(), obs)
                assert td["next", "reward"][i, t, 0].item() == np.float32(reward)
                assert td["next", "truncated"][i, t, 0].item() == truncated
            single.close()
        for bad in ("7", -1, 1.5):  # refused before the env keeps it for its next reset
            with pytest.raises(ValueError) as err:
                env.set_seed(bad)
            assert str(err.value) == f"`seed` must be None or an int >= 0. Received {bad!r} ({type(bad).__name__})."
        env.reset()
    finally:
        env.close()


# -- evaluate on both users' envs -----------------------------------------------------------------------------------


def _hold(obs: np.ndarray) -> np.ndarray:
    """A policy that drives each servo towards a fixed pose, with a little feedback so the noise matters."""
    return np.array([0.5, 0.6, -1.0, 0.4, 0.3], np.float32) - 0.2 * obs[:5].astype(np.float32)


def test_evaluate_batches_the_mjcf_arm_and_gives_the_per_env_results(arm_path: str) -> None:
    task = f"model:{arm_path}"
    effects = _signals_and_physics()
    push = s2r.Damping(scale=s2r.Uniform(0.5, 2.0), schedule=s2r.Interval(5))  # redrawn mid-episode: per env
    conditions = [
        nominal(),
        randomized(effects),
        real(
            [s2r.ActionLatency(steps=3), s2r.ObservationNoise(s2r.Gaussian(std=0.02))], params={"body_mass[fore]": 0.5}
        ),
        *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 2.0]),
        randomized([push], name="redrawn"),
    ]
    common = {"episodes": 3, "seed": 3, "task_options": {"max_episode_steps": STEPS}}
    auto = evaluate({"hold": _hold}, task, conditions, **common)
    per_env = evaluate({"hold": _hold}, task, conditions, engine="per-env", **common)
    assert dict(auto.engines) == {**{c.name: "batched" for c in conditions[:-1]}, "redrawn": "per-env"}
    assert dict(auto.fallbacks) == {"redrawn": "Damping acts during the episode (per-step effects are not batched)"}
    assert set(per_env.engines.values()) == {"per-env"}
    assert dict(per_env.fallbacks) == {c.name: "engine='per-env' was asked for" for c in conditions}
    assert auto == per_env  # returns, lengths, draws: bitwise (Evaluation's equality)
    assert auto.draws["randomized"]["dof_damping[elbow]"].shape == (3,)


def test_evaluate_ends_a_bare_mjcf_episode_where_the_env_does(tmp_path: Path) -> None:
    # Unrandomised conditions step bare envs: MjcfEnv itself ends an episode whose accelerations blow up (truncated,
    # its own reward and observation); the engine must end it on the same step, not run on to the time limit.
    wild = tmp_path / "wild.xml"
    wild.write_text(ARM.replace('kp="30"', 'kp="1e9"').replace('timestep="0.005"', 'timestep="0.02"'))
    task = f"model:{wild}"
    common = {"episodes": 2, "seed": 0, "task_options": {"max_episode_steps": STEPS}}
    auto = evaluate({"hold": _hold}, task, [nominal()], **common)
    per_env = evaluate({"hold": _hold}, task, [nominal()], engine="per-env", **common)
    assert dict(auto.engines) == {"sim": "batched"}
    assert (per_env.lengths["hold"]["sim"] < STEPS).all()  # the env ended its episodes early
    assert auto == per_env


def test_the_registered_mujoco_env_falls_back_with_the_reason(gym_task: str) -> None:
    effects = _signals_and_physics()
    reason = (
        f"no batched kernel for task {gym_task!r}: its observations, rewards and ends come from the env's own Python "
        "step, which the engine cannot compute for all worlds at once (an MJCF file as 'model:<path>' can be batched)"
    )
    assert supports(gym_task, *effects) == reason
    with pytest.raises(ValueError, match=r"`task` and `effects` must be supported by the batched engine") as err:
        make_batched(gym_task, 2, *effects)
    assert reason in str(err.value) and f"Received task {gym_task!r}." in str(err.value)
    env = s2r.make(gym_task)
    assert supports(env) == (
        "no batched kernel for an env object (TimeLimit): the engine builds its worlds from a task id"
    )
    env.close()

    result = evaluate({"hold": _hold}, gym_task, [nominal(), randomized(effects)], episodes=2, seed=1)
    assert dict(result.engines) == {"sim": "per-env", "randomized": "per-env"}
    assert dict(result.fallbacks) == {"sim": reason, "randomized": reason}
    # The fallback is the per-env loop users would write: the same returns, episode by episode.
    for e in range(2):
        env = s2r.wrap(s2r.make(gym_task), *effects, seed=1)
        obs, _ = env.reset(seed=episode_seed(1, e))
        total, done, steps = 0.0, False, 0
        while not done:
            obs, reward, terminated, truncated, _ = env.step(_hold(obs))
            total, done, steps = total + reward, terminated or truncated, steps + 1
        env.close()
        assert result.returns["hold"]["randomized"][e] == total
        assert result.lengths["hold"]["randomized"][e] == steps


# -- errors ---------------------------------------------------------------------------------------------------------


def test_a_bare_model_path_is_pointed_to_its_model_id(arm_path: str) -> None:
    with pytest.raises(ValueError) as err:
        s2r.make(arm_path)
    assert str(err.value).endswith(f"Received {arm_path!r}. An MJCF file is 'model:<path>': use 'model:{arm_path}'.")
    assert s2r.make(f"model:{arm_path}").observation_space.shape == (10,)


def test_bad_counts_seeds_and_indices_name_the_argument(arm_path: str) -> None:
    task = f"model:{arm_path}"
    for bad in (0, -3, 2.0, True):
        with pytest.raises(ValueError, match=rf"^`num_envs` must be an int >= 1\. Received {bad!r}\.$"):
            make_batched(task, bad)
    for bad in ("1", 1.5, -1, None):
        with pytest.raises(ValueError, match=rf"^`seed` must be an int >= 0\. Received {bad!r}\.$"):
            make_batched(task, 2, seed=bad)
    with pytest.raises(ValueError, match=r"task options \['render_mode'\] are not batched \(allowed: "
                       r"\['max_episode_steps', 'control_timestep', 'reset_noise'\]\)"):  # fmt: skip
        make_batched(task, 2, render_mode="rgb_array")
    envs = make_batched(task, 2, max_episode_steps=3)
    allowed = "`seed` must be None, an int >= 0 or a sequence of one int >= 0 or None per reset world (2)."
    cases = {
        "1": "Received '1' (str).",
        1.5: "Received 1.5 (float).",
        -2: "Received -2 (int).",
        (1,): "Received 1 seeds: (1,).",
        (1, "a"): "Received the entries ['a']: (1, 'a').",
        (1, -1): "Received the entries [-1]: (1, -1).",
    }
    try:
        for bad, received in cases.items():
            with pytest.raises(ValueError) as err:
                envs.reset(seed=bad)
            assert str(err.value) == f"{allowed} Received {received.removeprefix('Received ')}"
        with pytest.raises(ValueError, match=r"^`indices` must be world numbers in \[0, 2\)\. Received \[2\]"):
            envs.reset(indices=[0, 2])
        obs, _ = envs.reset(seed=np.array([3, 4]))  # a numpy array of seeds is a sequence of them
        assert obs.shape == (2, 10)
    finally:
        envs.close()
    vector = BatchedVectorEnv(task, 2, max_episode_steps=3)
    with pytest.raises(ValueError, match=r"Received 2\.5 \(float\)\.$"):
        vector.reset(seed=2.5)
    vector.close()
