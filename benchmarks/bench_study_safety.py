"""What measuring the study arm's safety envelope costs the study's evaluation (issue 14), and what it samples.

The study's own spec (``dmc/reacher-easy``, its shipped checkpoints and the scripted baseline) on the nominal sim
(batched engine), the randomised sim and the twin (per-env: action latency is not batched), ``--episodes`` full
episodes each, serial backend, two arms alternating in one process: **no limits** (``spec.run()``) and **limits**
(``spec.run(safety=profile.safety)``, the profile's ``safety.yaml``). The figure is control steps per CPU second of
this process (``time.process_time``, so other processes on a shared box move it less), median over repeats.

It also prints the physics steps per control step of the task: the meter samples once per control step, so with 1
(reacher: control timestep = physics timestep = 0.02 s) every physics step is seen and sampling the substeps would
measure nothing more. Usage::

    .venv/bin/python benchmarks/bench_study_safety.py --episodes 8 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("MUJOCO_GL", "egl")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    import sim2real
    from sim2real.safety import physics_substeps
    from sim2real.spec import load_spec
    from sim2real.study import BUDGETS, load_profile

    profile = load_profile()
    folder = profile.folder / "checkpoints"
    policies = {r: {"checkpoint": str(folder / f"{r}.pt")} for r in ("nominal", "randomized", "calibrated")}
    config = profile.spec_config(BUDGETS["standard"], seed=0, policies={**policies, "scripted": "baseline"})
    config.update(sweeps=[], grids=[], episodes=args.episodes, batch=args.episodes)
    spec = load_spec(config)
    env = sim2real.make(profile.task)
    print(f"# bench_study_safety  task {profile.task}  physics steps per control step {physics_substeps(env)}  "
          f"episodes {args.episodes}  repeats {args.repeats}")  # fmt: skip
    env.close()
    rates: dict[str, list[float]] = {"no limits": [], "limits": []}
    walls: dict[str, list[float]] = {"no limits": [], "limits": []}
    for k in range(args.repeats):
        for arm in (("no limits", "limits") if k % 2 == 0 else ("limits", "no limits")):
            cpu, wall = time.process_time(), time.perf_counter()
            ev = spec.run(backend="serial", safety=profile.safety if arm == "limits" else None)
            cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
            rates[arm].append(ev.env_steps / cpu)
            walls[arm].append(wall)
            print(f"repeat {k} {arm:9s} {ev.env_steps} steps  {cpu:6.1f} s CPU  {wall:6.1f} s wall  "
                  f"engines {dict(ev.engines)}")  # fmt: skip
    med = {arm: statistics.median(v) for arm, v in rates.items()}
    for arm in rates:
        print(f"{arm:9s} {med[arm]:8.0f} control steps per CPU s (median), wall {statistics.median(walls[arm]):.1f} s")
    print(f"RESULT limits / no limits = {med['limits'] / med['no limits']:.3f}")


if __name__ == "__main__":
    main()
