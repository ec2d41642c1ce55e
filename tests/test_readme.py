"""README.md runs as written: every ```python block, every ```bash block, with the files the README defines.

A fenced block preceded by ``<!-- file: NAME -->`` is a file the commands read (written into the working folder
before the bash blocks run). The bash blocks run in order, in one fresh folder, as the README's reader would run
them from a checkout: ``.venv`` there points at this interpreter's environment. The quick-start block (the README's
two commands) is what ``.ci/run`` runs, verbatim, on a clean clone; here we check that it still does.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
TEXT = README.read_text()
FENCE = re.compile(r"(?:<!-- file: (?P<file>[^ ]+) -->\n)?```(?P<lang>\w*)\n(?P<body>.*?)```", re.DOTALL)
BLOCKS = [(m["lang"], m["body"], m["file"], TEXT.count("\n", 0, m.start()) + 1) for m in FENCE.finditer(TEXT)]
PYTHON = [body for lang, body, _, _ in BLOCKS if lang == "python"]
BASH = [(body, line) for lang, body, name, line in BLOCKS if lang == "bash" and name is None]
FILES = {name: body for _, body, name, _ in BLOCKS if name is not None}
QUICK_START, COMMANDS = BASH[0], BASH[1:]


def test_readme_has_examples() -> None:
    assert PYTHON and COMMANDS
    assert {"effects.yaml", "twin.yaml", "study.yaml"} <= set(FILES)


@pytest.mark.parametrize("index", range(len(PYTHON)))
def test_readme_python_block_runs(index: int) -> None:
    exec(compile(PYTHON[index], f"README.md[python block {index}]", "exec"), {"__name__": "__readme__"})


def test_quick_start_is_what_ci_runs() -> None:
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    for line in QUICK_START[0].strip().splitlines():
        assert line in ci, f"README quick-start line {line!r} is not run verbatim by .ci/run"


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("readme")
    (folder / ".venv").symlink_to(Path(sys.prefix))
    for name, body in FILES.items():
        (folder / name).write_text(body)
    return folder


@pytest.mark.parametrize("index", range(len(COMMANDS)), ids=[f"line{line}" for _, line in COMMANDS])
def test_readme_bash_block_runs(index: int, workdir: Path) -> None:
    """Blocks share one folder and run in README order (later blocks read what earlier ones wrote)."""
    body, line = COMMANDS[index]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    run = subprocess.run(
        ["bash", "-euo", "pipefail", "-c", body], cwd=workdir, env=env, capture_output=True, text=True, timeout=900
    )
    assert run.returncode == 0, f"README.md line {line}: exit {run.returncode}\n{body}\n--- stderr:\n{run.stderr[-3000:]}"
