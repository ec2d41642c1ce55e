"""Overhead of physics randomisation (issue #2) and of the full sim-to-real stack (issue #3) on the hot path.

Measures in one run, side by side:

1. Step throughput of a raw task (``s2r.make(task)``) against the same task wrapped with seven
   reset-schedule effects (``s2r.wrap(..., seed=0)``), plus a third arm, raw+params: the raw env
   whose model gets the same per-episode values at each reset from a bare ``PhysicsRandomizer``
   but with no wrapper on ``step``. It splits the gap into simulating the perturbed physics
   (raw+params vs raw) and the wrapper's own step code (wrapped vs raw+params). The arms run one
   after the other inside every repeat, in an order that rotates and flips each repeat, so machine
   noise hits all of them alike; figures are medians over repeats, ratios the median of the
   per-repeat paired ratios. Actions come from a pre-generated array (no sampling in the loop).
   Resets are excluded from the timing: only the ``step`` calls between resets are timed, in
   blocks, so the clock is read twice per episode, not per step. Episode ``k`` of a run starts
   with ``reset(seed=k)`` in every arm, so all see the same initial states (and the wrapped and
   raw+params arms the same physics values).
2. The cost of one physics resample at reset: ``PhysicsRandomizer(<same 7 effects>)`` bound to the
   task's model, timing ``begin_episode(); apply()`` (Mass and Armature make ``apply`` run
   ``mj_setConst``), with ``begin_episode`` alone, ``apply`` alone and ``mj_setConst`` alone for
   context, and the seeded variant ``begin_episode(seed=k); apply()`` that ``reset(seed=k)`` runs.
3. The full stack of issue #3 over the raw env, interleaved the same way: physics DR at reset
   (:func:`make_stack_physics`) + an observation noise pipeline (Gaussian + per-episode Bias) + action
   noise + ``ObservationLatency(steps=3)`` + ``ActionLatency(seconds=0.02)`` at physics rate. Its
   raw+params arm again separates the perturbed physics from the wrappers' own step code. On
   manipulator a second stack uses ``ActionLatency(steps=5)``, which lands mid control step and
   makes every step run in two physics segments.

4. P1 of issue 15 (:mod:`bench_p1`): the same full stack as two wrapper layers (as ``wrap`` built it before) and
   as one fused layer, each over the raw env, side by side in CPU time; on manipulator also over dm-control's own
   task (before its cached-index fast path).

Usage:
    .venv/bin/python benchmarks/bench_overhead.py            # full run
    .venv/bin/python benchmarks/bench_overhead.py --quick    # smoke test (seconds)
    nice -n 10 .venv/bin/python benchmarks/bench_overhead.py --p1-only   # section [4] only

The last line printed is ``RESULT ...`` with the ratios and the resample cost against the goals
(step ratio >= 0.97, resample <= 50 µs).
"""

from __future__ import annotations

import argparse
import gc
import itertools
import os
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

import sim2real as s2r
from randomizers import PhysicsRandomizer

STEP_RATIO_GOAL = 0.97
RESAMPLE_US_GOAL = 50.0
STACK_GOALS = {"reacher-easy": 0.90, "manipulator-bring_ball": 0.97}
DEFAULT_TASKS = ("reacher-easy", "manipulator-bring_ball")


def make_effects() -> list[Any]:
    """The seven reset-schedule effects of the benchmark (Mass makes the resample run mj_setConst)."""
    u = s2r.Uniform
    return [
        s2r.Friction(scale=u(0.5, 1.5)),
        s2r.Mass(scale=u(0.8, 1.2), bodies="*"),
        s2r.Damping(scale=u(0.5, 2.0)),
        s2r.Armature(scale=u(0.5, 2.0)),
        s2r.FrictionLoss(add=u(0.0, 0.01)),
        s2r.ActuatorGain(scale=u(0.9, 1.1)),
        s2r.Gravity(scale=u(0.95, 1.05), axes="z"),
    ]


