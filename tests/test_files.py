"""randomizers.files: atomic writes with the usual permissions, computed without touching the process umask."""

from __future__ import annotations

import os
import stat
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from randomizers.files import atomic_write, make_temp_dir
from sim2real.evaluation import Evaluation, nominal, real
from sim2real.report import GapReport

UMASK = 0o027  # unlike any default umask, so a mode computed from a wrong mask shows


@pytest.fixture
def umask_forbidden(monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """A known umask is set, and ``os.umask`` raises for the duration of the test (reading it means setting it)."""
    real_umask = os.umask
    old = real_umask(UMASK)

    def forbidden(mask: int) -> int:
        raise AssertionError(f"os.umask({mask:#o}) called: it changes the umask of every thread")

    monkeypatch.setattr(os, "umask", forbidden)
    try:
        yield UMASK
    finally:
        real_umask(old)  # os.umask may still be patched here


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _replace_with_private_file(tmp: str) -> None:
    # a writer that saves elsewhere and renames over the path it was given (its file is mkstemp-private)
    other = Path(tmp).with_suffix(".other")
    other.write_bytes(b"replaced")
    other.chmod(0o600)
    os.replace(other, tmp)


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ("text é", "text é".encode()),
        (b"\x00\x01bytes", b"\x00\x01bytes"),
        (lambda tmp: Path(tmp).write_bytes(b"from a function"), b"from a function"),
        (_replace_with_private_file, b"replaced"),
    ],
    ids=["str", "bytes", "function", "function-replacing-the-file"],
)
def test_atomic_write_gives_the_umask_mode_without_touching_the_umask(
    tmp_path: Path, umask_forbidden: int, content: object, expected: bytes
) -> None:
    target = tmp_path / "sub" / "out.bin"
    atomic_write(target, content)  # type: ignore[arg-type]
    assert target.read_bytes() == expected
    assert _mode(target) == 0o666 & ~umask_forbidden == 0o640
    assert [p.name for p in target.parent.iterdir()] == ["out.bin"]  # no temporary file left
    atomic_write(target, b"again")  # over an existing file
    assert target.read_bytes() == b"again" and _mode(target) == 0o640


def test_make_temp_dir_gives_the_umask_mode_and_unique_names(tmp_path: Path, umask_forbidden: int) -> None:
    made = {make_temp_dir(tmp_path, prefix=".out.", suffix=".tmp") for _ in range(20)}
    assert len(made) == 20
    for folder in made:
        assert folder.parent == tmp_path and folder.name.startswith(".out.") and folder.name.endswith(".tmp")
        assert folder.is_dir() and list(folder.iterdir()) == []
        assert _mode(folder) == 0o777 & ~umask_forbidden == 0o750


def test_failed_write_leaves_nothing(tmp_path: Path) -> None:
    def broken(tmp: str) -> None:
        Path(tmp).write_text("half")
        raise KeyboardInterrupt

    (tmp_path / "keep.txt").write_text("old")
    with pytest.raises(KeyboardInterrupt):
        atomic_write(tmp_path / "keep.txt", broken)
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]
    assert (tmp_path / "keep.txt").read_text() == "old"
    with pytest.raises(FileNotFoundError) as caught:
        atomic_write(tmp_path / "missing" / "a.txt", "x", make_parents=False)
    assert str(caught.value) == f"`out` directory {str(tmp_path / 'missing')!r} does not exist."


def test_concurrent_files_keep_the_umask_mode(tmp_path: Path, umask_forbidden: int) -> None:
    # the old writer set the umask to 0 for a moment: a file another thread created then was world-writable
    def create(k: int) -> None:
        for i in range(50):
            fd = os.open(tmp_path / f"plain-{k}-{i}", os.O_WRONLY | os.O_CREAT, 0o666)
            os.close(fd)

    threads = [threading.Thread(target=create, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for i in range(50):
        atomic_write(tmp_path / f"atomic-{i}", b"x")
    for t in threads:
        t.join()
    assert {_mode(p) for p in tmp_path.iterdir()} == {0o640}


def test_gap_report_write_gives_the_umask_modes_without_touching_the_umask(
    tmp_path: Path, umask_forbidden: int
) -> None:
    sim = np.arange(12.0)
    evaluation = Evaluation(
        task="synthetic",
        seed=0,
        episodes=12,
        max_steps=None,
        policies=("p",),
        conditions=(nominal(), real()),
        returns={"p": {"sim": sim, "real": sim - 1.0}},
        successes={},
        lengths={},
        draws={},
    )
    report = GapReport.build(evaluation, rng=0, num_resamples=50)
    out = tmp_path / "report"
    for _ in range(2):  # a new folder (staged, then renamed into place), then the same folder again
        files = report.write(out)
        assert files.json.read_text() == report.to_json()
        assert _mode(out) == _mode(out / "figures") == 0o750
        written = [p for p in out.rglob("*") if p.is_file()]
        assert len(written) == 4 and {_mode(p) for p in written} == {0o640}
        assert [p.name for p in tmp_path.iterdir()] == ["report"]
