"""Tests for the ``sim2real`` command line."""

from __future__ import annotations

from pathlib import Path

import pytest

import sim2real
from sim2real.cli import main


def test_tasks_lists_every_task_id(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tasks"]) == 0
    out = capsys.readouterr().out
    for task_id, task in sim2real.TASKS.items():
        assert task_id in out
        assert task.description in out
    assert "gym/<id>" in out


def test_help_and_version_exit_zero(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "tasks" in out and "demo" in out
    assert main(["demo", "--help"]) == 0
    assert "--episodes" in capsys.readouterr().out
    assert main(["--version"]) == 0
    assert sim2real.__version__ in capsys.readouterr().out


def test_no_command_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 2
    assert "usage: sim2real" in capsys.readouterr().err


def test_demo_prints_both_conditions_and_is_deterministic(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--episodes", "2", "--seed", "0"]) == 0
    first = capsys.readouterr().out
    assert main(["demo", "--episodes", "2", "--seed", "0"]) == 0
    second = capsys.readouterr().out
    assert first == second
    lines = first.splitlines()
    assert any(line.startswith("nominal ") for line in lines)
    assert any(line.startswith("randomised ") for line in lines)
    assert "success" in first
    assert "scripted reach" in first
    # sampled parameters of the first episodes, by address
    assert "actuator_gain[base_yaw]" in first
    assert "dof_damping[elbow_pitch]" in first
    assert "ep 1 (seed 1)" in first


def test_demo_seed_changes_the_draws(capsys: pytest.CaptureFixture[str]) -> None:
    main(["demo", "--episodes", "1", "--seed", "0", "--quiet"])
    a = capsys.readouterr().out
    main(["demo", "--episodes", "1", "--seed", "1", "--quiet"])
    b = capsys.readouterr().out
    assert a != b


def test_demo_with_config_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "effects.yml"
    config.write_text("effects:\n  - type: Damping\n    scale: [2.0, 4.0]\n    joints: elbow_pitch\n")
    assert main(["demo", "--episodes", "1", "--config", str(config)]) == 0
    out = capsys.readouterr().out
    assert "Damping(scale=Uniform(low=2.0, high=4.0), joints='elbow_pitch')" in out
    assert "dof_damping[elbow_pitch]" in out
    assert "body_mass" not in out


def test_demo_other_task_uses_zero_action(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--task", "dmc/reacher-easy", "--episodes", "1"]) == 0
    out = capsys.readouterr().out
    assert "zero action" in out
    assert "n/a" in out  # dm-control reports no success flag


def test_unknown_task_exits_2_with_message(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError) as expected:
        sim2real.make("dmc/reacher-eazy")
    assert main(["demo", "--task", "dmc/reacher-eazy"]) == 2
    captured = capsys.readouterr()
    assert str(expected.value) in captured.err
    assert "Traceback" not in captured.err
    assert captured.out == ""


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["demo", "--episodes", "0"], "argument --episodes: must be an int >= 1. Received '0'."),
        (["demo", "--seed", "-1"], "argument --seed: must be an int >= 0. Received '-1'."),
        (["demo", "--config", "missing.yaml"], "--config: `config` file 'missing.yaml' does not exist."),
        (["nope"], "invalid choice: 'nope'"),
    ],
)
def test_bad_input_exits_2(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_effects_that_do_not_fit_the_task_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "effects.yaml"
    config.write_text("effects:\n  - type: Mass\n    scale: 2\n    bodies: 'arm*'\n")
    assert main(["demo", "--episodes", "1", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert "'arm*' matches no body" in err


def test_study_help_says_what_happens_to_an_existing_folder(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["study", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "An existing folder that holds anything is never overwritten: the command refuses with exit 2" in text
    assert "the first free sim2real-study-2, -3, ..." in text
    assert main(["evaluate", "--help"]) == 0
    assert "nothing else in it is touched" in " ".join(capsys.readouterr().out.split())


def test_train_checks_the_default_log_folder_first(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import sim2real.output_paths as output_paths

    # Tests run as root, for whom every folder is writable: the check asks os.access, so make it say no for '.'.
    monkeypatch.setattr(output_paths.os, "access", lambda path, mode: Path(path).resolve() != tmp_path.resolve())
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--task", "sim2real/arm-reach", "--frames", "1", "--quiet", "--out", "/tmp/c.pt"]) == 2
    assert capsys.readouterr().err == (
        "sim2real train: error: --log-dir must be in a writable folder; '.' is not writable. Received 'sim2real_runs'.\n"
    )
    assert list(tmp_path.iterdir()) == []


def test_train_evaluate_and_visualize_take_your_own_model(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """--model robot.xml reaches train, evaluate (and the spec's `model:`) and visualize; tiny budgets."""
    from sim2real.agents.checkpoint import load_checkpoint
    from sysid.synthetic import generate_arm

    monkeypatch.chdir(tmp_path)
    (tmp_path / "arm.xml").write_text(generate_arm(dof=6, seed=7, actuators="position"))
    (tmp_path / "tiny.yaml").write_text(
        "algo: ppo\nframes: 64\nframes_per_batch: 64\nminibatch_size: 32\nepochs: 1\nobs_norm_frames: 16\n"
        "hidden_sizes: [8]\n"
    )
    train = ["train", "--model", "arm.xml", "--agent-config", "tiny.yaml", "--no-log", "--quiet"]
    assert main([*train, "--out", "arm.pt"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("sim2real train: ppo on arm.xml, 64 frames")
    assert load_checkpoint("arm.pt").task == f"model:{tmp_path / 'arm.xml'}"
    assert main(["train", "--model", "missing.xml", "--out", "x.pt", "--no-log"]) == 2
    assert "sim2real train: error: `--model` 'missing.xml' does not exist" in capsys.readouterr().err

    spec = "episodes: 2\nmax_steps: 10\nbatch: 2\npolicies: {ppo: {checkpoint: arm.pt}}\n"
    (tmp_path / "eval.yaml").write_text("model: arm.xml\n" + spec)
    assert main(["evaluate", "--config", "eval.yaml", "--out", "report", "--backend", "serial", "--quiet"]) == 0
    assert f"1 policy evaluated on model:{tmp_path / 'arm.xml'}" in capsys.readouterr().out
    assert (tmp_path / "report" / "report.json").is_file()
    (tmp_path / "both.yaml").write_text("task: sim2real/arm-reach\nmodel: arm.xml\n" + spec)
    assert main(["evaluate", "--config", "both.yaml", "--out", "r2", "--backend", "serial"]) == 2
    assert capsys.readouterr().err == (
        "sim2real evaluate: error: both.yaml: give one of task, model and env. Received task and model.\n"
    )

    (tmp_path / "task.yaml").write_text("task: dmc/reacher-easy\n" + spec)  # --model overrides the spec's task
    assert main(["evaluate", "--config", "task.yaml", "--model", "arm.xml", "--out", "r3", "--backend", "serial"]) == 0
    assert f"1 policy evaluated on model:{tmp_path / 'arm.xml'}" in capsys.readouterr().out

    assert main(["visualize", "--model", "arm.xml", "--n", "2", "--size", "24", "--out", "sheet.png"]) == 0
    assert "wrote sheet.png (2 frames of arm.xml, 0 effect(s)" in capsys.readouterr().out
    assert main(["visualize", "sim2real/arm-reach", "--model", "arm.xml", "--out", "s.png"]) == 2
    assert capsys.readouterr().err == (
        "sim2real visualize: error: give one of --task, --model and --env. Received --task and --model.\n"
    )
