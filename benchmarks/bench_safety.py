"""What the safety envelope (issue 14) costs ``evaluate``: nothing without limits, a measured price with them.

Three arms per engine, run one after the other in every repeat (order rotating), in one process, on
``sim2real/arm-reach`` with the scripted ``ReachController`` (no torch in the loop), a randomised condition:

* **before**: ``sim2real/evaluation.py`` as it was before the safety measurements (``--before``, a git revision; the
  file is loaded from git into a module of its own, everything else is today's code);
* **no limits**: today's ``evaluate`` without ``safety=`` (the goal: the same speed as *before*, ratio ~1.0);
* **limits**: today's ``evaluate(..., safety=limits)`` measuring joint limits, effort, contact force on every geom
  and the end-effector site's speed.

Each engine is benchmarked: ``per-env`` (gymnasium envs stepped one by one) and ``auto`` (the batched engine).
The figure is control steps per CPU second of this process (``time.process_time``: the serial backend runs here,
so the figure does not move with the other processes on a shared box), median over repeats, and the ratios to
*before*; wall-clock medians are printed beside them. Usage::

    .venv/bin/python benchmarks/bench_safety.py            # 32 episodes x 100 steps, 3 repeats
    .venv/bin/python benchmarks/bench_safety.py --quick    # smoke test
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco

import sim2real as s2r
from sim2real.agents import ReachController
from sim2real.evaluation import evaluate, randomized
from sim2real.safety import load_limits

ROOT = Path(__file__).resolve().parents[1]
BEFORE = "1166bce"  # the last commit of sim2real/evaluation.py before the safety measurements


def before_module(revision: str) -> Any:
    """``sim2real/evaluation.py`` at ``revision``, imported as a module of its own."""
    text = subprocess.run(["git", "show", f"{revision}:sim2real/evaluation.py"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout  # fmt: skip
    path = Path(tempfile.mkdtemp()) / "evaluation_before.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("evaluation_before", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["evaluation_before"] = module
    spec.loader.exec_module(module)
    return module


def rate(fn: Any, episodes: int, steps: int, engine: str, **kwargs: Any) -> tuple[float, float]:
    """(steps per CPU second, steps per wall second)."""
    condition = randomized([s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2))])
    cpu, wall = time.process_time(), time.perf_counter()
    result = fn({"reach": ReachController(kp=5.0)}, "sim2real/arm-reach", [condition], episodes=episodes,
                batch=episodes, seed=0, max_steps=steps, engine=engine, **kwargs)  # fmt: skip
    return result.env_steps / (time.process_time() - cpu), result.env_steps / (time.perf_counter() - wall)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--steps", type=int, default=100, help="control steps per episode (cap)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--before", default=BEFORE, help="git revision of evaluation.py without safety")
    parser.add_argument("--engines", nargs="+", choices=("per-env", "auto"), default=["per-env", "auto"])
    parser.add_argument("--quick", action="store_true", help="smoke test: 8 episodes x 30 steps, 1 repeat")
    args = parser.parse_args(argv)
    if args.quick:
        args.episodes, args.steps, args.repeats = 8, 30, 1
    old = before_module(args.before)
    limits = load_limits({"joint_limit_hits": 0, "max_effort_ratio": 1.0, "max_contact_force": {"geoms": "*"},
                          "max_ee_speed": {"site": "ee"}, "divergences": 0})  # fmt: skip
    print(f"# bench_safety  python {platform.python_version()}  mujoco {mujoco.__version__}  "
          f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")  # fmt: skip
    print(f"# sim2real/arm-reach, ReachController, {args.episodes} episodes x {args.steps} steps, randomized "
          f"(Damping, ActuatorGain), {args.repeats} repeats, before = evaluation.py at {args.before}")  # fmt: skip
    for engine in args.engines:
        arms = [
            ("before", lambda e=engine: rate(old.evaluate, args.episodes, args.steps, e)),
            ("no limits", lambda e=engine: rate(evaluate, args.episodes, args.steps, e)),
            ("limits", lambda e=engine: rate(evaluate, args.episodes, args.steps, e, safety=limits)),
        ]
        rates: dict[str, list[tuple[float, float]]] = {name: [] for name, _ in arms}
        for r in range(args.repeats):
            order = arms[r % 3 :] + arms[: r % 3]
            for name, fn in order:
                rates[name].append(fn())
        med = {name: statistics.median(c for c, _ in v) for name, v in rates.items()}
        wall = {name: statistics.median(w for _, w in v) for name, v in rates.items()}
        print(f"engine={engine}: " + ", ".join(f"{n} {med[n]:,.0f}" for n in med) + " steps/CPU-s"
              + f"; no limits / before = {med['no limits'] / med['before']:.3f}, "
              f"limits / before = {med['limits'] / med['before']:.3f}"
              f"  (wall: " + ", ".join(f"{n} {wall[n]:,.0f}" for n in wall) + " steps/s)")  # fmt: skip
        for name, values in rates.items():
            print(f"#   {name} CPU: " + ", ".join(f"{c:,.0f}" for c, _ in values))


if __name__ == "__main__":
    main()
