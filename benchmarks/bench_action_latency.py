"""Engine step cost of ActionLatency (issue 15), side by side by this process's CPU time: physics DR alone vs
DR + ActionLatency, 64 worlds per arm, arms alternating over repeats (R=5 by default). Three paths: reacher (the
delayed ctrl, whole control steps), manipulator (ctrl, 3 physics steps: the command arrives mid control step),
arm-reach (the action path: IK targets delayed by whole control steps).

Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_action_latency.py
"""

import os
import statistics
import time

os.environ.setdefault("MUJOCO_GL", "egl")
import numpy as np

import sim2real as s2r
from sim2real.batched import make_batched

dr = [
    s2r.Mass(scale=s2r.Uniform(0.7, 1.3)),
    s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
    s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2)),
]
cases = {
    ("dmc/reacher-easy", "DR"): dr,
    ("dmc/reacher-easy", "DR+ActionLatency(0.04 s)"): [*dr, s2r.ActionLatency(seconds=0.04)],
    ("dmc/manipulator-bring_ball", "DR"): dr,
    ("dmc/manipulator-bring_ball", "DR+ActionLatency(0.006 s, mid-step)"): [*dr, s2r.ActionLatency(seconds=0.006)],
    ("sim2real/arm-reach", "DR"): dr,
    ("sim2real/arm-reach", "DR+ActionLatency(0.04 s, action path)"): [*dr, s2r.ActionLatency(seconds=0.04)],
}
N, STEPS = 64, {"dmc/reacher-easy": 300, "dmc/manipulator-bring_ball": 100, "sim2real/arm-reach": 200}
envs = {k: make_batched(k[0], N, *v, seed=0) for k, v in cases.items()}
rates = {k: [] for k in cases}
rng = np.random.default_rng(0)
for r in range(int(os.environ.get("R", "5"))):
    for k in list(cases) if r % 2 == 0 else list(cases)[::-1]:
        e = envs[k]
        e.reset(seed=0)
        a = rng.uniform(-0.05, 0.05, (N, e.action_dim)).astype(np.float32)
        t = time.process_time()
        for _ in range(STEPS[k[0]]):
            e.step(a)
        rates[k].append(N * STEPS[k[0]] / (time.process_time() - t))
for task in STEPS:
    base = [k for k in cases if k[0] == task]
    m = {k: statistics.median(rates[k]) for k in base}
    for k in base:
        print(f"{task:28s} {k[1]:40s} {m[k]:9.0f} control steps/s  runs {[round(x) for x in rates[k]]}")
    print(f"RESULT {task}: with/without ActionLatency = {m[base[1]] / m[base[0]]:.3f}")
