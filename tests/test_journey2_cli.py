"""Journey 2 through the command line: a 7-DoF arm with a tendon gripper, a foreign driver CSV, a user's own
gymnasium MujocoEnv. Each test pins what a user saw before a fix and sees now."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import mujoco
import pytest
from conftest import run_cli as _run

import sysid

ARM = """<mujoco model="two_link">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <custom><numeric name="sim2real_control_timestep" data="0.01"/></custom>
  <worldbody>
    <body name="upper" pos="0 0 0.5">
      <joint name="shoulder" axis="0 1 0" range="-1.5 1.5" damping="0.5" armature="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="1"/>
      <body name="fore" pos="0.2 0 0">
        <joint name="elbow" axis="0 1 0" range="-2 2" damping="0.2" armature="0.01"/>
        <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.02" mass="0.5"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="servo_shoulder" joint="shoulder" kp="30" kv="1" ctrlrange="-1.5 1.5"/>
    <position name="servo_elbow" joint="elbow" kp="10" kv="0.5" ctrlrange="-2 2"/>
  </actuator>
  <keyframe><key name="home" qpos="0.3 -0.5"/></keyframe>
</mujoco>
"""


@pytest.fixture
def arm(tmp_path: Path) -> Path:
    path = tmp_path / "arm.xml"
    path.write_text(ARM)
    return path


def test_mujoco_instability_warnings_during_a_fit_are_counted_not_printed(
    tmp_path: Path, arm: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Before: every diverging rollout of the search printed "WARNING:absl:Nan, Inf or huge value in QACC ... The
    # simulation is unstable" (about 1900 lines for one fit of a 7-DoF arm's CSV in the wrong units) around the
    # one line that mattered. Now one note counts them.
    log = tmp_path / "log.npz"
    code, _, err = _run(
        ["record", "--model", str(arm), "--episodes", "1", "--steps", "40", "--quiet", "--out", str(log)]
    )
    assert code == 0, err
    real_fit = sysid.fit

    def fit(*args: Any, **kwargs: Any) -> Any:
        for _ in range(3):
            logging.getLogger("absl").warning("Nan, Inf or huge value in QACC at DOF 0. The simulation is unstable.")
        logging.getLogger("absl").warning("something else")
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(sysid, "fit", fit)
    seen: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: seen.append(record.getMessage())  # type: ignore[method-assign]
    logging.getLogger().addHandler(handler)
    try:
        code, _, err = _run(
            ["sysid", "fit", str(log), "--model", str(arm), "--params", "dof_damping[*]", "--quiet",
             "--out", str(tmp_path / "fit.json")]
        )  # fmt: skip
    finally:
        logging.getLogger().removeHandler(handler)
    assert code == 0, err
    assert "MuJoCo reported an unstable simulation 3 time(s) during the search" in err
    assert seen == ["something else"]  # other warnings still pass


USER_ENV = '''
import os, tempfile
import numpy as np
from gymnasium import spaces
from gymnasium.envs.mujoco import MujocoEnv

XML = """<mujoco model="arm2">
  <compiler angle="radian"/>
  <option timestep="0.0025"/>
  <worldbody>
    <body name="b1" pos="0 0 0.2">
      <joint name="s" axis="0 1 0" range="-2 2" damping="0.8"/>
      <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.03" mass="1.2"/>
      <body name="b2" pos="0.25 0 0">
        <joint name="e" axis="0 1 0" range="-2.5 2.5" damping="0.4"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.025" mass="0.7"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="s" ctrlrange="-8 8"/><motor joint="e" ctrlrange="-4 4"/></actuator>
  <sensor><jointvel joint="e"/></sensor>
