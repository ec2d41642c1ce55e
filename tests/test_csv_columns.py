"""A driver's CSV whose columns name the joints in the driver's own order, a clock that restarts per episode, and
a model with a free body beside the arm: what ``sysid.load_csv`` (and ``sim2real sysid fit``) say about each.

The arm is written here (3 hinges with limits, position servos named apart from their joints, a free puck); the
CSV numbers are generated, so nothing is simulated and every test runs in well under a second.
"""

from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim2real.cli import main
from sim2real.cli.sysid_commands import EXIT_FIT_NOT_OK
from sysid import LogError, load_csv

ARM = """
<mujoco model="csv_arm">
  <compiler angle="radian"/>
  <option timestep="0.005"/>
  <worldbody>
    <body name="base">
      <joint name="yaw" axis="0 0 1" range="-2 2"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="1"/>
      <body name="upper" pos="0.2 0 0">
        <joint name="shoulder" axis="0 1 0" range="-1.5 1.5"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="1"/>
        <body name="fore" pos="0.2 0 0">
          <joint name="elbow" axis="0 1 0" range="-2 2"/>
          <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.02" mass="0.5"/>
        </body>
      </body>
    </body>
    {puck}
  </worldbody>
  <actuator>
    <position name="servo_yaw" joint="yaw" kp="20" ctrlrange="-2 2"/>
    <position name="servo_shoulder" joint="shoulder" kp="40" ctrlrange="-1.5 1.5"/>
    <position name="servo_elbow" joint="elbow" kp="20" ctrlrange="-2 2"/>
  </actuator>
</mujoco>
"""
PUCK = '<body name="puck" pos="0.5 0 0.1"><freejoint name="puck_free"/><geom size="0.03" mass="0.1"/></body>'
JOINTS = ["yaw", "shoulder", "elbow"]
DRIVER_ORDER = [2, 0, 1]  # the driver writes elbow, yaw, shoulder
META = {"timestep": 0.005, "control_timestep": 0.02}
UNITS = {"stamp_ms": "ms", "*_deg": "deg", "*_dps": "deg/s"}


def _model(puck: bool = False) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(ARM.replace("{puck}", PUCK if puck else ""))


def _write(path: Path, *, episodes: int = 1, rows: int = 12) -> np.ndarray:
    """A driver's CSV in degrees and milliseconds, joints in the driver's order, each episode's clock from 0;
    returns the qpos (radians, model order) it holds."""
    k = np.arange(rows)
    qpos = 0.1 * np.sin(0.3 * k[:, None] + np.arange(3))  # column j is joint j, model order
    header = ["status", "stamp_ms", "ep"] + [f"{JOINTS[j]}_deg" for j in DRIVER_ORDER]
    header += [f"{JOINTS[j]}_dps" for j in DRIVER_ORDER] + [f"cmd_{JOINTS[j]}" for j in DRIVER_ORDER]
    lines = [",".join(header)]
    for e in range(episodes):
        for r in range(rows):
            q = [math.degrees(qpos[r, j]) for j in DRIVER_ORDER]
            lines.append(
                ",".join(map(str, ["OK", 20.0 * r, e, *q, *(0.0 for _ in q), *(0.01 * j for j in DRIVER_ORDER)]))
            )
    path.write_text("\n".join(lines) + "\n")
    return np.tile(qpos, (episodes, 1))


def test_a_pattern_matching_joints_in_the_drivers_order_is_refused_with_the_list_to_use(tmp_path: Path) -> None:
    path = tmp_path / "driver.csv"
    _write(path)
    columns = {"time": "stamp_ms", "qpos": "*_deg", "qvel": "*_dps", "ctrl": "cmd_*"}
    with pytest.raises(LogError) as caught:
        load_csv(path, columns, meta=META, model=_model(), units=UNITS)
    message = str(caught.value)
    assert (
        "`columns['qpos']` must list the CSV columns in the model's order of joints ('yaw', 'shoulder', 'elbow')"
        in message
    )
    assert "Received them in the order ['elbow_deg', 'yaw_deg', 'shoulder_deg']" in message
    assert "qpos: [yaw_deg, shoulder_deg, elbow_deg]" in message


