"""Monte Carlo of ``sysid.fit`` with default settings on generated arms nobody tuned it on (issue #17).

Arms: :func:`sysid.synthetic.generate_arm` — 6 and 7 DoF, torque motors and position servos (kp, kv), gravity,
joint limits, friction loss. Per arm the true joint dampings are the generated ones scaled by factors in
0.8–1.3 (fixed per arm); every Monte Carlo run records a fresh 8 s log at 50 Hz with
:func:`sysid.synthetic.excitation_log` (gravity-compensated multisine torques under a soft PD around home, or
servo set-points around home; noisy true initial state; noise 1e-3 rad / 1e-2 rad/s) and fits
``sysid.fit(log, xml, ["dof_damping[*]"])`` from the generated (nominal) values, nothing else given.

Plus the manipulator case: ``dmc/manipulator-bring_ball``, the 4 arm dampings scaled by 0.8–1.3, a 3 s multisine
log from the nominal start (``qpos0``), noise 1e-3 / 1e-2 on every logged row (so the logged initial state is
noisy), fitted from the nominal values.

Reported per arm and parameter: coverage of the 95% intervals, SD of the estimates over the Cramér–Rao SD, bias
in SDs, seconds per fit. The CRLB is evaluated at the truth with the true noise and the fit's own shooting
segments (every segment's initial state a nuisance parameter): ``fit(..., initial=truth, max_iter=0, noise_std=
true, horizon=<the fit's>)``, averaged as an RMS over runs; ``SD/CRLB_whole`` uses whole episodes instead (only
the first state a nuisance): the bound of single shooting, which multiple shooting gives up on drifting arms. Goals: pooled coverage in [0.90, 0.98] and
SD/CRLB <= 1.2 on the arms; SD/CRLB <= 1.1 per parameter on the manipulator and <= 6 s per manipulator fit.

Next to every SD/CRLB the script prints its 95% interval from the chi-square law of a sample variance,
``(n-1) s^2 / sd^2 ~ chi2(n-1)``, with the CRLB taken as known (an RMS over the runs of a deterministic bound; it
varies by a few percent between runs, far less than the SD does). Chi-square rather than a bootstrap over fits:
with 10-40 fits a percentile bootstrap of an SD is too narrow (it cannot see the tail it did not sample), while
the chi-square interval is exact for normal estimates. Because it is not robust to heavy tails, the script also
prints the excess kurtosis of the errors and the largest |z| = |estimate - truth| / CRLB, so an SD driven by a
few outlier fits shows instead of hiding inside the interval, and ``SD(z_own)``: the SD of every run's error over
that run's own CRLB (runs whose auto horizon differs carry different information).

Usage:
    python benchmarks/bench_sysid_arms.py --fits 8          # 8 fits per arm and 8 manipulator fits
    python benchmarks/bench_sysid_arms.py --fits 2 --arms 1 # smoke test
    python benchmarks/bench_sysid_arms.py --fits 10 --arm 1 --no-manipulator  # only the 6-DoF servo arm
    python benchmarks/bench_sysid_arms.py --fits 30 --workers 2 --save /tmp/mc.npz  # 2 processes, keep every run
    python benchmarks/bench_sysid_arms.py --time-manipulator 0,4,5  # only time the manipulator fit on 3 logs
    python benchmarks/bench_sysid_arms.py --merge a.npz b.npz  # report runs saved by two --save runs together
"""

from __future__ import annotations

import argparse
import copy
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy import stats

from sysid import FitResult, ParameterSpace, fit, record_log
from sysid.logs import TrajectoryLog, channel_names
from sysid.synthetic import excitation_log, generate_arm

PARAMS = ["dof_damping[*]"]
ARMS = (  # (dof, seed, actuators, frictionloss)
    (7, 11, "motor", None),
    (6, 12, "position", None),
    (7, 13, "position", 0.2),
    (6, 14, "motor", 0.0),
)
SIGMA = {"qpos": 1e-3, "qvel": 1e-2}
MANIPULATOR_PARAMS = [f"dof_damping[arm_{j}]" for j in ("root", "shoulder", "elbow", "wrist")]


