"""The own-robot journey through the commands a user reaches for next: ``demo`` and ``visualize`` on an MJCF file,
with the config ``sysid fit --export`` writes (effects *and* signal models), and configs with a mistyped key.

The arm is written here (2 limited hinges, position servos, gravity); every run is a few short episodes.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import run_cli as _run

import sim2real as s2r
from randomizers import load_config, load_effects
from sim2real.output_paths import OutputPathError

ARM = """<mujoco model="two_link">
  <compiler angle="radian"/>
  <option timestep="0.004"/>
  <worldbody>
    <light pos="0 0 2"/>
    <body name="upper" pos="0 0 0.5">
      <joint name="shoulder" axis="0 1 0" range="-1.5 1.5" damping="0.5"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="1"/>
      <body name="fore" pos="0.2 0 0">
        <joint name="elbow" axis="0 1 0" range="-2 2" damping="0.2"/>
        <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.02" mass="0.5"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="servo_shoulder" joint="shoulder" kp="30" ctrlrange="-1.5 1.5"/>
    <position name="servo_elbow" joint="elbow" kp="10" ctrlrange="-2 2"/>
  </actuator>
  <keyframe><key name="home" qpos="0.3 -0.5"/></keyframe>
</mujoco>
"""
EXPORTED = """effects:
- type: Damping
  set: {type: Uniform, low: 0.45, high: 0.55}
  joints: shoulder
signals:
- type: ObservationNoise
  processes:
  - {type: Gaussian, std: 0.001}
