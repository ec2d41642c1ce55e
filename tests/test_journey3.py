"""User journey #3: a robotics engineer with their own env classes, not an MJCF path.

The user's module (generated here, its MJCF written beside it) holds a gymnasium ``MujocoEnv`` subclass of a 4-joint arm
(gravity, joint limits, position servos, ``frame_skip=5``, qpos/qvel plus an end-effector site in the observation,
registered with ``gym.register`` so it has a spec), a ``dm_env.Environment`` written by hand around ``mujoco`` and a
TorchRL ``EnvBase`` written by hand. Every command and API the README promises for "your own env" is walked on them:
the perturbation is read back from the model, the reported latency is the one applied, specs rebuild the env, errors
are one line naming the argument, and nothing is left half-written.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import yaml
from conftest import assert_same_model, model_arrays, run_cli

import sim2real as s2r
import sysid
from noise_models import ActionLatency, Gaussian, ObservationLatency, ObservationNoise

MODULE = "journey3_user_arm"
USER_MODULE = r'''
from __future__ import annotations
import os
import numpy as np
import mujoco
import gymnasium as gym
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.spaces import Box
import dm_env
from dm_env import specs

XML = """
<mujoco model="user_arm4">
  <compiler angle="radian"/>
  <option timestep="0.002" gravity="0 0 -9.81"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="base" pos="0 0 0.1">
      <joint name="yaw" axis="0 0 1" range="-2.5 2.5" damping="1.5" armature="0.05"/>
      <geom name="base_g" type="cylinder" size="0.06 0.05" mass="3"/>
      <body name="upper" pos="0 0 0.08">
        <joint name="shoulder" axis="0 1 0" range="-1.6 1.6" damping="2.0" armature="0.05"/>
        <geom name="upper_g" type="capsule" fromto="0 0 0 0.3 0 0" size="0.04" mass="2.5"/>
        <body name="fore" pos="0.3 0 0">
          <joint name="elbow" axis="0 1 0" range="-2.4 2.4" damping="1.0" armature="0.03"/>
          <geom name="fore_g" type="capsule" fromto="0 0 0 0.25 0 0" size="0.035" mass="1.5"/>
          <body name="hand" pos="0.25 0 0">
            <joint name="wrist" axis="1 0 0" range="-2.8 2.8" damping="0.3" armature="0.01"/>
            <geom name="hand_g" type="box" size="0.04 0.03 0.03" mass="0.6"/>
            <site name="ee" pos="0.05 0 0" size="0.01"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="yaw" joint="yaw" kp="60" kv="4" ctrlrange="-2.5 2.5" forcerange="-40 40"/>
    <position name="shoulder" joint="shoulder" kp="120" kv="6" ctrlrange="-1.6 1.6" forcerange="-60 60"/>
    <position name="elbow" joint="elbow" kp="60" kv="3" ctrlrange="-2.4 2.4" forcerange="-30 30"/>
    <position name="wrist" joint="wrist" kp="10" kv="0.5" ctrlrange="-2.8 2.8" forcerange="-8 8"/>
  </actuator>
  <keyframe><key name="home" qpos="0 -0.6 1.2 0"/></keyframe>
