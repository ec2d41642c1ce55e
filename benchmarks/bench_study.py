"""Wall-clock time of ``sim2real study`` on its embedded default (issue #7 goal: <= 180 s on a 2-core CPU box).

Runs the study in a temporary folder with the given budget and backend, prints every stage's time and the total
against the goal, and checks that a second run with the same seed reproduces ``report.json`` bitwise (``--twice``).

Usage::

    .venv/bin/python benchmarks/bench_study.py                       # standard budget, local backend
    .venv/bin/python benchmarks/bench_study.py --budget quick --twice
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

GOAL_SECONDS = 180.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", default="standard", choices=("quick", "standard", "full"))
    parser.add_argument("--backend", default="local", choices=("local", "serial", "ray"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--twice", action="store_true", help="run again and compare report.json bitwise")
    args = parser.parse_args()
    start = time.perf_counter()
    from sim2real.study import run_study  # the import is part of what a user waits for

    print(f"# bench_study  python {platform.python_version()}  cpus {os.cpu_count()}  budget {args.budget}  "
          f"backend {args.backend}  seed {args.seed}")  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        result = run_study(out=Path(tmp) / "study", budget=args.budget, backend=args.backend, seed=args.seed,
                           progress=False, log=None)  # fmt: skip
        total = time.perf_counter() - start
        for stage, seconds in result.seconds.items():
            print(f"stage {stage:9s} {seconds:7.1f} s")
        print(f"policies: {dict(result.policies)}")
        print(f"total (import + study) {total:7.1f} s")
        verdict = "met" if total <= GOAL_SECONDS else "missed"
        print(f"RESULT study {args.budget} on {args.backend}: {total:.1f} s (goal <= {GOAL_SECONDS:.0f} s: {verdict})")
        if args.twice:
            again = run_study(out=Path(tmp) / "again", budget=args.budget, backend=args.backend, seed=args.seed,
                              progress=False, log=None)  # fmt: skip
            same = (again.out / "report.json").read_bytes() == (result.out / "report.json").read_bytes()
            print(f"RESULT second run reproduces report.json bitwise: {same}")


if __name__ == "__main__":
    main()