def test_explicit_lists_in_the_models_order_load_each_joint_into_its_own_column(tmp_path: Path) -> None:
    path = tmp_path / "driver.csv"
    qpos = _write(path)
    columns = {
        "time": "stamp_ms",
        "qpos": [f"{j}_deg" for j in JOINTS],
        "qvel": [f"{j}_dps" for j in JOINTS],
        "ctrl": [f"cmd_{j}" for j in JOINTS],  # named by the joints the servos drive, not by the servos
    }
    log = load_csv(path, columns, meta=META, model=_model(), units=UNITS)
    np.testing.assert_allclose(log.qpos, qpos, atol=1e-12)
    np.testing.assert_allclose(log.ctrl[0], [0.0, 0.01, 0.02])


def test_commands_named_by_joint_in_another_order_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "driver.csv"
    _write(path)
    columns = {"time": "stamp_ms", "qpos": [f"{j}_deg" for j in JOINTS], "qvel": [f"{j}_dps" for j in JOINTS],
               "ctrl": "cmd_*"}  # fmt: skip
    with pytest.raises(LogError, match=r"`columns\['ctrl'\]` must list .* order of actuators \('servo_yaw'"):
        load_csv(path, columns, meta=META, model=_model(), units=UNITS)


def test_columns_that_do_not_name_joints_keep_the_files_order(tmp_path: Path) -> None:
    path = tmp_path / "plain.csv"
    rows = ["t,q0,q1,q2,dq0,dq1,dq2,u0,u1,u2"] + [f"{0.02 * k},{0.01 * k},0,0,0,0,0,0,0,0" for k in range(5)]
    path.write_text("\n".join(rows) + "\n")
    log = load_csv(path, {"time": "t", "qpos": "q*", "qvel": "dq*", "ctrl": "u*"}, meta=META, model=_model())
    assert log.qpos[:, 0].tolist() == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04])


def test_a_clock_that_restarts_without_an_episode_column_says_to_map_one(tmp_path: Path) -> None:
    path = tmp_path / "two_episodes.csv"
    _write(path, episodes=2)
    columns = {"time": "stamp_ms", "qpos": [f"{j}_deg" for j in JOINTS], "qvel": [f"{j}_dps" for j in JOINTS],
               "ctrl": [f"cmd_{j}" for j in JOINTS]}  # fmt: skip
    with pytest.raises(LogError) as caught:
        load_csv(path, columns, meta=META, model=_model(), units=UNITS)
    message = str(caught.value)
    assert "row 14, time column 'stamp_ms' must increase within a segment. Received 0 s after 0.22 s." in message
    assert "map the column that numbers them as columns['episode']" in message
    assert "np.float64" not in message
    log = load_csv(path, {**columns, "episode": "ep"}, meta=META, model=_model(), units=UNITS)
    assert log.episode is not None and log.episode.max() == 1


def test_a_model_with_a_free_body_names_it_when_the_log_lacks_its_state(tmp_path: Path) -> None:
    path = tmp_path / "driver.csv"
    _write(path)
    columns = {"time": "stamp_ms", "qpos": [f"{j}_deg" for j in JOINTS], "qvel": [f"{j}_dps" for j in JOINTS],
               "ctrl": [f"cmd_{j}" for j in JOINTS]}  # fmt: skip
    with pytest.raises(LogError) as caught:
        load_csv(path, columns, meta=META, model=_model(puck=True), units=UNITS)
    assert "`qpos` must have nq=10 columns to match the model (it holds every joint, free joint 'puck_free' (7)" in str(
        caught.value
    )
    assert "Received 3 columns" in str(caught.value)


