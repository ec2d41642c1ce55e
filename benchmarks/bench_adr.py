"""ADR's cost in training and its entropy curve (issue #13).

Measures in one run, side by side, PPO training (:func:`sim2real.agents.train`) on one task under:

- *dr*: plain domain randomisation with hand-picked ranges, the effects below with their full ranges;
- *adr*: the same effects driven by an :class:`~randomizers.ADR` controller whose hard limits are those ranges,
  starting at the nominal point (``p_boundary`` 0.5, ``m`` 2, ``delta`` 0.1, metric = episode return with
  ``t_low`` -130 and ``t_high`` -105: about a random policy's return, so ranges grow early in training).

Both arms collect on the same engine (``--engine``, default ``auto``: the batched engine, which PPO chooses for
both since ADR is batched, :mod:`sim2real.batched.adr`; ``per-env`` compares the one-TorchRL-env path), so the
ratio is what ADR costs and not a difference of engines. What ADR adds there: the boundary stream and the range
draws at each world's reset, two ``(N,)`` array updates per step, the controller's bookkeeping at each episode end.

**Measurement.** CPU time of this process (``time.process_time``, torch on one thread, the engine on one thread:
a steadier figure than wall time on a shared box), one untimed warm-up run per arm, then ``--repeats`` pairs; pair
``k`` runs both arms with seed ``k``, in counterbalanced order (dr-adr, adr-dr, dr-adr, ...: a load that drifts
lands on both arms alike). Reported: each pair's ratio adr/dr of CPU frames/s, their median (the figure against
the goal >= 0.97), the interquartile range, and a distribution-free 95% interval for the median ratio from the
order statistics of the paired ratios (the sign-test interval: with 9 pairs the 2nd and 8th smallest, coverage
96.1%; with 7 the extremes, 98.4%).

Sequential pairs on a shared box still see the load change between the two runs of a pair (one pair's ratio can be
off by 20%). ``--concurrent`` pairs run both arms at the same time, each in its own thread, each timed by its own
thread's CPU clock (``time.thread_time``; torch and the engine use no other threads): the load of the box then lands
on both arms at the same instants, and the ratios come out several times tighter. The arms share torch's global
generator in that mode, so their trajectories are not the seeded ones; the work per frame is what is timed. Both
figures are reported, each with its interval.

The engine-step arm isolates what ADR changes per step: ``--env-blocks`` alternating blocks of ``--env-steps``
steps of the batched engine (20 worlds, DR vs ADR, random actions, finished worlds reset as the collector does),
CPU microseconds per engine step.

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
    MUJOCO_GL=egl nice -n 10 .venv/bin/python benchmarks/bench_adr.py   # arm-reach, 9 + 9 pairs of 4000 frames
    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_adr.py --frames 1000 --repeats 1 --concurrent 1 \
        --curve-frames 0 --env-blocks 0   # smoke test

The last line printed is ``RESULT ...`` with the median ratio, its interval and the verdict against the goal.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import threading
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
    task: str,
    frames: int,
    seed: int,
    adr: ADR | None,
    bc: str | None = None,
    bc_frames: int = 0,
    engine: str = "auto",
    clock: Any = time.process_time,
) -> tuple[float, float, Any]:
    """One PPO run: (CPU frames/s by ``clock``, wall frames/s, the TrainResult)."""
    cfg = PPOConfig(
        frames=frames,
        frames_per_batch=500,
        minibatch_size=250,
        epochs=4,
        obs_norm_frames=500,
        bc_baseline=bc,
        bc_frames=bc_frames if bc else 0,
        engine=engine,
    )
    chosen = [adr] if adr is not None else effects()
    cpu = clock()
    result = train(task, cfg, effects=chosen, seed=seed, progress=False, logger=None)
    cpu = clock() - cpu
    return result.frames / cpu, result.frames / result.wall_time, result


def concurrent_pair(task: str, frames: int, seed: int, make_adr: Any, engine: str, adr_first: bool) -> float:
    """Both arms at once, each in its own thread, timed by its own thread's CPU clock: the ratio adr/dr of CPU
    frames/s. Whatever else loads the box loads both arms at the same instants (the GIL and MuJoCo's and torch's
    GIL-free C calls interleave them at millisecond scale), so the pair's ratio is not at the mercy of a load that
    changes between two sequential runs. The arms share torch's global generator here (``train`` seeds it in each
    thread), so their trajectories are not reproducible; what is timed is the same work per frame."""
    out: dict[str, float] = {}

    def arm(name: str) -> None:
        adr = make_adr() if name == "adr" else None
        out[name] = run(task, frames, seed, adr, engine=engine, clock=time.thread_time)[0]

    names = ("adr", "dr") if adr_first else ("dr", "adr")
    threads = [threading.Thread(target=arm, args=(name,)) for name in names]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    if set(out) != {"dr", "adr"}:
        raise RuntimeError(f"an arm of the concurrent pair failed (finished: {sorted(out)})")
    return out["adr"] / out["dr"]


def summary(label: str, ratios: list[float]) -> str:
    """Prints the paired ratios' spread; returns the RESULT fragment with the verdict."""
    median = statistics.median(ratios)
    quartiles = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else [ratios[0]] * 3
    low, high, coverage = median_interval(ratios)
    above = sum(r >= RATIO_GOAL for r in ratios)
    print(f"# {label}: paired adr/dr cpu ratios, sorted: {', '.join(f'{r:.3f}' for r in sorted(ratios))}")
    print(
        f"# {label}: median {median:.3f}, interquartile range {quartiles[0]:.3f}-{quartiles[2]:.3f}, median "
        f"interval {low:.3f}-{high:.3f} (coverage {coverage:.3f}), pairs >= {RATIO_GOAL}: {above}/{len(ratios)}"
    )
    verdict = "met" if median >= RATIO_GOAL else "missed"
    resolved = (
        "interval above the goal" if low >= RATIO_GOAL else
        "interval below the goal" if high < RATIO_GOAL else "interval includes the goal"
    )  # fmt: skip
    return f"{label} {median:.3f} [{low:.3f}, {high:.3f}] over {len(ratios)} pairs: {verdict} ({resolved})"


