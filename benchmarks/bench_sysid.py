"""Monte Carlo benchmark of ``sysid.fit`` on the five-joint arm (issue #5).

Truth: ``sim2real.tasks.arm_reach`` with damping, armature, frictionloss and actuator gain of the shoulder and
elbow joints changed from their nominal values and a 2-control-step action latency. Logs: 3 episodes of 2 s at
50 Hz (10 physics steps per control step) under multisine position targets, Gaussian noise on qpos and qvel,
one noise seed per Monte Carlo run (same excitation). Every fit starts 3x off (alternately x3 and x1/3 per
parameter) with the latency searched over 0–4 steps.

Reported, all in one run:
  * per parameter: empirical SD over seeds / Cramér–Rao SD at the truth (goal <= 1.1);
  * coverage of the reported 95% intervals (goal in [0.92, 0.98]);
  * share of far starts that converge (every estimate within 5 CRLB SDs of the truth and the latency exact;
    goal >= 95%);
  * wall time per fit over ``mujoco.sysid`` on the same logs (goal <= 1.0), run in a separate venv
    (``--sysid-python``; ``mujoco[sysid]`` is not installed in the project venv);
  * speed-up over a naive Nelder–Mead loop on a Python ``mj_step`` simulation (goal >= 20x).

Usage:
    python benchmarks/bench_sysid.py            # 50 seeds
    python benchmarks/bench_sysid.py --quick    # 4 seeds, short baselines
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from typing import Any

import mujoco
import numpy as np
from scipy import optimize

from sim2real.tasks.arm_reach import ARM_REACH_XML
from sysid import ParameterSpace, TrajectoryLog, fit, record_log

JOINTS = ("shoulder_pitch", "elbow_pitch")
PARAMS = [
    f"{field}[{j}]" for field in ("dof_damping", "dof_armature", "dof_frictionloss", "actuator_gain") for j in JOINTS
]
TRUE = np.array([1.3, 0.6, 0.13, 0.075, 0.4, 0.25, 230.0, 130.0])
BOUNDS = {
    "dof_frictionloss[shoulder_pitch]": (0.01, 5.0),
    "dof_frictionloss[elbow_pitch]": (0.01, 5.0),
}
N_SUB, EPISODES, STEPS, LATENCY = 10, 3, 100, 2
SIGMA_POS, SIGMA_VEL = 2e-3, 4e-2


def truth_model() -> mujoco.MjModel:
    model = mujoco.MjModel.from_xml_string(ARM_REACH_XML)
    ParameterSpace(model, PARAMS, BOUNDS).writer(model)(TRUE)
    return model


def excitation(rng: np.random.Generator, model: mujoco.MjModel) -> np.ndarray:
    t = np.arange(STEPS) * N_SUB * model.opt.timestep
    ctrl = np.zeros((EPISODES, STEPS, model.nu))
    for e in range(EPISODES):
        for j in range(model.nu):
            for f in rng.uniform(0.3, 3.0, 4):
                ctrl[e, :, j] += 0.2 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return ctrl


def far_start() -> np.ndarray:
    return np.where(np.arange(len(TRUE)) % 2 == 0, 3.0, 1.0 / 3.0) * TRUE


def noisy(clean: TrajectoryLog, seed: int) -> TrajectoryLog:
    rng = np.random.default_rng(1000 + seed)
    return TrajectoryLog(
        time=clean.time,
        qpos=clean.qpos + rng.normal(0, SIGMA_POS, clean.qpos.shape),
        qvel=clean.qvel + rng.normal(0, SIGMA_VEL, clean.qvel.shape),
        ctrl=clean.ctrl,
        episode=clean.episode,
        meta=clean.meta,
    )


def crlb_at_truth(log: TrajectoryLog, model: mujoco.MjModel) -> np.ndarray:
    """Cramér–Rao SDs at the true parameters with the true noise (max_iter=0 evaluates, no fitting)."""
    names = {f"qpos[{n}]": SIGMA_POS for n in _joint_names(model)} | {
        f"qvel[{n}]": SIGMA_VEL for n in _joint_names(model)
    }
    result = fit(
        log,
        model,
        PARAMS,
        bounds=BOUNDS,
        initial=TRUE,
        latency={"action": LATENCY},
        noise_std=names,
        max_iter=0,
        global_search=False,
        validation=0.0,
    )
    return np.asarray(result.crlb_sd)


def _joint_names(model: mujoco.MjModel) -> list[str]:
    return [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(model.njnt)]


def run_fit(log: TrajectoryLog, seed: int) -> tuple[object, float]:
    start = time.perf_counter()
    result = fit(
        log,
        ARM_REACH_XML,
        PARAMS,
        bounds=BOUNDS,
        initial=far_start(),
        latency={"action": (0, 4)},
        validation=0.0,
        seed=seed,
        progress=False,
    )
    return result, time.perf_counter() - start


# ----------------------------------------------------------------------------- naive baseline
class _Reached(Exception):
    """The naive baseline reached the target accuracy."""


def naive_nelder_mead(
    log: TrajectoryLog, budget_s: float, reached: Any = None
) -> tuple[float, int, bool, np.ndarray]:
    """Nelder–Mead on the same weighted simulation error, simulated with a Python mj_step loop, true latency.

    Restarted from its best point (a fresh simplex) until ``reached(theta)`` holds — the accuracy our fit
    reaches — or the time budget runs out; the returned time is the time to reach it."""
    model = mujoco.MjModel.from_xml_string(ARM_REACH_XML)
    space = ParameterSpace(model, PARAMS, BOUNDS)
    write = space.writer(model)
    data = mujoco.MjData(model)
    bounds = log.episode_bounds()
    weights = np.r_[np.full(model.nq, 1 / SIGMA_POS), np.full(model.nv, 1 / SIGMA_VEL)]
    started = time.perf_counter()
    evals = 0

    def cost(z: np.ndarray) -> float:
        nonlocal evals
        evals += 1
        if time.perf_counter() - started > budget_s:
            raise TimeoutError
        theta = np.clip(np.exp(z), space.lower, space.upper)
        write(theta)
        total = 0.0
        for a, b in bounds:
            mujoco.mj_resetData(model, data)
            data.qpos[:] = log.qpos[a]
            data.qvel[:] = log.qvel[a]
            for t in range(a, b - 1):
                data.ctrl[:] = log.ctrl[max(a, t - LATENCY)]
                for _ in range(N_SUB):
                    mujoco.mj_step(model, data)
                err = np.r_[data.qpos - log.qpos[t + 1], data.qvel - log.qvel[t + 1]] * weights
                total += float(err @ err)
        return 0.5 * total

    z0 = np.log(far_start())
    best = [z0, cost(z0)]

    def tracked(z: np.ndarray) -> float:
        value = cost(z)
        if value < best[1]:
            best[0], best[1] = z.copy(), value
            if reached is not None and reached(np.exp(z)):
                raise _Reached
        return value

    finished = False
    try:
        while True:
            before = best[1]
            optimize.minimize(
                tracked, best[0], method="Nelder-Mead", options={"maxfev": 20000, "xatol": 1e-6, "fatol": 1e-9}
            )
            if reached is None or best[1] >= before * (1 - 1e-12):
                break  # no target, or a restart no longer improves: stuck
    except _Reached:
        finished = True
    except TimeoutError:
        finished = False
    return time.perf_counter() - started, evals, finished, np.exp(best[0])


# ----------------------------------------------------------------------------- mujoco.sysid baseline
_SYSID_SCRIPT = r"""
import json, sys, time
import numpy as np, mujoco
from mujoco import sysid
payload = np.load(sys.argv[1], allow_pickle=False)
meta = json.loads(str(payload["meta"]))
spec = mujoco.MjSpec.from_string(meta["xml"])
params = sysid.ParameterDict()
def setter(kind, name):
    if kind == "actuator_gain":
        def f(s, p):
            s.actuator(name).gainprm[0] = p.value[0]
            s.actuator(name).biasprm[1] = -p.value[0]
        return f
    if kind == "dof_damping":  # damping is a vector in MjSpec (polynomial damping); slot 0 is linear
        def g(s, p):
            s.joint(name).damping[0] = p.value[0]
        return g
    attr = {"dof_armature": "armature", "dof_frictionloss": "frictionloss"}[kind]
    return lambda s, p: setattr(s.joint(name), attr, float(p.value[0]))
