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

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sim2real import cli
from sim2real.output_paths import OutputPathError, check_distinct, check_not_inputs, held_signals

ROOT = Path(__file__).resolve().parents[1]
ARM = "sim2real/arm-reach"
SPEC = "task: sim2real/arm-reach\nepisodes: 1\nmax_steps: 2\npolicies: {scripted: baseline}\n"
#: Long enough to be interrupted while the pool's workers run (each job is many episodes of 200 steps).
LONG_SPEC = (
    "task: sim2real/arm-reach\nepisodes: 2000\nbatch: 16\npolicies: {scripted: baseline, hold: {constant: [0, 0, 0]}}\n"
    "randomized: {effects: [{type: Damping, scale: [0.5, 2.0]}]}\n"
)


@pytest.fixture(autouse=True)
def _ctrl_c_raises() -> Any:
    """SIGINT raises KeyboardInterrupt in this process during each test, as in a terminal: a run started in the
    background (nohup, a CI job without a terminal) inherits it ignored, and signal.raise_signal then does nothing."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


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
    # Ctrl-C as a terminal delivers it: a test run started in the background (nohup, a CI job) inherits SIGINT
    # ignored, and Python then keeps ignoring it.
    code = "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); from sim2real.cli import main; sys.exit(main())"
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


@pytest.mark.parametrize(
    ("signum", "group", "code", "by"),
    [(signal.SIGTERM, False, 143, " by SIGTERM"), (signal.SIGINT, True, 130, "")],
    ids=["kill", "ctrl-c"],
)
def test_study_killed_while_writing_leaves_the_empty_folder_empty_and_no_worker(
    signum: int, group: bool, code: int, by: str, tmp_path: Path
) -> None:
    # Before: SIGTERM killed the study at once: its staging folder stayed inside the user's empty folder (which the
    # next study refused: "holds 1 entry"), and the pool's workers kept running, holding the pipes: the command
    # never ended for its caller (`sim2real study | tee log`). Ctrl-C already cleaned up; it must stay so.
    (tmp_path / "s").mkdir()
    (tmp_path / "mine.txt").write_text("user data")
    proc = _start(["study", "--budget", "quick", "--quiet", "--workers", "2", "--out", "s"], tmp_path)

    def writing() -> bool:  # the twin's log and the fit are written (and for Ctrl-C, the pool's workers are up)
        staged = any((tmp_path / "s").glob(".sim2real-study.*.partial/sysid/calibrated.yaml"))
        return staged and (not group or _workers_ignore_ctrl_c(proc.pid, 3))

    out, err = _signal_when(proc, writing, signum, group=group)
    assert proc.returncode == code
    assert err == f"sim2real study: interrupted{by}; no partial output was left behind\n"
    assert out == ""
    assert _tree(tmp_path) == {"s": None, "mine.txt": b"user data"}


def test_train_killed_keeps_the_old_checkpoint(tmp_path: Path) -> None:
    # Before: SIGTERM ended train with -15 and no word (and whatever it had staged stayed).
    (tmp_path / "c.pt").write_bytes(b"the user's checkpoint")
    argv = ["train", "--task", ARM, "--frames", "400000", "--out", "c.pt", "--log-dir", "logs", "--quiet"]
    proc = _start(argv, tmp_path)
    out, err = _signal_when(proc, lambda: any(tmp_path.glob("logs/*/scalars/*.csv")), signal.SIGTERM, group=False)
    assert proc.returncode == 143
    (run,) = tmp_path.glob("logs/*/run.json")  # the log folder is marked (tests/test_train_interrupted.py)
    assert _own_lines(err) == [
        "sim2real train: interrupted by SIGTERM; no checkpoint was written to 'c.pt'; the partial run "
        f"({json.loads(run.read_text())['frames']} of 400000 frames) is in 'logs/{run.parent.name}', marked "
        "interrupted in its run.json"
    ]
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


def test_held_signals_delivers_ctrl_c_after_the_block() -> None:
    done = []
    with pytest.raises(KeyboardInterrupt), held_signals():
        signal.raise_signal(signal.SIGINT)
        done.append("renamed")
    assert done == ["renamed"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# ------------------------------------------------------------------------------------ the report folder


@pytest.fixture(scope="module")
def reports() -> tuple[object, object]:
    """Two gap reports of the same shape (a new one replaces an old one in a folder)."""
    from sim2real.evaluation import Evaluation, nominal, real
    from sim2real.report import GapReport

    made = []
    for shift in (10.0, 20.0):
        rng = np.random.default_rng(0)
        sim = rng.normal(100.0, 5.0, 12)
        evaluation = Evaluation(
            task="demo", seed=0, episodes=12, max_steps=None, policies=("ppo",),
            conditions=(nominal(), real(params={"body_mass[arm]": 1.2})),
            returns={"ppo": {"sim": sim, "real": sim - shift}}, successes={}, lengths={}, draws={},
        )  # fmt: skip
        made.append(GapReport.build(evaluation, rng=0, num_resamples=200))
    return made[0], made[1]


def _with_user_files(out: Path, old: object) -> dict[str, bytes | None]:
    old.write(out)  # type: ignore[attr-defined]
    (out / "notes.txt").write_text("mine")
    (out / "figures" / "mine.png").write_bytes(b"my figure")
    return _tree(out)


def test_ctrl_c_while_a_report_replaces_another_leaves_the_whole_new_one(
    tmp_path: Path, reports: tuple[object, object], monkeypatch: pytest.MonkeyPatch
) -> None:
    # Before: Ctrl-C between the renames left a mix: the old report.json removed, new figures and report.md beside
    # the old report.html.
    import sim2real.report.files as report_files

    old, new = reports
    out = tmp_path / "out"
    _with_user_files(out, old)
    real_replace = os.replace

    def replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        if Path(dst).parent in (out, out / "figures") and not replace.sent:  # type: ignore[attr-defined]
            replace.sent = True  # type: ignore[attr-defined]
            signal.raise_signal(signal.SIGINT)
        real_replace(src, dst)

    replace.sent = False  # type: ignore[attr-defined]
    monkeypatch.setattr(report_files.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        new.write(out)  # type: ignore[attr-defined]
    monkeypatch.undo()
    assert replace.sent  # type: ignore[attr-defined]
    expected = tmp_path / "expected"
    new.write(expected)  # type: ignore[attr-defined]
    user = {"notes.txt": b"mine", "figures/mine.png": b"my figure"}
    assert _tree(out) == {**_tree(expected), **user}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["expected", "out"]  # no staging folder left


def test_a_rename_failing_midway_puts_the_old_report_back(
    tmp_path: Path, reports: tuple[object, object], monkeypatch: pytest.MonkeyPatch
) -> None:
    # Before: a failure after the first rename left the old report.json deleted and new files beside old ones.
    import sim2real.report.files as report_files

    old, new = reports
    out = tmp_path / "out"
    before = _with_user_files(out, old)
    real_replace = os.replace
    failed = []

    def replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        if Path(dst) == out / "report.html" and not failed:  # the new report.html, once
            failed.append(dst)
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(report_files.os, "replace", replace)
    with pytest.raises(OSError, match="No space left"):
        new.write(out)  # type: ignore[attr-defined]
    assert _tree(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_a_report_file_that_became_a_folder_during_the_work_changes_nothing(
    tmp_path: Path, reports: tuple[object, object]
) -> None:
    old, new = reports
    out = tmp_path / "out"
    _with_user_files(out, old)
    (out / "report.html").unlink()
    (out / "report.html").mkdir()  # what the API cannot check before the caller's work
    before = _tree(out)
    with pytest.raises(OSError, match=r"report\.html' is a folder, where a report file goes; nothing in"):
        new.write(out)  # type: ignore[attr-defined]
    assert _tree(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.mark.parametrize(
    ("make", "problem"),
    [
        (lambda out: (out / "report.html").mkdir(), "'out/report.html' is a folder, where a report file goes"),
        (lambda out: (out / "figures").write_text("mine"), "'out/figures' is a file, where the figures go"),
    ],
    ids=["report-is-a-folder", "figures-is-a-file"],
)
def test_evaluate_refuses_a_report_folder_it_could_only_half_replace_before_any_episode(
    make: Callable[[Path], object],
    problem: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # Before: found after the whole evaluation, by the renames: "cannot write 'out': Is a directory." with the old
    # report.json already gone and new figures and report.md in the folder.
    import sim2real.spec as spec_module

    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("evaluated before checking --out")

    monkeypatch.setattr(spec_module.EvaluationSpec, "run", no_work)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "spec.yaml").write_text(SPEC)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "report.json").write_text("old")
    make(tmp_path / "out")
    before = _tree(tmp_path)
    assert cli.main(["evaluate", "--config", "spec.yaml", "--backend", "serial", "--quiet", "--out", "out"]) == 2
    captured = capsys.readouterr()
    assert captured.err == (
        f"sim2real evaluate: error: --out must be a folder whose report files can be replaced; {problem}. "
        "Received 'out'.\n"
    )
    assert captured.out == ""
    assert _tree(tmp_path) == before


def test_evaluate_progress_goes_to_stderr_and_quiet_silences_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "spec.yaml").write_text(SPEC)
    outs = {}
    for quiet in ([], ["--quiet"]):
        out = f"out{len(quiet)}"
        assert cli.main(["evaluate", "--config", "spec.yaml", "--backend", "serial", *quiet, "--out", out]) == 0
        outs[bool(quiet)] = capsys.readouterr()
    assert "evaluate" in outs[False].err and outs[True].err == ""
    assert outs[False].out == outs[True].out.replace("out1", "out0")  # stdout: the summary, the same either way
    assert "\r" not in outs[False].out and "it/s" not in outs[False].out


# ------------------------------------------------------------------------------------ the study folder


def test_a_study_moved_into_an_empty_folder_is_all_or_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before: the entries were moved up one by one; a failure midway left sysid/ in the user's folder without the
    # report, and the rest was deleted with the staging folder.
    import sim2real.study as study
    import sim2real.study.run as study_run

    def run(profile, budget, staging, backend, seed, workers, progress, log):  # type: ignore[no-untyped-def]
        (staging / "sysid").mkdir()
        (staging / "sysid" / "fit.json").write_text("{}")
        (staging / "report.html").write_text("<html></html>")
        return study.StudyResult(staging, staging / "report.html", "summary", {}, {}, None, None)

    real_rename = Path.rename

    def rename(self: Path, target: str | os.PathLike[str]) -> Path:
        if Path(target).name == "report.html":
            raise OSError(28, "No space left on device")
        return real_rename(self, target)

    monkeypatch.setattr(study_run, "_run", run)
    monkeypatch.setattr(Path, "rename", rename)
    (tmp_path / "s").mkdir()
    code = cli.main(["study", "--budget", "quick", "--backend", "serial", "--quiet", "--out", str(tmp_path / "s")])
    assert code == 2
    assert capsys.readouterr().err == (
        f"sim2real study: error: cannot write {str(tmp_path / 's')!r}: No space left on device.\n"
    )
    assert _tree(tmp_path) == {"s": None}


@pytest.mark.parametrize("flag", ["--force", "--resume", "--overwrite", "--clean"])
def test_no_study_flag_can_reuse_a_folder_that_holds_anything(
    flag: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The study once deleted an existing folder: no flag may bring that back.
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "keep.txt").write_text("user data")
    before = _tree(tmp_path)
    assert (
        cli.main(["study", "--budget", "quick", "--backend", "serial", "--quiet", flag, "--out", str(tmp_path / "s")])
        == 2
    )
    err = capsys.readouterr().err
    assert err.startswith("sim2real: error: unrecognized arguments: ") and err.count("\n") == 1
    assert _tree(tmp_path) == before


# ------------------------------------------------------------------------------------ paths through '..' and links


def test_an_output_through_a_link_and_dotdot_is_matched_as_the_os_resolves_it(tmp_path: Path) -> None:
    # Before: 'link/..' was collapsed as text (to the folder holding the link), but the OS goes to the parent of
    # the link's target, so an output there overwrote the input while the check saw two different files.
    (tmp_path / "real" / "sub").mkdir(parents=True)
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "link").symlink_to(tmp_path / "real" / "sub")
    config = tmp_path / "work" / "link" / ".." / "cfg.yaml"  # is tmp_path/real/cfg.yaml
    with pytest.raises(OutputPathError, match="--out must not be the input --config"):
        check_not_inputs({"--out": tmp_path / "real" / "cfg.yaml"}, {"--config": config})
    check_not_inputs({"--out": tmp_path / "work" / "cfg.yaml"}, {"--config": config})  # another file: allowed
    with pytest.raises(OutputPathError, match="--report must differ from --out"):
        check_distinct({"--out": config, "--report": tmp_path / "real" / "cfg.yaml"})


def test_train_refuses_to_write_its_checkpoint_over_its_config_spelled_through_a_link(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "real" / "sub").mkdir(parents=True)
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "link").symlink_to(tmp_path / "real" / "sub")
    (tmp_path / "real" / "cfg.yaml").write_text("effects: []\n")
    monkeypatch.chdir(tmp_path / "work")
    argv = ["train", "--task", ARM, "--frames", "1", "--no-log", "--quiet", "--config", "link/../cfg.yaml"]
    assert cli.main([*argv, "--out", "../real/cfg.yaml"]) == 2
    assert capsys.readouterr().err == (
        "sim2real train: error: --out must not be the input --config, which it would overwrite. Received "
        "'../real/cfg.yaml' for both.\n"
    )
    assert (tmp_path / "real" / "cfg.yaml").read_text() == "effects: []\n"


def test_a_relative_out_with_dotdot_writes_where_it_points(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "here").mkdir()
    (tmp_path / "spec.yaml").write_text(SPEC)
    monkeypatch.chdir(tmp_path / "here")
    assert cli.main(["evaluate", "--config", "../spec.yaml", "--backend", "serial", "--quiet", "--out", "../r"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["figures", "report.html", "report.json", "report.md"]
    assert list((tmp_path / "here").iterdir()) == []


@pytest.mark.parametrize("log_dir", [["--log-dir", "x"], []], ids=["given", "default"])
def test_train_refuses_a_checkpoint_named_as_its_log_folder_before_training(
    log_dir: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before: the logger made the folder as training started and the checkpoint's rename onto it failed after the
    # whole training: "cannot write 'x': Is a directory."
    import sim2real.agents.training as training

    def no_training(*args: object, **kwargs: object) -> None:
        raise AssertionError("trained before checking --out")

    monkeypatch.setattr(training, "train", no_training)
    monkeypatch.chdir(tmp_path)
    out = "x" if log_dir else "sim2real_runs"
    assert cli.main(["train", "--task", ARM, "--frames", "1", "--quiet", *log_dir, "--out", out]) == 2
    assert capsys.readouterr().err == (
        f"sim2real train: error: --log-dir must differ from --out. Received {out!r} for both.\n"
    )
    assert list(tmp_path.iterdir()) == []


def test_a_second_ctrl_c_does_not_cut_the_clean_up_short(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # Before: a second Ctrl-C while the first one's clean-up ran raised again inside it: the study's staging folder
    # was not removed (and the pool's workers not killed, when they were being killed).
    import sim2real.study.run as study_run

    def run(profile, budget, staging, backend, seed, workers, progress, log):  # type: ignore[no-untyped-def]
        (staging / "sysid").mkdir()
        (staging / "sysid" / "fit.json").write_text("{}")
        signal.raise_signal(signal.SIGINT)  # Ctrl-C while the study works
        raise AssertionError("Ctrl-C did not interrupt")

    real_rmtree = study_run.shutil.rmtree

    def rmtree(path: str | os.PathLike[str], **kwargs: object) -> None:
        signal.raise_signal(signal.SIGINT)  # the user presses Ctrl-C again
        real_rmtree(path, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(study_run, "_run", run)
    monkeypatch.setattr(study_run.shutil, "rmtree", rmtree)
    (tmp_path / "s").mkdir()
    try:
        code = cli.main(["study", "--budget", "quick", "--backend", "serial", "--quiet", "--out", str(tmp_path / "s")])
    except KeyboardInterrupt:
        pytest.fail("the second Ctrl-C escaped main")
    assert code == 130
    assert capsys.readouterr().err == "sim2real study: interrupted; no partial output was left behind\n"
    assert _tree(tmp_path) == {"s": None}
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_study_folder_holding_only_a_killed_studys_staging_folder_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # After a SIGKILL (nothing can clean up) the hidden staging folder stays in the user's empty folder, which `ls`
    # shows empty; before, the refusal said only "which holds 1 entry".
    out = tmp_path / "s"
    (out / ".sim2real-study.0123abcd4567.partial" / "sysid").mkdir(parents=True)
    before = _tree(tmp_path)
    assert cli.main(["study", "--budget", "quick", "--backend", "serial", "--quiet", "--out", str(out)]) == 2
    assert capsys.readouterr().err == (
        f"sim2real study: error: --out must be a new or empty folder (an existing folder is never overwritten). "
        f"Received {str(out)!r}, which holds 1 entry ('.sim2real-study.0123abcd4567.partial' is the staging folder "
        "of a study that was killed before it could remove it (SIGKILL, a crash): delete it to use this folder); "
        f"choose another --out, e.g. {str(tmp_path / 's-2')!r}.\n"
    )
    assert _tree(tmp_path) == before


def test_a_report_folder_that_appeared_during_the_work_gets_the_report_beside_the_users_files(
    tmp_path: Path, reports: tuple[object, object], monkeypatch: pytest.MonkeyPatch
) -> None:
    # A folder of that name made by the user while the evaluation ran is an existing folder like any: the report's
    # files go beside the user's, and the evaluation is not lost to a rename onto a folder that is not empty.
    import sim2real.report.files as report_files

    _, new = reports
    out = tmp_path / "out"
    real_make = report_files.make_temp_dir

    def make_temp_dir(parent: Path, **kwargs: str) -> Path:
        out.mkdir()  # the user made the folder while the report was computed
        (out / "notes.txt").write_text("mine")
        return real_make(parent, **kwargs)

    monkeypatch.setattr(report_files, "make_temp_dir", make_temp_dir)
    files = new.write(out)  # type: ignore[attr-defined]
    monkeypatch.undo()
    expected = tmp_path / "expected"
    new.write(expected)  # type: ignore[attr-defined]
    assert _tree(out) == {**_tree(expected), "notes.txt": b"mine"}
    assert files.html == out / "report.html"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["expected", "out"]


def test_evaluate_help_says_the_report_is_replaced_all_or_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["evaluate", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "are replaced, all or none of them (also on Ctrl-C), nothing else in it is touched" in text
