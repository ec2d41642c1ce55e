"""ADR's cost in training and its entropy curve (issue #13).

Measures in one run, side by side, PPO training (:func:`sim2real.agents.train`) on one task under:

- *dr*: plain domain randomisation with hand-picked ranges, the effects below with their full ranges;
- *adr*: the same effects driven by an :class:`~randomizers.ADR` controller whose hard limits are those ranges,
  starting at the nominal point (``p_boundary`` 0.5, ``m`` 3, ``delta`` 0.1, metric = episode return).

Both arms draw the same effects through the same physics transform; what ADR adds is the boundary stream at reset,
the reward sum per step and the controller's bookkeeping at each episode end. The arms alternate (dr, adr, dr,
adr, ...) after one untimed warm-up run of each; repeat ``k`` of both uses seed ``k``. Frames/s are CPU frames/s
(frames over ``time.process_time`` in :func:`train`, torch on one thread), the steadier figure on a shared box;
wall frames/s are printed too. The ratio is the median of the per-repeat adr/dr ratios; the goal is >= 0.97.

The entropy curve is the ADR history of the timed runs (frames, mean nats per dimension; ``-inf`` while every
dimension is still a point) next to the entropy of the hand-picked ranges.

Usage:
    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_adr.py                  # arm-reach, 3 repeats of 3000 frames
    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_adr.py --frames 1000 --repeats 1   # smoke test

The last line printed is ``RESULT ...`` with the ratio against the goal.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import time
from typing import Any

import mujoco
import numpy as np
import torch

from randomizers import ADR, ActuatorGain, Damping, Mass, Uniform
from sim2real.agents import PPOConfig, train

RATIO_GOAL = 0.97


def effects() -> list[Any]:
    """The hand-picked ranges (also ADR's hard limits)."""
    return [
        Damping(scale=Uniform(0.5, 2.0)),
        Mass(scale=Uniform(0.8, 1.2), bodies="*"),
        ActuatorGain(scale=Uniform(0.9, 1.1)),
    ]


def controller(t_low: float, t_high: float) -> ADR:
    return ADR(effects(), delta=0.1, t_low=t_low, t_high=t_high, p_boundary=0.5, m=3, metric="return")


def run(task: str, frames: int, seed: int, adr: ADR | None) -> tuple[float, float, Any]:
    cfg = PPOConfig(frames=frames, frames_per_batch=500, minibatch_size=250, epochs=4, obs_norm_frames=500)
    chosen = [adr] if adr is not None else effects()
    cpu = time.process_time()
    result = train(task, cfg, effects=chosen, seed=seed, progress=False, logger=None)
    cpu = time.process_time() - cpu
    return result.frames / cpu, result.frames / result.wall_time, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="sim2real/arm-reach")
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--t-low", type=float, default=-115.0, help="ADR t_low (episode return)")
    parser.add_argument("--t-high", type=float, default=-100.0, help="ADR t_high (episode return)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"# bench_adr: {args.task}, {args.frames} PPO frames x {args.repeats} repeats per arm, 1 torch thread")
    print(f"# python {platform.python_version()}, mujoco {mujoco.__version__}, torch {torch.__version__}")
    run(args.task, min(args.frames, 1000), 99, None)  # warm-up, untimed
    run(args.task, min(args.frames, 1000), 99, controller(args.t_low, args.t_high))
    ratios, wall_ratios, rows = [], [], []
    curves = []
    for k in range(args.repeats):
        dr_cpu, dr_wall, _ = run(args.task, args.frames, k, None)
        adr = controller(args.t_low, args.t_high)
        adr_cpu, adr_wall, result = run(args.task, args.frames, k, adr)
        ratios.append(adr_cpu / dr_cpu)
        wall_ratios.append(adr_wall / dr_wall)
        rows.append((dr_cpu, adr_cpu, dr_wall, adr_wall))
        curves.append(ADR.from_state(result.adr).history)
        print(
            f"repeat {k}: dr {dr_cpu:7.1f} cpu-f/s {dr_wall:7.1f} wall-f/s | adr {adr_cpu:7.1f} cpu-f/s "
            f"{adr_wall:7.1f} wall-f/s | adr/dr cpu {ratios[-1]:.3f} wall {wall_ratios[-1]:.3f}"
        )
    hand = float(np.mean([math.log(e.distribution.high - e.distribution.low) for e in effects()]))
    print(f"# entropy of the hand-picked ranges: {hand:.3f} nats/dim")
    for k, hist in enumerate(curves):
        points = ", ".join(f"{f}:{e:.3f}" for f, e in zip(hist.frames, hist.entropy, strict=True))
        final = dict(zip(hist.keys, zip(hist.low[-1], hist.high[-1], strict=True), strict=True))
        print(f"# adr entropy curve, seed {k} (frames:nats/dim): {points}")
        print(f"#   final ranges: { {key: (round(lo, 3), round(hi, 3)) for key, (lo, hi) in final.items()} }")
    median = statistics.median(ratios)
    med = [statistics.median(col) for col in zip(*rows, strict=True)]
    print(f"# medians: dr {med[0]:.1f} cpu-f/s, adr {med[1]:.1f} cpu-f/s; dr {med[2]:.1f} wall-f/s, adr {med[3]:.1f}")
    verdict = "met" if median >= RATIO_GOAL else "missed"
    print(
        f"RESULT {args.task}: adr/dr cpu frames/s {median:.3f} (range {min(ratios):.3f}-{max(ratios):.3f}; wall "
        f"{statistics.median(wall_ratios):.3f}) goal >= {RATIO_GOAL}: {verdict}"
    )


if __name__ == "__main__":
    main()