def test_the_cli_refuses_a_reordered_map_with_exit_2_and_one_line(tmp_path: Path) -> None:
    path, arm, columns = tmp_path / "driver.csv", tmp_path / "arm.xml", tmp_path / "map.yaml"
    _write(path)
    arm.write_text(ARM.replace("{puck}", ""))
    columns.write_text(
        'columns: {time: stamp_ms, qpos: "*_deg", qvel: "*_dps", ctrl: "cmd_*"}\n'
        'units: {stamp_ms: ms, "*_deg": deg, "*_dps": deg/s}\n'
    )
    out = tmp_path / "fit.json"
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["sysid", "fit", str(path), "--model", str(arm), "--columns", str(columns),
                     "--params", "dof_damping[elbow]", "--out", str(out), "--quiet"])  # fmt: skip
    assert code == 2
    assert err.getvalue().count("\n") == 1 and "must list the CSV columns in the model's order" in err.getvalue()
    assert not out.exists()


def test_sysid_fit_help_states_the_exit_code_the_command_returns() -> None:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["sysid", "fit", "--help"]) == 0
    text = " ".join(out.getvalue().split())
    assert f"Exit {EXIT_FIT_NOT_OK} when the fitted model cannot reproduce the log" in text
    assert f"(exit {EXIT_FIT_NOT_OK}) unless --force" in text
    assert "%%" not in text and "95% intervals" in text


def test_a_whiteness_failure_on_a_jittery_csv_names_the_command_timing_among_its_causes(tmp_path: Path) -> None:
    from sysid.fit import _jitter_steps
    from sysid.quality import assess

    path = tmp_path / "jittery.csv"
    rows = ["t,yaw,shoulder,elbow,dyaw,dshoulder,delbow,u0,u1,u2"]
    rows += [f"{0.02 * k + (0.004 if k % 3 == 1 else 0.0)},0,0,0,0,0,0,0,0,0" for k in range(8)]
    path.write_text("\n".join(rows) + "\n")
    columns = {"time": "t", "qpos": ["yaw", "shoulder", "elbow"], "qvel": "d*", "ctrl": "u*"}
    log = load_csv(path, columns, meta=META, model=_model())
    assert log.meta["csv"]["resampled"] and _jitter_steps(log) == pytest.approx(0.2)
    coloured = ({"qvel[a]": 40.0}, {"qvel[a]": 1e-6}, (), 10.0, True, 1.0, {"d": 1.0}, 0, 1)
    (reason,) = [r for r in assess(*coloured, jitter=_jitter_steps(log)).reasons if "far from white" in r]
    assert reason.endswith(
        "a wrong model, or the CSV's jittery clock (samples up to 20% of a control step off the grid; the fit takes "
        "each command to act from its grid point)"
    )
    assert [r for r in assess(*coloured).reasons if r.endswith("a wrong latency or a wrong model")]


def test_a_pattern_that_also_takes_another_keys_columns_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "driver.csv"
    _write(path)
    columns = {"time": "stamp_ms", "qpos": "*_d*", "qvel": [f"{j}_dps" for j in JOINTS],
               "ctrl": [f"cmd_{j}" for j in JOINTS]}  # fmt: skip
    with pytest.raises(LogError, match=r"maps CSV column 'yaw_dps' to both 'qpos' and 'qvel'; a column feeds one key"):
        load_csv(path, columns, meta=META, model=_model(), units=UNITS)


def test_a_time_unit_on_commands_is_refused_and_degrees_on_servo_commands_convert(tmp_path: Path) -> None:
    path = tmp_path / "driver.csv"
    _write(path)
    columns = {"time": "stamp_ms", "qpos": [f"{j}_deg" for j in JOINTS], "qvel": [f"{j}_dps" for j in JOINTS],
               "ctrl": [f"cmd_{j}" for j in JOINTS]}  # fmt: skip
    with pytest.raises(LogError, match=r"`units` of column 'cmd_yaw' \(mapped to ctrl\) must be one of \['rad', 'deg'"):
        load_csv(path, columns, meta=META, model=_model(), units={**UNITS, "cmd_*": "ms"})
    log = load_csv(path, columns, meta=META, model=_model(), units={**UNITS, "cmd_*": "deg"})
    np.testing.assert_allclose(log.ctrl[0], np.radians([0.0, 0.01, 0.02]))
