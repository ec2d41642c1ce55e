"""Coverage of the report's agreement intervals (issue 14): plain percentile bootstrap against the median-bias
corrected one that :mod:`sim2real.metrics` now uses when the plain interval misses its own point estimate.

Synthetic studies like the quick study: 4 policies whose true means are far apart (525, 680, 720, 815), episodes
with noise ``sigma`` in sim and real (real = sim means, so the truth of Pearson over the true means is known), a
few episodes per policy. For each dataset: is the point estimate inside the plain percentile interval, and does each
interval cover the true correlation of the true means? Both intervals come from the same replicates, side by side.

Usage:
    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_report_intervals.py --datasets 300 --resamples 500
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from sim2real.metrics import FewSamplesWarning
from sim2real.metrics.agreement import _correlation
from sim2real.metrics.bootstrap import _columns, _estimate, _interval


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=300)
    parser.add_argument("--resamples", type=int, default=500)
    parser.add_argument("--sigma", type=float, nargs="+", default=[60.0, 120.0])
    parser.add_argument("--episodes", type=int, nargs="+", default=[4, 32])
    args = parser.parse_args()
    means = np.array([525.0, 680.0, 720.0, 815.0])
    scale = np.array([1.0, 1.02, 0.98, 1.01])  # real differs a little from sim, so the true r is just below 1
    truth = float(_correlation(means[None, :], (means * scale)[None, :], "pearson")[0])
    print(f"true Pearson of the per-policy means: {truth:.4f}")
    print("episodes sigma  point-outside-plain  plain-coverage  corrected-coverage  plain-width  corrected-width")
    warnings.simplefilter("ignore", FewSamplesWarning)
    start = time.perf_counter()
    for n in args.episodes:
        for sigma in args.sigma:
            rng = np.random.default_rng(0)
            outside = plain_hits = fixed_hits = 0
            plain_width = fixed_width = 0.0
            for _ in range(args.datasets):
                sim = means + rng.normal(0.0, sigma, (n, 4))
                real = means * scale + rng.normal(0.0, sigma, (n, 4))
                s_point, s_boot = _columns(sim, "mean", rng, args.resamples)
                r_point, r_boot = _columns(real, "mean", rng, args.resamples)
                value = float(_correlation(s_point[None, :], r_point[None, :], "pearson")[0])
                boots = _correlation(s_boot, r_boot, "pearson")
                low, high = _interval(boots, 0.95)
                fixed = _estimate(value, boots, 0.95, 2 * sim.size, bounds=(-1.0, 1.0))
                outside += not low <= value <= high
                plain_hits += low <= truth <= high
                fixed_hits += fixed.low <= truth <= fixed.high
                plain_width += high - low
                fixed_width += fixed.high - fixed.low
            d = args.datasets
            print(
                f"{n:8d} {sigma:5.0f}  {outside / d:19.3f}  {plain_hits / d:14.3f}  {fixed_hits / d:18.3f}  "
                f"{plain_width / d:11.3f}  {fixed_width / d:15.3f}"
            )
    print(f"wall time {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
