"""``sim2real train`` cut short marks its log folder: ``run.json`` says ``"interrupted"`` (Ctrl-C, SIGTERM) or
``"failed"`` (an exception, a checkpoint that cannot be written) with the frames done and the signal, and no
checkpoint; a run that ends says ``"completed"`` with its checkpoint. The CSVs already written stay as they were.

Before: an interrupted run's folder (``scalars/*.csv``, ``texts/hparams0.txt``) looked like a run that simply
stopped; the command said only ``no checkpoint was written to 'c.pt'``, and a failed run left a traceback and the
same unmarked folder.

Runs are cut deterministically by raising from the logger's row writer after N batches (PPO collects batches of
1,000 frames), and once by a real SIGTERM to a subprocess.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

import sim2real.agents.loop_utils as loop_utils
import sim2real.agents.training as training
from sim2real import cli
from sim2real.agents.config import SACConfig
from sim2real.agents.loop_utils import log_row
from sim2real.agents.run_status import RunStatus, marked_run, read_run_status
from sim2real.cli._common import Interrupted

ROOT = Path(__file__).resolve().parents[1]
ARM = "sim2real/arm-reach"


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)


def _cut_after(rows: int, error: BaseException, monkeypatch: pytest.MonkeyPatch) -> list[RunStatus | None]:
    """Raises ``error`` once ``rows`` metric rows are written and counted: as the next batch's row is about to be
    logged. Returns the statuses read from run.json at each row (what a reader sees while the run goes on)."""
    seen: list[RunStatus | None] = []
    calls: list[int] = []

    def cut(log: Any, row: Any, frames: int) -> None:
        if len(calls) == rows:
            raise error
        calls.append(frames)
        if log is not None:
            seen.append(read_run_status(Path(log.log_dir) / log.exp_name))
        log_row(log, row, frames)

    monkeypatch.setattr(loop_utils, "log_row", cut)
    return seen


def _train(*extra: str, frames: int = 5000) -> int:
    argv = ["train", "--task", ARM, "--frames", str(frames), "--out", "c.pt", "--log-dir", "logs", "--quiet"]
    return cli.main([*argv, *extra])


def _run_folder() -> Path:
    (folder,) = Path("logs").iterdir()
    return folder


def _status(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "run.json").read_text())


def _expected(folder: Path, status: str, frames: int, asked: int = 5000, **rest: Any) -> dict[str, Any]:
    fields = {"signal": None, "error": None, "checkpoint": None, **rest}
    return {"status": status, "run_id": folder.name, "algo": "ppo", "task": ARM, "seed": 0,
            "frames_asked": asked, "frames": frames, **fields}  # fmt: skip


def test_a_completed_run_says_completed_with_its_checkpoint(capsys: pytest.CaptureFixture[str]) -> None:
    assert _train(frames=1000) == 0
    folder = _run_folder()
    expected = _expected(folder, "completed", 1000, asked=1000, checkpoint=str(Path("c.pt").resolve()))
    assert _status(folder) == expected
    assert capsys.readouterr().err == ""


def test_ctrl_c_mid_training_marks_the_run_interrupted_and_keeps_its_logs(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    Path("c.pt").write_bytes(b"the user's checkpoint")
    seen = _cut_after(2, KeyboardInterrupt(), monkeypatch)
    assert _train() == 130
    folder = _run_folder()
    assert capsys.readouterr().err == (
        "sim2real train: interrupted; no checkpoint was written to 'c.pt'; the partial run (2000 of 5000 frames) "
        f"is in 'logs/{folder.name}', marked interrupted in its run.json\n"
    )
    assert _status(folder) == _expected(folder, "interrupted", 2000, signal="SIGINT")
    # While it ran, a reader saw "running" (as a run killed with SIGKILL is left).
    assert [s.status if s else None for s in seen] == ["running", "running"]
    assert (folder / "scalars" / "reward.csv").read_text().splitlines()[0].startswith("1000,")
    assert len((folder / "scalars" / "reward.csv").read_text().splitlines()) == 2  # both batches' rows kept
    assert (folder / "texts" / "hparams0.txt").exists()
    assert Path("c.pt").read_bytes() == b"the user's checkpoint"
    assert sorted(p.name for p in Path().iterdir()) == ["c.pt", "logs"]
    assert sorted(p.name for p in folder.iterdir()) == ["run.json", "scalars", "texts", "videos"]  # no temp file


def test_sigterm_mid_training_says_sigterm_and_exits_143(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _cut_after(3, Interrupted(signal.SIGTERM), monkeypatch)
    assert _train() == 143
    folder = _run_folder()
    assert capsys.readouterr().err == (
        "sim2real train: interrupted by SIGTERM; no checkpoint was written to 'c.pt'; the partial run (3000 of 5000 "
        f"frames) is in 'logs/{folder.name}', marked interrupted in its run.json\n"
    )
    assert _status(folder) == _expected(folder, "interrupted", 3000, signal="SIGTERM")


def test_ctrl_c_at_start_up_after_the_logger_marks_zero_frames(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def interrupted(*args: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(training, "_fit_normalizer", interrupted)  # the first thing PPO does
    assert _train() == 130
    folder = _run_folder()
    assert capsys.readouterr().err == (
        "sim2real train: interrupted; no checkpoint was written to 'c.pt'; the partial run (0 of 5000 frames) is in "
        f"'logs/{folder.name}', marked interrupted in its run.json\n"
    )
    assert _status(folder) == _expected(folder, "interrupted", 0, signal="SIGINT")


def test_ctrl_c_before_the_log_folder_exists_leaves_nothing_to_mark(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def interrupted(*args: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(training, "choose_collection", interrupted)  # inside train, before its logger
    assert _train() == 130
    assert capsys.readouterr().err == "sim2real train: interrupted; no checkpoint was written to 'c.pt'\n"
    assert list(Path().iterdir()) == []


def test_no_log_interrupted_says_only_the_checkpoint(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _cut_after(1, KeyboardInterrupt(), monkeypatch)
    argv = ["train", "--task", ARM, "--frames", "5000", "--out", "c.pt", "--no-log", "--quiet"]
    assert cli.main(argv) == 130
    assert capsys.readouterr().err == "sim2real train: interrupted; no checkpoint was written to 'c.pt'\n"
    assert list(Path().iterdir()) == []


def test_an_exception_mid_training_marks_the_run_failed_and_is_raised_as_before(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _cut_after(2, RuntimeError("boom"), monkeypatch)
    with pytest.raises(RuntimeError) as raised:
        _train()
    assert raised.value.args == ("boom",)
    folder = _run_folder()
    assert _status(folder) == _expected(folder, "failed", 2000, error="RuntimeError: boom")
    # Printed under the traceback:
    assert raised.value.__notes__ == [
        f"sim2real: the partial run (2000 of 5000 frames) is in 'logs/{folder.name}', marked failed in its run.json"
    ]
    assert not Path("c.pt").exists()


def test_interrupted_while_saving_the_checkpoint_is_marked_with_all_frames(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def save(self: Any, path: Any) -> None:
        raise Interrupted(signal.SIGHUP)

    monkeypatch.setattr(training.TrainResult, "save", save)
    assert _train(frames=1000) == 129
    folder = _run_folder()
    assert capsys.readouterr().err == (
        "sim2real train: interrupted by SIGHUP; no checkpoint was written to 'c.pt'; the partial run (1000 of 1000 "
        f"frames) is in 'logs/{folder.name}', marked interrupted in its run.json\n"
    )
    assert _status(folder) == _expected(folder, "interrupted", 1000, asked=1000, signal="SIGHUP")


def test_a_checkpoint_that_cannot_be_written_marks_the_run_failed(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def save(self: Any, path: Any) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(training.TrainResult, "save", save)
    assert _train(frames=1000) == 2
    assert capsys.readouterr().err == "sim2real train: error: cannot write 'c.pt': Permission denied.\n"
    folder = _run_folder()
    error = "cannot write the checkpoint 'c.pt': Permission denied"
    assert _status(folder) == _expected(folder, "failed", 1000, asked=1000, error=error)


def test_a_log_that_cannot_be_written_mid_training_says_so_not_that_the_checkpoint_failed(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: any OSError while training (the run's own CSV on a full disk) read "cannot write 'c.pt'"."""
    _cut_after(2, OSError(28, "No space left on device", "logs/x/scalars/loss.csv"), monkeypatch)
    assert _train() == 2
    folder = _run_folder()
    assert capsys.readouterr().err == (
        "sim2real train: error: training stopped: cannot write 'logs/x/scalars/loss.csv': No space left on device; "
        f"the partial run (2000 of 5000 frames) is in 'logs/{folder.name}', marked failed in its run.json; no "
        "checkpoint was written to 'c.pt'.\n"
    )
    error = "OSError: [Errno 28] No space left on device: 'logs/x/scalars/loss.csv'"
    assert _status(folder) == _expected(folder, "failed", 2000, error=error)
    assert not Path("c.pt").exists()


