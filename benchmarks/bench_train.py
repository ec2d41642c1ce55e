"""PPO training throughput with the full sim-to-real stack of issue #3 over plain training (issue #6).

Measures in one run, side by side, the frames per second of :func:`sim2real.agents.train` with PPO:

- *plain*: the task with no effects;
- *stack*: the same task under physics randomisation at reset (``Friction(scale=U(0.5,1.5))``,
  ``Mass(scale=U(0.8,1.2), bodies="*")``, ``Damping(scale=U(0.5,2))``, ``ActuatorGain(scale=U(0.9,1.1))``), an
  observation noise pipeline (``Gaussian(std=0.01)`` + per-episode ``Bias(U(-0.02,0.02))`` + a ``Drift(std=0.001)``
  random walk), ``ActionNoise(Gaussian(std=0.05))``, ``ObservationLatency(steps=1)`` and ``ActionLatency(steps=1)``.

The arms alternate (plain, stack, plain, stack, ...) after one untimed warm-up run of each, so drift in the
machine's load hits both alike. Repeat ``k`` of both arms uses seed ``k``. Each run covers everything
:func:`train` does (env construction, the observation normaliser's random steps, collection, GAE and the gradient
steps) and gives two figures:

- wall frames/s: ``TrainResult.frames / TrainResult.wall_time``, what a user waits for;
- CPU frames/s: frames over the CPU time this process spent in :func:`train` (``time.process_time``, all
  threads). On a shared machine other jobs stretch the wall time but hardly the CPU time, so this is the steadier
  figure for comparing the arms. It is only meaningful with torch on one thread (``--threads 1``, the default):
  with more, idle threads spin and their CPU time tracks the load.

The ratios are medians of the per-repeat stack/plain ratios; the goal is >= 0.95. Times are printed, never asserted.

Usage:
    .venv/bin/python benchmarks/bench_train.py                      # reacher-easy, 3 repeats of 10k frames
    .venv/bin/python benchmarks/bench_train.py --tasks dmc/reacher-easy sim2real/arm-reach --repeats 5
    .venv/bin/python benchmarks/bench_train.py --quick              # smoke test

The last line printed is ``RESULT ...`` with each task's ratio against the goal.

``--arm batched`` measures PPO collection through the batched engine (issue #15, P5), side by side in one run,
alternating after a warm-up of each: *single* (``engine="per-env"``: one TorchRL env, today's collector), *batched*
(``engine="auto"``, ``num_envs`` worlds, no effects) and *batched-stack* (the batched engine under the whole stack,
``ActionLatency`` included since the engine batches it; without it when the engine refuses the whole stack, which
the run prints). The arms' order reverses every repeat. Ratios, medians of per-repeat pairs: batched/single
(goal >= 3) and batched-stack/batched (goal >= 0.95).

    .venv/bin/python benchmarks/bench_train.py --arm batched [--num-envs 16 --repeats 3]

``--algo sac`` measures instead the SAC update (issue #14): updates/s of :class:`sim2real.agents.sac.SACUpdate`
(what :func:`train` runs, batches sampled from its replay buffer) against a minimal plain-PyTorch SAC update
(``benchmarks/sac_reference.py``: actor + twin critics + targets + temperature, one Adam) and, for the record,
TorchRL's ``SACLoss`` + ``SoftUpdate`` on TensorDict batches from a TorchRL ``ReplayBuffer`` (the path ``train``
used before). Same 256x256 networks, batch 256, one thread, CPU time, blocks alternating; the goal is
sim2real/plain >= 0.8 (see ``bench_sac.py``).

    .venv/bin/python benchmarks/bench_train.py --algo sac [--repeats 7 --updates 60]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from typing import Any

import mujoco
import numpy as np
import torch
from bench_overhead import cpu_model, make_stack_physics  # benchmarks/ is on sys.path when run as a script

import sim2real as s2r
from noise_models import ActionLatency, ActionNoise, Bias, Drift, Gaussian, ObservationLatency, ObservationNoise
from sim2real.agents import PPOConfig, train
from sim2real.agents.config import replace

RATIO_GOAL = 0.95
BATCHED_GOAL = 3.0
DEFAULT_TASKS = ("dmc/reacher-easy",)


def make_stack(obs_latency: int = 1, action_latency: int = 1) -> list[Any]:
    """The full issue-#3 stack: physics randomisation at reset, observation and action noise, both latencies."""
    return [
        *make_stack_physics(),  # the physics DR of bench_overhead's full stack
        ObservationNoise(Gaussian(std=0.01), Bias(s2r.Uniform(-0.02, 0.02)), Drift(std=0.001)),
        ActionNoise(Gaussian(std=0.05)),
        ObservationLatency(steps=obs_latency),
        ActionLatency(steps=action_latency),
    ]


def load() -> str:
    try:
        return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "load average unknown"


def fps(task: str, config: PPOConfig, effects: list[Any], seed: int) -> tuple[float, float]:
    """(wall frames/s, CPU frames/s) of one training run."""
    cpu = time.process_time()
    result = train(task, config, effects=effects, seed=seed, progress=False, logger=None)
    cpu = time.process_time() - cpu
    return result.frames / result.wall_time, result.frames / cpu


