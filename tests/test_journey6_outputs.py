"""Journey 6: "never destroy user data; nothing lost on bad input or interruption", command by command.

What tests/test_output_paths.py already pins (every command's bad ``--out``: an existing file or folder, a
read-only folder, a path under a file, the empty path; a failed ``record`` write; the study folder rules) is not
repeated. Here: a command killed or interrupted while it works (real signals to real subprocesses, tiny budgets),
a write that fails midway into an existing report folder, outputs spelled through ``..`` and links, and progress
on stderr only.

Interrupted commands exit 128 + the signal's number (130 on Ctrl-C / SIGINT, 143 on SIGTERM), with one line on
stderr, and leave no staging folder, no temporary file and no worker process behind.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from sim2real import cli

ROOT = Path(__file__).resolve().parents[1]
ARM = "sim2real/arm-reach"
SPEC = "task: sim2real/arm-reach\nepisodes: 1\nmax_steps: 2\npolicies: {scripted: baseline}\n"
#: Long enough to be interrupted while the pool's workers run (each job is many episodes of 200 steps).
LONG_SPEC = (
    "task: sim2real/arm-reach\nepisodes: 2000\nbatch: 16\npolicies: {scripted: baseline, hold: {constant: [0, 0, 0]}}\n"
    "randomized: {effects: [{type: Damping, scale: [0.5, 2.0]}]}\n"
)


def _tree(root: Path) -> dict[str, bytes | None]:
    """Every entry under ``root`` with its bytes (None for a folder)."""
    return {str(p.relative_to(root)): (None if p.is_dir() else p.read_bytes()) for p in sorted(root.rglob("*"))}


# ------------------------------------------------------------------------------------ signals to real processes


def _start(argv: list[str], cwd: Path) -> subprocess.Popen[str]:
    """``sim2real ARGV`` in a new session (its own process group, as a shell job is), importing this tree."""
    env = {
        **os.environ,
        "MUJOCO_GL": "egl",
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    code = "import sys; from sim2real.cli import main; sys.exit(main())"
    return subprocess.Popen(
        [sys.executable, "-c", code, *argv],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def _workers_ignore_ctrl_c(pid: int, count: int) -> bool:
    """Whether ``pid`` has ``count`` children (the pool's workers and multiprocessing's resource tracker) and each
    of them ignores SIGINT (/proc/<pid>/status SigIgn), as the workers do once they are set up: Ctrl-C reaches the
    whole process group, and is the parent's to handle."""
    ignoring = 0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) != pid:
                continue
            status = (stat.parent / "status").read_text()
        except (OSError, IndexError, ValueError):
            continue
        mask = next(int(line.split()[1], 16) for line in status.splitlines() if line.startswith("SigIgn:"))
        ignoring += bool(mask & (1 << (signal.SIGINT - 1)))
    return ignoring >= count


def _signal_when(proc: subprocess.Popen[str], ready: Callable[[], bool], signum: int, group: bool) -> tuple[str, str]:
    """Sends ``signum`` (to the process group, as Ctrl-C in a terminal does, or to the process alone, as ``kill``
    does) once ``ready()``; returns stdout and stderr. The command must then end, and with it every process of
    its group (a kill that left the pool's workers running kept the pipes open: the command never ended)."""
    deadline = time.monotonic() + 90
    while not ready():
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"ended with {proc.returncode} before it was signalled: {err[-2000:]}")
        if time.monotonic() > deadline:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail("never got to the point where it is signalled")
        time.sleep(0.05)
    (os.killpg if group else os.kill)(proc.pid, signum)
    try:
        out, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("the command did not end after the signal (its workers hold its pipes)")
    deadline = time.monotonic() + 10
    while True:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        if time.monotonic() > deadline:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail("processes of the command were left running after it ended")
        time.sleep(0.1)
    return out, err


def _own_lines(err: str) -> list[str]:
    """stderr without the DeprecationWarnings torchrl turns on for itself (torchrl._utils, RL_WARNINGS)."""
    return [line for line in err.splitlines() if "DeprecationWarning" not in line]


