"""``sim2real evaluate --config study.yaml --out DIR`` and the evaluation spec format."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sim2real import cli
from sim2real.spec import SpecError, load_spec

SPEC = """
task: sim2real/arm-reach
seed: 1
episodes: 3
max_steps: 15
policies:
  scripted: baseline
  gentle: {baseline: ReachController, kp: 0.3}
randomized:
  effects:
    - {type: Damping, scale: [0.5, 2.0]}
    - {type: GeomColor, set: [0.2, 0.9]}
real: {csv: real.csv}
sweeps:
  - {type: ActuatorGain, field: scale, low: 0.5, high: 1.5, num: 3}
report: {title: "CLI <study>", num_resamples: 200}
"""


@pytest.mark.render
def test_evaluate_writes_the_report_with_a_contact_sheet(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "real.csv").write_text("policy,return\nscripted,-9.5\nscripted,-10.5\ngentle,-14\n")
    (tmp_path / "study.yaml").write_text(SPEC)
    out = tmp_path / "report"
    code = cli.main(["evaluate", "--config", str(tmp_path / "study.yaml"), "--out", str(out), "--backend", "serial",
                     "--quiet"])  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert f"wrote {out / 'report.html'}" in printed
    assert sorted(p.name for p in out.iterdir()) == ["figures", "report.html", "report.json", "report.md"]
    figures = sorted(p.name for p in (out / "figures").iterdir())
    assert figures == ["contact_sheet.png", "returns.png", "robustness_actuatorgain-scale.png"]
    report = json.loads((out / "report.json").read_text())
    assert report["title"] == "CLI <study>"
    assert "CLI &lt;study&gt;" in (out / "report.html").read_text()


def test_spec_errors_name_the_file_and_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("task: sim2real/arm-reach\npolicies: {p: baseline}\nsweeps: [{type: Damping, values: [1, 2]}]\n")
    assert cli.main(["evaluate", "--config", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: sweeps[0]: `field` must name the swept argument. Received keys ['type', 'values']." in err
    with pytest.raises(SpecError, match=r"keys must be among .* Received unknown \['episode'\]"):
        load_spec({"task": "sim2real/arm-reach", "policies": {"p": "baseline"}, "episode": 3})
    with pytest.raises(SpecError, match=r"policies.p must be 'baseline', \{baseline: <class>, ...\} or"):
        load_spec({"task": "sim2real/arm-reach", "policies": {"p": "ppo"}})
    with pytest.raises(SpecError, match=r"policies.p.checkpoint: file '.*missing.pt' does not exist."):
        load_spec({"task": "sim2real/arm-reach", "policies": {"p": {"checkpoint": "missing.pt"}}})
    assert not (tmp_path / "o").exists()


def test_evaluate_into_an_existing_folder_keeps_the_users_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "spec.yaml").write_text(
        "task: sim2real/arm-reach\nepisodes: 1\nmax_steps: 2\npolicies: {s: baseline}\n"
    )
    out = tmp_path / "report"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "report.html").write_text("an older report")
    argv = ["evaluate", "--config", str(tmp_path / "spec.yaml"), "--out", str(out), "--backend", "serial", "--quiet"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["figures", "notes.txt", "report.html", "report.json", "report.md"]
    assert (out / "notes.txt").read_text() == "mine"
    assert "an older report" not in (out / "report.html").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report", "spec.yaml"]  # no staging folder left


def test_a_spec_without_a_source_runs_on_the_command_lines_model_and_says_which_engine_ran(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``evaluate --config eval.yaml --model robot.xml`` with no ``task:``/``model:`` in the YAML failed with "give one
    of task, model and env. Received none." although --model was given (the spec's source was read before the
    command line's replaced it); and the output never said which conditions the batched engine ran, or why not."""
    from sysid.synthetic import generate_arm

    (tmp_path / "robot.xml").write_text(generate_arm(dof=6, seed=4, actuators="position"))
    (tmp_path / "eval.yaml").write_text(
        "seed: 0\nepisodes: 2\nmax_steps: 10\npolicies: {hold: {constant: [0, 0, 0, 0, 0, 0]}}\n"
        "randomized: {effects: [{type: Damping, scale: [0.5, 2.0]}]}\n"
    )
    out = tmp_path / "report"
    code = cli.main(["evaluate", "--config", str(tmp_path / "eval.yaml"), "--model", str(tmp_path / "robot.xml"),
                     "--out", str(out), "--backend", "serial", "--quiet"])  # fmt: skip
    captured = capsys.readouterr()
    assert code == 0, captured.err
    report = json.loads((out / "report.json").read_text())
    assert report["evaluation"]["task"] == f"model:{tmp_path / 'robot.xml'}"
    assert "engines: batched for sim, randomized\n" in captured.out
    # A spec that names a task of its own is overridden the same way (before and after this change).
    spec = load_spec("task: dmc/reacher-easy\npolicies: {hold: {constant: [0, 0]}}", task="sim2real/arm-reach")
    assert spec.task == "sim2real/arm-reach"