def bench_batched(task: str, config: PPOConfig, warmup: PPOConfig, repeats: int, stack: list[Any]) -> dict[str, Any]:
    """``--arm batched``: single-env collection vs the batched engine, plain and under the batched stack."""
    from sim2real.agents.collect import BATCHED, choose_collection

    whole = choose_collection(task, stack, config)
    batched_stack = stack if whole.engine == BATCHED else [e for e in stack if not isinstance(e, ActionLatency)]
    print(f"  full stack with ActionLatency: {whole}")
    print(f"  batched-stack arm:             {choose_collection(task, batched_stack, config)}")
    arms: dict[str, tuple[PPOConfig, PPOConfig, list[Any]]] = {
        "single": (replace(config, engine="per-env"), replace(warmup, engine="per-env"), []),
        "batched": (config, warmup, []),
        "batched-stack": (config, warmup, batched_stack),
    }
    for _, warm, effects in arms.values():
        fps(task, warm, effects, seed=10_000)  # untimed warm-up of each arm
    wall: dict[str, list[float]] = {arm: [] for arm in arms}
    cpu: dict[str, list[float]] = {arm: [] for arm in arms}
    for rep in range(repeats):
        for arm in list(arms) if rep % 2 == 0 else list(arms)[::-1]:  # alternate: drift hits every arm alike
            cfg, _, effects = arms[arm]
            w, c = fps(task, cfg, effects, seed=rep)
            wall[arm].append(w)
            cpu[arm].append(c)
        print(
            f"  {task:<20} repeat {rep + 1}/{repeats}: "
            + "  ".join(f"{arm} wall {wall[arm][-1]:7.1f} cpu {cpu[arm][-1]:7.1f}" for arm in arms)
            + f" frames/s  [{load()}]",
            flush=True,
        )
    out: dict[str, Any] = {}
    for name, rates in (("wall", wall), ("cpu", cpu)):
        pairs = {
            "batched/single": [b / s for b, s in zip(rates["batched"], rates["single"], strict=True)],
            "stack/plain": [b / s for b, s in zip(rates["batched-stack"], rates["batched"], strict=True)],
        }
        out[name] = {arm: statistics.median(r) for arm, r in rates.items()}
        out[name].update({key: statistics.median(r) for key, r in pairs.items()})
        out[name].update({f"{key} range": (min(r), max(r)) for key, r in pairs.items()})
    return out


def report_batched(results: dict[str, Any]) -> None:
    print(
        f"\n{'task':<22}{'clock':>6}{'single':>9}{'batched':>9}{'b-stack':>9}{'batched/single':>16}{'(min-max)':>13}"
        f"{'stack/plain':>13}{'(min-max)':>13}"
    )
    for task, by_clock in results.items():
        for clock, r in by_clock.items():
            spans = [f"{lo:.2f}-{hi:.2f}" for lo, hi in (r["batched/single range"], r["stack/plain range"])]
            print(
                f"{task:<22}{clock:>6}{r['single']:>9.1f}{r['batched']:>9.1f}{r['batched-stack']:>9.1f}"
                f"{r['batched/single']:>16.2f}{spans[0]:>13}{r['stack/plain']:>13.3f}{spans[1]:>13}"
            )
    print("(frames/s medians over repeats; ratios = medians of the per-repeat paired ratios)")
    for clock in ("wall", "cpu"):
        fast = all(r[clock]["batched/single"] >= BATCHED_GOAL for r in results.values())
        lean = all(r[clock]["stack/plain"] >= RATIO_GOAL for r in results.values())
        text = " ".join(
            f"{task}=({r[clock]['batched/single']:.2f}, {r[clock]['stack/plain']:.3f})" for task, r in results.items()
        )
        print(
            f"RESULT {clock} (batched_over_single, batched_stack_over_plain): {text} (goals: >={BATCHED_GOAL}: "
            f"{'MET' if fast else 'MISSED'}; >={RATIO_GOAL}: {'MET' if lean else 'MISSED'})"
        )