def test_study_killed_while_writing_leaves_the_empty_folder_empty_and_no_worker(tmp_path: Path) -> None:
    # Before: SIGTERM killed the study at once: its staging folder stayed inside the user's empty folder (which the
    # next study refused: "holds 1 entry"), and the pool's workers kept running, holding the pipes: the command
    # never ended for its caller (`sim2real study | tee log`).
    (tmp_path / "s").mkdir()
    (tmp_path / "mine.txt").write_text("user data")
    proc = _start(["study", "--budget", "quick", "--quiet", "--workers", "2", "--out", "s"], tmp_path)

    def writing() -> bool:  # the twin's log and the fit are written: it is in the policies or evaluate stage
        return any((tmp_path / "s").glob(".sim2real-study.*.partial/sysid/calibrated.yaml"))

    out, err = _signal_when(proc, writing, signal.SIGTERM, group=False)
    assert proc.returncode == 143
    assert err == "sim2real study: interrupted by SIGTERM; no partial output was left behind\n"
    assert out == ""
    assert _tree(tmp_path) == {"s": None, "mine.txt": b"user data"}


def test_train_killed_keeps_the_old_checkpoint(tmp_path: Path) -> None:
    # Before: SIGTERM ended train with -15 and no word (and whatever it had staged stayed).
    (tmp_path / "c.pt").write_bytes(b"the user's checkpoint")
    argv = ["train", "--task", ARM, "--frames", "400000", "--out", "c.pt", "--log-dir", "logs", "--quiet"]
    proc = _start(argv, tmp_path)
    out, err = _signal_when(proc, lambda: any(tmp_path.glob("logs/*/scalars/*.csv")), signal.SIGTERM, group=False)
    assert proc.returncode == 143
    assert _own_lines(err) == ["sim2real train: interrupted by SIGTERM; no checkpoint was written to 'c.pt'"]
    assert out == ""
    assert (tmp_path / "c.pt").read_bytes() == b"the user's checkpoint"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.pt", "logs"]  # no temporary checkpoint beside it


def test_evaluate_interrupted_by_ctrl_c_keeps_the_old_report_and_the_users_files(tmp_path: Path) -> None:
    (tmp_path / "spec.yaml").write_text(LONG_SPEC)
    out_dir = tmp_path / "out"
    (out_dir / "figures").mkdir(parents=True)
    for name in ("report.html", "report.md", "report.json", "notes.txt", "figures/returns.png", "figures/mine.png"):
        (out_dir / name).write_text(f"old {name}")
    before = _tree(tmp_path)
    proc = _start(["evaluate", "--config", "spec.yaml", "--workers", "2", "--out", "out"], tmp_path)
    out, err = _signal_when(proc, lambda: _workers_ignore_ctrl_c(proc.pid, 3), signal.SIGINT, group=True)
    assert proc.returncode == 130
    assert out == ""  # progress went to stderr
    assert err.splitlines()[-1] == "sim2real evaluate: interrupted; no partial output was left behind"
    assert "Traceback" not in err
    assert _tree(tmp_path) == before  # no staging folder beside out, nothing in it changed


# ------------------------------------------------------------------------------------ interruptions in-process


def test_train_interrupted_before_training_is_one_line_not_a_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before: Ctrl-C while train built and checked its env (before the training loop) escaped main as a
    # KeyboardInterrupt traceback: only the training loop itself was guarded.
    import sim2real.agents.cli as train_cli

    def interrupted(*args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(train_cli, "_check_effects", interrupted)
    monkeypatch.chdir(tmp_path)
    try:
        code = cli.main(["train", "--task", ARM, "--frames", "1", "--no-log", "--out", "c.pt"])
    except KeyboardInterrupt:
        pytest.fail("Ctrl-C escaped main as a traceback")
    assert code == 130
    captured = capsys.readouterr()
    assert captured.err == "sim2real train: interrupted; no partial output was left behind\n"
    assert captured.out == ""
    assert list(tmp_path.iterdir()) == []


def test_main_restores_the_signal_handlers_and_leaves_an_ignored_hangup_ignored(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    term = signal.getsignal(signal.SIGTERM)
    seen: list[tuple[object, object]] = []

    def tasks(out: object) -> int:
        seen.append((signal.getsignal(signal.SIGHUP), signal.getsignal(signal.SIGTERM)))
        return 0

    monkeypatch.setattr(cli, "cmd_tasks", tasks)
    old = signal.signal(signal.SIGHUP, signal.SIG_IGN)  # as under nohup
    try:
        assert cli.main(["tasks"]) == 0
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN and signal.getsignal(signal.SIGTERM) is term
    finally:
        signal.signal(signal.SIGHUP, old)
    assert seen[0][0] is signal.SIG_IGN and callable(seen[0][1])  # SIGTERM interrupts while the command runs
    capsys.readouterr()
