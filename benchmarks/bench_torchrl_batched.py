"""BatchedTorchRLEnv step cost (issue 15), side by side by this process's CPU time: an older copy of the class
(OLD=<file>, e.g. ``git show 7161e85:sim2real/batched/torchrl_env.py > /tmp/old_trl.py``) vs this checkout's,
and the engine step alone; 20 reacher worlds, K steps per run (a fresh input TensorDict per step, as rollout
makes), R runs alternating. ``--prof`` profiles this checkout's step.

Usage::

    OLD=/tmp/old_trl.py MUJOCO_GL=egl .venv/bin/python benchmarks/bench_torchrl_batched.py
"""

import cProfile
import importlib.util
import os
import pstats
import statistics
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
import numpy as np
import torch
from tensordict import TensorDict

import sim2real as s2r
from sim2real.batched.torchrl_env import BatchedTorchRLEnv

_spec = importlib.util.spec_from_file_location("old_trl", os.environ["OLD"])
_old = importlib.util.module_from_spec(_spec)  # type: ignore[arg-type]
_spec.loader.exec_module(_old)  # type: ignore[union-attr]
OldEnv = _old.BatchedTorchRLEnv
eff = [s2r.Mass(scale=s2r.Uniform(0.7, 1.3)), s2r.Damping(scale=s2r.Uniform(0.5, 2.0))]
N, K = 20, int(os.environ.get("K", "400"))
envs = {
    "old": OldEnv("dmc/reacher-easy", N, *eff, seed=0),
    "new": BatchedTorchRLEnv("dmc/reacher-easy", N, *eff, seed=0),
}
for e in envs.values():
    e.reset()


def run(env, k):
    tds = [TensorDict({"action": torch.zeros(N, 2)}, batch_size=[N]) for _ in range(k)]
    t = time.process_time()
    for td in tds:
        env.step(td)
    return (time.process_time() - t) / k * 1e3


def eng(env, k):
    a = np.zeros((N, 2), np.float32)
    t = time.process_time()
    for _ in range(k):
        env.engine.step(a)
    return (time.process_time() - t) / k * 1e3


res = {"old": [], "new": [], "engine": []}
for r in range(int(os.environ.get("R", "5"))):
    for name in ["old", "new"] if r % 2 == 0 else ["new", "old"]:
        res[name].append(run(envs[name], K))
    res["engine"].append(eng(envs["new"], K))
med = {k: statistics.median(v) for k, v in res.items()}
for k, v in res.items():
    print(f"{k:7s} median {med[k]:.3f} ms/step of {N} worlds  runs {[round(x, 3) for x in v]}")
print(
    f"RESULT torchrl overhead over the engine: old {med['old'] - med['engine']:.3f} ms, new {med['new'] - med['engine']:.3f} ms; "
    f"new/old step {med['new'] / med['old']:.2f}"
)
if "--prof" in sys.argv:
    cProfile.run("run(envs['new'], 300)", "/tmp/g/p.out")
    pstats.Stats("/tmp/g/p.out").sort_stats("tottime").print_stats(22)
