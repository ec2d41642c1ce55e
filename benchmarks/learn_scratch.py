"""Learning from scratch (issue #14): a trained checkpoint against the task's scripted baseline, same episodes.

Evaluates the checkpoint's deterministic policy and ``baseline_for(task)`` on the nominal task over the same
``--episodes`` reset seeds (``1000 + i``, disjoint from training) and prints the mean return with a 95% interval
(Student t over episodes), the success rate where the task reports ``is_success``, and the learning curve from the
run's CSV log (``episode_return`` per batch, averaged in ``--bins`` windows).

Usage (train first with the exact command of the recipe, then evaluate):

    MUJOCO_GL=egl .venv/bin/sim2real train --task dmc/reacher-easy --algo sac \\
        --agent-config sim2real/agents/recipes/sac-dmc-reacher-easy.yaml --seed 0 --out reacher.pt --log-dir runs
    MUJOCO_GL=egl .venv/bin/python benchmarks/learn_scratch.py --task dmc/reacher-easy --checkpoint reacher.pt \\
        --log runs/<run id> --episodes 30
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np
from scipy import stats

import sim2real
from sim2real.agents import as_policy, baseline_for


def run_episodes(task: str, policy: object, episodes: int) -> tuple[np.ndarray, np.ndarray]:
    """(returns, successes) of ``policy`` over reset seeds 1000..1000+episodes-1 (successes NaN if not reported)."""
    returns, successes, _ = run_episodes_with_distance(task, policy, episodes)
    return returns, successes


def run_episodes_with_distance(
    task: str, policy: object, episodes: int, first_seed: int = 1000
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`run_episodes` plus each episode's final ``info["distance"]`` in metres (NaN if not reported); reset
    seeds ``first_seed .. first_seed + episodes - 1``."""
    env = sim2real.make(task)
    act = as_policy(policy)
    returns, successes, distances = [], [], []
    try:
        for i in range(episodes):
            obs, info = env.reset(seed=first_seed + i)
            total, done = 0.0, False
            while not done:
                obs, reward, terminated, truncated, info = env.step(act(obs))
                total += float(reward)
                done = terminated or truncated
            returns.append(total)
            successes.append(float(info["is_success"]) if "is_success" in info else math.nan)
            distances.append(float(info["distance"]) if "distance" in info else math.nan)
    finally:
        env.close()
    return np.asarray(returns), np.asarray(successes), np.asarray(distances)


def interval(values: np.ndarray) -> tuple[float, float, float]:
    """Mean and its 95% Student-t interval."""
    mean = float(values.mean())
    half = float(stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / math.sqrt(len(values)))
    return mean, mean - half, mean + half


def curve(log: Path, bins: int) -> list[tuple[int, float]]:
    """(last frame, mean episode return) of ``bins`` consecutive windows of the run's ``episode_return`` log."""
    rows = [(int(float(f)), float(r)) for f, r in csv.reader((log / "scalars" / "episode_return.csv").open())]
    out = []
    for chunk in np.array_split(np.arange(len(rows)), bins):
        if len(chunk):
            out.append((rows[chunk[-1]][0], float(np.mean([rows[i][1] for i in chunk]))))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--log", default=None, help="the run's CSV log folder (for the learning curve)")
    parser.add_argument("--bins", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=1000, help="reset seed of the first episode (the goal's: 1000)")
    args = parser.parse_args()
    if args.log:
        print("learning curve (frames: mean training-episode return in the window):")
        print("  " + ", ".join(f"{f}: {r:.1f}" for f, r in curve(Path(args.log), args.bins)))
    for name, policy in (("learned", args.checkpoint), ("scripted", baseline_for(args.task))):
        returns, success, distance = run_episodes_with_distance(args.task, policy, args.episodes, args.first_seed)
        mean, low, high = interval(returns)
        rate = "" if np.isnan(success).all() else f", success {int(np.nansum(success))}/{len(success)}"
        print(f"{name:<9} return {mean:8.2f} [{low:.2f}, {high:.2f}] (95% t, {args.episodes} episodes){rate}; "
              f"min {returns.min():.2f}; {int((returns < 100).sum())} below 100 (stalls)")  # fmt: skip
        print("  returns: " + " ".join(f"{r:.1f}" for r in returns))
        failed = distance[(success == 0) & np.isfinite(distance)]
        if len(failed):
            print("  final distance of failed episodes (m): " + " ".join(f"{d:.3f}" for d in failed))


if __name__ == "__main__":
    main()