for (address, lo, hi, start) in meta["params"]:
    kind, name = address[:-1].split("[")
    params.add(sysid.Parameter(address, nominal=start, min_value=lo, max_value=hi, modifier=setter(kind, name)))
    params[address].value[:] = start
model = spec.compile()
sequences = []
for e in range(meta["episodes"]):
    init = sysid.create_initial_state(model, payload["qpos0"][e], payload["qvel0"][e], np.zeros(model.na))
    ctrl_ts = sysid.TimeSeries(payload["ctrl_t"][e], payload["ctrl"][e])
    sens_ts = sysid.TimeSeries.from_names(payload["sens_t"][e], payload["sens"][e], model)
    sequences.append((f"ep{e}", init, ctrl_ts, sens_ts))
ms = sysid.ModelSequences("arm", spec, [s[0] for s in sequences], [s[1] for s in sequences],
                          [s[2] for s in sequences], [s[3] for s in sequences])
residual_fn = sysid.build_residual_fn(models_sequences=[ms])
start = time.perf_counter()
opt_params, result = sysid.optimize(initial_params=params, residual_fn=residual_fn, optimizer="mujoco", verbose=False)
elapsed = time.perf_counter() - start
print(json.dumps({"time": elapsed, "estimates": opt_params.as_vector().tolist()}))
"""


def mujoco_sysid(log: TrajectoryLog, python: str, start: np.ndarray) -> dict[str, object]:
    """Runs mujoco.sysid (Gauss–Newton over rollouts, its defaults) on the same log in a subprocess.

    It gets the true latency for free (commands pre-shifted) and fits the same 8 parameters from the same start.
    """
    if not os.path.exists(python):
        return {
            "error": f"{python} not found (create it: python -m venv /tmp/sysidvenv && "
            "/tmp/sysidvenv/bin/pip install 'mujoco[sysid]==3.17.0')"
        }
    xml = ARM_REACH_XML.replace(
        "</actuator>",
        "</actuator>\n  <sensor>"
        + "".join(
            f'<jointpos name="{j}_pos" joint="{j}"/>'
            for j in _joint_names(mujoco.MjModel.from_xml_string(ARM_REACH_XML))
        )
        + "".join(
            f'<jointvel name="{j}_vel" joint="{j}"/>'
            for j in _joint_names(mujoco.MjModel.from_xml_string(ARM_REACH_XML))
        )
        + "</sensor>",
    )
    dt = float(log.meta["timestep"])
    ctrl_t, ctrl, sens_t, sens, q0, v0 = [], [], [], [], [], []
    for a, b in log.episode_bounds():
        rows = np.clip(np.arange(a, b) - LATENCY, a, None)
        phys = np.repeat(log.ctrl[rows], N_SUB, axis=0)
        ctrl_t.append(np.arange(phys.shape[0]) * dt)
        ctrl.append(phys)
        sens_t.append((np.arange(b - a) * N_SUB) * dt)
        sens.append(np.concatenate([log.qpos[a:b], log.qvel[a:b]], axis=1))
        q0.append(log.qpos[a])
        v0.append(log.qvel[a])
    model = mujoco.MjModel.from_xml_string(ARM_REACH_XML)
    space = ParameterSpace(model, PARAMS, BOUNDS)
    meta = {
        "xml": xml,
        "episodes": len(ctrl),
        "params": [
            [a, float(lo), float(hi), float(s)]
            for a, lo, hi, s in zip(PARAMS, space.lower, space.upper, start, strict=True)
        ],
    }
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "payload.npz")
        np.savez(
            path,
            ctrl_t=np.array(ctrl_t),
            ctrl=np.array(ctrl),
            sens_t=np.array(sens_t),
            sens=np.array(sens),
            qpos0=np.array(q0),
            qvel0=np.array(v0),
            meta=np.array(json.dumps(meta)),
        )
        script = os.path.join(tmp, "run_sysid.py")
        with open(script, "w") as handle:
            handle.write(_SYSID_SCRIPT)
        proc = subprocess.run([python, script, path], capture_output=True, text=True, timeout=3600)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="4 seeds, 30 s naive budget, 1 mujoco.sysid run")
    parser.add_argument("--seeds", type=int, default=None)
    parser.add_argument("--sysid-python", default="/tmp/sysidvenv/bin/python")
    parser.add_argument("--naive-budget", type=float, default=None, help="seconds for the Nelder–Mead baseline")
    args = parser.parse_args()
    seeds = args.seeds or (4 if args.quick else 50)
    naive_budget = args.naive_budget or (30.0 if args.quick else 300.0)
    sysid_runs = 1 if args.quick else 3

    model = truth_model()
    ctrl = excitation(np.random.default_rng(0), model)
    clean = record_log(
        model,
        ctrl,
        n_substeps=N_SUB,
        action_latency=LATENCY,
        task="arm_reach",
        true_params=dict(zip(PARAMS, TRUE.tolist(), strict=True)),
    )
    crlb = crlb_at_truth(clean, model)
    print(f"arm_reach, {len(PARAMS)} parameters + action latency, {EPISODES}x{STEPS} control steps, {seeds} seeds")
    estimates, stderrs, lowers, uppers, times, latencies = [], [], [], [], [], []
    for seed in range(seeds):
        log = noisy(clean, seed)
        result, elapsed = run_fit(log, seed)
        estimates.append(result.estimates)
        stderrs.append(result.stderr)
        lowers.append(result.ci95[:, 0])
        uppers.append(result.ci95[:, 1])
        times.append(elapsed)
        latencies.append(result.latency_steps.get("action"))
        print(
            f"  seed {seed:3d}: {elapsed:6.2f} s, latency {latencies[-1]}, max |z| "
            f"{np.max(np.abs((result.estimates - TRUE) / crlb)):.2f}",
            flush=True,
        )
    est = np.array(estimates)
    lo, hi = np.array(lowers), np.array(uppers)
    emp_sd = est.std(axis=0, ddof=1)
    ratio = emp_sd / crlb
    covered = (lo <= TRUE) & (hi >= TRUE)
    converged = np.all(np.abs(est - TRUE) <= 5 * crlb, axis=1) & (np.array(latencies) == LATENCY)
    fit_time = float(np.median(times))
    print(f"\n{'parameter':<34}{'truth':>9}{'mean est':>11}{'emp SD':>10}{'CRLB SD':>10}{'SD/CRLB':>9}{'cover95':>9}")
    for i, name in enumerate(PARAMS):
        print(
            f"{name:<34}{TRUE[i]:>9.4g}{est[:, i].mean():>11.5g}{emp_sd[i]:>10.3g}{crlb[i]:>10.3g}"
            f"{ratio[i]:>9.3f}{covered[:, i].mean():>9.2f}"
        )
    print(
        f"coverage (all parameters pooled): {covered.mean():.3f}; latency exact in {np.mean(np.array(latencies) == LATENCY):.0%}"
    )
    print(f"far starts (3x off) converged: {converged.mean():.0%}; median fit time {fit_time:.2f} s")

    first = noisy(clean, 0)
    naive_time, evals, finished, naive_est = naive_nelder_mead(
        first, naive_budget, lambda theta: bool(np.all(np.abs(theta - TRUE) <= 5 * crlb))
    )
    naive_ok = bool(np.all(np.abs(naive_est - TRUE) <= 5 * crlb))
    speedup = naive_time / fit_time
    print(
        f"naive Nelder–Mead + Python mj_step: {naive_time:.1f} s, {evals} evaluations, "
        f"{'reached 5 CRLB SD of the truth' if finished else 'budget exhausted or stuck'}, within 5 CRLB SD: "
        f"{naive_ok} -> speed-up "
        f"{'>= ' if not finished else ''}{speedup:.1f}x"
    )

    sysid_times, sysid_err = [], None
    for seed in range(sysid_runs):
        out = mujoco_sysid(noisy(clean, seed), args.sysid_python, far_start())
        if "error" in out:
            sysid_err = str(out["error"])
            break
        sysid_times.append(float(out["time"]))
        est_ms = np.array(out["estimates"])
        print(
            f"  mujoco.sysid seed {seed}: {out['time']:.2f} s, max |error|/CRLB SD {np.max(np.abs(est_ms - TRUE) / crlb):.1f}"
        )
    if sysid_times:
        ours = float(np.median(times[:sysid_runs]))
        rel = ours / float(np.median(sysid_times))
        rel_text = f"{rel:.2f}"
        print(
            f"time per fit over mujoco.sysid: {rel_text} (ours {ours:.2f} s incl. latency search and global stage, "
            f"mujoco.sysid {np.median(sysid_times):.2f} s with the latency given)"
        )
    else:
        rel_text = f"n/a ({sysid_err})"
        print(f"mujoco.sysid unavailable: {sysid_err}")
    print(
        f"RESULT sd_over_crlb_max={ratio.max():.3f} sd_over_crlb_median={np.median(ratio):.3f} "
        f"coverage95={covered.mean():.3f} coverage95_min={covered.mean(axis=0).min():.3f} "
        f"far_start_converged={converged.mean():.3f} time_over_mujoco_sysid={rel_text} "
        f"speedup_over_naive={'>=' if not finished else ''}{speedup:.1f} fit_time_s={fit_time:.2f} seeds={seeds}"
    )


if __name__ == "__main__":
    sys.exit(main())
