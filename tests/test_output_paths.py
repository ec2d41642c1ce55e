"""Output paths: every command checks every output before any work, and never destroys what is there.

Each bad path must give exit 2, exactly one line on stderr (pinned), no traceback, nothing on stdout and nothing
created. The budgets are tiny, and the checks run before any recording, fitting, training or evaluation, so a
regression (a check moved after the work) shows as a wrong message, not only as a slow test.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

import sim2real.output_paths as output_paths
from sim2real import cli
from sim2real.output_paths import OutputPathError, check_distinct, check_file, check_folder, free_folder

ARM = "sim2real/arm-reach"
SPEC = "task: sim2real/arm-reach\nepisodes: 1\nmax_steps: 2\npolicies: {scripted: baseline}\n"

#: command -> (argv with OUT where the output goes, the prefix of its error line, file or folder output)
COMMANDS: dict[str, tuple[list[str], str, str]] = {
    "record": (["record", "--task", ARM, "--episodes", "1", "--steps", "2", "--out", "OUT"], "record", "file"),
    "sysid": (
        ["sysid", "fit", "log.npz", "--task", ARM, "--params", "dof_damping[*]", "--out", "OUT"],
        "sysid",
        "file",
    ),
    "sysid-report": (
        ["sysid", "fit", "log.npz", "--task", ARM, "--params", "dof_damping[*]", "--out", "r.json", "--report", "OUT"],
        "sysid",
        "file",
    ),
    "train": (["train", "--task", ARM, "--frames", "1", "--no-log", "--quiet", "--out", "OUT"], "train", "file"),
    "train-log-dir": (
        ["train", "--task", ARM, "--frames", "1", "--quiet", "--out", "c.pt", "--log-dir", "OUT"],
        "train",
        "folder",
    ),
    "visualize": (["visualize", ARM, "--n", "1", "--size", "8", "--out", "OUT"], "visualize", "file"),
    "evaluate": (
        ["evaluate", "--config", "spec.yaml", "--backend", "serial", "--quiet", "--out", "OUT"],
        "evaluate",
        "folder",
    ),
    "study": (["study", "--budget", "quick", "--backend", "serial", "--quiet", "--out", "OUT"], "study", "folder"),
}


def _option(name: str) -> str:
    return {"sysid-report": "--report", "train-log-dir": "--log-dir"}.get(name, "--out")


def _bad_paths(name: str) -> list[tuple[str, str]]:
    """(path, the message after "error: ") for one command; run in a folder holding `afile`, `adir/` and `ro/`."""
    option, kind = _option(name), COMMANDS[name][2]
    noun = "file" if kind == "file" else "folder"
    cases = [
        (
            "afile/out",
            f"{option} must be in a folder that exists or can be created; 'afile' is a file. Received 'afile/out'.",
        ),
        (
            "afile/a/b/out",
            f"{option} must be in a folder that exists or can be created; 'afile' is a file. Received 'afile/a/b/out'.",
        ),
        ("ro/out", f"{option} must be in a writable folder; 'ro' is not writable. Received 'ro/out'."),
        ("ro/new/out", f"{option} must be in a writable folder; 'ro' is not writable. Received 'ro/new/out'."),
        ("", f"{option} must be a {noun} path. Received ''."),
    ]
    if kind == "file":
        cases += [
            ("adir", f"{option} must name a file, not a folder. Received 'adir'."),
            (".", f"{option} must name a file, not a folder. Received '.'."),
            ("..", f"{option} must name a file, not a folder. Received '..'."),
            ("new/", f"{option} must name a file, not a folder. Received 'new/'."),
        ]
    else:
        cases += [("afile", f"{option} must name a folder, not an existing file. Received 'afile'.")]
    if name == "study":
        cases += [
            (
                ".",
                "--out must be a new or empty folder (an existing folder is never overwritten). Received '.', "
                "which holds 4 entries; choose another --out, e.g. 'sim2real-study'.",
            ),
            (
                "adir",
                "--out must be a new or empty folder (an existing folder is never overwritten). Received "
                "'adir', which holds 1 entry; choose another --out, e.g. 'adir-2'.",
            ),
        ]
    else:
        cases += (
            [("ro", f"{option} must be a writable folder. Received 'ro', which is not writable.")]
            if (kind == "folder")
            else []
        )
    return cases


CASES = [(name, path, message) for name in COMMANDS for path, message in _bad_paths(name)]


@pytest.fixture
def workdir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A folder with a file, a non-empty folder, a "read-only" folder and the evaluation spec, as the cwd.

    The tests run as root, for whom every folder is writable, so a read-only folder is simulated by making
    ``os.access`` (what the check asks) answer no for ``ro``; the chmod is there for non-root runs.
    """
    (tmp_path / "afile").write_text("user data")
    (tmp_path / "adir").mkdir()
    (tmp_path / "adir" / "keep.txt").write_text("user data")
    (tmp_path / "ro").mkdir()
    (tmp_path / "spec.yaml").write_text(SPEC)
    os.chmod(tmp_path / "ro", 0o555)
    real_access = os.access

    def access(path: str | os.PathLike[str], mode: int) -> bool:
        return False if Path(path).resolve() == (tmp_path / "ro").resolve() else real_access(path, mode)

    monkeypatch.setattr(output_paths.os, "access", access)
    monkeypatch.chdir(tmp_path)
    yield tmp_path
    os.chmod(tmp_path / "ro", 0o755)


