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

Usage:
    python benchmarks/bench_sysid_arms.py --fits 8          # 8 fits per arm and 8 manipulator fits
    python benchmarks/bench_sysid_arms.py --fits 2 --arms 1 # smoke test
    python benchmarks/bench_sysid_arms.py --fits 10 --arm 1 --no-manipulator  # only the 6-DoF servo arm
"""

from __future__ import annotations

import argparse
import copy
import time
from dataclasses import dataclass

import mujoco
import numpy as np

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
class Case:
    """One Monte Carlo case: its name, addresses, truth and the per-run results."""

    name: str
    addresses: tuple[str, ...]
    truth: np.ndarray
    estimates: np.ndarray  # (runs, P)
    inside: np.ndarray  # (runs, P) bool
    crlb: np.ndarray  # (runs, 2, P): with the fit's segments, with whole episodes
    seconds: np.ndarray  # (runs,)
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
    out = []
    for horizon in (result.quality.horizon or None, None):
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


def run_arm(dof: int, seed: int, actuators: str, frictionloss: float | None, fits: int) -> Case:
    xml = generate_arm(dof=dof, seed=seed, actuators=actuators, frictionloss=frictionloss)  # type: ignore[arg-type]
    truth_model = mujoco.MjModel.from_xml_string(xml)
    space = ParameterSpace(truth_model, PARAMS)
    truth = space.nominal * np.random.default_rng(seed).uniform(0.8, 1.3, space.size)
    space.writer(truth_model)(truth)
    rows = []
    for run in range(fits):
        log = excitation_log(truth_model, duration=8.0, seed=1000 * seed + run)
        started = time.perf_counter()
        result = fit(log, xml, PARAMS, progress=False)
        seconds = time.perf_counter() - started
        crlb = _crlb(log, truth_model, PARAMS, truth, result)
        rows.append((result, seconds, crlb))
    fr = f"fl={frictionloss:g}" if frictionloss is not None else "fl=random"
    return _case(f"arm{dof}-{actuators}-s{seed}-{fr}", truth, rows)


def _case(name: str, truth: np.ndarray, rows: list[tuple[FitResult, float, np.ndarray]]) -> Case:
    est = np.array([r.estimates for r, _, _ in rows])
    lo = np.array([r.ci95[:, 0] for r, _, _ in rows])
    hi = np.array([r.ci95[:, 1] for r, _, _ in rows])
    return Case(
        name=name,
        addresses=tuple(str(a) for a in rows[0][0].addresses),
        truth=truth,
        estimates=est,
        inside=(lo <= truth) & (truth <= hi),
        crlb=np.array([c for _, _, c in rows]),
        seconds=np.array([s for _, s, _ in rows]),
        horizons=tuple(r.quality.horizon for r, _, _ in rows),
        ok=tuple(r.ok for r, _, _ in rows),
        contact_rows=tuple(r.quality.contact_rows for r, _, _ in rows),
    )


def manipulator_model() -> mujoco.MjModel:
    import sim2real as s2r
    from sim2real.physics import find_physics

    handle = find_physics(s2r.make("dmc/manipulator-bring_ball"))
    assert handle is not None
    return copy.deepcopy(handle.model)


def run_manipulator(fits: int) -> Case:
    nominal = manipulator_model()
    truth_model = copy.deepcopy(nominal)
    space = ParameterSpace(truth_model, MANIPULATOR_PARAMS)
    truth = space.nominal * np.array([0.8, 1.3, 1.15, 0.9])
    space.writer(truth_model)(truth)
    n_sub, steps = 10, 300  # 0.01 s control step, 3 s
    rows = []
    for run in range(fits):
        rng = np.random.default_rng(500 + run)
        t = np.arange(steps) * n_sub * nominal.opt.timestep
        ctrl = np.zeros((steps, nominal.nu))
        for j in range(nominal.nu):
            for f in rng.uniform(0.3, 3.0, 4):
                ctrl[:, j] += 0.25 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
        ctrl = np.clip(ctrl, -1.0, 1.0)
        log = record_log(truth_model, ctrl, n_substeps=n_sub, noise_std=SIGMA, rng=rng)
        started = time.perf_counter()
        result = fit(log, nominal, MANIPULATOR_PARAMS, progress=False)
        seconds = time.perf_counter() - started
        crlb = _crlb(log, truth_model, MANIPULATOR_PARAMS, truth, result)
        rows.append((result, seconds, crlb))
    return _case("dmc/manipulator-bring_ball", truth, rows)


def report(case: Case) -> dict[str, float]:
    err = case.estimates - case.truth
    sd = err.std(axis=0, ddof=1) if len(err) > 1 else np.full(err.shape[1], np.nan)
    crlb = np.sqrt(np.mean(case.crlb[:, 0] ** 2, axis=0))
    whole = np.sqrt(np.mean(case.crlb[:, 1] ** 2, axis=0))
    ratio = sd / crlb
    bias = err.mean(axis=0) / crlb
    print(
        f"\n{case.name}: {len(err)} fits, {np.median(case.seconds):.1f} s/fit (median), horizons {case.horizons}, "
        f"ok {sum(case.ok)}/{len(case.ok)}, contact rows left out {case.contact_rows}"
    )
    print(f"  {'parameter':<32}{'truth':>9}{'coverage':>10}{'SD/CRLB':>9}{'bias/CRLB':>11}{'SD/CRLB_whole':>15}")
    for i, a in enumerate(case.addresses):
        print(
            f"  {a:<32}{case.truth[i]:>9.4g}{case.inside[:, i].mean():>10.2f}{ratio[i]:>9.2f}{bias[i]:>+11.2f}"
            f"{sd[i] / whole[i]:>15.2f}",
            flush=True,
        )
    return {"coverage": float(case.inside.mean()), "max_ratio": float(np.nanmax(ratio)), "n": case.inside.size}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--fits", type=int, default=8, help="Monte Carlo fits per arm and for the manipulator")
    parser.add_argument("--arms", type=int, default=len(ARMS), help="how many of the generated arms to run")
    parser.add_argument("--arm", type=int, default=None, help="run only this arm (index into ARMS)")
    parser.add_argument("--no-manipulator", action="store_true")
    args = parser.parse_args()
    started = time.perf_counter()
    inside, ratios = [], []
    chosen = ARMS[: args.arms] if args.arm is None else (ARMS[args.arm],)
    for dof, seed, actuators, fl in chosen:
        case = run_arm(dof, seed, actuators, fl, args.fits)
        summary = report(case)
        inside.append(case.inside.ravel())
        ratios.append(summary["max_ratio"])
    pooled = float(np.concatenate(inside).mean()) if inside else float("nan")
    line = (
        f"RESULT arms={len(chosen)} fits_per_arm={args.fits} pooled_coverage={pooled:.3f} "
        f"(n={sum(i.size for i in inside)}) max_sd_over_crlb={max(ratios) if ratios else float('nan'):.2f}"
    )
    if not args.no_manipulator:
        case = run_manipulator(args.fits)
        summary = report(case)
        line += (
            f" manipulator_coverage={summary['coverage']:.3f} manipulator_max_sd_over_crlb={summary['max_ratio']:.2f}"
            f" manipulator_s_per_fit={np.median(case.seconds):.2f}"
        )
    print(f"\n{line} total_s={time.perf_counter() - started:.0f}")


if __name__ == "__main__":
    main()