def make_stack_physics() -> list[Any]:
    """Physics DR of the full-stack benchmark: reset-schedule effects that leave the solver's work
    unchanged (FrictionLoss, which adds constraint rows, is measured in section [1])."""
    u = s2r.Uniform
    return [
        s2r.Friction(scale=u(0.5, 1.5)),
        s2r.Mass(scale=u(0.8, 1.2), bodies="*"),
        s2r.Damping(scale=u(0.5, 2.0)),
        s2r.ActuatorGain(scale=u(0.9, 1.1)),
    ]


def make_signal_models(action_latency: Any = None) -> list[Any]:
    """The noise and latency models of the full-stack benchmark (the issue's example plus action noise)."""
    from noise_models import ActionLatency, ActionNoise, Bias, Gaussian, ObservationLatency, ObservationNoise

    return [
        ObservationNoise(Gaussian(std=0.01), Bias(s2r.Uniform(-0.02, 0.02))),
        ActionNoise(Gaussian(std=0.05)),
        ObservationLatency(steps=3),
        action_latency if action_latency is not None else ActionLatency(seconds=0.02),
    ]


def task_id(name: str) -> str:
    return name if "/" in name else f"dmc/{name}"


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def time_steps(
    env: Any,
    actions: np.ndarray,
    steps: int,
    before_reset: Callable[[int], None] | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> float:
    """Steps/s of ``env`` over ``steps`` steps; resets (``reset(seed=k)`` for episode k) are not timed.

    ``before_reset(k)`` runs (untimed) before each reset, for the raw+params arm; ``clock`` is wall time by default
    (``time.process_time`` for CPU time).
    """
    n_actions = len(actions)

    def reset(episode: int) -> None:
        if before_reset is not None:
            before_reset(episode)
        env.reset(seed=episode)

    episode = 0
    reset(episode)
    done_steps = 0
    elapsed = 0.0
    gc.collect()
    while done_steps < steps:
        block = 0
        remaining = steps - done_steps
        done = False
        start = clock()
        while block < remaining:
            _, _, terminated, truncated, _ = env.step(actions[(done_steps + block) % n_actions])
            block += 1
            if terminated or truncated:
                done = True
                break
        elapsed += clock() - start
        done_steps += block
        if done:
            episode += 1
            reset(episode)
    return steps / elapsed


def bench_steps(
    tasks: list[str],
    steps: int,
    repeats: int,
    warmup: int,
    effects: Callable[[], list[Any]] = make_effects,
    signals: Callable[[], list[Any]] | None = None,
) -> dict[str, dict[str, Any]]:
    """Interleaved step throughput of the raw, wrapped and raw+params arms of each task.

    raw+params is the raw env whose model gets the wrapped env's per-episode values at each reset
    (a bare ``PhysicsRandomizer`` with the same seed, ``begin_episode(k); apply()`` before
    ``reset(seed=k)``, exactly what the wrapper does) but no wrapper on ``step``: it splits the
    wrapped/raw gap into the cost of simulating the perturbed physics (raw+params vs raw) and the
    cost of the wrapper's own ``step`` code (wrapped vs raw+params).
    """
    results: dict[str, dict[str, Any]] = {}
    for name in tasks:
        tid = task_id(name)
        extra = signals() if signals is not None else []
        arms: dict[str, Any] = {"raw": s2r.make(tid), "wrapped": s2r.wrap(s2r.make(tid), effects(), *extra, seed=0)}
        arms["raw+params"] = s2r.make(tid)
        handle = s2r.find_physics(arms["raw+params"])
        assert handle is not None
        twin = PhysicsRandomizer(effects(), seed=0)
        twin.bind(handle.model, handle.data)

        def apply_twin(episode: int, twin: PhysicsRandomizer = twin) -> None:
            twin.begin_episode(episode)
            twin.apply()

        hooks: dict[str, Callable[[int], None] | None] = {"raw": None, "wrapped": None, "raw+params": apply_twin}
        rng = np.random.default_rng(12345)
        space = arms["raw"].action_space
        actions = rng.uniform(space.low, space.high, size=(4096, *space.shape)).astype(space.dtype)
        for arm, env in arms.items():
            time_steps(env, actions, warmup, hooks[arm])
        names = list(arms)
        rates: dict[str, list[float]] = {arm: [] for arm in names}
        for rep in range(repeats):
            # Rotate the order every repeat so no arm always runs first (or right after another).
            order = names[rep % len(names) :] + names[: rep % len(names)]
            if rep % 2:
                order.reverse()
            for arm in order:
                rates[arm].append(time_steps(arms[arm], actions, steps, hooks[arm]))
            print(
                f"  {name:<24} repeat {rep + 1}/{repeats}: "
                + "  ".join(f"{arm} {rates[arm][-1]:7.0f}" for arm in names)
                + f" steps/s  wrapped/raw {rates['wrapped'][-1] / rates['raw'][-1]:.3f}",
                flush=True,
            )
        med = {arm: statistics.median(v) for arm, v in rates.items()}
        results[name] = {
            **med,
            "ratio": statistics.median(w / r for w, r in zip(rates["wrapped"], rates["raw"], strict=True)),
            "ratio_of_medians": med["wrapped"] / med["raw"],
            "physics_ratio": statistics.median(p / r for p, r in zip(rates["raw+params"], rates["raw"], strict=True)),
            "wrapper_ratio": statistics.median(
                w / p for w, p in zip(rates["wrapped"], rates["raw+params"], strict=True)
            ),
            "raw_us": 1e6 / med["raw"],
            "physics_us": 1e6 / med["raw+params"] - 1e6 / med["raw"],
            "wrapper_us": 1e6 / med["wrapped"] - 1e6 / med["raw+params"],
            "n_params": len(twin.current_params),
        }
        for env in arms.values():
            env.close()
    return results


def _time_loop(fn: Callable[[], None], iterations: int) -> float:
    """µs per call of ``fn`` over ``iterations`` calls."""
    clock = time.perf_counter
    gc.collect()
    start = clock()
    for _ in range(iterations):
        fn()
    return (clock() - start) / iterations * 1e6


def resampler(r: PhysicsRandomizer, seeded: bool = False) -> Callable[[], None]:
    """``begin_episode(); apply()``, or with ``seeded`` the ``begin_episode(seed=k); apply()`` of ``reset(seed=k)``
    (streams re-rooted at (wrap seed, k), a new k each call)."""
    if not seeded:

        def resample() -> None:
            r.begin_episode()
            r.apply()

        return resample
    seeds = itertools.count()

    def resample_seeded() -> None:
        r.begin_episode(next(seeds))
        r.apply()

    return resample_seeded


def bench_resample(tasks: list[str], iterations: int, repeats: int) -> dict[str, dict[str, Any]]:
    results: dict[str, dict[str, Any]] = {}
    for name in tasks:
        env = s2r.make(task_id(name))
        handle = s2r.find_physics(env)
        assert handle is not None
        model, data = handle.model, handle.data
        randomizer = PhysicsRandomizer(make_effects(), seed=0)
        randomizer.bind(model, data)
        scratch = mujoco.MjData(model)

        pieces: dict[str, Callable[[], None]] = {
            "resample": resampler(randomizer),
            "resample_seeded": resampler(randomizer, seeded=True),
            "begin_episode": randomizer.begin_episode,
            "apply": randomizer.apply,
            "mj_setConst": lambda m=model, d=scratch: mujoco.mj_setConst(m, d),
        }
        for fn in pieces.values():
            _time_loop(fn, max(1, iterations // 10))
        samples: dict[str, list[float]] = {k: [] for k in pieces}
        for _ in range(repeats):
            for key, fn in pieces.items():
                samples[key].append(_time_loop(fn, iterations))
        results[name] = {k: statistics.median(v) for k, v in samples.items()}
        results[name]["n_params"] = len(randomizer.current_params)
        randomizer.restore_nominal()
        env.close()
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=20000, help="timed steps per arm per repeat")
    parser.add_argument("--repeats", type=int, default=5, help="repeats (the median is reported)")
    parser.add_argument("--tasks", nargs="+", default=list(DEFAULT_TASKS), help="dm-control suite tasks")
    parser.add_argument("--resample-iters", type=int, default=5000, help="resamples timed per repeat")
    parser.add_argument("--quick", action="store_true", help="tiny run to check the script works")
    parser.add_argument(
        "--p1-only", action="store_true", help="only section [4], P1 of issue 15 (two layers vs one fused layer)"
    )
    parser.add_argument("--p1-steps", type=int, default=10000, help="section [4]: timed steps per arm per repeat")
    parser.add_argument("--p1-chunk", type=int, default=0, help="section [4]: interleave the arms every N steps")
    args = parser.parse_args()
    steps, repeats, iters, warmup = args.steps, args.repeats, args.resample_iters, 2000
    if args.quick:
        steps, repeats, iters, warmup = 1000, 2, 200, 100
    if args.p1_only:
        _section_p1(
            args.tasks, 500 if args.quick else args.p1_steps, repeats, 100 if args.quick else 1000, args.p1_chunk
        )
        return

    print(f"bench_overhead: python {platform.python_version()}, mujoco {mujoco.__version__}, numpy {np.__version__}")
    print(f"machine: {os.cpu_count()} CPUs, {cpu_model()}")
    print(f"steps={steps} repeats={repeats} resample_iters={iters} tasks={args.tasks}")
    print("effects:", ", ".join(repr(e) for e in make_effects()))
    print("resets are excluded from the step timing (only step calls between resets are timed)")

    print("\n[1] step throughput, raw vs wrapped (interleaved)")
    step_res = bench_steps(args.tasks, steps, repeats, warmup)
    print(
        f"\n{'task':<24}{'raw':>8}{'wrapped':>9}{'raw+par':>9}{'wrap/raw':>9}{'(of med)':>9}"
        f"{'phys':>7}{'wrapper':>8}{'raw µs':>8}{'+phys µs':>9}{'+wrap µs':>9}"
    )
    for name, r in step_res.items():
        print(
            f"{name:<24}{r['raw']:>8.0f}{r['wrapped']:>9.0f}{r['raw+params']:>9.0f}{r['ratio']:>9.3f}"
            f"{r['ratio_of_medians']:>9.3f}{r['physics_ratio']:>7.3f}{r['wrapper_ratio']:>8.3f}"
            f"{r['raw_us']:>8.1f}{r['physics_us']:>9.2f}{r['wrapper_us']:>9.2f}"
        )
    print(
        "(steps/s medians; wrap/raw = median of per-repeat wrapped/raw ratios; phys = raw+params/raw, the cost of\n"
        " simulating the perturbed model; wrapper = wrapped/raw+params, the wrapper's own step code; µs per step)"
    )

    print("\n[2] physics resample at reset: begin_episode(); apply()  (µs, median of repeats)")
    res = bench_resample(args.tasks, iters, repeats)
    print(f"\n{'task':<26}{'params':>7}{'resample':>10}{'begin_ep':>10}{'apply':>8}{'setConst':>10}{'seeded':>8}")
    for name, r in res.items():
        print(
            f"{name:<26}{r['n_params']:>7}{r['resample']:>10.1f}{r['begin_episode']:>10.1f}"
            f"{r['apply']:>8.1f}{r['mj_setConst']:>10.1f}{r['resample_seeded']:>8.1f}"
        )
    print(
        "(resample = begin_episode(); apply(), the goal's figure; begin_ep, apply and setConst = mj_setConst alone\n"
        " are its parts; seeded = begin_episode(seed=k); apply() with a new k each time, what reset(seed=k) costs)"
    )

    print("\n[3] full stack (issue #3): physics DR at reset + obs noise + action noise + obs/action latency")
    print("stack physics:", ", ".join(repr(e) for e in make_stack_physics()))
    print("stack signals:", ", ".join(repr(m) for m in make_signal_models()))
    stack = bench_steps(args.tasks, steps, repeats, warmup, make_stack_physics, make_signal_models)
    mid: dict[str, dict[str, Any]] = {}
    if "manipulator-bring_ball" in args.tasks:
        from noise_models import ActionLatency

        print("stack variant: ActionLatency(steps=5), mid control step on manipulator (10 substeps)")
        mid = bench_steps(
            ["manipulator-bring_ball"],
            steps,
            repeats,
            warmup,
            make_stack_physics,
            lambda: make_signal_models(ActionLatency(steps=5)),
        )
    print(f"\n{'task':<32}{'raw':>8}{'stack':>8}{'raw+par':>9}{'stack/raw':>10}{'goal':>6}{'wrappers':>9}{'+wrap µs':>9}")
    for label, group in (("", stack), (" (latency mid-step)", mid)):
        for name, r in group.items():
            goal = STACK_GOALS.get(name, STEP_RATIO_GOAL)
            print(
                f"{name + label:<32}{r['raw']:>8.0f}{r['wrapped']:>8.0f}{r['raw+params']:>9.0f}{r['ratio']:>10.3f}"
                f"{goal:>6.2f}{r['wrapper_ratio']:>9.3f}{r['wrapper_us']:>9.2f}"
            )
    print("(stack/raw = median of per-repeat ratios; wrappers = stack/raw+params, the wrappers' own step code)")

    worst_resample = max(r["resample"] for r in res.values())
    ok_steps = all(r["ratio"] >= STEP_RATIO_GOAL for r in step_res.values())
    ok_resample = worst_resample <= RESAMPLE_US_GOAL
    verdict = "PASS" if ok_steps and ok_resample else "MISS"
    ratios = " ".join(f"{name} step_ratio={r['ratio']:.3f}" for name, r in step_res.items())
    wrapper = " ".join(f"{name}={r['wrapper_ratio']:.3f}" for name, r in step_res.items())
    resample = " ".join(f"{name}={r['resample']:.1f}" for name, r in res.items())
    print(
        f"RESULT {ratios} resample_us={worst_resample:.1f} ({resample}) wrapper_only_ratio({wrapper}) "
        f"(goals: >={STEP_RATIO_GOAL}, <={RESAMPLE_US_GOAL:g}) {verdict}"
    )
    ok_stack = all(r["ratio"] >= STACK_GOALS.get(n, STEP_RATIO_GOAL) for n, r in stack.items())
    stack_text = " ".join(f"{n}={r['ratio']:.3f}" for n, r in stack.items())
    stack_wrapper = " ".join(f"{n}={r['wrapper_ratio']:.3f}" for n, r in stack.items())
    mid_text = " ".join(f"{n}={r['ratio']:.3f}" for n, r in mid.items())
    print(
        f"RESULT_STACK stack_ratio({stack_text}) wrappers_only({stack_wrapper}) mid_step_latency({mid_text}) "
        f"(goals: {', '.join(f'{n}>={g}' for n, g in STACK_GOALS.items())}) {'PASS' if ok_stack else 'MISS'}"
    )
    _section_p1(args.tasks, steps if args.quick else args.p1_steps, repeats, warmup, args.p1_chunk)


def _section_p1(tasks: list[str], steps: int, repeats: int, warmup: int, chunk: int = 0) -> None:
    """Section [4]: P1 of issue 15, the full stack over raw with two layers and with one fused layer
    (``bench_p1.py``; CPU time)."""
    from bench_p1 import bench_p1, report

    print("\n[4] P1 (issue 15): full stack over raw, two layers (before) vs one fused layer (after), CPU time")
    report(bench_p1(tasks, steps, repeats, warmup, chunk))


if __name__ == "__main__":
    main()
