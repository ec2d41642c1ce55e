"""P4 of issue 15, end to end: ``evaluate`` today against the code of the day the issue was filed.

The issue measured "batched evaluation reaches 21-26k control steps/s on ``dmc/reacher-easy`` (64 parameter
samples)" and asks for >= 7x that. This script checks the tree of that day out (``git archive REF``, default
``e685055^``, into a temporary folder it creates and removes) and runs the same job with both trees, each in its own
process, alternating: ``evaluate({"mlp": NumpyMLP}, "dmc/reacher-easy", [randomized(Mass, Damping, ActuatorGain)],
episodes=64, batch=64, seed=0, max_steps=1000)``, end to end (building the 64 worlds included), several calls per
process after one untimed warm-up call. Both CPU time (``time.process_time``: every thread of the process) and wall
time are printed: that day's code steps in one thread (its wall and CPU time agree), today's engine may use MuJoCo's
thread pool (``engine="auto"``), which spends more CPU for less wall time. The mean return must agree (same episodes).

Usage (from the repo root, with the repo's venv)::

    .venv/bin/python benchmarks/bench_vs_filing.py [--runs 2] [--calls 4] [--ref e685055^]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
PACKAGES = ("sim2real", "randomizers", "noise_models", "sysid")


def child(calls: int, engine: str) -> None:
    """One process: a warm-up call, then ``calls`` timed calls; prints one JSON line."""
    import numpy as np

    sys.path.insert(0, str(HERE))
    from bench_eval import NumpyMLP

    import sim2real as s2r
    from sim2real.evaluation import evaluate, randomized

    task = "dmc/reacher-easy"
    env = s2r.make(task)
    policy = NumpyMLP(env.observation_space.shape[0], env.action_space.shape[0])
    env.close()
    effects = [
        s2r.Mass(scale=s2r.Uniform(0.7, 1.3)),
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
        s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2)),
    ]
    kwargs = {"engine": engine} if engine else {}
    cpu, wall, mean = [], [], 0.0
    for call in range(calls + 1):
        t, w = time.process_time(), time.perf_counter()
        result = evaluate({"mlp": policy}, task, [randomized(effects)], episodes=64, batch=64, seed=0, max_steps=1000,
                          **kwargs)  # fmt: skip
        if call:  # the first call of a process pays first-touch page faults: untimed
            cpu.append(result.env_steps / (time.process_time() - t))
            wall.append(result.env_steps / (time.perf_counter() - w))
        mean = float(np.mean(result.returns["mlp"]["randomized"]))
    print(json.dumps({"cpu": cpu, "wall": wall, "mean_return": mean, "module": s2r.__file__}))


def run(tree: Path, calls: int, engine: str) -> dict[str, object]:
    env = {**os.environ, "PYTHONPATH": str(tree), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    out = subprocess.run(
        [sys.executable, __file__, "--child", "--calls", str(calls), "--engine", engine],
        env=env, capture_output=True, text=True, check=True, cwd=tempfile.gettempdir(),
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ref", default="e685055^", help="git revision of the filing day's code")
    parser.add_argument("--runs", type=int, default=2, help="processes per tree, alternating")
    parser.add_argument("--calls", type=int, default=4, help="timed evaluate calls per process")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--engine", default="", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.calls, args.engine)
        return
    rates: dict[str, dict[str, list[float]]] = {k: {"cpu": [], "wall": []} for k in ("filing day", "today")}
    means: dict[str, set[float]] = {"filing day": set(), "today": set()}
    with tempfile.TemporaryDirectory(prefix="s2r-filing-") as tmp:
        archive = subprocess.run(
            ["git", "-C", str(REPO), "archive", args.ref, *PACKAGES], capture_output=True, check=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        trees = {"filing day": (Path(tmp), ""), "today": (REPO, "auto")}
        print(f"filing day = {args.ref}, today = {REPO}; {args.runs} processes each, {args.calls} calls per process")
        for r in range(args.runs):
            for name in ("filing day", "today") if r % 2 == 0 else ("today", "filing day"):
                tree, engine = trees[name]
                got = run(tree, args.calls, engine)
                for clock in ("cpu", "wall"):
                    rates[name][clock] += got[clock]  # type: ignore[operator]
                means[name].add(got["mean_return"])  # type: ignore[arg-type]
                cpu = ", ".join(f"{x / 1e3:.1f}k" for x in got["cpu"])  # type: ignore[attr-defined]
                wall = ", ".join(f"{x / 1e3:.1f}k" for x in got["wall"])  # type: ignore[attr-defined]
                print(f"  run {r + 1} {name:<10} steps/s CPU [{cpu}]  wall [{wall}]", flush=True)
    print(f"mean return: filing day {sorted(means['filing day'])}, today {sorted(means['today'])}")
    line = []
    for clock in ("cpu", "wall"):
        old, new = statistics.median(rates["filing day"][clock]), statistics.median(rates["today"][clock])
        print(f"{clock:>4}: filing day {old / 1e3:.1f}k, today {new / 1e3:.1f}k steps/s -> {new / old:.2f}x (goal 7x)")
        line.append(f"{clock}={new / old:.2f}x")
    print("RESULT_P4_VS_FILING " + " ".join(line))


if __name__ == "__main__":
    main()
