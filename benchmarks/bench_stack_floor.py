"""Where the batched full stack's cost over batched raw goes (issue 15, P4's "full stack / raw >= 0.95"), and the
ceiling the keyed noise streams put on that ratio.

On ``--worlds`` reacher worlds (threads=1), this process's CPU time:

* **raw / stack**: ``make_batched`` without effects and with ``bench_eval.stack()`` (the three physics effects,
  observation Gaussian noise and bias, action Gaussian noise, observation latency), stepped in alternating chunks
  of 25 control steps by the numpy MLP policy (as ``bench_eval._p4_interleaved``): the cost of a step of every world;
* **in place**: the stack's refills timed inside its own steps (per control step: the steps between refills amortise
  them), where the physics of every world has just been through the caches;
* **normals**: what the keyed-stream promise makes every step draw, timed alone: each world's observation and action
  Gaussian blocks (``BLOCK`` rows of 6 and 2 normals) from a Philox generator put at its block's counter, as the
  engine's refill does, per control step;
* **refill**: one refill of every world's observation and action blocks (``SignalCorruptor.next_noise_blocks`` into
  the engine's own blocks: the normals plus the scale, bias, cast and per-world Python), per control step, hot;
* **per-step signals**: the engine's ``act`` and ``observe`` of every world between refills (noise add, action clip,
  observation ring slot and lagged copy), and the same numpy calls written out with no Python around them.

The ceilings: raw / (raw + normals), what the stack could reach if drawing the normals were its only cost, and
raw / (raw + normals + the per-step numpy calls). Usage::

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_stack_floor.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np
from bench_eval import NumpyMLP, stack

from noise_models.corruptor import SignalCorruptor
from noise_models.processes import BLOCK
from sim2real.batched import make_batched

try:  # the clip ufunc itself, as sim2real.batched.signals
    from numpy._core.umath import clip as _clip  # type: ignore[attr-defined]
except ImportError:  # pragma: no cover - numpy < 2
    from numpy.core.umath import clip as _clip  # type: ignore[no-redef]

_clock = time.process_time
TASK = "dmc/reacher-easy"


def _interleaved(num: int, steps: int) -> tuple[float, float, float]:
    """Seconds per control step of every world: (raw, stack, the stack's refills in place), alternating chunks of 25
    steps. The refills are timed inside the stack's own steps (a timer around each pipeline's refill), where the
    physics of 64 worlds has just run through the caches."""
    arms = {
        "raw": make_batched(TASK, num, seed=0, threads=1),
        "stack": make_batched(TASK, num, *stack(), seed=0, threads=1),
    }
    signals = arms["stack"]._signals
    assert signals is not None
    in_place = [0.0]
    for pipes in (*signals._obs, *signals._act):
        refill = pipes._refill

        def timed(worlds: list[int], refill: Any = refill) -> None:
            start = _clock()
            refill(worlds)
            in_place[0] += _clock() - start

        pipes._refill = timed  # type: ignore[method-assign]
    policy = NumpyMLP(arms["raw"].observation_dim, arms["raw"].action_dim)
    obs = {arm: worlds.reset(seed=0)[0] for arm, worlds in arms.items()}
    spent = dict.fromkeys(arms, 0.0)
    for c, first in enumerate(range(0, steps, 25)):
        for arm in list(arms) if c % 2 == 0 else list(arms)[::-1]:
            worlds, o = arms[arm], obs[arm]
            start = _clock()
            for _ in range(min(25, steps - first)):
                o, *_ = worlds.step(policy(o))
            spent[arm] += _clock() - start
            obs[arm] = o
    for worlds in arms.values():
        worlds.close()
    return spent["raw"] / steps, spent["stack"] / steps, in_place[0] / steps


def _normals(num: int, sizes: tuple[int, ...], blocks: int = 8) -> float:
    """Seconds per control step to draw every world's BLOCK rows of each size, one Philox block start each."""
    gen = np.random.Generator(np.random.Philox(key=np.array([1, 2], np.uint64)))
    outs = [np.empty((BLOCK, k)) for k in sizes]
    start = _clock()
    for b in range(blocks):
        for i in range(num):
            for out in outs:
                gen.bit_generator.state = {"bit_generator": "Philox", "state": {"counter": [0, 0, 1 + b, i],
                                           "key": [1, 2]}, "buffer": [0, 0, 0, 0], "buffer_pos": 4,
                                           "has_uint32": 0, "uinteger": 0}  # fmt: skip
                gen.standard_normal(out=out)
    return (_clock() - start) / (blocks * BLOCK)