def median_interval(values: list[float], level: float = 0.95) -> tuple[float, float, float]:
    """The distribution-free interval for the median from order statistics (the sign-test interval): the
    narrowest ``[x_(j), x_(n+1-j)]`` whose coverage is at least ``level``; returns (low, high, coverage). With fewer
    than 6 values even the full range covers less than 95%; it is returned with its coverage.

    Example:
        >>> median_interval([0.9, 1.1, 1.0, 0.95, 1.05, 0.98, 1.02, 0.97, 1.01])
        (0.95, 1.05, 0.9609375)
    """
    x = sorted(values)
    n = len(x)
    tail = [math.comb(n, i) / 2**n for i in range(n + 1)]
    # [x_(j), x_(n+1-j)] misses the median with probability 2 P(Binomial(n, 1/2) <= j - 1).
    j = 1
    while j + 1 <= (n + 1) // 2 and sum(tail[: j + 1]) <= (1 - level) / 2:
        j += 1
    return x[j - 1], x[n - j], 1 - 2 * sum(tail[:j])


def env_steps(task: str, steps: int, blocks: int, t_low: float, t_high: float, m: int) -> tuple[float, float]:
    """Median CPU microseconds per batched engine step (20 worlds) under DR and under ADR (blocks alternating)."""
    from sim2real.batched import make_batched

    arms = {
        "dr": make_batched(task, 20, *effects(), seed=0),
        "adr": make_batched(task, 20, controller(t_low, t_high, m), seed=0),
    }
    rng = np.random.default_rng(0)
    times: dict[str, list[float]] = {"dr": [], "adr": []}

    def block(envs: Any, count: int) -> float:
        start = time.process_time()
        for _ in range(count):
            act = rng.uniform(-1.0, 1.0, (envs.num_envs, envs.action_dim)).astype(np.float32)
            _, _, terminated, truncated, _ = envs.step(act)
            done = np.flatnonzero(terminated | truncated)
            if len(done):
                envs.reset(indices=done)
        return (time.process_time() - start) / count * 1e6

    for envs in arms.values():
        envs.reset(seed=0)
        block(envs, 200)  # warm-up
    for _ in range(blocks):
        for name, envs in arms.items():
            times[name].append(block(envs, steps))
    for envs in arms.values():
        envs.close()
    return statistics.median(times["dr"]), statistics.median(times["adr"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="sim2real/arm-reach")
    parser.add_argument("--frames", type=int, default=4000)
    parser.add_argument(
        "--repeats", type=int, default=9, help="sequential pairs (dr, adr) timed (>= 7 for the interval)"
    )
    parser.add_argument("--concurrent", type=int, default=9, help="concurrent pairs (both arms in threads at once)")
    parser.add_argument("--engine", default="auto", choices=["auto", "per-env"], help="PPOConfig.engine of both arms")
    parser.add_argument("--t-low", type=float, default=-130.0, help="ADR t_low (episode return)")
    parser.add_argument("--t-high", type=float, default=-105.0, help="ADR t_high (episode return)")
    parser.add_argument("--m", type=int, default=2, help="ADR buffer size")
    parser.add_argument("--curve-frames", type=int, default=30000, help="frames of the entropy-curve run (0: none)")
    parser.add_argument("--curve-bc", default="ReachController", help="BC warm start of the curve run ('' for none)")
    parser.add_argument("--curve-bc-frames", type=int, default=4000, help="frames the BC teacher records")
    parser.add_argument("--curve-metric", default="auto", help="ADR metric of the curve run (auto: success)")
    parser.add_argument("--curve-t-low", type=float, default=0.3, help="curve run t_low (success rate)")
    parser.add_argument("--curve-t-high", type=float, default=0.7, help="curve run t_high (success rate)")
    parser.add_argument("--env-steps", type=int, default=1000, help="engine steps per block of the engine-step arm")
    parser.add_argument("--env-blocks", type=int, default=7, help="blocks per arm of the engine-step arm (0: none)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"# bench_adr: {args.task}, {args.frames} PPO frames x {args.repeats} pairs, engine {args.engine}, 1 thread")
    print(f"# python {platform.python_version()}, mujoco {mujoco.__version__}, torch {torch.__version__}")
    make_adr = lambda: controller(args.t_low, args.t_high, args.m)  # noqa: E731
    _, _, warm = run(args.task, min(args.frames, 1000), 99, None, engine=args.engine)  # warm-up, untimed
    _, _, warm_adr = run(args.task, min(args.frames, 1000), 99, make_adr(), engine=args.engine)
    print(f"# collection: dr {warm.collection}; adr {warm_adr.collection}")
    ratios, wall_ratios, rows = [], [], []
    for k in range(args.repeats):
        # Counterbalanced pairs (dr first in even pairs, adr first in odd ones): a load that drifts during the run
        # would otherwise always land on the arm that runs second.
        if k % 2 == 0:
            dr_cpu, dr_wall, _ = run(args.task, args.frames, k, None, engine=args.engine)
            adr_cpu, adr_wall, result = run(args.task, args.frames, k, make_adr(), engine=args.engine)
        else:
            adr_cpu, adr_wall, result = run(args.task, args.frames, k, make_adr(), engine=args.engine)
            dr_cpu, dr_wall, _ = run(args.task, args.frames, k, None, engine=args.engine)
        ratios.append(adr_cpu / dr_cpu)
        wall_ratios.append(adr_wall / dr_wall)
        rows.append((dr_cpu, adr_cpu, dr_wall, adr_wall))
        print(
            f"pair {k}: dr {dr_cpu:7.1f} cpu-f/s {dr_wall:7.1f} wall-f/s | adr {adr_cpu:7.1f} cpu-f/s "
            f"{adr_wall:7.1f} wall-f/s | adr/dr cpu {ratios[-1]:.3f} wall {wall_ratios[-1]:.3f}",
            flush=True,
        )
    hand = float(np.mean([math.log(e.distribution.high - e.distribution.low) for e in effects()]))
    print(f"# entropy of the hand-picked ranges: {hand:.3f} nats/dim")
    if args.curve_frames > 0:
        curve = curve_controller(args.curve_t_low, args.curve_t_high, args.m, args.curve_metric)
        bc = args.curve_bc or None
        _, _, result = run(args.task, args.curve_frames, 0, curve, bc, args.curve_bc_frames, engine=args.engine)
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
            f"# engine steps (20 worlds): dr {dr_us:.1f} us/step, adr {adr_us:.1f} us/step (median of "
            f"{args.env_blocks} blocks of {args.env_steps}); adr/dr steps/s {dr_us / adr_us:.3f}"
        )
    parts = []
    if ratios:
        med = [statistics.median(col) for col in zip(*rows, strict=True)]
        print(f"# sequential medians: dr {med[0]:.1f} cpu-f/s, adr {med[1]:.1f} cpu-f/s; dr {med[2]:.1f} wall-f/s, "
              f"adr {med[3]:.1f} (wall ratio {statistics.median(wall_ratios):.3f})")  # fmt: skip
        parts.append(summary("sequential", ratios))
    concurrent = []
    for k in range(args.concurrent):
        concurrent.append(concurrent_pair(args.task, args.frames, k, make_adr, args.engine, adr_first=k % 2 == 1))
        print(f"concurrent pair {k}: adr/dr cpu {concurrent[-1]:.3f}", flush=True)
    if concurrent:
        parts.append(summary("concurrent", concurrent))
    if parts:
        print(f"RESULT {args.task} ({args.engine}): adr/dr cpu frames/s goal >= {RATIO_GOAL}: " + "; ".join(parts))


if __name__ == "__main__":
    main()