def test_sac_interrupted_through_the_library_is_marked_and_found_on_the_exception(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _cut_after(3, KeyboardInterrupt(), monkeypatch)
    config = SACConfig(frames=1000, frames_per_batch=100, init_random_frames=100, batch_size=32, obs_norm_frames=100,
                       hidden_sizes=(16,))  # fmt: skip
    with pytest.raises(KeyboardInterrupt) as raised:
        training.train(ARM, config, progress=False, log_dir="logs")
    folder = _run_folder()
    run = RunStatus("interrupted", folder.name, "sac", ARM, 0, 1000, 300, signal="SIGINT")
    assert marked_run(raised.value) == (folder, run)
    assert read_run_status(folder) == run


def test_a_status_file_that_is_not_one_is_refused_by_name(tmp_path: Path) -> None:
    fields = {"status": "paused", "run_id": "r", "algo": "ppo", "task": None, "seed": 0, "frames_asked": 1, "frames": 0}
    (tmp_path / "run.json").write_text(json.dumps(fields))
    with pytest.raises(ValueError, match=r"run.json' is not a run status .*Received 'paused'"):
        read_run_status(tmp_path)
    assert read_run_status(tmp_path / "nowhere") is None


def test_a_real_sigterm_marks_the_frames_of_the_last_logged_batch(tmp_path: Path) -> None:
    env = {
        **os.environ,
        "MUJOCO_GL": "egl",
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    code = "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); from sim2real.cli import main; sys.exit(main())"
    argv = ["train", "--task", ARM, "--frames", "400000", "--out", "c.pt", "--log-dir", "logs", "--quiet"]
    proc = subprocess.Popen([sys.executable, "-c", code, *argv], cwd=tmp_path, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 90
        while not list(tmp_path.glob("logs/*/scalars/reward.csv")):
            assert proc.poll() is None, proc.communicate()[1][-2000:]
            assert time.monotonic() < deadline, "never logged a batch"
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 143
    folder = next((tmp_path / "logs").iterdir())
    status = _status(folder)
    rows = (folder / "scalars" / "reward.csv").read_text().splitlines()
    assert status == _expected(folder, "interrupted", 1000 * len(rows), asked=400000, signal="SIGTERM")
    # Whole rows only (the row is written with the signal held): every metric's file ends at the marked frame.
    ends = {p.name: p.read_text().splitlines()[-1].split(",")[0] for p in (folder / "scalars").glob("loss_*.csv")}
    assert ends == dict.fromkeys(("loss_critic.csv", "loss_entropy.csv", "loss_objective.csv"), str(len(rows) * 1000))
    own = [line for line in err.splitlines() if "DeprecationWarning" not in line]
    assert own == [
        f"sim2real train: interrupted by SIGTERM; no checkpoint was written to 'c.pt'; the partial run "
        f"({status['frames']} of 400000 frames) is in 'logs/{folder.name}', marked interrupted in its run.json"
    ]
    assert out == ""


def test_the_run_status_reader_is_part_of_the_agents_api(tmp_path: Path) -> None:
    import sim2real.agents as agents

    run = RunStatus("completed", "ppo_x_seed0", "ppo", ARM, 0, 1000, 1000)
    from sim2real.agents.run_status import write_run_status

    write_run_status(tmp_path, run)
    assert agents.read_run_status(tmp_path) == agents.RunStatus(**run.__dict__) == run
