"""Spread of a CI learning test over training seeds: how much one seed says (``--algo ppo``: tests/test_agents.py,
``--algo sac``: tests/test_sac_learns.py).

Trains the test's config on ``sim2real/arm-reach`` from each seed and prints the mean return over the test's
evaluation episodes against the test's random-policy return (SAC also: the median final distance), one JSON line per
seed, then the summary that the test's thresholds are set from.

    MUJOCO_GL=egl .venv/bin/python benchmarks/learn_spread.py --algo ppo --seeds 0-7 [--workers 2]
    MUJOCO_GL=egl .venv/bin/python benchmarks/learn_spread.py --algo sac --seeds 0-5 [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from sim2real.parallel import run_tasks


def _seeds(text: str) -> list[int]:
    low, _, high = text.partition("-")
    return list(range(int(low), int(high or low) + 1))


def _ppo() -> tuple[float, Callable[[int], Any]]:
    from test_agents import ARM, EVAL_SEEDS, _RandomPolicy, episode_returns, trained_return

    from sim2real.agents import as_policy

    random = float(episode_returns(ARM, as_policy(_RandomPolicy(-0.05, 0.05, 3, seed=0)), EVAL_SEEDS).mean())
    return random, trained_return


def _sac() -> tuple[float, Callable[[int], Any]]:
    from test_sac_learns import random_return, sac_trained

    return random_return(), sac_trained


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=("ppo", "sac"), default="ppo", help="which CI test (default: %(default)s)")
    parser.add_argument("--seeds", default="0-7", help="inclusive range, e.g. 0-7 (default: %(default)s)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    seeds = _seeds(args.seeds)
    random, trained = _ppo() if args.algo == "ppo" else _sac()
    start = time.perf_counter()
    results = run_tasks(trained, seeds, backend="local", workers=args.workers, progress=True).results
    wall = time.perf_counter() - start
    values = [r[0] if isinstance(r, tuple) else r for r in results]
    gains = np.array(values) - random
    for seed, result, value, gain in zip(seeds, results, values, gains, strict=True):
        row = {"seed": seed, "trained": round(value, 2), "random": round(random, 2), "gain": round(float(gain), 2)}
        if isinstance(result, tuple):
            row["median_final_distance_m"] = round(result[1], 3)
        print(json.dumps(row))
    print(f"gain over random: mean {gains.mean():.1f}, sd {gains.std(ddof=1):.1f}, min {gains.min():.1f}, "
          f"max {gains.max():.1f}; runs with gain < 10: {int((gains < 10).sum())}/{len(gains)}; "
          f"{len(seeds)} seeds in {wall:.0f} s wall ({args.workers} workers)")  # fmt: skip


if __name__ == "__main__":
    main()
