"""ADR's cost in training and its entropy curve (issue #13).

Measures in one run, side by side, PPO training (:func:`sim2real.agents.train`) on one task under:

- *dr*: plain domain randomisation with hand-picked ranges, the effects below with their full ranges;
- *adr*: the same effects driven by an :class:`~randomizers.ADR` controller whose hard limits are those ranges,
  starting at the nominal point (``p_boundary`` 0.5, ``m`` 2, ``delta`` 0.1, metric = episode return with
  ``t_low`` -130 and ``t_high`` -105: about a random policy's return, so ranges grow early in training).

Both arms draw the same effects through the same physics transform; what ADR adds is the boundary stream at reset,
the reward sum per step and the controller's bookkeeping at each episode end. The arms alternate in ABBA order
(dr, adr, adr, dr, dr, adr, ...) after one untimed warm-up run of each, so a drifting load cancels; repeat ``k`` of
both uses seed ``k``. Frames/s are CPU frames/s (frames over ``time.process_time`` in :func:`train`, torch on one
thread), the steadier figure on a shared box; wall frames/s are printed too. The ratio is the median of the per-repeat adr/dr ratios; the goal is >= 0.97.

Training runs are short and PPO's own cost varies from run to run, so the env-step arm isolates what ADR changes:
rollouts of the TorchRL training env (``GymWrapper`` + the physics transform, DR or ADR) under a fixed random
policy, ``--env-blocks`` alternating blocks of ``--env-steps`` steps each, CPU time per step.

The entropy curve comes from one more ADR run of ``--curve-frames`` (untimed, seed 0): its ADR history (frames,
mean nats per dimension; ``-inf`` while a dimension is still a point) next to the entropy of the hand-picked ranges,
with the training returns per batch. That run's controller is the one a user would write (:func:`curve_controller`):
hard limits that only keep the model physical (damping 0-5x, gain 0.25-2x, mass 0.25-4x, wider than the hand-picked
ranges, which cap the timed arms' controller so its entropy can never exceed theirs), started at the nominal point,
and by default PPO warm-started by behaviour cloning of the task's scripted baseline (``--curve-bc``) so the policy
can succeed at all: the metric is then the episode's success (``auto``), a boundary widens when both episodes of its
buffer (``m`` 2) succeed and narrows when both fail. The teacher's own episodes (while its data is recorded) report to
the controller too, so the entropy at the end of the warm start is printed separately.

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


def controller(t_low: float, t_high: float, m: int) -> ADR:
    return ADR(effects(), delta=0.1, t_low=t_low, t_high=t_high, p_boundary=0.5, m=m, metric="return")


def curve_controller(t_low: float, t_high: float, m: int, metric: str) -> ADR:
    """ADR over the same parameters with physical hard limits only (the study's ``adr`` section uses the same)."""
    wide = [
        Damping(scale=Uniform(0.0, 5.0)),
        Mass(scale=Uniform(0.25, 4.0), bodies="*"),
        ActuatorGain(scale=Uniform(0.25, 2.0)),
    ]
    # About 1/16-1/20 of each limit's span: a boundary that always copes reaches its limit in ~16 moves.
    delta = {"Damping[joints=*]": 0.25, "Mass[bodies=*]": 0.2, "ActuatorGain[actuators=*]": 0.1}
    return ADR(wide, delta=delta, t_low=t_low, t_high=t_high, p_boundary=0.5, m=m, metric=metric)


def run(
    task: str, frames: int, seed: int, adr: ADR | None, bc: str | None = None, bc_frames: int = 0
) -> tuple[float, float, Any]:
    cfg = PPOConfig(
        frames=frames,
        frames_per_batch=500,
        minibatch_size=250,
        epochs=4,
        obs_norm_frames=500,
        bc_baseline=bc,
        bc_frames=bc_frames if bc else 0,
        # ADR collects per env (sim2real.agents.collect); the DR arm must too, or the ratio measures the engine.
        engine="per-env",
    )
    chosen = [adr] if adr is not None else effects()
    cpu = time.process_time()
    result = train(task, cfg, effects=chosen, seed=seed, progress=False, logger=None)
    cpu = time.process_time() - cpu
    return result.frames / cpu, result.frames / result.wall_time, result


def env_steps(task: str, steps: int, blocks: int, t_low: float, t_high: float, m: int) -> tuple[float, float]:
    """Median CPU microseconds per TorchRL env step under DR and under ADR (blocks alternating)."""
    from torchrl.envs import GymWrapper

    import sim2real

    arms = {
        "dr": sim2real.wrap(GymWrapper(sim2real.make(task)), *effects(), seed=0),
        "adr": sim2real.wrap(GymWrapper(sim2real.make(task)), controller(t_low, t_high, m), seed=0),
    }
    times: dict[str, list[float]] = {"dr": [], "adr": []}
    for env in arms.values():
        env.rollout(200, break_when_any_done=False)  # warm-up
    for _ in range(blocks):
        for name, env in arms.items():
            start = time.process_time()
            env.rollout(steps, break_when_any_done=False)
            times[name].append((time.process_time() - start) / steps * 1e6)
    for env in arms.values():
        env.close()
    return statistics.median(times["dr"]), statistics.median(times["adr"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="sim2real/arm-reach")
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--t-low", type=float, default=-130.0, help="ADR t_low (episode return)")
    parser.add_argument("--t-high", type=float, default=-105.0, help="ADR t_high (episode return)")
    parser.add_argument("--m", type=int, default=2, help="ADR buffer size")
    parser.add_argument("--curve-frames", type=int, default=30000, help="frames of the entropy-curve run (0: none)")
    parser.add_argument("--curve-bc", default="ReachController", help="BC warm start of the curve run ('' for none)")
    parser.add_argument("--curve-bc-frames", type=int, default=4000, help="frames the BC teacher records")
    parser.add_argument("--curve-metric", default="auto", help="ADR metric of the curve run (auto: success)")
    parser.add_argument("--curve-t-low", type=float, default=0.3, help="curve run t_low (success rate)")
    parser.add_argument("--curve-t-high", type=float, default=0.7, help="curve run t_high (success rate)")
    parser.add_argument("--env-steps", type=int, default=2000, help="steps per block of the env-step arm")
    parser.add_argument("--env-blocks", type=int, default=7, help="blocks per arm of the env-step arm (0: none)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"# bench_adr: {args.task}, {args.frames} PPO frames x {args.repeats} repeats per arm, 1 torch thread")
    print(f"# python {platform.python_version()}, mujoco {mujoco.__version__}, torch {torch.__version__}")
    run(args.task, min(args.frames, 1000), 99, None)  # warm-up, untimed
    run(args.task, min(args.frames, 1000), 99, controller(args.t_low, args.t_high, args.m))
    ratios, wall_ratios, rows = [], [], []
    for k in range(args.repeats):
        # ABBA order (dr first in even repeats, adr first in odd ones): a load that drifts during the run would
        # otherwise always land on the arm that runs second.
        if k % 2 == 0:
            dr_cpu, dr_wall, _ = run(args.task, args.frames, k, None)
            adr_cpu, adr_wall, result = run(args.task, args.frames, k, controller(args.t_low, args.t_high, args.m))
        else:
            adr_cpu, adr_wall, result = run(args.task, args.frames, k, controller(args.t_low, args.t_high, args.m))
            dr_cpu, dr_wall, _ = run(args.task, args.frames, k, None)
        ratios.append(adr_cpu / dr_cpu)
        wall_ratios.append(adr_wall / dr_wall)
        rows.append((dr_cpu, adr_cpu, dr_wall, adr_wall))
        print(
            f"repeat {k}: dr {dr_cpu:7.1f} cpu-f/s {dr_wall:7.1f} wall-f/s | adr {adr_cpu:7.1f} cpu-f/s "
            f"{adr_wall:7.1f} wall-f/s | adr/dr cpu {ratios[-1]:.3f} wall {wall_ratios[-1]:.3f}"
        )
    hand = float(np.mean([math.log(e.distribution.high - e.distribution.low) for e in effects()]))
    print(f"# entropy of the hand-picked ranges: {hand:.3f} nats/dim")
    if args.curve_frames > 0:
        curve = curve_controller(args.curve_t_low, args.curve_t_high, args.m, args.curve_metric)
        bc = args.curve_bc or None
        _, _, result = run(args.task, args.curve_frames, 0, curve, bc, args.curve_bc_frames)
        hist = ADR.from_state(result.adr).history
        warm = 500 + (args.curve_bc_frames if bc else 0)
        at_warm = [e for f, e in zip(hist.frames, hist.entropy, strict=True) if f <= warm][-1]
        print(
            f"# curve controller: {curve!r} at the end; metric {args.curve_metric}, t {args.curve_t_low}/{args.curve_t_high}"
        )
        print(f"# entropy after the normaliser + BC warm start ({warm} frames): {at_warm:.3f} nats/dim")
        points = ", ".join(f"{f}:{e:.3f}" for f, e in zip(hist.frames, hist.entropy, strict=True))
        final = dict(zip(hist.keys, zip(hist.low[-1], hist.high[-1], strict=True), strict=True))
        returns = ", ".join(
            f"{int(f)}:{r:.1f}" for f, r in zip(result.metrics["frames"], result.metrics["episode_return"], strict=True)
        )
        print(f"# adr entropy curve, {args.curve_frames} frames, seed 0 (frames:nats/dim): {points}")
        print(f"#   final ranges: { {key: (round(lo, 3), round(hi, 3)) for key, (lo, hi) in final.items()} }")
        print(f"#   training return per batch (frames:return): {returns}")
    if args.env_blocks > 0:
        dr_us, adr_us = env_steps(args.task, args.env_steps, args.env_blocks, args.t_low, args.t_high, args.m)
        print(
            f"# env steps: dr {dr_us:.1f} us/step, adr {adr_us:.1f} us/step (median of {args.env_blocks} blocks of "
            f"{args.env_steps}); adr/dr steps/s {dr_us / adr_us:.3f}"
        )
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