def _refill_and_signals(num: int, rounds: int = 8) -> tuple[float, float, float]:
    """Seconds per control step: (the refill of every world's blocks, the engine's act + observe between refills,
    the same numpy calls with no Python around them)."""
    worlds = make_batched(TASK, num, *stack(), seed=0, threads=1)
    obs, _ = worlds.reset(seed=0)
    signals = worlds._signals
    assert signals is not None
    every = np.ones(num, bool)
    actions = np.random.default_rng(0).uniform(-1, 1, (num, worlds.action_dim)).astype(np.float32)
    signals.act(actions, every, True)  # the action pipelines draw their first block on the first step
    refill = 0.0
    for _ in range(rounds):
        for pipes in (*signals._obs, *signals._act):
            out = (pipes.F.transpose(1, 0, 2), pipes.G, pipes.unit)
            start = _clock()
            SignalCorruptor.next_noise_blocks(pipes.corruptors, pipes.side, pipes.k, out)
            refill += _clock() - start
    previous = obs.copy()
    calls = 0.0
    for _ in range(rounds):
        worlds.reset(seed=0)
        signals.act(actions, every, True)
        start = _clock()
        for _ in range(200):  # rows 1..200 of blocks drawn at reset: no refill
            signals.act(actions, every, True)
            previous = signals.observe(obs, every, previous, True)
        calls += _clock() - start
    act_f = np.zeros((BLOCK, num, worlds.action_dim), np.float32)
    obs_f = np.zeros((BLOCK, num, worlds.observation_dim), np.float32)
    ring = np.zeros((3, num, worlds.observation_dim), np.float32)
    low = np.full((num, worlds.action_dim), -1.0, np.float32)
    high = -low
    bare = 0.0
    for _ in range(rounds):
        start = _clock()
        for r in range(200):
            w = np.add(actions, act_f[r])
            _clip(w, low, high, w)
            np.add(obs, obs_f[r], ring[r % 3])
            np.copyto(previous, ring[(r + 1) % 3])
        bare += _clock() - start
    worlds.close()
    return refill / (rounds * BLOCK), calls / (rounds * 200), bare / (rounds * 200)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=64)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    n = args.worlds
    print(f"# bench_stack_floor  python {platform.python_version()}  numpy {np.__version__}  {os.cpu_count()} CPUs; "
          f"{TASK}, {n} worlds, threads=1, {args.repeats} repeats; clock: process CPU time; us per control step "
          f"of every world")  # fmt: skip
    rows: dict[str, list[float]] = {
        k: [] for k in ("raw", "stack", "in_place", "normals", "refill", "signals", "numpy")
    }
    for _ in range(args.repeats):
        raw, full, in_place = _interleaved(n, args.steps)
        refill, calls, bare = _refill_and_signals(n)
        for key, value in (("raw", raw), ("stack", full), ("in_place", in_place), ("normals", _normals(n, (6, 2))), ("refill", refill),
                           ("signals", calls), ("numpy", bare)):  # fmt: skip
            rows[key].append(1e6 * value)
    med = {k: statistics.median(v) for k, v in rows.items()}
    labels = {
        "raw": "batched raw step",
        "stack": "batched full stack step",
        "in_place": "  its refills, timed in place",
        "normals": "  the normals alone (Philox standard_normal)",
        "refill": "  refill of every block (normals included)",
        "signals": "  act + observe between refills",
        "numpy": "  the same numpy calls, no Python",
    }
    for key, label in labels.items():
        runs = ", ".join(f"{x:.1f}" for x in rows[key])
        print(f"{label:46s} {med[key]:7.1f} us  (runs: {runs})")
    print(f"stack - raw {med['stack'] - med['raw']:.1f} us a step; timed alone (hot caches, not additive to the "
          f"interleaved figure): refill {med['refill']:.1f}, act + observe {med['signals']:.1f}")  # fmt: skip
    print(f"RESULT full stack / raw = {med['raw'] / med['stack']:.3f} (runs: "
          f"{', '.join(f'{r / s:.3f}' for r, s in zip(rows['raw'], rows['stack'], strict=True))}; goal >= 0.95); "
          f"ceilings: normals only {med['raw'] / (med['raw'] + med['normals']):.3f}, normals + per-step numpy "
          f"{med['raw'] / (med['raw'] + med['normals'] + med['numpy']):.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
