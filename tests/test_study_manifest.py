"""The maintainers' tools behind the study's shipped checkpoints: the training commands, running them with their
wall and CPU time, and the manifest that records both (issue 14: "the manifest says how")."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from sim2real.study import load_profile, write_manifest
from sim2real.study import profile as profile_module
from sim2real.study.policies import TrainingTime, command_role, train_checkpoints

TINY_SAC = """algo: sac
frames: 200
frames_per_batch: 100
init_random_frames: 100
batch_size: 32
hidden_sizes: [16]
obs_norm_frames: 50
"""


def test_command_role_reads_the_out_file_and_names_what_it_needs() -> None:
    assert command_role("sim2real train --task t --algo sac --seed 0 --out calibrated.pt --no-log") == "calibrated"
    with pytest.raises(
        ValueError,
        match=r"`command` must end its output in --out <role>.pt, role one of "
        r"\['nominal', 'randomized', 'calibrated', 'adr'\]. Received 'sim2real train --out x.pt'.",
    ):
        command_role("sim2real train --out x.pt")
    with pytest.raises(ValueError, match="Received 'sim2real train --task t'"):
        command_role("sim2real train --task t")


def test_train_checkpoints_runs_the_commands_and_times_each(tmp_path: Path) -> None:
    (tmp_path / "agent.yaml").write_text(TINY_SAC)
    command = (
        "sim2real train --task sim2real/arm-reach --algo sac --agent-config agent.yaml --seed 0 --out {}.pt --no-log"
    )
    times = train_checkpoints([command.format("nominal"), command.format("randomized")], tmp_path, parallel=2)
    assert sorted(times) == ["nominal", "randomized"]
    assert (tmp_path / "nominal.pt").is_file() and (tmp_path / "randomized.pt").is_file()
    for t in times.values():
        # Both ran a whole Python process (imports included): seconds, not zero, and the CPU time is the child's own.
        assert 0.5 < t.wall_s < 600 and t.cpu_s is not None and 0.5 < t.cpu_s < 2 * t.wall_s + 1


def test_train_checkpoints_reports_the_failing_command(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"`parallel` must be an int >= 1. Received 0."):
        train_checkpoints([], tmp_path, parallel=0)
    with pytest.raises(ValueError, match=r"`commands` must be `sim2real train` commands. Received 'ls --out a.pt'."):
        train_checkpoints(["ls --out a.pt"], tmp_path)
    bad = "sim2real train --task sim2real/arm-reach --frames 0 --seed 0 --out nominal.pt --no-log"
    with pytest.raises(
        RuntimeError,
        match=r"training 'nominal' exited with 2: sim2real train: error: --frames must "
        r"be a positive int. Received 0.",
    ):
        train_checkpoints([bad], tmp_path)
    assert not (tmp_path / "nominal.pt").exists()


def test_write_manifest_records_and_keeps_training_times(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # A copy of the bundled profile, so the package's own manifest is never rewritten by a test.
    shutil.copytree(profile_module.PROFILES, tmp_path / "study")
    monkeypatch.setattr(profile_module, "PROFILES", tmp_path / "study")
    profile = load_profile()
    assert profile.folder.is_relative_to(tmp_path)
    shutil.copy(profile.folder / "checkpoints" / "manifest.json", tmp_path / "before.json")
    path = write_manifest(
        commands=["sim2real train ... --out nominal.pt"],
        times={"nominal": TrainingTime(wall_s=1946.2), "adr": TrainingTime(812.5, 790.25)},
    )
    entries = {e["role"]: e for e in json.loads(path.read_text())["checkpoints"]}
    assert (entries["nominal"]["train_wall_s"], entries["nominal"]["train_cpu_s"]) == (1946.2, None)
    assert (entries["adr"]["train_wall_s"], entries["adr"]["train_cpu_s"]) == (812.5, 790.25)
    assert entries["nominal"]["command"] == "sim2real train ... --out nominal.pt"
    # Not given here: the entry keeps what the shipped manifest recorded for that very run (nothing is made up).
    before = {e["role"]: e for e in json.loads((tmp_path / "before.json").read_text())["checkpoints"]}
    assert entries["randomized"] == before["randomized"]
    # Rewritten without new times or commands (e.g. after shipping one more checkpoint), each entry keeps its own.
    again = {e["role"]: e for e in json.loads(write_manifest().read_text())["checkpoints"]}
    assert again == entries
