"""ADR (from nominal) vs hand-picked DR SAC policies on arm-reach: nominal and harder physics, 30 episodes each.

Train the two checkpoints first (commands in BENCHMARKS.md, "ADR vs hand-picked DR with SAC on arm-reach"), then:

    MUJOCO_GL=egl .venv/bin/python benchmarks/compare_adr_arm_reach.py ADR.pt DR.pt
"""

import sys

import numpy as np
from scipy import stats

import sim2real as s2r
from sim2real.agents.baselines import ReachController
from sim2real.conditions import nominal, randomized
from sim2real.evaluation import evaluate

conds = [
    nominal("nominal"),
    randomized(
        [
            s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
            s2r.Mass(scale=s2r.Uniform(0.8, 1.2), bodies="*"),
            s2r.ActuatorGain(scale=s2r.Uniform(0.9, 1.1)),
        ],
        name="hand-picked DR",
    ),
    randomized([s2r.Damping(scale=s2r.Uniform(2.0, 3.0))], name="damping 2-3x"),
    randomized([s2r.ActuatorGain(scale=s2r.Uniform(0.3, 0.6))], name="gain 0.3-0.6x"),
    randomized([s2r.Mass(scale=s2r.Uniform(2.0, 2.6), bodies="*")], name="mass 2-2.6x"),
]
pols = {"adr": sys.argv[1], "dr": sys.argv[2], "scripted": ReachController(kp=5.0)}
ev = evaluate(pols, "sim2real/arm-reach", conds, episodes=30, seed=1000)
for c in [c.name for c in conds]:
    row = []
    for p in pols:
        r = ev.returns[p][c]
        s = ev.successes[p][c]
        h = stats.t.ppf(0.975, len(r) - 1) * r.std(ddof=1) / np.sqrt(len(r))
        row.append(f"{p} {r.mean():.1f} [{r.mean() - h:.1f}, {r.mean() + h:.1f}] succ {int(s.sum())}/{len(s)}")
    d = ev.returns["adr"][c] - ev.returns["dr"][c]
    hd = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d))
    print(
        f"{c}: " + " | ".join(row) + f" | adr-dr {d.mean():+.1f} [{d.mean() - hd:+.1f}, {d.mean() + hd:+.1f}] (paired)"
    )
