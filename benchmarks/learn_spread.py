"""Spread of the PPO learning test over training seeds: how much one seed says (tests/test_agents.py).

Trains ``LEARN_CONFIG`` of tests/test_agents.py on ``sim2real/arm-reach`` from each seed and prints the mean return
over the test's evaluation episodes against the seeded random policy's, one JSON line per seed, then the summary
that the test's thresholds are set from.

    MUJOCO_GL=egl .venv/bin/python benchmarks/learn_spread.py --seeds 0-7 [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_agents import ARM, EVAL_SEEDS, _RandomPolicy, episode_returns, trained_return

from sim2real.agents import as_policy
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
    random = float(episode_returns(ARM, as_policy(_RandomPolicy(-0.05, 0.05, 3, seed=0)), EVAL_SEEDS).mean())
    trained = run_tasks(trained_return, seeds, backend="local", workers=args.workers, progress=True).results
    gains = np.array(trained) - random
    for seed, value, gain in zip(seeds, trained, gains, strict=True):
        print(json.dumps({"seed": seed, "trained": round(value, 2), "random": round(random, 2), "gain": round(float(gain), 2)}))
    print(f"gain over random: mean {gains.mean():.1f}, sd {gains.std(ddof=1):.1f}, min {gains.min():.1f}, "
          f"runs with gain < 10: {int((gains < 10).sum())}/{len(gains)}")


if __name__ == "__main__":
    main()
