"""Spread of the SAC learning test over training seeds (tests/test_sac_learns.py): how much one seed says.

Trains ``SAC_LEARN_CONFIG`` of tests/test_sac_learns.py on ``sim2real/arm-reach`` from each seed and prints the mean
return over the test's evaluation episodes against uniform random actions', and the median final distance, one JSON
line per seed, then the summary the test's thresholds are set from.

    MUJOCO_GL=egl .venv/bin/python benchmarks/learn_spread_sac.py --seeds 0-7 [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_sac_learns import random_return, sac_trained

from sim2real.parallel import run_tasks


def _seeds(text: str) -> list[int]:
    low, _, high = text.partition("-")
    return list(range(int(low), int(high or low) + 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-7", help="inclusive range, e.g. 0-7 (default: %(default)s)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    seeds = _seeds(args.seeds)
    random = random_return()
    start = time.perf_counter()
    results = run_tasks(sac_trained, seeds, backend="local", workers=args.workers, progress=True).results
    wall = time.perf_counter() - start
    gains = np.array([r for r, _ in results]) - random
    for seed, (value, dist), gain in zip(seeds, results, gains, strict=True):
        print(json.dumps({"seed": seed, "trained": round(value, 2), "random": round(random, 2),
                          "gain": round(float(gain), 2), "median_final_distance_m": round(dist, 3)}))  # fmt: skip
    print(f"gain over random: mean {gains.mean():.1f}, sd {gains.std(ddof=1):.1f}, min {gains.min():.1f}, "
          f"max {gains.max():.1f}; {len(seeds)} seeds in {wall:.0f} s wall ({args.workers} workers)")  # fmt: skip


if __name__ == "__main__":
    main()
