"""Bring-your-own-robot costs (issue 17 B): a driver CSV's import and the home-pose excitation of ``record``.

Side by side in one run, as ratios:

* ``sysid.load_csv`` of a 7-DoF driver CSV (ms, degrees) on the control grid and with a jittery clock
  (resampled), against ``numpy.loadtxt`` of the same file (the bare parse);
* ``record`` on a generated 7-DoF arm around its home keyframe (the joint-limit guard simulates the episodes
  first; with ``gravity_comp`` the commands come from a per-step Python loop) against ``home="current"``
  (the excitation computed in one block, no guard).

Usage: ``MUJOCO_GL=egl .venv/bin/python benchmarks/bench_own_robot.py [--rows 20000] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np


def _best(run: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def _csv(path: Path, rows: int, jitter: bool) -> None:
    rng = np.random.default_rng(0)
    t = 0.02 * np.arange(rows) + (rng.uniform(-0.003, 0.003, rows) if jitter else 0.0)
    t[0] = 0.0
    q = np.degrees(np.sin(np.outer(t, np.linspace(0.5, 2.0, 7))))
    table = np.column_stack([1e3 * t, q, 10 * q, rng.normal(size=(rows, 7))])
    header = ["t_ms", *(f"q{i}" for i in range(7)), *(f"dq{i}" for i in range(7)), *(f"u{i}" for i in range(7))]
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.10g")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=20_000, help="CSV rows (control steps at 50 Hz)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    import sysid
    from sim2real.recording import record
    from sim2real.sources import Source
    from sysid.synthetic import generate_arm

    folder = Path(tempfile.mkdtemp())
    columns = {"time": "t_ms", "qpos": "q*", "qvel": "dq*", "ctrl": "u*"}
    units = {"t_ms": "ms", "q*": "deg", "dq*": "deg/s"}
    meta = {"timestep": 0.002, "control_timestep": 0.02}
    print(f"load_csv: {args.rows} rows x 22 columns (7-DoF arm, ms and degrees), best of {args.repeats}")
    base = None
    for name, jitter in (("on the grid", False), ("jittery +-3 ms", True)):
        path = folder / f"{name[:2]}.csv"
        _csv(path, args.rows, jitter)
        parse = _best(lambda p=path: np.loadtxt(p, delimiter=",", skiprows=1), args.repeats)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            load = _best(lambda p=path: sysid.load_csv(p, columns, meta, units=units), args.repeats)
        base = base or load
        print(
            f"  {name:<16} load_csv {load:7.3f} s ({args.rows / load / 1e3:6.1f}k rows/s)   numpy.loadtxt "
            f"{parse:7.3f} s   ratio {load / parse:5.2f}"
        )

    arm = folder / "arm7.xml"
    arm.write_text(generate_arm(dof=7, seed=1))
    source = Source("model", str(arm))
    steps, episodes = 400, 4
    print(
        f"record: generated 7-DoF torque arm, {episodes} episodes x {steps} steps (8 s at 50 Hz), best of "
        f"{args.repeats}"
    )
    cases = {
        "home=current (block)": {"home": "current"},
        "home=keyframe (guard)": {"home": "keyframe"},
        "keyframe + gravity_comp": {"home": "keyframe", "gravity_comp": True},
    }
    reference = math.nan
    for name, options in cases.items():
        seconds = _best(lambda o=options: record(source, episodes=episodes, steps=steps, seed=0, **o), args.repeats)
        reference = seconds if math.isnan(reference) else reference
        print(f"  {name:<24} {seconds:7.3f} s   x{seconds / reference:5.2f}")


if __name__ == "__main__":
    main()