</mujoco>
"""
HERE = os.path.dirname(os.path.abspath(__file__))
XML_PATH = os.path.join(HERE, "user_arm4.xml")
if not os.path.exists(XML_PATH):
    with open(XML_PATH, "w") as f:
        f.write(XML)
TARGET = np.array([0.35, 0.1, 0.45])


class UserArmEnv(MujocoEnv):
    metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}

    def __init__(self, target=(0.35, 0.1, 0.45), **kwargs):
        obs_space = Box(-np.inf, np.inf, shape=(11,), dtype=np.float64)
        MujocoEnv.__init__(self, XML_PATH, frame_skip=5, observation_space=obs_space, **kwargs)
        self.metadata["render_fps"] = int(np.round(1.0 / self.dt))
        self.target = np.asarray(target, dtype=np.float64)

    def _get_obs(self):
        return np.concatenate([self.data.qpos, self.data.qvel, self.data.site("ee").xpos]).astype(np.float64)

    def step(self, action):
        self.do_simulation(action, self.frame_skip)
        obs = self._get_obs()
        dist = float(np.linalg.norm(obs[8:] - self.target))
        reward = -dist - 1e-3 * float(np.square(action).sum())
        return obs, reward, False, False, {"dist": dist}

    def reset_model(self):
        qpos = self.model.key_qpos[0] + self.np_random.uniform(-0.05, 0.05, self.model.nq)
        qvel = np.zeros(self.model.nv)
        self.set_state(qpos, qvel)
        return self._get_obs()


if "UserArm3-v0" not in gym.registry:
    gym.register("UserArm3-v0", entry_point=f"{__name__}:UserArmEnv", max_episode_steps=100)


def make_gym():
    return gym.make("UserArm3-v0")


def make_gym_raw():
    return UserArmEnv()


class UserArmDmEnv(dm_env.Environment):
    """A dm_env written by hand around mujoco: no dm-control suite."""

    def __init__(self, n_sub=5, episode_len=100):
        self.model = mujoco.MjModel.from_xml_string(XML)
        self.data = mujoco.MjData(self.model)
        self.n_sub = n_sub
        self.episode_len = episode_len
        self._t = 0
        self._reset_next = True

    def _obs(self):
        return {"qpos": self.data.qpos.copy(), "qvel": self.data.qvel.copy(), "ee": self.data.site("ee").xpos.copy()}

    def reset(self):
        mujoco.mj_resetDataKeyframe(self.model, self.data, 0)
        mujoco.mj_forward(self.model, self.data)
        self._t = 0
        self._reset_next = False
        return dm_env.restart(self._obs())

    def step(self, action):
        if self._reset_next:
            return self.reset()
        self.data.ctrl[:] = action
        self._simulate(self.n_sub)
        self._t += 1
        obs = self._obs()
        reward = -float(np.linalg.norm(obs["ee"] - TARGET))
        if self._t >= self.episode_len:
            self._reset_next = True
            return dm_env.truncation(reward, obs)
        return dm_env.transition(reward, obs)

    def _simulate(self, nstep):
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def control_timestep(self):
        return self.n_sub * self.model.opt.timestep

    def observation_spec(self):
        return {"qpos": specs.Array((4,), np.float64, "qpos"), "qvel": specs.Array((4,), np.float64, "qvel"),
                "ee": specs.Array((3,), np.float64, "ee")}

    def action_spec(self):
        r = self.model.actuator_ctrlrange
        return specs.BoundedArray((4,), np.float64, r[:, 0], r[:, 1], "action")


def make_dm():
    return UserArmDmEnv()


def make_torchrl():
    import torch
    from tensordict import TensorDict
    from torchrl.data import Bounded, Composite, Unbounded
    from torchrl.envs import EnvBase

    class UserArmTorchEnv(EnvBase):
        """A TorchRL env written by hand around mujoco."""

        def __init__(self, frame_skip=5):
            super().__init__(device="cpu", batch_size=torch.Size([]))
            self.model = mujoco.MjModel.from_xml_string(XML)
            self.data = mujoco.MjData(self.model)
            self.frame_skip = frame_skip
            r = torch.as_tensor(self.model.actuator_ctrlrange, dtype=torch.float32)
            self.action_spec = Bounded(r[:, 0], r[:, 1], shape=(4,), dtype=torch.float32)
            self.observation_spec = Composite(observation=Unbounded(shape=(11,), dtype=torch.float32))
            self.reward_spec = Unbounded(shape=(1,), dtype=torch.float32)

        def _obs(self):
            o = np.concatenate([self.data.qpos, self.data.qvel, self.data.site("ee").xpos])
            return torch.as_tensor(o, dtype=torch.float32)

        def _reset(self, tensordict=None, **kw):
            mujoco.mj_resetDataKeyframe(self.model, self.data, 0)
            mujoco.mj_forward(self.model, self.data)
            return TensorDict({"observation": self._obs(), "done": torch.zeros(1, dtype=torch.bool),
                               "terminated": torch.zeros(1, dtype=torch.bool)}, batch_size=[])

        def _step(self, tensordict):
            self.data.ctrl[:] = tensordict["action"].numpy()
            self._simulate(self.frame_skip)
            obs = self._obs()
            reward = -torch.linalg.norm(obs[8:] - torch.as_tensor(TARGET, dtype=torch.float32)).reshape(1)
            return TensorDict({"observation": obs, "reward": reward, "done": torch.zeros(1, dtype=torch.bool),
                               "terminated": torch.zeros(1, dtype=torch.bool)}, batch_size=[])

        def _simulate(self, nstep):
            mujoco.mj_step(self.model, self.data, nstep=nstep)

        def _set_seed(self, seed):
            return seed

    return UserArmTorchEnv()

'''


@pytest.fixture(scope="module")
def user_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    folder = tmp_path_factory.mktemp("journey3")
    (folder / f"{MODULE}.py").write_text(USER_MODULE)
    sys.path.insert(0, str(folder))
    yield folder
    sys.path.remove(str(folder))
    sys.modules.pop(MODULE, None)


@pytest.fixture
def user(user_dir: Path, monkeypatch: pytest.MonkeyPatch) -> Any:
    monkeypatch.chdir(user_dir)
    import importlib

    return importlib.import_module(MODULE)


HOME = np.array([0.0, -0.6, 1.2, 0.0])


def test_the_registered_mujoco_env_is_perturbed_reported_rebuilt_from_its_spec_and_restored(user: Any) -> None:
    env = gym.make("UserArm3-v0")
    model = env.unwrapped.model
    nominal = model_arrays(model)
    wrapped = s2r.wrap(
        env,
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
        s2r.Mass(scale=1.5, bodies="fore"),
        ActionLatency(seconds=0.013),
        ObservationLatency(steps=3),
        ObservationNoise(Gaussian(0.01)),
        seed=0,
    )
    _, info = wrapped.reset(seed=1)
    params = info["sim2real"]["params"]
    fore = model.body("fore").id
    # The drawn values are the model's: read them back.
    assert [params[f"dof_damping[{j}]"] for j in ("yaw", "shoulder", "elbow", "wrist")] == model.dof_damping.tolist()
    assert params["body_mass[fore]"] == model.body_mass[fore] == 1.5 * nominal["body_mass"][fore]
    assert np.allclose(model.body_inertia[fore], 1.5 * nominal["body_inertia"][fore])
    # 0.013 s is 6.5 physics steps of 2 ms: 7 are applied, and the report says 7 and 0.014 s, not 0.013.
    assert (params["action_latency_steps"], params["action_latency"]) == (7, pytest.approx(0.014))
    assert (params["obs_latency_steps"], params["obs_latency"]) == (3, pytest.approx(0.006))
    data = env.unwrapped.data
    before = data.ctrl.copy()
    wrapped.step(HOME)  # 5 physics steps: the command has not arrived yet
    assert np.array_equal(data.ctrl, before)
    wrapped.step(HOME)  # 10 physics steps: it arrived at step 7, mid control step
    assert np.allclose(data.ctrl, HOME)
    # gym.make(env.spec) rebuilds the user's env and the whole wrapper stack: the same draws, bitwise.
    assert wrapped.spec is not None and wrapped.spec.id == "UserArm3-v0"
    again = gym.make(wrapped.spec)
    (o1, i1), (o2, i2) = wrapped.reset(seed=3), again.reset(seed=3)
    assert o1.tobytes() == o2.tobytes() and i1["sim2real"]["params"] == i2["sim2real"]["params"]
    for k in range(5):
        a = HOME + 0.1 * k
        assert wrapped.step(a)[0].tobytes() == again.step(a)[0].tobytes()
    again.close()
    wrapped.close()
    assert_same_model(nominal, model)


@pytest.mark.parametrize("task", ["gym/UserArm3-v0", f"env:{MODULE}:make_gym", f"env:{MODULE}:make_dm"])
def test_make_vec_calibration_and_specs_of_every_own_env(user: Any, task: str) -> None:
    fit = {"dof_damping[shoulder]": 2.6, "dof_damping[elbow]": 1.3}
    env = s2r.make(task, params=fit)
    model = s2r.find_physics(env).model
    assert (model.dof_damping[1], model.dof_damping[2]) == (2.6, 1.3)
    again = gym.make(env.spec)  # the calibration travels with the spec
    assert s2r.find_physics(again).model.dof_damping.tolist() == model.dof_damping.tolist()
    again.close()
    wrapped = s2r.wrap(env, s2r.Mass(scale=s2r.Uniform(0.8, 1.2)), ActionLatency(seconds=0.02), seed=0)
    vec = gym.make_vec(wrapped.spec, 2)
    obs, info = vec.reset(seed=0)
    masses = info["sim2real"]["params"]["body_mass[fore]"]
    assert obs.shape == (2, 11) and masses[0] != masses[1]
    assert info["sim2real"]["params"]["action_latency_steps"].tolist() == [10, 10]  # 20 ms at 2 ms a physics step
    vec.close()
    wrapped.close()
    draws = []
    for _ in range(2):  # make_vec: sub-env i draws from the streams at (seed, i); the same seed, the same draws
        batch = s2r.make_vec(task, 2, s2r.Mass(scale=s2r.Uniform(0.8, 1.2)), seed=0)
        _, info2 = batch.reset(seed=0)
        draws.append(info2["sim2real"]["params"]["body_mass[fore]"].tolist())
        assert s2r.find_physics(batch.envs[1]).model.body_mass[3] == draws[-1][1]  # sub-env 1's own model
        batch.close()
    assert draws[0] == draws[1] and draws[0][0] != draws[0][1]


def test_the_hand_written_dm_env_and_torchrl_env_take_draws_and_give_them_back(user: Any) -> None:
    dm = user.make_dm()
    nominal = model_arrays(dm.model)
    wrapped = s2r.wrap(dm, s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), ActionLatency(seconds=0.02), seed=0)
    wrapped.reset()
    params = wrapped.current_params
    assert [params[f"dof_damping[{j}]"] for j in ("yaw", "shoulder", "elbow", "wrist")] == dm.model.dof_damping.tolist()
    wrapped.close()
    assert_same_model(nominal, dm.model)

    from torchrl.envs.utils import check_env_specs

    base = user.make_torchrl()
    nominal = model_arrays(base.model)
    env = s2r.wrap(base, s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), ObservationNoise(Gaussian(0.01)), seed=0)
    td = env.reset()
    assert td["sim2real_params"].tolist() == base.model.dof_damping.tolist()
    check_env_specs(env)
    assert env.rollout(5)["next", "observation"].shape == (5, 11)
    env.close()
    assert_same_model(nominal, base.model)


def test_adr_grows_the_ranges_on_the_users_env(user: Any) -> None:
    adr = s2r.ADR(
        [s2r.Damping(scale=s2r.Uniform(0.0, 4.0))], delta=0.5, t_low=-500.0, t_high=-100.0, m=1, p_boundary=1.0
    )
    env = s2r.wrap(gym.make("UserArm3-v0", max_episode_steps=10), adr=adr, seed=0)
    pinned = []
    for _ in range(4):
        _, info = env.reset()
        pinned.append(info["sim2real"]["adr"]["pin"])
        assert env.unwrapped.model.dof_damping[1] == pytest.approx(2.0 * pinned[-1][2])  # the pin is what is applied
        done = False
        while not done:
            *_, terminated, truncated, _ = env.step(HOME)
            done = terminated or truncated
    env.close()
    low, high = adr.ranges["Damping[joints=*]"]
    assert low < 1.0 or high > 1.0  # a return of about -5 is >= t_high: the pinned boundaries moved out


def test_the_cli_loop_on_an_own_gym_env_record_fit_export_train_evaluate_with_safety(user_dir: Path, user: Any) -> None:
    source = ["--env", f"{MODULE}:make_gym"]
    code, out, err = run_cli(
        ["record", *source, "--set", "dof_damping[*]=*1.3", "--latency", "2", "--episodes", "2", "--steps", "100",
         "--obs-noise", "1e-3", "--seed", "0", "--out", "log.npz", "--quiet"]
    )  # fmt: skip
    assert (code, err) == (0, "")
    log = sysid.load_log("log.npz")
    assert (log.timestep, log.control_timestep) == (0.002, pytest.approx(0.01))  # frame_skip=5 found
    assert log.meta["true_latency_seconds"]["action"] == pytest.approx(0.02)  # 2 control steps, in seconds
    code, out, err = run_cli(
        ["sysid", "fit", "log.npz", *source, "--params", "dof_damping[*]", "--latency", "--quiet", "--out", "fit.json",
         "--export", "fit.yaml"]
    )  # fmt: skip
    assert code == 0, err
    assert "latency (s): action=0.02\n" in out  # the fitted latency, in seconds: 2 control steps of 10 ms
    fit = sysid.FitResult.from_json(Path("fit.json"))
    truth = [1.3 * d for d in (1.5, 2.0, 1.0, 0.3)]
    assert all(lo <= t <= hi for t, (lo, hi) in zip(truth, fit.ci95, strict=True))
    exported = yaml.safe_load(Path("fit.yaml").read_text())
    latency = [s for s in exported["signals"] if s["type"] == "ActionLatency"]
    assert latency == [{"type": "ActionLatency", "seconds": pytest.approx(0.02)}]
    Path("tiny_ppo.yaml").write_text(
        "algo: ppo\nframes: 256\nframes_per_batch: 128\nminibatch_size: 64\nepochs: 2\nobs_norm_frames: 64\n"
        "hidden_sizes: [32, 32]\n"
    )
    code, _, err = run_cli(
        ["train", *source, "--config", "fit.yaml", "--agent-config", "tiny_ppo.yaml", "--no-log", "--quiet",
         "--out", "ppo.pt"]
    )  # fmt: skip
    assert code == 0 and Path("ppo.pt").is_file(), err
    Path("limits.yaml").write_text("max_ee_speed: {site: ee, m_per_s: 100.0}\njoint_limit_hits: 1000\n")
    Path("eval.yaml").write_text(
        f"env: {MODULE}:make_gym\nepisodes: 2\nmax_steps: 20\nbatch: 2\n"
        "policies: {ppo: {checkpoint: ppo.pt}, hold: {constant: [0.0, -0.6, 1.2, 0.0]}}\n"
        "randomized: fit.yaml\n"
        "sweeps: [{type: ActionLatency, field: seconds, values: [0.0, 0.02]}]\n"
        "report: {num_resamples: 50}\n"
    )
    Path("report").mkdir(exist_ok=True)
    Path("report/mine.txt").write_text("keep")
    code, _, err = run_cli(["evaluate", "--config", "eval.yaml", "--out", "report", "--backend", "serial",
                              "--quiet", "--safety", "limits.yaml"])  # fmt: skip
    assert code == 0, err
    assert Path("report/mine.txt").read_text() == "keep"  # an existing folder: only report.* and figures/ replaced
    report = json.loads(Path("report/report.json").read_text())
    assert (report["control_timestep"], report["substeps"]) == (pytest.approx(0.01), 5)
    draws = {c["name"]: {d["address"]: d["mean"] for d in c["draws"]} for c in report["evaluation"]["conditions"]}
    assert draws["ActionLatency.seconds=0.02"]["action_latency_steps"] == 10
    assert "safety" in report


def test_train_refuses_effects_that_do_not_fit_the_env_in_one_line(user_dir: Path, user: Any) -> None:
    # Before: the wrong joint name surfaced from inside training as a ValueError traceback (exit 1).
    Path("bad.yaml").write_text("effects:\n  - {type: Damping, scale: 1.2, joints: nope}\n")
    code, out, err = run_cli(["train", "--env", f"{MODULE}:make_gym", "--config", "bad.yaml", "--frames", "64",
                              "--no-log", "--quiet", "--out", "bad.pt"])  # fmt: skip
    assert (code, out) == (2, "") and not Path("bad.pt").exists()
    assert err == (
        f"sim2real train: error: the effects of --config do not fit '{MODULE}:make_gym': `joints` pattern 'nope' "
        "matches no joint in the model. Known joints: 'yaw', 'shoulder', 'elbow', 'wrist'.\n"
    )
    Path("bad_signal.yaml").write_text(
        "signals:\n  - {type: ObservationNoise, processes: [{type: Gaussian, std: 0.01}], select: velocity}\n"
    )
    code, out, err = run_cli(["train", "--env", f"{MODULE}:make_gym", "--config", "bad_signal.yaml", "--frames",
                              "64", "--no-log", "--quiet", "--out", "bad.pt"])  # fmt: skip
    assert (code, out) == (2, "") and not Path("bad.pt").exists() and err.count("\n") == 1
    assert err.startswith(f"sim2real train: error: the effects of --config do not fit '{MODULE}:make_gym': `select`")


def test_train_interrupted_says_so_in_one_line_and_leaves_no_checkpoint(
    user_dir: Path, user: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Before: Ctrl-C during `train` printed a traceback and exited 1; every other command says one line (exit 130).
    import sim2real.agents.training as training

    def interrupted(*args: Any, **kwargs: Any) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(training, "train", interrupted)
    code, out, err = run_cli(
        ["train", "--env", f"{MODULE}:make_gym", "--frames", "64", "--no-log", "--quiet", "--out", "cut.pt"]
    )
    assert (code, out) == (130, "") and not Path("cut.pt").exists()
    assert err == "sim2real train: interrupted; no checkpoint was written to 'cut.pt'\n"


def test_evaluate_refuses_a_spec_that_does_not_fit_the_env_before_any_episode(user_dir: Path, user: Any) -> None:
    # Before: both specs ran into a traceback inside the evaluation (exit 1): effects naming a joint the user's arm
    # does not have, and a constant action with 3 values for a 4-actuator arm.
    Path("bad.yaml").write_text("effects:\n  - {type: Damping, scale: 1.2, joints: nope}\n")
    spec = (
        f"env: {MODULE}:make_gym\nepisodes: 1\nmax_steps: 5\npolicies: {{hold: {{constant: [0.0, -0.6, 1.2, 0.0]}}}}\n"
    )
    Path("misfit.yaml").write_text(spec + "randomized: bad.yaml\n")
    Path("short.yaml").write_text(spec.replace("1.2, 0.0", "1.2"))
    code, out, err = run_cli(["evaluate", "--config", "misfit.yaml", "--out", "r1", "--backend", "serial", "--quiet"])
    assert (code, out) == (2, "") and not Path("r1").exists()
    assert err == (
        f"sim2real evaluate: error: misfit.yaml: the effects of condition 'randomized' do not fit "
        f"'env:{MODULE}:make_gym': `joints` pattern 'nope' matches no joint in the model. Known joints: 'yaw', "
        "'shoulder', 'elbow', 'wrist'.\n"
    )
    code, out, err = run_cli(["evaluate", "--config", "short.yaml", "--out", "r2", "--backend", "serial", "--quiet"])
    assert (code, out) == (2, "") and not Path("r2").exists()
    assert err == (
        f"sim2real evaluate: error: short.yaml: policies.hold.constant must have 4 values, the action size of "
        f"'env:{MODULE}:make_gym'. Received 3: [0.0, -0.6, 1.2].\n"
    )


def test_study_on_an_own_env_names_the_commands_with_that_env(user_dir: Path, user: Any) -> None:
    # Before: `study --env pkg:make` told the user to run `record --model ROBOT.xml`, ... (an MJCF they do not have).
    code, out, err = run_cli(["study", "--env", f"{MODULE}:make_gym", "--out", "study"])
    assert (code, out) == (2, "") and not Path("study").exists() and err.count("\n") == 1
    assert f"`sim2real record --env {MODULE}:make_gym`" in err and "--model" not in err
    assert err.endswith(f"Received --env {MODULE}:make_gym.\n")


def test_an_env_module_beside_the_spec_is_found_from_any_folder(
    tmp_path: Path, user: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A spec's `model:` is relative to the spec; its `env:` module was only looked for in the working folder, so
    # `sim2real evaluate --config project/eval.yaml` from anywhere else failed with 'No module named ...'.
    monkeypatch.setattr(sys, "path", list(sys.path))  # the folder that finds the module is left on it: undo that
    monkeypatch.delitem(sys.modules, "journey3_beside_spec", raising=False)
    project, elsewhere = tmp_path / "project", tmp_path / "elsewhere"
    project.mkdir()
    elsewhere.mkdir()
    (project / "journey3_beside_spec.py").write_text(f"from {MODULE} import make_gym as make\n")
    (project / "eval.yaml").write_text(
        "env: journey3_beside_spec:make\nepisodes: 1\nmax_steps: 5\n"
        "policies: {hold: {constant: [0.0, -0.6, 1.2, 0.0]}}\n"
    )
    monkeypatch.chdir(elsewhere)
    code, out, err = run_cli(
        ["evaluate", "--config", str(project / "eval.yaml"), "--out", "report", "--backend", "serial", "--quiet"]
    )
    assert (code, err) == (0, "") and (elsewhere / "report" / "report.json").is_file()
    assert str(project) in sys.path
    code, out, err = run_cli(["record", "--env", "journey3_nowhere:make", "--out", "log.npz"])
    assert (code, out) == (2, "") and not Path("log.npz").exists()
    assert err == (
        "sim2real record: error: `--env` 'journey3_nowhere:make': cannot import module 'journey3_nowhere': "
        "No module named 'journey3_nowhere'.\n"
    )


def test_a_gymnasium_id_without_its_prefix_is_refused_with_the_id_to_use(user: Any) -> None:
    # Before: the message listed the form 'gym/<gymnasium id>' but not that this id is one (no close match either).
    message = (
        "`task_id` must be one of the ids listed by `sim2real tasks` or 'gym/<gymnasium id>'. Received 'UserArm3-v0'. "
        "'UserArm3-v0' is registered with gymnasium: use 'gym/UserArm3-v0'."
    )
    with pytest.raises(ValueError) as err:
        s2r.make("UserArm3-v0")
    assert str(err.value) == message
    with pytest.raises(ValueError) as err:
        s2r.make_vec("UserArm3-v0", 2)
    assert str(err.value) == message
    code, out, err_text = run_cli(["record", "--task", "UserArm3-v0", "--out", "never.npz"])
    assert (code, out) == (2, "") and not Path("never.npz").exists()
    assert err_text.endswith(message + "\n") and err_text.count("\n") == 1


def test_the_hand_written_dm_env_gets_the_action_latency_it_reports(user: Any) -> None:
    # Before the lead's 2157f6a the clock took 1 physics step per control step here (PhysicsHandle.substeps read
    # frame_skip/n_substeps only): 7 reported physics steps were applied as 7 control steps (70-80 ms).
    dm = user.make_dm()  # 5 physics steps of 2 ms per step, declared by control_timestep() = 0.01 s
    env = s2r.wrap(dm, ActionLatency(seconds=0.013), seed=0)
    env.reset()
    assert (env.current_params["action_latency_steps"], env.current_params["action_latency"]) == (7, 0.014)
    env.step(HOME)  # physics steps 0-4: the command is not there yet
    assert not dm.data.ctrl.any()
    env.step(HOME)  # physics steps 5-9: it lands at step 7
    assert np.allclose(dm.data.ctrl, HOME)
    env.close()


def test_train_on_a_batched_task_takes_signal_models_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Before: `train --config` holding only `signals:` (an actuator delay, sensor noise) on a task with a batched
    # kernel stopped with "AttributeError: 'ArmReachEnv' object has no attribute 'randomizer'": the batched TorchRL
    # env read the physics layer's addresses from a layer that was not there.
    from sim2real.batched.torchrl_env import BatchedTorchRLEnv

    env = BatchedTorchRLEnv("sim2real/arm-reach", 2, ActionLatency(seconds=0.1), seed=0)
    td = env.reset()
    assert env.param_names == ("action_latency_steps", "action_latency", "action_latency_control_steps")
    assert td["sim2real_params"].tolist() == [[50.0, 0.1, 5.0]] * 2  # as the single env reports them
    env.close()
    monkeypatch.chdir(tmp_path)
    Path("lat.yaml").write_text("signals:\n- {type: ActionLatency, seconds: 0.1}\n")
    Path("ppo.yaml").write_text("algo: ppo\nframes: 128\nframes_per_batch: 128\nminibatch_size: 64\nepochs: 1\n")
    code, out, err = run_cli(
        ["train", "--task", "sim2real/arm-reach", "--config", "lat.yaml", "--agent-config", "ppo.yaml", "--no-log",
         "--quiet", "--out", "ppo.pt"]
    )  # fmt: skip
    assert (code, err) == (0, "") and "collection: batched engine" in out and Path("ppo.pt").is_file()


def test_train_selects_the_dm_envs_observation_parts_through_torchrl(user_dir: Path, user: Any) -> None:
    # The hand-written dm_env's observation parts are named qpos/qvel: gymnasium's view of it (DmEnvToGym) takes
    # `select: qpos`, and so does TorchRL's (one flat 'observation' whose parts the gym env names), through which
    # PPO collects. Before, training stopped in a ValueError traceback (exit 1), then (HC's bc4a1d5) was refused in
    # one line: "`select` names key 'qpos', which the signal does not have. Known keys: 'observation'."
    Path("qpos_noise.yaml").write_text(
        "signals:\n- type: ObservationNoise\n  processes: [{type: Gaussian, std: 0.002}]\n  select: qpos\n"
    )
    code, _, err = run_cli(["train", "--env", f"{MODULE}:make_dm", "--config", "qpos_noise.yaml", "--frames", "64",
                              "--no-log", "--quiet", "--out", "qpos.pt"])  # fmt: skip
    assert (code, err) == (0, "") and Path("qpos.pt").exists()


def test_record_and_fit_step_the_hand_written_dm_env_at_its_declared_period(user_dir: Path, user: Any) -> None:
    # The dm_env says its period only through control_timestep() (0.01 s: 5 physics steps). Before the lead's
    # 2157f6a, record logged it at one physics step per control step (control_timestep 0.002, `--latency 2` = 4 ms)
    # and a driver CSV at 100 Hz was refused ("median spacing of 0.01 s, but meta['control_timestep'] is 0.002 s").
    source = ["--env", f"{MODULE}:make_dm"]
    code, out, err = run_cli(
        ["record", *source, "--set", "dof_damping[elbow]=*1.3", "--latency", "2", "--episodes", "1", "--steps", "100",
         "--obs-noise", "1e-3", "--seed", "0", "--out", "dm_log.npz", "--quiet"]
    )  # fmt: skip
    assert (code, err) == (0, "")
    log = sysid.load_log("dm_log.npz")
    assert log.control_timestep == pytest.approx(0.01) and log.meta["true_latency_seconds"]["action"] == 0.02
    with open("dm_log.csv", "w") as f:  # what a 100 Hz driver would write: ms and degrees
        header = ["t [ms]", *(f"q{i} [deg]" for i in range(4)), *(f"dq{i} [deg/s]" for i in range(4))]
        f.write(",".join([*header, *(f"u{i}" for i in range(4))]) + "\n")
        for t, q, dq, u in zip(log.time, log.qpos, log.qvel, log.ctrl, strict=True):
            f.write(",".join(str(v) for v in [1000 * t, *np.degrees(q), *np.degrees(dq), *u]) + "\n")
    Path("dm_map.yaml").write_text('columns: {time: "t [ms]", qpos: "q* [deg]", qvel: "dq* [deg/s]", ctrl: "u*"}\n')
    code, out, err = run_cli(
        ["sysid", "fit", "dm_log.csv", "--columns", "dm_map.yaml", *source, "--params", "dof_damping[elbow]",
         "--latency", "--quiet", "--out", "dm_fit.json"]
    )  # fmt: skip
    assert code in (0, 4), err
    fit = sysid.FitResult.from_json(Path("dm_fit.json"))
    assert "latency (s): action=0.02\n" in out
    assert fit.ci95[0][0] <= 1.3 <= fit.ci95[0][1]


def test_no_output_overwrites_the_module_of_the_users_env(user_dir: Path, user: Any) -> None:
    # Before: `--model robot.xml` was an input no output could overwrite, but the module of `--env pkg:make` was not:
    # `train --out`, `sysid fit --out` and `--export` naming it replaced the user's source with a checkpoint,
    # JSON or YAML (exit 0).
    module = Path(f"{MODULE}.py")
    source = module.read_bytes()
    env = ["--env", f"{MODULE}:make_gym"]
    fit = ["sysid", "fit", "dm_log.npz", *env, "--params", "dof_damping[*]", "--quiet"]
    runs = [
        ("train", ["train", *env, "--frames", "64", "--no-log", "--quiet", "--out", str(module)], "--out"),
        ("sysid", [*fit, "--out", "f.json", "--export", str(module)], "--export"),
        ("sysid", [*fit, "--out", f"./{module}"], "--out"),
    ]
    if not Path("dm_log.npz").exists():  # the log of the dm_env test; never read here: outputs are checked first
        Path("dm_log.npz").write_bytes(b"")
    for command, argv, flag in runs:
        code, out, err = run_cli(argv)
        given = argv[argv.index(flag) + 1]
        assert (code, out) == (2, "")
        assert err == (
            f"sim2real {command}: error: {flag} must not be the input --env module, which it would overwrite. "
            f"Received {given!r} for both.\n"
        )
        assert module.read_bytes() == source and not Path("f.json").exists()


def test_demo_holds_the_users_servo_arm_at_its_home_pose(user_dir: Path, user: Any) -> None:
    # The registered MujocoEnv's actions are its position servos' set points (the Box is the ctrlrange): the demo holds
    # them at the home keyframe's joint angles, as it does for an MJCF. Before it ran the zero action, which sends
    # every servo to 0 rad (HC's journey 3), under a line saying so.
    code, out, err = run_cli(["demo", "--env", f"{MODULE}:make_gym", "--episodes", "1", "--quiet"])
    assert (code, err) == (0, "")
    assert "policy: hold the home pose (position servos at their home set points; no scripted controller for" in out
    from sim2real.cli.demo import _hold_policy

    env = user.make_gym()
    hold = _hold_policy(env)
    assert hold is not None
    np.testing.assert_allclose(hold(None), HOME, atol=1e-6)  # the keyframe's joint angles, in the ctrl range
    env.close()