@dataclass(frozen=True)
class Run:
    """One Monte Carlo fit: estimates, interval, CRLB SDs (fit's segments, whole episodes), cost, verdicts."""

    estimates: np.ndarray  # (P,)
    lo: np.ndarray  # (P,)
    hi: np.ndarray  # (P,)
    crlb: np.ndarray  # (2, P)
    seconds: float
    cpu_seconds: float
    horizon: int
    ok: bool
    contact_rows: int
    reasons: tuple[str, ...] = ()  # why the fit is not ok (FitQuality.reasons)


@dataclass(frozen=True)
class Case:
    """One Monte Carlo case: its name, addresses, truth and the per-run results."""

    name: str
    addresses: tuple[str, ...]
    truth: np.ndarray
    estimates: np.ndarray  # (runs, P)
    inside: np.ndarray  # (runs, P) bool
    crlb: np.ndarray  # (runs, 2, P): with the fit's segments, with whole episodes
    seconds: np.ndarray  # (runs,) wall
    cpu_seconds: np.ndarray  # (runs,) CPU of the fitting process (all its rollout threads)
    horizons: tuple[int, ...]
    ok: tuple[bool, ...]
    contact_rows: tuple[int, ...]


def _known_noise(model: mujoco.MjModel) -> dict[str, float]:
    names = channel_names(model)
    return {n: SIGMA["qpos"] for n in names["qpos"]} | {n: SIGMA["qvel"] for n in names["qvel"]}


def _crlb(
    log: TrajectoryLog, truth_model: mujoco.MjModel, params: list[str], truth: np.ndarray, result: FitResult
) -> np.ndarray:
    """(2, P): CRLB SDs with the fit's segments, and with whole episodes (one initial state per episode)."""
    noise = _known_noise(truth_model)
    noise.update({k: v for k, v in result.noise_std.items() if k not in noise})  # sensors: as fitted
    out: list[np.ndarray] = []
    for horizon in (result.quality.horizon or None, None):
        if out and horizon is None and result.quality.horizon == 0:
            out.append(out[0])  # the fit used whole episodes: the two bounds are one
            continue
        at_truth = fit(
            log,
            truth_model,
            params,
            initial=truth.tolist(),
            max_iter=0,
            global_search=False,
            noise_std=noise,
            horizon=horizon,
            progress=False,
        )
        out.append(np.asarray(at_truth.crlb_sd))
    return np.array(out)


def _timed_fit(
    log: TrajectoryLog,
    model: mujoco.MjModel | str,
    params: list[str],
    truth_model: mujoco.MjModel,
    truth: np.ndarray,
) -> Run:
    wall, cpu = time.perf_counter(), time.process_time()
    result = fit(log, model, params, progress=False)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return Run(
        estimates=np.asarray(result.estimates),
        lo=np.asarray(result.ci95[:, 0]),
        hi=np.asarray(result.ci95[:, 1]),
        crlb=_crlb(log, truth_model, params, truth, result),
        seconds=wall,
        cpu_seconds=cpu,
        horizon=int(result.quality.horizon),
        ok=bool(result.ok),
        contact_rows=int(result.quality.contact_rows),
        reasons=tuple(result.quality.reasons),
    )


def arm_truth(index: int) -> tuple[str, mujoco.MjModel, np.ndarray, str]:
    """MJCF, truth model, true dampings and case name of ``ARMS[index]``."""
    dof, seed, actuators, frictionloss = ARMS[index]
    xml = generate_arm(dof=dof, seed=seed, actuators=actuators, frictionloss=frictionloss)  # type: ignore[arg-type]
    truth_model = mujoco.MjModel.from_xml_string(xml)
    space = ParameterSpace(truth_model, PARAMS)
    truth = space.nominal * np.random.default_rng(seed).uniform(0.8, 1.3, space.size)
    space.writer(truth_model)(truth)
    fr = f"fl={frictionloss:g}" if frictionloss is not None else "fl=random"
    return xml, truth_model, truth, f"arm{dof}-{actuators}-s{seed}-{fr}"


def arm_run(index: int, run: int) -> Run:
    """Monte Carlo run ``run`` of ``ARMS[index]``: a fresh 8 s log (seed ``1000 * arm seed + run``), the fit."""
    xml, truth_model, truth, _ = arm_truth(index)
    log = excitation_log(truth_model, duration=8.0, seed=1000 * ARMS[index][1] + run)
    return _timed_fit(log, xml, PARAMS, truth_model, truth)