def bench_task(task: str, config: PPOConfig, warmup: PPOConfig, repeats: int, stack: list[Any]) -> dict[str, Any]:
    arms: dict[str, list[Any]] = {"plain": [], "stack": stack}
    for effects in arms.values():
        fps(task, warmup, effects, seed=10_000)  # untimed: imports, allocator and caches warm for both arms
    wall: dict[str, list[float]] = {arm: [] for arm in arms}
    cpu: dict[str, list[float]] = {arm: [] for arm in arms}
    for rep in range(repeats):
        for arm, effects in arms.items():
            w, c = fps(task, config, effects, seed=rep)
            wall[arm].append(w)
            cpu[arm].append(c)
        print(
            f"  {task:<20} repeat {rep + 1}/{repeats}: wall plain {wall['plain'][-1]:6.1f} stack "
            f"{wall['stack'][-1]:6.1f} ({wall['stack'][-1] / wall['plain'][-1]:.3f})   cpu plain "
            f"{cpu['plain'][-1]:6.1f} stack {cpu['stack'][-1]:6.1f} ({cpu['stack'][-1] / cpu['plain'][-1]:.3f}) "
            f"frames/s  [{load()}]",
            flush=True,
        )
    out: dict[str, Any] = {}
    for name, rates in (("wall", wall), ("cpu", cpu)):
        ratios = [s / p for s, p in zip(rates["stack"], rates["plain"], strict=True)]
        out[name] = {
            "plain": statistics.median(rates["plain"]),
            "stack": statistics.median(rates["stack"]),
            "ratio": statistics.median(ratios),
            "ratio_min": min(ratios),
            "ratio_max": max(ratios),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=list(DEFAULT_TASKS), help="task ids for sim2real.make")
    parser.add_argument("--frames", type=int, default=10_000, help="PPO frames per timed run")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per arm (the median is reported)")
    parser.add_argument("--warmup-frames", type=int, default=2_000, help="frames of the untimed warm-up run per arm")
    parser.add_argument("--obs-latency", type=int, default=1, help="ObservationLatency steps of the stack")
    parser.add_argument("--action-latency", type=int, default=1, help="ActionLatency steps of the stack")
    parser.add_argument(
        "--threads", type=int, default=1, help="torch.set_num_threads (0 keeps torch's default); see CPU frames/s"
    )
    parser.add_argument("--quick", action="store_true", help="tiny run to check the script works")
    parser.add_argument("--algo", choices=("ppo", "sac"), default="ppo",
                        help="ppo: stack-over-plain training fps; sac: SAC updates/s against plain PyTorch")
    parser.add_argument("--updates", type=int, default=60, help="--algo sac: updates per timed block")
    parser.add_argument("--arm", choices=("stack", "batched"), default="stack",
                        help="ppo: stack = stack over plain on today's path; batched = issue-15 batched engine arms")
    parser.add_argument("--num-envs", type=int, default=PPOConfig().num_envs, help="--arm batched: PPOConfig.num_envs")
    args = parser.parse_args()
    if args.algo == "sac":
        from bench_sac import main as sac_main

        sac_main(repeats=1 if args.quick else args.repeats, updates=10 if args.quick else args.updates,
                 threads=args.threads)  # fmt: skip
        return
    frames, repeats, warmup_frames = args.frames, args.repeats, args.warmup_frames
    if args.quick:
        frames, repeats, warmup_frames = 1_000, 1, 500
    config = PPOConfig(frames=frames, num_envs=args.num_envs)
    warmup = PPOConfig(frames=warmup_frames, frames_per_batch=min(warmup_frames, config.frames_per_batch),
                       num_envs=args.num_envs)  # fmt: skip
    stack = make_stack(args.obs_latency, args.action_latency)
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    print(
        f"bench_train: python {platform.python_version()}, torch {torch.__version__} ({torch.get_num_threads()} "
        f"threads), mujoco {mujoco.__version__}, numpy {np.__version__}"
    )
    print(f"machine: {os.cpu_count()} CPUs, {cpu_model()}, {load()}")
    print(f"frames={frames} repeats={repeats} warmup_frames={warmup_frames} tasks={args.tasks}")
    print(f"config: {config}")
    print("stack:", ", ".join(repr(e) for e in stack))
    if args.arm == "batched":
        print("arms alternate single, batched, batched-stack, ...; wall = frames / wall time, cpu = frames / CPU time\n")
        report_batched({task: bench_batched(task, config, warmup, repeats, stack) for task in args.tasks})
        return
    print("arms alternate plain, stack, plain, stack, ...; wall = frames / wall time, cpu = frames / CPU time\n")

    results = {task: bench_task(task, config, warmup, repeats, stack) for task in args.tasks}

    print(
        f"\n{'task':<22}{'clock':>6}{'plain fps':>11}{'stack fps':>11}{'stack/plain':>13}{'(min-max)':>15}"
        f"{'goal':>7}  verdict"
    )
    for task, by_clock in results.items():
        for clock, r in by_clock.items():
            verdict = "met" if r["ratio"] >= RATIO_GOAL else "missed"
            span = f"{r['ratio_min']:.3f}-{r['ratio_max']:.3f}"
            print(
                f"{task:<22}{clock:>6}{r['plain']:>11.1f}{r['stack']:>11.1f}{r['ratio']:>13.3f}{span:>15}"
                f"{RATIO_GOAL:>7.2f}  {verdict}"
            )
    print("(frames/s medians over repeats; stack/plain = median of the per-repeat paired ratios)")
    for clock in ("wall", "cpu"):
        ok = all(r[clock]["ratio"] >= RATIO_GOAL for r in results.values())
        text = " ".join(f"{task}={r[clock]['ratio']:.3f}" for task, r in results.items())
        print(f"RESULT {clock} stack_over_plain_fps({text}) (goal: >={RATIO_GOAL}) {'MET' if ok else 'MISSED'}")


if __name__ == "__main__":
    main()
