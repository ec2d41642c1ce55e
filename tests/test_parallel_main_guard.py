"""A script that starts the local backend at its top level (no ``if __name__ == '__main__':``) gets told so."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_a_script_without_a_main_guard_is_told_to_add_one(tmp_path: Path) -> None:
    # Each spawned worker imports the script again, which starts a pool while the worker is still starting: Python
    # refuses and the worker exits with 1 before it takes an item. The pool just breaks; the error says why.
    script = tmp_path / "my_eval.py"
    script.write_text(
        "from sim2real.parallel import run_tasks\n"
        "print(list(run_tasks(abs, [-1, -2], backend='local', workers=2, retries=0)))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 1
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("sim2real.parallel.WorkerError: task ")
    assert "every worker that died exited with code 1 before it ran an item" in last
    assert "a script must start workers under `if __name__ == '__main__':`, not at its top level" in last