def manipulator_model() -> mujoco.MjModel:
    import sim2real as s2r
    from sim2real.physics import find_physics

    handle = find_physics(s2r.make("dmc/manipulator-bring_ball"))
    assert handle is not None
    return copy.deepcopy(handle.model)


def manipulator_truth() -> tuple[mujoco.MjModel, mujoco.MjModel, np.ndarray]:
    """Nominal model, truth model and true dampings of the manipulator case."""
    nominal = manipulator_model()
    truth_model = copy.deepcopy(nominal)
    space = ParameterSpace(truth_model, MANIPULATOR_PARAMS)
    truth = space.nominal * np.array([0.8, 1.3, 1.15, 0.9])
    space.writer(truth_model)(truth)
    return nominal, truth_model, truth


def manipulator_log(truth_model: mujoco.MjModel, run: int) -> TrajectoryLog:
    """The 3 s multisine log of manipulator run ``run`` (seed ``500 + run``), noisy on every row."""
    n_sub, steps = 10, 300  # 0.01 s control step, 3 s
    rng = np.random.default_rng(500 + run)
    t = np.arange(steps) * n_sub * truth_model.opt.timestep
    ctrl = np.zeros((steps, truth_model.nu))
    for j in range(truth_model.nu):
        for f in rng.uniform(0.3, 3.0, 4):
            ctrl[:, j] += 0.25 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    ctrl = np.clip(ctrl, -1.0, 1.0)
    return record_log(truth_model, ctrl, n_substeps=n_sub, noise_std=SIGMA, rng=rng)


def manipulator_run(run: int) -> Run:
    """Monte Carlo run ``run`` of the manipulator case."""
    nominal, truth_model, truth = manipulator_truth()
    return _timed_fit(manipulator_log(truth_model, run), nominal, MANIPULATOR_PARAMS, truth_model, truth)


def time_manipulator(runs: list[int]) -> None:
    """Times the default manipulator fit alone on the logs of ``runs``: wall, CPU, physics steps rolled out.

    The step count (every row of every ``mujoco.rollout`` call the fit makes, times its physics steps) is the
    load-independent cost; wall and CPU seconds depend on what else runs on the box.
    """
    from sysid._problem import Problem

    steps = [0]
    original = Problem.rollout

    def counting(self: Problem, models: list, states: np.ndarray, controls: np.ndarray) -> tuple:
        steps[0] += states.shape[0] * self.L * self.n_sub
        return original(self, models, states, controls)

    Problem.rollout = counting  # type: ignore[method-assign]
    nominal, truth_model, _ = manipulator_truth()
    try:
        for run in runs:
            log = manipulator_log(truth_model, run)
            steps[0] = 0
            wall, cpu = time.perf_counter(), time.process_time()
            result = fit(log, nominal, MANIPULATOR_PARAMS, progress=False)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            print(
                f"manipulator run {run} (seed {500 + run}): wall {wall:.2f} s, CPU {cpu:.2f} s, physics steps "
                f"{steps[0]}, load {os.getloadavg()[0]:.1f}, estimates {result.estimates.tolist()}, "
                f"stderr {result.stderr.tolist()}",
                flush=True,
            )
    finally:
        Problem.rollout = original  # type: ignore[method-assign]


def _call(job: tuple[str, int, int]) -> Run:
    kind, index, run = job
    return manipulator_run(run) if kind == "manipulator" else arm_run(index, run)


def _progress(done: int, total: int, job: tuple[str, int, int], run: Run, started: float) -> None:
    kind, index, number = job
    what = "manipulator" if kind == "manipulator" else f"arm {index}"
    print(
        f"  [{done}/{total}] {what} run {number}: {run.seconds:.1f} s, ok {run.ok}, "
        f"{time.perf_counter() - started:.0f} s elapsed" + ("" if run.ok else f", reasons {list(run.reasons)}"),
        flush=True,
    )
    # Every run's numbers in the log too, so an interrupted Monte Carlo can still be analysed.
    fields = {"estimates": run.estimates, "lo": run.lo, "hi": run.hi, "crlb": run.crlb[0], "crlb_whole": run.crlb[1]}
    print(
        f"  RUN {kind} {index} {number} " + " ".join(f"{k}={v.tolist()!r}".replace(" ", "") for k, v in fields.items())
    )


