"""How often `fit.ok` refuses a right model, and how often it catches a wrong one (issue 17).

Right model: the manipulator case of ``bench_sysid_arms.py`` (the fitted family contains the truth); every not-ok
fit prints its reasons. With ``--reference NPZ`` (a ``bench_sysid_arms.py --save`` of the same runs) the estimates
are compared bitwise: the verdict is computed after the fit and must not move them. Wrong models (``--wrong``): the
same logs fitted with a lower arm 30% heavier than the truth's, and the logs re-recorded with a 20 ms action latency
the fit does not model.

Usage:
    MUJOCO_GL=egl nice -n 10 .venv/bin/python -u benchmarks/bench_fit_verdict.py --first 0 --runs 60 \\
        [--reference mc.npz] [--wrong]
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_sysid_arms import MANIPULATOR_PARAMS, SIGMA, manipulator_log, manipulator_truth

from sysid import FitResult, fit, record_log


def _line(label: str, result: FitResult, seconds: float) -> str:
    q = result.quality
    return (
        f"{label}: ok {result.ok}, held-out/in-fit {q.validation_ratio:.3f}, held-out rows {result.trace_time.size}, "
        f"{seconds:.1f} s" + ("" if result.ok else f", reasons {list(q.reasons)}")
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--first", type=int, default=0, help="first manipulator run (log seed 500 + run)")
    parser.add_argument("--runs", type=int, default=10, help="how many runs")
    parser.add_argument("--reference", default=None, help="bench_sysid_arms.py --save npz of the same runs")
    parser.add_argument("--wrong", action="store_true", help="also fit the two wrong models on every log")
    args = parser.parse_args()
    if args.runs < 1 or args.first < 0:
        parser.error(f"--runs must be >= 1 and --first >= 0. Received {args.runs} and {args.first}.")
    reference = np.load(args.reference)["0_estimates"] if args.reference else None
    nominal, truth_model, _ = manipulator_truth()
    heavy = copy.deepcopy(nominal)
    arm = mujoco.mj_name2id(heavy, mujoco.mjtObj.mjOBJ_BODY, "lower_arm")
    heavy.body_mass[arm] *= 1.3
    heavy.body_inertia[arm] *= 1.3
    refused, same, caught = [], 0, {"heavy": 0, "latency": 0}
    started = time.perf_counter()
    runs = range(args.first, args.first + args.runs)
    for run in runs:
        log = manipulator_log(truth_model, run)
        t = time.perf_counter()
        right = fit(log, nominal, MANIPULATOR_PARAMS, progress=False)
        line = _line(f"run {run} right model", right, time.perf_counter() - t)
        if reference is not None:
            bitwise = bool(np.array_equal(right.estimates, reference[run]))
            same += bitwise
            line += f", estimates bitwise {bitwise}"
        print(line, flush=True)
        if not right.ok:
            refused.append(run)
        if args.wrong:
            late = record_log(
                truth_model,
                log.ctrl,
                n_substeps=10,
                action_latency=2,
                noise_std=SIGMA,
                rng=np.random.default_rng(500 + run),
            )
            for name, wrong_log, model in (("heavy", log, heavy), ("latency", late, nominal)):
                t = time.perf_counter()
                result = fit(wrong_log, model, MANIPULATOR_PARAMS, progress=False)
                caught[name] += not result.ok
                print(_line(f"run {run} wrong model ({name})", result, time.perf_counter() - t), flush=True)
    n = len(runs)
    summary = f"RESULT runs {runs.start}-{runs.stop - 1}: right model refused {len(refused)}/{n} {refused}"
    if reference is not None:
        summary += f"; estimates bitwise {same}/{n}"
    if args.wrong:
        summary += (
            f"; heavier lower arm caught {caught['heavy']}/{n}; unmodelled 20 ms latency caught {caught['latency']}/{n}"
        )
    print(f"{summary}; {time.perf_counter() - started:.0f} s", flush=True)


if __name__ == "__main__":
    main()