</mujoco>"""


class Arm2(MujocoEnv):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}

    def __init__(self):
        path = os.path.join(tempfile.mkdtemp(), "arm2.xml")
        open(path, "w").write(XML)
        space = spaces.Box(-np.inf, np.inf, shape=(5,), dtype=np.float64)
        super().__init__(path, frame_skip=4, observation_space=space)

    def _get_obs(self):
        return np.concatenate([self.data.qpos, self.data.qvel, self.data.sensordata]).copy()

    def step(self, action):
        self.do_simulation(action, self.frame_skip)
        cost = 1e-3 * float(np.sum(np.square(action)))
        return self._get_obs(), -float(np.sum(self.data.qpos ** 2)) - cost, False, False, {}

    def reset_model(self):
        self.set_state(self.init_qpos, self.init_qvel)
        return self._get_obs()


def make():
    from gymnasium.wrappers import TimeLimit
    return TimeLimit(Arm2(), max_episode_steps=20)
'''


def test_a_latency_sweep_on_a_frame_skip_env_is_labelled_in_the_time_it_applies(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Before: ActionLatency.steps counts physics steps, but the report labelled the sweep 'action latency (control
    # steps)', so on a MujocoEnv with frame_skip=4 (100 Hz, 2.5 ms physics) the points 0, 4, 8 read as 0-80 ms of
    # latency when 0-20 ms were applied.
    (tmp_path / "journey2_user_env.py").write_text(USER_ENV)
    monkeypatch.syspath_prepend(str(tmp_path))
    spec = tmp_path / "eval.yaml"
    spec.write_text(
        "env: journey2_user_env:make\nepisodes: 2\nmax_steps: 5\nbatch: 2\n"
        "policies: {hold: {constant: [0.0, 0.0]}}\n"
        'real: {params: {"dof_damping[s]": 1.2}}\n'
        "sweeps: [{type: ActionLatency, steps: 0, field: steps, values: [0, 4, 8]}]\n"
    )
    code, _, err = _run(["evaluate", "--config", str(spec), "--out", str(tmp_path / "rep"), "--backend", "serial",
                         "--quiet"])  # fmt: skip
    assert code == 0, err
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "action latency (ms)" in md and "action latency (control steps)" not in md
    data = __import__("json").loads((tmp_path / "rep" / "report.json").read_text())
    assert (data["control_timestep"], data["substeps"]) == (0.01, 4)
    from sim2real.report.labels import axis_label

    assert axis_label("ActionLatency.steps", 0.01, substeps=4).factor == 2.5  # 4 physics steps = 10 ms


def test_sysid_fit_takes_a_horizon_and_a_short_automatic_one_gets_a_hint(
    tmp_path: Path, arm: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Before: the 7-DoF arm with an equality-coupled tendon gripper fitted its true values to 5 digits but ended
    # "not ok" (residuals not white, held-out error 2.59x) on the automatic 8-step shooting segments, and the CLI had
    # no way to ask for longer ones (sysid.fit(horizon=None) is ok on that log): the user could only --force.
    import dataclasses

    from sysid.quality import FitQuality

    log = tmp_path / "log.npz"
    code, _, err = _run(
        ["record", "--model", str(arm), "--episodes", "1", "--steps", "40", "--quiet", "--out", str(log)]
    )
    assert code == 0, err
    real_fit, asked = sysid.fit, []

    def fit(*args: Any, **kwargs: Any) -> Any:
        asked.append(kwargs["horizon"])
        result = real_fit(*args, **kwargs)
        return dataclasses.replace(result, quality=FitQuality(reasons=("residuals far from white",), horizon=8))

    monkeypatch.setattr(sysid, "fit", fit)
    base = ["sysid", "fit", str(log), "--model", str(arm), "--params", "dof_damping[*]", "--quiet"]
    code, _, err = _run([*base, "--out", str(tmp_path / "a.json")])
    assert code == 4 and asked == ["auto"]
    assert err.splitlines()[-1] == (
        "sim2real sysid fit: hint: the fit used shooting segments of 8 control steps (--horizon auto); if the model "
        "is right, refit with --horizon episode or a longer --horizon N"
    )
    code, _, err = _run([*base, "--out", str(tmp_path / "b.json"), "--horizon", "episode"])
    assert code == 4 and asked[-1] is None and "hint" not in err
    code, _, err = _run([*base, "--out", str(tmp_path / "c.json"), "--horizon", "40"])
    assert asked[-1] == 40
    code, _, err = _run([*base, "--horizon", "0"])
    assert code == 2 and "argument --horizon: must be 'auto', 'episode' or a number of control steps >= 1" in err


def test_an_empty_or_unreadable_log_says_what_it_is(tmp_path: Path, arm: Path) -> None:
    # Before: an empty driver CSV with --columns was "--columns applies to CSV logs; 'empty.csv' is a .npz log."
    columns = tmp_path / "map.yaml"
    columns.write_text("columns: {time: t, qpos: 'q*', qvel: 'dq*', ctrl: 'u*'}\n")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    binary = tmp_path / "log.bin"
    binary.write_bytes(bytes(range(256)))
    base = ["--model", str(arm), "--params", "dof_damping[*]", "--quiet", "--out", str(tmp_path / "f.json")]
    code, _, err = _run(["sysid", "fit", str(empty), "--columns", str(columns), *base])
    assert code == 2
    assert err == (
        f"sim2real sysid: error: `log` {str(empty)!r} must be a .npz log from `sim2real record` or a driver's CSV (a "
        "header row with ',', ';' or tabs). Received a file that is empty.\n"
    )
    code, _, err = _run(["sysid", "fit", str(binary), *base])
    assert code == 2 and err.endswith("Received a file that starts with neither a zip header nor a CSV header row.\n")
    assert not (tmp_path / "f.json").exists()


GRIPPER = """<mujoco model="wrist_gripper">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <worldbody>
    <body name="hand" pos="0 0 0.3">
      <joint name="wrist" axis="0 0 1" range="-2 2" damping="0.3"/>
      <geom type="box" size="0.03 0.03 0.02" mass="0.5"/>
      <body name="left" pos="0.03 0.02 0">
        <joint name="left" type="slide" axis="0 1 0" range="0 0.04" damping="0.5"/>
        <geom type="box" size="0.02 0.005 0.01" mass="0.05"/>
      </body>
      <body name="right" pos="0.03 -0.02 0">
        <joint name="right" type="slide" axis="0 -1 0" range="0 0.04" damping="0.5"/>
        <geom type="box" size="0.02 0.005 0.01" mass="0.05"/>
      </body>
    </body>
  </worldbody>
  <tendon><fixed name="grip"><joint joint="left" coef="0.5"/><joint joint="right" coef="0.5"/></fixed></tendon>
  <actuator>
    <position name="turn" joint="wrist" kp="5" kv="0.3" ctrlrange="-2 2"/>
    <position name="squeeze" tendon="grip" kp="40" kv="2" ctrlrange="0 0.04"/>
  </actuator>
  <keyframe><key name="home" qpos="0 0.02 0.02"/></keyframe>