def run_jobs(jobs: list[tuple[str, int, int]], workers: int) -> list[Run]:
    """Runs the jobs, results in job order, in ``workers`` processes (each fit keeps its rollout threads)."""
    started = time.perf_counter()
    if workers <= 1:
        out = []
        for k, job in enumerate(jobs):
            out.append(_call(job))
            _progress(k + 1, len(jobs), job, out[-1], started)
        return out
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(_call, job): k for k, job in enumerate(jobs)}
        results: dict[int, Run] = {}
        for future in as_completed(futures):
            k = futures[future]
            results[k] = future.result()
            _progress(len(results), len(jobs), jobs[k], results[k], started)
    return [results[k] for k in range(len(jobs))]


def _case(name: str, addresses: list[str], truth: np.ndarray, rows: list[Run]) -> Case:
    lo = np.array([r.lo for r in rows])
    hi = np.array([r.hi for r in rows])
    return Case(
        name=name,
        addresses=tuple(addresses),
        truth=truth,
        estimates=np.array([r.estimates for r in rows]),
        inside=(lo <= truth) & (truth <= hi),
        crlb=np.array([r.crlb for r in rows]),
        seconds=np.array([r.seconds for r in rows]),
        cpu_seconds=np.array([r.cpu_seconds for r in rows]),
        horizons=tuple(r.horizon for r in rows),
        ok=tuple(r.ok for r in rows),
        contact_rows=tuple(r.contact_rows for r in rows),
    )


