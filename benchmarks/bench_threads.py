"""The batched engine's default thread count (issue 15) with the other cores busy and idle: wall time of stepping
N reacher worlds at 1 thread and at every core, side by side, and the count each rule picks.

Two conditions, one after the other: ``idle`` (nothing started by this script; other users of the box are not
controlled, so their runnable tasks are printed) and ``busy`` (``--busy`` child processes ``python -c "while 1:
pass"`` at nice 0, started ``--warmup`` seconds before the condition's readings). In each, the readings are taken
first, then ``make_batched(task, N, seed=0, threads=k)`` for k = 1 and k = os.cpu_count() steps ``--steps`` control
steps of a fixed random policy ``--repeats`` times, alternating, each run timed by the wall clock (a thread waiting for
a busy core is what this measures). The rules:

* ``load``: the rule before (``min(cores, N)`` less ``floor(one-minute load - 1)``): at a load of 1.0-1.99 from
  another process it picks every core. Its pick is shown for this moment's load average, which lags a busy loop
  started seconds ago, and is the same at any load below 2;
* ``now``: :func:`sim2real.batched.worlds.default_threads` (the runnable tasks of the whole system right now, the
  fewest of a few readings, less this thread).

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_threads.py [--steps 300] [--repeats 5] [--busy 1]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np

from sim2real.batched import make_batched
from sim2real.batched.worlds import busy_cores, default_threads, read_cpu


def _wall(task: str, num: int, steps: int, threads: int) -> float:
    """Seconds of wall time for ``steps`` control steps of ``num`` worlds at ``threads`` (construction excluded)."""
    worlds = make_batched(task, num, seed=0, threads=threads)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, num, worlds.action_dim))
    worlds.reset(seed=0)
    start = time.perf_counter()
    for t in range(steps):
        worlds.step(actions[t])
    seconds = time.perf_counter() - start
    worlds.close()
    return seconds


def _load_rule(num: int) -> int:
    """The rule before: every core (at most ``num``) less one per unit of the one-minute load above 1."""
    return max(1, min(os.cpu_count() or 1, num) - max(0, math.floor(os.getloadavg()[0] - 1.0)))


def _condition(name: str, args: Any, cores: int) -> None:
    readings = read_cpu()
    load = os.getloadavg()[0]
    start = time.perf_counter()
    for _ in range(100):
        default_threads(args.worlds)
    cost = (time.perf_counter() - start) / 100
    picks = {"load": _load_rule(args.worlds), "now": default_threads(args.worlds, readings)}
    counts = sorted({1, min(cores, args.worlds)})
    walls: dict[int, list[float]] = {k: [] for k in counts}
    for r in range(args.repeats):
        for k in counts if r % 2 == 0 else counts[::-1]:
            walls[k].append(_wall(args.task, args.worlds, args.steps, k))
    med = {k: statistics.median(v) for k, v in walls.items()}
    best = min(med.values())
    print(f"\n## {name}: one-minute load {load:.2f}; runnable tasks {list(readings.running)} -> busy cores "
          f"{busy_cores(readings)} (cores {readings.cores}, elsewhere {readings.elsewhere}, cgroup quota "
          f"{readings.quota}); default_threads costs {1e3 * cost:.3f} ms")  # fmt: skip
    for k in counts:
        runs = ", ".join(f"{1e3 * x:.0f}" for x in walls[k])
        print(
            f"threads={k}: {1e3 * med[k]:6.0f} ms wall for {args.steps} steps of {args.worlds} worlds  (runs: {runs})"
        )
    for rule, k in picks.items():
        print(f"RESULT {name}: rule '{rule}' picks {k} thread(s): {1e3 * med[k]:.0f} ms, {med[k] / best:.2f} of the "
              f"faster count")  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="dmc/reacher-easy")
    parser.add_argument("--worlds", type=int, default=64)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--busy", type=int, default=1, help="busy-loop processes in the busy condition")
    parser.add_argument("--warmup", type=float, default=3.0, help="seconds the busy loops run before the readings")
    args = parser.parse_args(argv)
    cores = os.cpu_count() or 1
    print(f"# bench_threads  python {platform.python_version()}  {cores} CPUs; {args.task}, {args.worlds} worlds x "
          f"{args.steps} steps, {args.repeats} repeats alternating, wall clock; busy condition: {args.busy} "
          f"'while 1: pass' process(es) at nice 0, {args.warmup:.0f} s before")  # fmt: skip
    _condition("idle", args, cores)
    loops = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(args.busy)]
    try:
        time.sleep(args.warmup)
        _condition("busy", args, cores)
    finally:
        for p in loops:
            p.kill()
            p.wait()


if __name__ == "__main__":
    main()