- {type: ActionLatency, seconds: 0.032}
"""


@pytest.fixture
def arm(tmp_path: Path) -> Path:
    path = tmp_path / "my arm.xml"
    path.write_text(ARM)
    return path


def test_demo_takes_a_model_file_and_applies_the_exported_signals(tmp_path: Path, arm: Path) -> None:
    config = tmp_path / "exported.yaml"
    config.write_text(EXPORTED)
    code, out, err = _run(["demo", "--model", str(arm), "--config", str(config), "--episodes", "1", "--quiet"])
    assert (code, err) == (0, "")
    assert out.startswith("sim2real demo: my arm.xml, 1 episode(s) per condition")
    assert "hold the home pose (position servos at their home set points; no scripted controller for my arm.xml)" in out
    for model in ("Damping(set=Uniform(low=0.45, high=0.55), joints='shoulder')", "ActionLatency(seconds=0.032)"):
        assert f"  {model}\n" in out
    assert "ObservationNoise(Gaussian(std=0.001))" in out


def test_demo_refuses_two_sources_and_a_config_key_it_would_ignore(tmp_path: Path, arm: Path) -> None:
    code, _, err = _run(["demo", "--task", "sim2real/arm-reach", "--model", str(arm), "--episodes", "1"])
    assert (code, err) == (
        2,
        "sim2real demo: error: argument --model: not allowed with argument --task. See `sim2real demo --help`.\n",
    )  # one line, as the README promises for every failure (argparse printed its usage block first)
    typo = tmp_path / "typo.yaml"
    typo.write_text("effects: []\nsignal: [{type: ObservationLatency, steps: 2}]\n")
    code, out, err = _run(["demo", "--model", str(arm), "--config", str(typo), "--episodes", "1", "--quiet"])
    assert (code, out) == (2, "")
    assert err == (
        f"sim2real demo: error: --config: {typo}: the top-level keys must be among ['effects', 'signals']. Received "
        "unknown ['signal']. ('signal': did you mean 'signals'?)\n"
    )


def test_config_loaders_refuse_unknown_top_level_keys() -> None:
    with pytest.raises(ValueError, match=r"Received unknown \['signal'\]\. \('signal': did you mean 'signals'\?\)"):
        load_config("effects: [{type: Damping, scale: 2.0}]\nsignal: []\n")
    with pytest.raises(ValueError, match=r"Received unknown \['efects', 'notes'\]\. \('efects': did you mean"):
        load_effects({"effects": [], "efects": [], "notes": "x"})
    # signals are load_config's: load_effects reads the effects of a config that also holds them
    assert [type(m).__name__ for m in load_config(EXPORTED)] == ["Damping", "ObservationNoise", "ActionLatency"]
    assert [type(m).__name__ for m in load_effects(EXPORTED)] == ["Damping"]


def test_visualize_creates_a_missing_folder_and_the_api_checks_out_before_rendering(tmp_path: Path, arm: Path) -> None:
    out = tmp_path / "sheets ü" / "new" / "sheet.png"
    code, stdout, err = _run(["visualize", "--model", str(arm), "--n", "2", "--size", "16", "--out", str(out)])
    assert (code, err) == (0, "")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and stdout.startswith(f"wrote {out} (2 frames of my arm.xml")
    source_id = "model:" + str(arm)
    with pytest.raises(OutputPathError, match=r"`out` must be in a folder that exists or can be created; .* is a file"):
        s2r.contact_sheet(source_id, n=1, size=(8, 8), out=arm / "sheet.png")


def test_record_shows_a_progress_bar_when_asked_and_none_when_quiet(
    tmp_path: Path, arm: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sim2real.recording import record
    from sim2real.sources import resolve_source

    source = resolve_source(model=arm)
    shown = record(source, episodes=2, steps=20, progress=True)
    err = capsys.readouterr().err
    assert "record: " in err and "recording 2 episode(s)" in err
    assert record(source, episodes=2, steps=20).qpos.tobytes() == shown.qpos.tobytes()  # same log either way
    assert capsys.readouterr().err == ""  # None: only on a terminal (pytest's capture is not one)
    code, out, err = _run(["record", "--model", str(arm), "--episodes", "1", "--steps", "20", "--quiet",
                           "--out", str(tmp_path / "log.npz")])  # fmt: skip
    assert (code, err) == (0, "") and out.startswith(f"wrote {tmp_path / 'log.npz'}: 20 rows")


def test_record_takes_a_home_pose_of_negative_angles_and_says_when_it_starts_at_a_limit(
    tmp_path: Path, arm: Path
) -> None:
    import numpy as np

    import sysid

    out = tmp_path / "log.npz"
    code, stdout, err = _run(["record", "--model", str(arm), "--home", "-0.3,-0.5", "--episodes", "1", "--steps", "10",
                              "--quiet", "--out", str(out)])  # fmt: skip
    assert (code, err) == (0, "")
    assert sysid.load_log(out).meta["excitation"]["home"] == [-0.3, -0.5]
    np.testing.assert_allclose(sysid.load_log(out).qpos[0], [-0.3, -0.5])
    # 1.49 is inside shoulder's range [-1.5, 1.5] but within 1% of its end: no excitation can keep it clear
    code, stdout, err = _run(["record", "--model", str(arm), "--home", "1.49,0", "--episodes", "1", "--steps", "10",
                              "--quiet", "--out", str(out)])  # fmt: skip
    assert (code, err) == (0, "")
    assert (
        "note: joint 'shoulder' starts within 1% of an end of its range (home 1.49, range [-1.5, 1.5]), so the check "
        "that keeps joints clear of their limits cannot pass; the amplitude was not reduced.\n"
    ) in stdout
    assert "not at rest" not in stdout


def test_measured_returns_under_an_unknown_policy_name_are_refused_and_a_bom_is_read(tmp_path: Path, arm: Path) -> None:
    from sim2real.spec import SpecError, load_spec

    spec = tmp_path / "spec.yaml"
    spec.write_text(
        f"model: {arm.name}\nepisodes: 1\nmax_steps: 5\npolicies: {{hold: {{constant: [0.3, -0.5]}}, "
        "limp: {constant: [0.0, 0.0]}}\nreal: {csv: real.csv}\n"
    )
    (tmp_path / "real.csv").write_text("policy,return\nHold,-0.2\nlimp,-1.0\n")
    with pytest.raises(SpecError) as caught:
        load_spec(spec)
    assert str(caught.value) == (
        f"{spec}: real.csv: every policy of the measured returns must be one of `policies` ['hold', 'limp']. "
        "Received unknown ['Hold']. ('Hold': did you mean 'hold'?)"
    )
    (tmp_path / "real.csv").write_text("policy, return\nhold,-0.2\nlimp,-1.0\n", encoding="utf-8-sig")
    (real,) = [c for c in load_spec(spec).conditions if c.name == "real"]
    assert real.returns == {"hold": (-0.2,), "limp": (-1.0,)}


def test_record_refuses_a_sensor_latency_on_a_model_without_sensors(tmp_path: Path, arm: Path) -> None:
    out = tmp_path / "log.npz"
    code, stdout, err = _run(["record", "--model", str(arm), "--obs-latency", "2", "--episodes", "1", "--steps", "10",
                              "--quiet", "--out", str(out)])  # fmt: skip
    assert (code, stdout) == (2, "") and not out.exists()
    assert err == (
        "sim2real record: error: `obs_latency` delays the model's sensordata (qpos and qvel are the true state), and "
        "this model has no sensors. Received 2; give 0, or add <sensor> elements to the MJCF.\n"
    )


def test_a_latency_at_the_top_of_its_searched_range_is_flagged_and_latency_max_widens_it(
    tmp_path: Path, arm: Path
) -> None:
    log, fit = tmp_path / "log.npz", tmp_path / "fit.json"
    code, _, err = _run(["record", "--model", str(arm), "--latency", "3", "--obs-noise", "1e-3", "--episodes", "1",
                         "--steps", "80", "--quiet", "--out", str(log)])  # fmt: skip
    assert (code, err) == (0, "")
    argv = ["sysid", "fit", str(log), "--model", str(arm), "--params", "dof_damping[elbow]", "--quiet",
            "--out", str(fit)]  # fmt: skip
    _, out, _ = _run([*argv, "--latency-max", "2"])
    assert (
        "warning: the action latency is the largest searched (2 control steps, 0.04 s): the true delay may be longer; "
        "search further with latency=4 (sysid fit --latency-max 4)." in out
    )
    code, out, err = _run([*argv, "--latency-max", "4"])
    assert code == 0 and "latency (s): action=0.06" in out and "largest searched" not in out


def test_record_refuses_an_out_that_is_not_a_npz_before_recording(tmp_path: Path, arm: Path, monkeypatch) -> None:
    import sim2real.recording

    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError("recorded before the output path was checked")

    monkeypatch.setattr(sim2real.recording, "record", fail)
    code, out, err = _run(["record", "--model", str(arm), "--out", str(tmp_path / "log.dat")])
    assert (code, out) == (2, "")
    assert (
        err
        == f"sim2real record: error: --out must end in '.npz' (a trajectory log). Received {str(tmp_path / 'log.dat')!r}.\n"
    )
    assert list(tmp_path.iterdir()) == [arm]


def test_visualize_refuses_a_non_png_name_and_a_config_folder_is_named_as_such(tmp_path: Path, arm: Path) -> None:
    code, out, err = _run(
        ["visualize", "--model", str(arm), "--n", "1", "--size", "8", "--out", str(tmp_path / "s.jpg")]
    )
    assert (code, out) == (2, "") and not (tmp_path / "s.jpg").exists()
    assert (
        err
        == f"sim2real visualize: error: `out` must end in '.png' (the sheet is a PNG image). Received {str(tmp_path / 's.jpg')!r}.\n"
    )
    with pytest.raises(FileNotFoundError, match=r"`config` file .* is a folder, not a file\."):
        load_config(tmp_path)


def test_no_output_may_overwrite_an_input_file(tmp_path: Path, arm: Path) -> None:
    log = tmp_path / "log.npz"
    assert (
        _run(["record", "--model", str(arm), "--episodes", "1", "--steps", "10", "--quiet", "--out", str(log)])[0] == 0
    )
    before = {p: p.read_bytes() for p in (arm, log)}
    fit = ["sysid", "fit", str(log), "--model", str(arm), "--params", "dof_damping[elbow]", "--quiet"]
    spelled = str(tmp_path / "sub" / ".." / arm.name)  # another spelling of the MJCF
    cases = [
        ([*fit, "--out", str(log)], "sysid", "--out", "the input `log`", str(log)),
        ([*fit, "--out", str(tmp_path / "r.json"), "--export", spelled], "sysid", "--export", "the input --model", spelled),
        (["train", "--model", str(arm), "--no-log", "--quiet", "--out", str(arm)], "train", "--out", "the input --model", str(arm)),
    ]  # fmt: skip
    for argv, command, option, source, path in cases:
        code, out, err = _run(argv)
        assert (code, out) == (2, ""), argv
        assert (
            err
            == f"sim2real {command}: error: {option} must not be {source}, which it would overwrite. Received {path!r} for both.\n"
        )
    assert {p: p.read_bytes() for p in (arm, log)} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.npz", "my arm.xml"]


def test_sysid_fit_refuses_a_report_that_is_not_html_before_fitting(tmp_path: Path, arm: Path, monkeypatch) -> None:
    import sysid

    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError("fitted before the report path was checked")

    monkeypatch.setattr(sysid, "fit", fail)
    log = tmp_path / "log.npz"
    log.write_bytes(b"")  # never read: the outputs are checked first
    report = tmp_path / "fit.pdf"
    argv = ["sysid", "fit", str(log), "--model", str(arm), "--params", "dof_damping[*]", "--report", str(report)]
    code, out, err = _run(argv)
    assert (code, out) == (2, "")
    assert (
        err
        == f"sim2real sysid: error: --report must end in '.html' or '.htm' (an HTML page). Received {str(report)!r}.\n"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([arm.name, "log.npz"])


def test_study_on_a_model_says_which_commands_run_its_loop(tmp_path: Path, arm: Path) -> None:
    out = tmp_path / "study"
    code, stdout, err = _run(["study", "--model", str(arm), "--out", str(out)])
    assert (code, stdout) == (2, "") and not out.exists()
    assert err.startswith("sim2real study: error: the study runs on tasks with a bundled profile and trained policies")
    assert err.endswith(f"(README, 'Your own robot'). Received --model {arm}.\n") and err.count("\n") == 1


def test_sysid_export_of_a_model_file_puts_the_noise_on_qpos_and_qvel_separately(tmp_path: Path, arm: Path) -> None:
    # Before: `sysid fit --model robot.xml --export` wrote one sensor-noise level for the whole observation, the mean
    # of the position and velocity channels' (sysid can fit them apart: FitResult.noise_level). An MJCF robot's
    # observation is qpos then qvel, so each group now gets its own level, where the env says which entries it is.
    log, out, export = tmp_path / "log.npz", tmp_path / "fit.json", tmp_path / "calibrated.yaml"
    code, _, err = _run(
        ["record", "--model", str(arm), "--policy", "multisine", "--episodes", "2", "--steps", "150", "--seed", "3",
         "--obs-noise", "0.002", "--out", str(log), "--quiet"]
    )  # fmt: skip
    assert code == 0, err
    code, _, err = _run(
        ["sysid", "fit", str(log), "--model", str(arm), "--params", "dof_damping[shoulder]", "--out", str(out),
         "--export", str(export), "--quiet", "--force"]
    )  # fmt: skip
    assert code in (0, 4), err
    (noise,) = [m for m in load_config(export) if type(m).__name__ == "ObservationNoise"]
    assert [p.select for p in noise.processes] == [(0, 1), (2, 3)]  # qpos (2 hinges), then qvel
    for process in noise.processes:
        assert process.std.low < 0.002 < process.std.high, process