def sd_ratio_interval(sd: np.ndarray, crlb: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """95% chi-square interval of SD/CRLB for an SD over ``n`` estimates (normal errors, CRLB known).

    Example:
        >>> lo, hi = sd_ratio_interval(np.array([1.0]), np.array([1.0]), 30)
        >>> round(float(lo[0]), 3), round(float(hi[0]), 3)
        (0.796, 1.344)
    """
    lo = sd * np.sqrt((n - 1) / stats.chi2.ppf(0.975, n - 1))
    hi = sd * np.sqrt((n - 1) / stats.chi2.ppf(0.025, n - 1))
    return lo / crlb, hi / crlb


def report(case: Case) -> dict[str, float]:
    err = case.estimates - case.truth
    n = len(err)
    sd = err.std(axis=0, ddof=1) if n > 1 else np.full(err.shape[1], np.nan)
    crlb = np.sqrt(np.mean(case.crlb[:, 0] ** 2, axis=0))
    whole = np.sqrt(np.mean(case.crlb[:, 1] ** 2, axis=0))
    ratio = sd / crlb
    r_lo, r_hi = sd_ratio_interval(sd, crlb, n) if n > 1 else (ratio, ratio)
    bias = err.mean(axis=0) / crlb
    z = err / crlb
    # Each run against its own bound: runs whose auto horizon differs carry different information, and an RMS
    # bound over runs makes one short-horizon run's large error look like inefficiency.
    z_own = err / case.crlb[:, 0]
    sd_own = z_own.std(axis=0, ddof=1) if n > 1 else np.full(err.shape[1], np.nan)
    kurt = stats.kurtosis(err, axis=0) if n > 3 else np.full(err.shape[1], np.nan)
    print(
        f"\n{case.name}: {n} fits, {np.median(case.seconds):.1f} s/fit wall, {np.median(case.cpu_seconds):.1f} "
        f"CPU-s/fit (medians), horizons {sorted(set(case.horizons))}, ok {sum(case.ok)}/{len(case.ok)}, "
        f"contact rows left out {sum(case.contact_rows)}"
    )
    print(
        f"  {'parameter':<28}{'truth':>9}{'coverage':>10}{'SD/CRLB':>9}{'95% interval':>16}{'bias/CRLB':>11}"
        f"{'max|z|':>8}{'kurt':>7}{'SD(z_own)':>10}{'SD/CRLB_whole':>15}"
    )
    for i, a in enumerate(case.addresses):
        interval = f"[{r_lo[i]:.2f}, {r_hi[i]:.2f}]"
        print(
            f"  {a:<28}{case.truth[i]:>9.4g}{case.inside[:, i].mean():>10.2f}{ratio[i]:>9.2f}{interval:>16}"
            f"{bias[i]:>+11.2f}{np.abs(z[:, i]).max():>8.1f}{kurt[i]:>+7.1f}{sd_own[i]:>10.2f}{sd[i] / whole[i]:>15.2f}",
            flush=True,
        )
    return {
        "coverage": float(case.inside.mean()),
        "max_ratio": float(np.nanmax(ratio)),
        "n": case.inside.size,
        "above": int(np.sum(r_lo > 1.2)),
        "undecided": int(np.sum((r_lo <= 1.2) & (r_hi > 1.2))),
    }


def load_cases(paths: list[str]) -> list[Case]:
    """The cases of several ``--save`` files, runs concatenated per case name in the order given (``--merge``).

    A case may be in some of the files only (a Monte Carlo continued with ``--first`` for one ``--arm``); its
    truth must be the same in every file that holds it, else the error names the files.
    """
    merged: dict[str, list[dict[str, np.ndarray]]] = {}
    for path in paths:
        with np.load(path) as z:
            names = [str(z[k]) for k in sorted(k for k in z.files if k.endswith("_name"))]
            for k in range(len(names)):
                merged.setdefault(str(z[f"{k}_name"]), []).append({f: z[f"{k}_{f}"] for f in _SAVED})
    cases = []
    for name, parts in merged.items():
        if any(not np.array_equal(p["truth"], parts[0]["truth"]) for p in parts):
            raise SystemExit(f"--merge: case {name!r} has a different truth in one of {paths}.")
        cat = {f: np.concatenate([p[f] for p in parts]) for f in _SAVED if f not in ("name", "addresses", "truth")}
        cases.append(
            Case(
                name=name,
                addresses=tuple(str(a) for a in parts[0]["addresses"]),
                truth=parts[0]["truth"],
                estimates=cat["estimates"],
                inside=cat["inside"],
                crlb=cat["crlb"],
                seconds=cat["seconds"],
                cpu_seconds=cat["cpu_seconds"],
                horizons=tuple(int(h) for h in cat["horizons"]),
                ok=tuple(bool(o) for o in cat["ok"]),
                contact_rows=tuple(int(c) for c in cat["contact_rows"]),
            )
        )
    return cases


_SAVED = (
    "name",
    "addresses",
    "truth",
    "estimates",
    "inside",
    "crlb",
    "seconds",
    "cpu_seconds",
    "horizons",
    "ok",
    "contact_rows",
)


def save_cases(path: str, cases: list[Case]) -> None:
    """Writes every case's per-run arrays to ``path`` (.npz, via a temporary file and a rename)."""
    arrays: dict[str, np.ndarray] = {}
    for k, c in enumerate(cases):
        arrays[f"{k}_name"] = np.array(c.name)
        arrays[f"{k}_addresses"] = np.array(c.addresses)
        for field in ("truth", "estimates", "inside", "crlb", "seconds", "cpu_seconds"):
            arrays[f"{k}_{field}"] = np.asarray(getattr(c, field))
        arrays[f"{k}_horizons"] = np.array(c.horizons)
        arrays[f"{k}_ok"] = np.array(c.ok)
        arrays[f"{k}_contact_rows"] = np.array(c.contact_rows)
    tmp = f"{path}.tmp.npz"
    np.savez(tmp, **arrays)  # type: ignore[arg-type]
    os.replace(tmp, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--fits", type=int, default=8, help="Monte Carlo fits per arm and for the manipulator")
    parser.add_argument("--first", type=int, default=0, help="index of the first run (shifts the log seeds)")
    parser.add_argument("--arms", type=int, default=len(ARMS), help="how many of the generated arms to run")
    parser.add_argument("--arm", type=int, default=None, help="run only this arm (index into ARMS)")
    parser.add_argument("--no-manipulator", action="store_true")
    parser.add_argument("--workers", type=int, default=1, help="processes running fits side by side")
    parser.add_argument("--save", default=None, help="write every run's estimates and intervals to this .npz")
    parser.add_argument(
        "--merge",
        nargs="+",
        default=None,
        metavar="NPZ",
        help="report the runs of these --save files together (a Monte Carlo continued with --first) and exit",
    )
    parser.add_argument(
        "--time-manipulator",
        default=None,
        metavar="RUNS",
        help="only time the manipulator fit on these comma-separated runs (e.g. 0,4,5) and exit",
    )
    args = parser.parse_args()
    if args.time_manipulator is not None:
        try:
            chosen_runs = [int(r) for r in args.time_manipulator.split(",")]
        except ValueError:
            parser.error(f"--time-manipulator must be comma-separated run numbers. Received {args.time_manipulator!r}.")
        time_manipulator(chosen_runs)
        return
    if args.merge is not None:
        merged = load_cases(args.merge)
        arms = [c for c in merged if not c.name.startswith("dmc/")]
        summaries = [report(c) for c in merged]
        inside = np.concatenate([c.inside.ravel() for c in arms]) if arms else np.zeros(0)
        arm_summaries = [s for c, s in zip(merged, summaries, strict=True) if c in arms]
        print(
            f"\nMERGED {len(args.merge)} files: arms={len(arms)} fits_per_arm={[len(c.ok) for c in arms]} "
            f"pooled_coverage={inside.mean() if inside.size else float('nan'):.3f} (n={inside.size}) "
            f"max_sd_over_crlb={max((s['max_ratio'] for s in arm_summaries), default=float('nan')):.2f} "
            f"params_sd_over_crlb_above_1.2_at_95%={sum(int(s['above']) for s in arm_summaries)} "
            f"undecided={sum(int(s['undecided']) for s in arm_summaries)} ok={sum(sum(c.ok) for c in merged)}/"
            f"{sum(len(c.ok) for c in merged)}"
        )
        return
    if args.fits < 1 or args.workers < 1:
        parser.error(f"--fits and --workers must be >= 1. Received {args.fits} and {args.workers}.")
    if args.arm is not None and not 0 <= args.arm < len(ARMS):
        parser.error(f"--arm must be in 0..{len(ARMS) - 1}. Received {args.arm}.")
    started = time.perf_counter()
    runs = range(args.first, args.first + args.fits)
    chosen = list(range(min(args.arms, len(ARMS)))) if args.arm is None else [args.arm]
    # Run-major order, so every arm has as many finished runs as the others when the Monte Carlo is cut short.
    order = [("arm", i, r) for r in runs for i in chosen]
    if not args.no_manipulator:
        order += [("manipulator", -1, r) for r in runs]
    done = dict(zip(order, run_jobs(order, args.workers), strict=True))
    jobs = [("arm", i, r) for i in chosen for r in runs] + [j for j in order if j[0] == "manipulator"]
    results = [done[j] for j in jobs]
    cases = []
    for k, i in enumerate(chosen):
        xml, _, truth, name = arm_truth(i)
        addresses = [str(a) for a in ParameterSpace(mujoco.MjModel.from_xml_string(xml), PARAMS).addresses]
        cases.append(_case(name, addresses, truth, results[k * args.fits : (k + 1) * args.fits]))
    if not args.no_manipulator:
        _, _, truth = manipulator_truth()
        cases.append(_case("dmc/manipulator-bring_ball", MANIPULATOR_PARAMS, truth, results[-args.fits :]))
    if args.save:
        save_cases(args.save, cases)
    inside, ratios, above, undecided = [], [], 0, 0
    for case in cases[: len(chosen)]:
        summary = report(case)
        inside.append(case.inside.ravel())
        ratios.append(summary["max_ratio"])
        above += int(summary["above"])
        undecided += int(summary["undecided"])
    pooled = float(np.concatenate(inside).mean()) if inside else float("nan")
    line = (
        f"RESULT arms={len(chosen)} fits_per_arm={args.fits} pooled_coverage={pooled:.3f} "
        f"(n={sum(i.size for i in inside)}) max_sd_over_crlb={max(ratios) if ratios else float('nan'):.2f} "
        f"params_sd_over_crlb_above_1.2_at_95%={above} undecided={undecided}"
    )
    if not args.no_manipulator:
        summary = report(cases[-1])
        line += (
            f" manipulator_coverage={summary['coverage']:.3f} manipulator_max_sd_over_crlb={summary['max_ratio']:.2f}"
            f" manipulator_s_per_fit={np.median(cases[-1].seconds):.2f}"
            f" manipulator_cpu_s_per_fit={np.median(cases[-1].cpu_seconds):.2f}"
        )
    print(f"\n{line} total_s={time.perf_counter() - started:.0f}")


if __name__ == "__main__":
    main()