def _tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


@pytest.mark.parametrize(("name", "path", "message"), CASES, ids=[f"{n}:{p or 'empty'}" for n, p, _ in CASES])
def test_bad_output_path_exits_2_before_any_work(
    name: str, path: str, message: str, workdir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv, command, _ = COMMANDS[name]
    before = _tree(workdir)
    assert cli.main([path if a == "OUT" else a for a in argv]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"sim2real {command}: error: {message}\n"
    assert captured.out == ""
    assert _tree(workdir) == before  # nothing created, nothing removed


# ------------------------------------------------------------------------------------ the checks themselves


def test_checks_create_nothing_and_accept_good_paths(tmp_path: Path) -> None:
    assert check_file(tmp_path / "a" / "b" / "log.npz", "--out") == tmp_path / "a" / "b" / "log.npz"
    assert check_folder(tmp_path / "report", "--out") == tmp_path / "report"
    (tmp_path / "empty").mkdir()
    assert check_folder(tmp_path / "empty", "--out", new=True) == tmp_path / "empty"
    (tmp_path / "old.json").write_text("{}")
    assert check_file(tmp_path / "old.json", "--out") == tmp_path / "old.json"  # replaced atomically later
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "old.json"]


@pytest.mark.parametrize(
    ("outputs", "message"),
    [
        ({"--out": "r.json", "--report": "r.json"}, "--report must differ from --out. Received 'r.json' for both."),
        (
            {"--out": "a/r.json", "--report": "a/../a/r.json"},
            "--report must differ from --out. Received 'a/../a/r.json' for both.",
        ),
    ],
)
def test_outputs_of_one_command_must_differ(outputs: dict[str, str], message: str) -> None:
    with pytest.raises(OutputPathError) as raised:
        check_distinct(outputs)
    assert str(raised.value) == message


def test_sysid_out_and_report_must_differ(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    argv = ["sysid", "fit", "log.npz", "--task", ARM, "--params", "dof_damping[*]", "--out", "r.json"]
    assert cli.main([*argv, "--report", "./r.json"]) == 2
    assert (
        capsys.readouterr().err
        == "sim2real sysid: error: --report must differ from --out. Received './r.json' for both.\n"
    )
    assert list(tmp_path.iterdir()) == []


def test_free_folder_skips_taken_names(tmp_path: Path) -> None:
    for name in ("s", "s-2"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "x").write_text("")
    (tmp_path / "s-3").write_text("a file")
    (tmp_path / "e").mkdir()
    assert free_folder(tmp_path / "s") == tmp_path / "s-4"
    assert free_folder(tmp_path / "e") == tmp_path / "e"  # an empty folder is free
    assert free_folder(tmp_path / "new") == tmp_path / "new"


def test_a_failed_write_exits_2_and_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import randomizers.files

    def full(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(randomizers.files.os, "replace", full)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["record", "--task", ARM, "--episodes", "1", "--steps", "2", "--out", "logs/r.npz"]) == 2
    captured = capsys.readouterr()
    assert captured.err == "sim2real record: error: cannot write 'logs/r.npz': No space left on device.\n"
    assert captured.out == ""
    assert list((tmp_path / "logs").iterdir()) == []  # the temporary file is gone


# ------------------------------------------------------------------------------------ the study folder


@pytest.fixture
def fake_study(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """``run_study`` with its work replaced by two files written into the staging folder (the folder handling is
    what is tested; the real study runs in tests/test_study.py). Returns the staging folders it was given."""
    import sim2real.study as study
    import sim2real.study.run as study_run

    seen: list[Path] = []

    def run(profile, budget, staging, backend, seed, workers, progress, log):
        seen.append(staging)
        (staging / "sysid").mkdir()
        (staging / "sysid" / "fit.json").write_text("{}")
        (staging / "report.html").write_text("<html></html>")
        return study.StudyResult(staging, staging / "report.html", "summary", {}, {}, None, None)

    monkeypatch.setattr(study_run, "_run", run)
    return seen


STUDY = ["study", "--budget", "quick", "--backend", "serial", "--quiet"]


def test_study_refuses_a_folder_that_holds_anything(
    tmp_path: Path, fake_study: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / ".hidden").write_text("user data")  # hidden files count: nothing in the folder is ever overwritten
    assert cli.main([*STUDY, "--out", str(out)]) == 2
    assert capsys.readouterr().err == (
        f"sim2real study: error: --out must be a new or empty folder (an existing folder is never overwritten). "
        f"Received {str(out)!r}, which holds 1 entry; choose another --out, e.g. {str(tmp_path / 'mine-2')!r}.\n"
    )
    assert fake_study == []  # refused before any work
    assert _tree(tmp_path) == ["mine", "mine/.hidden"]
    assert (out / ".hidden").read_text() == "user data"


def test_study_default_folder_is_never_reused(
    tmp_path: Path, fake_study: list[Path], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert cli.main(STUDY) == 0
    assert capsys.readouterr().out == "summary\nreport: sim2real-study/report.html\n"
    assert cli.main(STUDY) == 0  # a second run (e.g. ./setup.sh again) writes beside the first
    assert capsys.readouterr().out == "summary\nreport: sim2real-study-2/report.html\n"
    assert _tree(tmp_path) == [
        "sim2real-study",
        "sim2real-study-2",
        "sim2real-study-2/report.html",
        "sim2real-study-2/sysid",
        "sim2real-study-2/sysid/fit.json",
        "sim2real-study/report.html",
        "sim2real-study/sysid",
        "sim2real-study/sysid/fit.json",
    ]


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_study_folder_gets_the_usual_permissions(
    tmp_path: Path, fake_study: list[Path], umask: int, capsys: pytest.CaptureFixture[str]
) -> None:
    old = os.umask(umask)
    try:
        assert cli.main([*STUDY, "--out", str(tmp_path / "a" / "study")]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a" / "study").stat().st_mode) == 0o777 & ~umask  # not mkdtemp's 0o700
    assert fake_study[0].parent == tmp_path / "a" and fake_study[0].name.startswith(".study.")
    assert _tree(tmp_path) == ["a", "a/study", "a/study/report.html", "a/study/sysid", "a/study/sysid/fit.json"]


@pytest.mark.parametrize("spelling", ["empty", "."])
def test_study_fills_an_existing_empty_folder_in_place(
    spelling: str,
    tmp_path: Path,
    fake_study: list[Path],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    folder = tmp_path / "empty"
    folder.mkdir(mode=0o750)
    inode = folder.stat().st_ino
    monkeypatch.chdir(folder if spelling == "." else tmp_path)
    assert cli.main([*STUDY, "--out", spelling]) == 0
    assert capsys.readouterr().out == f"summary\nreport: {Path(spelling) / 'report.html'}\n"
    assert folder.stat().st_ino == inode and stat.S_IMODE(folder.stat().st_mode) == 0o750  # the user's own folder
    assert fake_study[0].parent == Path(spelling)  # staged inside it (its parent may not be writable)
    assert _tree(folder) == ["report.html", "sysid", "sysid/fit.json"]


def test_study_never_overwrites_what_appeared_during_the_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import sim2real.study as study
    import sim2real.study.run as study_run

    out = tmp_path / "study"

    def run(profile, budget, staging, backend, seed, workers, progress, log):
        (staging / "report.html").write_text("new")
        out.mkdir()
        (out / "notes.txt").write_text("written by the user meanwhile")
        return study.StudyResult(staging, staging / "report.html", "summary", {}, {}, None, None)

    monkeypatch.setattr(study_run, "_run", run)
    result = study.run_study(out=out, budget="quick", backend="serial", progress=False, log=None)
    assert result.out == tmp_path / "study-2" and result.report == tmp_path / "study-2" / "report.html"
    assert _tree(tmp_path) == ["study", "study-2", "study-2/report.html", "study/notes.txt"]


def test_run_study_names_its_argument(tmp_path: Path) -> None:
    from sim2real.study import run_study

    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputPathError) as raised:
        run_study(out=tmp_path / "f", budget="quick", backend="serial", progress=False, log=None)
    assert str(raised.value) == f"`out` must name a folder, not an existing file. Received {str(tmp_path / 'f')!r}."
    assert _tree(tmp_path) == ["f"]