</mujoco>
"""


def test_slide_fingers_are_reported_in_linear_units(tmp_path: Path) -> None:
    # Before: the report's System identification table gave a gripper finger's (slide joint) damping in N·m·s/rad
    # and its gain in N·m per ctrl unit, and the fit figure its position in rad: every parameter and channel was
    # taken for a hinge. Now evaluate reads the model: N·s/m, N per ctrl unit, m.
    model = tmp_path / "gripper.xml"
    model.write_text(GRIPPER)
    log, fit = tmp_path / "log.npz", tmp_path / "fit.json"
    code, _, err = _run(
        ["record", "--model", str(model), "--set", "dof_damping[left]=*2", "--episodes", "1", "--steps", "60",
         "--quiet", "--out", str(log)]
    )  # fmt: skip
    assert code == 0, err
    code, _, err = _run(
        ["sysid", "fit", str(log), "--model", str(model), "--params", "dof_damping[left],actuator_gain[squeeze]",
         "--horizon", "episode", "--quiet", "--force", "--out", str(fit)]
    )  # fmt: skip
    assert code in (0, 4), err
    spec = tmp_path / "eval.yaml"
    spec.write_text(
        f"model: {model}\nepisodes: 2\nmax_steps: 5\nbatch: 2\npolicies: {{hold: {{constant: [0.0, 0.02]}}}}\n"
        f"real: {{params: {{'dof_damping[left]': 1.0}}}}\nreport: {{fit: {fit}}}\n"
    )
    code, _, err = _run(["evaluate", "--config", str(spec), "--out", str(tmp_path / "rep"), "--backend", "serial",
                         "--quiet"])  # fmt: skip
    assert code == 0, err
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "| dof\\_damping\\[left\\] | N·s/m |" in md, md
    assert "| actuator\\_gain\\[squeeze\\] | N per ctrl unit |" in md
    from sim2real.report.labels import channel_unit

    assert (channel_unit("qpos[left]", ("left",)), channel_unit("qvel[left]", ("left",))) == ("m", "m/s")
    assert channel_unit("qpos[wrist]", ("left",)) == "rad"


def test_demo_holds_a_servo_arm_at_home_and_gives_a_torque_arm_zero(tmp_path: Path, arm: Path) -> None:
    # Before: `demo --model` on a servo arm ran "zero action", which sends every servo to 0 rad: the 7-DoF arm's
    # nominal return was -385 for an env that scores holding the home pose, so the demo compared nominal and
    # randomised physics under a policy that left home at once (now -4.5 nominal, -24.9 randomised).
    code, out, err = _run(["demo", "--model", str(arm), "--episodes", "1", "--quiet"])
    assert code == 0, err
    assert (
        "policy: hold the home pose (position servos at their home set points; no scripted controller for arm.xml)"
        in out
    )
    nominal = float(next(line for line in out.splitlines() if line.startswith("nominal")).split()[1])
    assert nominal > -5.0  # the servos hold the two-link arm near home (-1.3; zero action: -64.5)
    torque = tmp_path / "torque.xml"
    torque.write_text(ARM.replace('<position name="servo_shoulder" joint="shoulder" kp="30" kv="1"', '<motor name="m1" joint="shoulder"').replace('<position name="servo_elbow" joint="elbow" kp="10" kv="0.5"', '<motor name="m2" joint="elbow"'))  # fmt: skip
    code, out, err = _run(["demo", "--model", str(torque), "--episodes", "1", "--quiet"])
    assert code == 0, err
    assert "policy: zero action (no scripted controller for torque.xml" in out


def test_record_prints_the_true_latency_it_applied(tmp_path: Path, arm: Path) -> None:
    # Before: `record --latency 2` printed "true params {}" and nothing about the 20 ms it applied (the log's meta
    # had it), so the line a user checks a fit against left the latency out.
    log = tmp_path / "log.npz"
    code, out, err = _run(
        ["record", "--model", str(arm), "--episodes", "1", "--steps", "30", "--latency", "2", "--quiet", "--out", str(log)]
    )  # fmt: skip
    assert code == 0, err
    assert "true latency (s): action=0.02\n" in out
    assert sysid.load_log(log).meta["true_latency_seconds"] == {"action": 0.02, "obs": 0.0}
    code, out, _ = _run(
        ["record", "--model", str(arm), "--episodes", "1", "--steps", "30", "--quiet", "--out", str(log)]
    )
    assert code == 0 and "true latency" not in out


def test_a_home_pose_of_the_wrong_length_names_the_joints_in_qpos_order(tmp_path: Path) -> None:
    # Before: "--home must give 3 joint positions (the model's nq). Received 1." for a wrist with two slide
    # fingers: the user of a 7-DoF arm gave its 7 angles and was not told the 8th and 9th are the fingers.
    model = tmp_path / "gripper.xml"
    model.write_text(GRIPPER)
    code, _, err = _run(["record", "--model", str(model), "--home", "0.2", "--quiet", "--out", str(tmp_path / "x.npz")])
    assert code == 2
    assert err == (
        "sim2real record: error: `--home` must give 3 joint positions (the model's nq, in qpos order: wrist, left, "
        "right). Received 1.\n"
    )
    from sim2real.home import resolve_home

    free = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body name='puck'><freejoint name='puck'/><geom size='0.1'/></body></worldbody></mujoco>"
    )
    with pytest.raises(ValueError, match=r"7 joint positions \(the model's nq, in qpos order: puck x7\)"):
        resolve_home((0.0,), free)


def test_a_sensor_noise_sweep_on_a_model_file_is_labelled_in_rad(tmp_path: Path, arm: Path) -> None:
    # Before: evaluate on --model / model: labelled a sensor-noise sweep "sensor noise std (observation units)",
    # though a bare MJCF env observes qpos and qvel of hinges: rad and rad/s.
    spec = tmp_path / "eval.yaml"
    spec.write_text(
        f"model: {arm}\nepisodes: 2\nmax_steps: 5\nbatch: 2\npolicies: {{hold: {{constant: [0.3, -0.5]}}}}\n"
        "real: {params: {'dof_damping[elbow]': 0.3}}\n"
        "sweeps: [{type: ObservationNoise, processes: [{type: Gaussian, std: 0.0}], field: processes.0.std, "
        "values: [0.0, 0.01]}]\n"
    )
    code, _, err = _run(["evaluate", "--config", str(spec), "--out", str(tmp_path / "rep"), "--backend", "serial",
                         "--quiet"])  # fmt: skip
    assert code == 0, err
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "sensor noise std (rad (qpos), rad/s (qvel))" in md and "observation units" not in md
