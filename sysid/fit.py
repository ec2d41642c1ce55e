"""`fit`: identify model parameters, latencies and sensor noise from a trajectory log.

The estimator minimises the simulation error ``Σ_c Σ_t ((ŷ_c(t; θ) - y_c(t)) / σ_c)²`` where ŷ comes from
open-loop rollouts of the model under the logged commands (``mujoco.rollout``, batched over parameter sets
and shooting segments, multi-threaded):

1. **Weights.** Every channel (``qpos[j]``, ``qvel[j]``, each sensor component) gets its own noise level σ_c,
   first from a model-free second-difference estimate, then re-estimated from the residuals and the fit
   repeated; weighting by 1/σ_c is what lets the estimate reach the Cramér–Rao bound.
2. **Global stage.** Scrambled-Sobol starts inside the bounds (log-spaced for positive ranges) are scored on a
   short-horizon multiple-shooting version of the problem, over every candidate latency, in batched rollouts;
   the best few are polished there by Levenberg–Marquardt. Short horizons keep the cost landscape close to
   convex, so starts far from the truth still reach the right basin.
3. **Local stage.** Levenberg–Marquardt (box-projected, Marquardt scaling) on the requested shooting horizon.
   With ``anchor="fit"`` each segment's initial state is a nuisance parameter, so noisy logged states do not
   bias the fit; with ``"logged"`` segments re-anchor to the logged state every ``horizon`` steps.
4. **Latency.** Integer action/observation delays are searched on the grid, then the action delay is refined
   to physics-substep resolution (when a control step spans several physics steps) and re-fitted.
5. **Uncertainty.** Standard errors, Cramér–Rao SDs and identifiability from the weighted Jacobian with the
   nuisance initial states profiled out; held-out validation gives fit percent and a residual whiteness test.

Example:
    >>> import mujoco, numpy as np
    >>> from sysid import fit, record_log
    >>> xml = '''<mujoco><option timestep="0.005"/><worldbody><body>
    ...   <joint name="hinge" axis="0 1 0" damping="0.3"/><geom type="capsule" size=".05" fromto="0 0 0 0 0 -.3"/>
    ... </body></worldbody><actuator><motor name="m" joint="hinge"/></actuator></mujoco>'''
    >>> truth = mujoco.MjModel.from_xml_string(xml)
    >>> ctrl = np.sin(np.linspace(0, 12, 200))[:, None] * 0.05
    >>> log = record_log(truth, ctrl, n_substeps=2)
    >>> guess = mujoco.MjModel.from_xml_string(xml.replace('damping="0.3"', 'damping="0.9"'))
    >>> result = fit(log, guess, params=["dof_damping[hinge]"], bounds={"dof_damping[hinge]": (0.01, 5)})
    >>> round(float(result.estimates[0]), 6)
    0.3
"""

from __future__ import annotations

import math
import os
import sys
import time as _time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import mujoco
import numpy as np
from scipy.stats import qmc

from noise_models.timing import convert_time
from sysid._heldout import Setting, held_out
from sysid._noise import difference_sigma, residual_sigma
from sysid._omitted import omitted_scores
from sysid._problem import Problem, make_segments
from sysid._solver import COST_ATOL, Progress, State, fd_steps, lm
from sysid._statistics import estimate_statistics
from sysid._whiteness import rejudge_low
from sysid.events import contact_rows, moved_trees, sensor_trees, split_ranges, state_trees
from sysid.logs import LogError, TrajectoryLog, channel_names, load_log, validate_log
from sysid.params import ModelPool, ParameterSpace
from sysid.profile import ProfileCheck, flat_parameters, profile_intervals
from sysid.quality import assess, pooled_ljung_box
from sysid.result import FitResult
from sysid.shooting import divergence_curve, divergence_horizon

__all__ = ["DEFAULT_LATENCY_RANGE", "fit"]

#: Delays (control steps) searched when ``latency=True``.
DEFAULT_LATENCY_RANGE: tuple[int, int] = (0, 5)
_SIGNALS = ("qpos", "qvel", "sensordata")
_REWEIGHT_CHANGE = 0.25  # log change of a channel weight below which the re-weighted problem is not re-solved
_MAX_NUISANCE = 1200  # initial-state unknowns above which anchor="auto" re-anchors to logged states instead


def _load_model(model: mujoco.MjModel | str | os.PathLike[str]) -> mujoco.MjModel:
    if isinstance(model, mujoco.MjModel):
        return model
    if isinstance(model, os.PathLike) or (isinstance(model, str) and "<mujoco" not in model):
        path = Path(model)
        if not path.is_file():
            raise FileNotFoundError(
                f"`model` must be an MjModel, MJCF text or an MJCF file path. Received {str(model)!r}."
            )
        return mujoco.MjModel.from_xml_path(str(path))
    if isinstance(model, str):
        return mujoco.MjModel.from_xml_string(model)
    raise TypeError(f"`model` must be an MjModel, MJCF text or an MJCF file path. Received {type(model).__name__}.")


def _latency_ranges(latency: Any, has_sensors: bool) -> dict[str, list[int]]:
    ranges = {"action": [0], "obs": [0]}
    if latency is None or latency is False:
        return ranges
    if latency is True or (isinstance(latency, (int, np.integer)) and not isinstance(latency, bool) and latency >= 1):
        lo, hi = DEFAULT_LATENCY_RANGE if latency is True else (0, int(latency))
        ranges["action"] = list(range(lo, hi + 1))
        if has_sensors:
            ranges["obs"] = list(range(lo, hi + 1))
        return ranges
    if not isinstance(latency, Mapping) or not set(latency) <= {"action", "obs"}:
        raise ValueError(
            "`latency` must be True, False/None, an int N >= 1 (True searching 0..N control steps), or a mapping "
            "with keys 'action' and/or 'obs' to an int (fixed "
            f"delay) or an inclusive (low, high) range of control steps. Received {latency!r}."
        )
    for key, value in latency.items():
        if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 0:
            ranges[key] = [int(value)]
        elif (
            isinstance(value, Sequence)
            and len(value) == 2
            and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in value)
            and 0 <= value[0] <= value[1]
        ):
            ranges[key] = list(range(int(value[0]), int(value[1]) + 1))
        else:
            raise ValueError(
                f"`latency['{key}']` must be an int >= 0 or an inclusive range (low, high) of ints with "
                f"0 <= low <= high. Received {value!r}."
            )
    if ranges["obs"] != [0] and not has_sensors:
        raise ValueError(
            "`latency['obs']` delays sensor readings relative to the logged state, so it needs `sensordata` in "
            f"the log and 'sensordata' in `signals`. Received {latency['obs']!r} without them."
        )
    return ranges


def _jitter_steps(log: TrajectoryLog) -> float:
    """How far (in control steps) a CSV log's samples were from the control grid they were interpolated onto."""
    csv = log.meta.get("csv")
    if not isinstance(csv, Mapping) or not csv.get("resampled"):
        return 0.0
    return float(csv.get("max_jitter_s", 0.0)) / log.control_timestep


def _split(
    log: TrajectoryLog, validation: float
) -> tuple[list[tuple[int, int, int, int]], list[tuple[int, int, int, int]]]:
    episodes = log.episode_bounds()
    if validation <= 0:
        return [(a, b, a, b) for a, b in episodes], []
    if len(episodes) >= 2:
        held = min(len(episodes) - 1, max(1, round(len(episodes) * validation)))
        fit_part, val_part = episodes[:-held], episodes[-held:]
        return [(a, b, a, b) for a, b in fit_part], [(a, b, a, b) for a, b in val_part]
    a, b = episodes[0]
    cut = a + round((b - a) * (1 - validation))
    if cut - a < 4 or b - cut < 4:
        return [(a, b, a, b)], []
    return [(a, cut, a, b)], [(cut, b, a, b)]


def _starts(space: ParameterSpace, theta0: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    if count <= 0:
        return theta0[None]
    lo, hi = space.lower, space.upper
    sampler = qmc.Sobol(d=space.size, scramble=True, seed=rng)
    u = sampler.random(1 << max(1, math.ceil(math.log2(count))))[:count]
    log_scale = (lo > 0) & (hi / np.where(lo > 0, lo, 1.0) >= 20.0)
    lin = lo + u * (hi - lo)
    geo = np.exp(
        np.log(np.where(log_scale, lo, 1.0)) + u * np.log(np.where(log_scale, hi / np.where(lo > 0, lo, 1.0), 1.0))
    )
    return np.vstack([theta0, np.where(log_scale, geo, lin)])


def fit(
    log: TrajectoryLog | str | os.PathLike[str],
    model: mujoco.MjModel | str | os.PathLike[str],
    params: Sequence[str],
    *,
    bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None = None,
    initial: Mapping[str, float] | Sequence[float] | None = None,
    latency: bool | int | Mapping[str, int | tuple[int, int]] | None = None,
    substep_latency: bool = True,
    signals: Sequence[str] | None = None,
    horizon: int | Literal["auto"] | None = "auto",
    contacts: Literal["cut", "keep"] = "cut",
    profile: bool = True,
    anchor: Literal["auto", "fit", "logged"] = "auto",
    noise_std: Mapping[str, float] | None = None,
    validation: float = 0.2,
    global_search: bool = True,
    n_starts: int = 32,
    max_iter: int = 50,
    fd_step: float = 1e-6,
    seed: int | np.random.Generator = 0,
    nthread: int | None = None,
    progress: bool | None = None,
) -> FitResult:
    """Fits ``params`` (and latencies) of ``model`` to ``log``.

    Args:
        log: a :class:`~sysid.logs.TrajectoryLog` or a path to a ``.npz`` log.
        model: the model to calibrate (``MjModel``, MJCF text or file path); its current values are the default
            starting point. It is never modified.
        params: parameter addresses, wildcards allowed (``["dof_damping[*]", "actuator_gain[elbow]"]``).
        bounds: ``{address or pattern: (low, high)}`` or one pair per ``params`` entry; default
            ``[nominal/10, nominal*10]``.
        initial: starting values ``{address: value}`` or (P,) (default: the model's values).
        latency: None/False (no delays), True (action delay 0–5 control steps, and sensor delay 0–5 when
            sensors are fitted), an int ``N`` (the same, searching 0–N), or ``{"action": k or (lo, hi), "obs": k or
            (lo, hi)}``. A delay estimated at the top of its searched range gets a warning: the true one may be
            longer.
        substep_latency: refine the action delay to physics-step resolution when a control step has several.
        signals: measured signals in the residual, from ``"qpos"``, ``"qvel"``, ``"sensordata"`` (default all
            present in the log).
        horizon: shooting-segment length in control steps; ``"auto"`` (default) chooses it from the data: the
            number of steps the model (after the global stage) stays within a few noise levels of the log when
            simulated open loop from logged states (a few times the response to the logged state's own noise
            when that is larger, as on stiff servos; :func:`sysid.shooting.divergence_horizon`), whole episodes
            when it never drifts away; None: whole episodes.
        contacts: ``"cut"`` (default) leaves out the rows where a contact touches a body the parameters move
            (a hand hitting the floor or an object; :mod:`sysid.events`), so no shooting segment crosses a
            contact event; contacts elsewhere, or when a parameter acts only through contacts, are kept.
            ``"keep"`` fits every row.
        profile: profile the likelihood of every parameter whose curvature is flat (standard error above 25%
            of the estimate, or an interval past a bound): :attr:`FitQuality.profiles` holds its 95% interval
            with every other parameter re-fitted, and a warning names a side the data do not bound
            (:mod:`sysid.profile`).
        anchor: ``"fit"`` estimates each segment's initial state, ``"logged"`` starts from the logged state,
            ``"auto"`` fits them when there are at most 1200 such unknowns.
        noise_std: known noise sigma per channel name (others are estimated).
        validation: share of the log held out for validation (last episodes, or the tail of a single one).
        global_search: run the multi-start global stage before the local refinement.
        n_starts: Sobol starts of the global stage.
        max_iter: Levenberg–Marquardt iterations of the final stage (0: evaluate statistics at the start).
        fd_step: relative finite-difference step of the Jacobian.
        seed: seed or Generator for the global stage's starts.
        nthread: rollout threads (default ``os.cpu_count()``).
        progress: show a tqdm progress bar (default: when stderr is a terminal).

    Returns:
        A :class:`~sysid.result.FitResult`.

    Raises:
        LogError: the log is malformed or does not match ``model``.
        ValueError: a bad argument (the message names it, says what is allowed and what was received).
    """
    started = _time.perf_counter()
    model = _load_model(model)
    if not isinstance(log, TrajectoryLog):
        log = load_log(log, model=model)
    else:
        validate_log(log, model)
    space = ParameterSpace(model, params, bounds)
    theta0 = space.values_from(initial, "initial")
    outside = np.flatnonzero((theta0 < space.lower) | (theta0 > space.upper))
    if outside.size:
        i = int(outside[0])
        raise ValueError(
            f"`initial` value of {space.addresses[i]!r} must lie within its bounds "
            f"[{float(space.lower[i])!r}, {float(space.upper[i])!r}]. Received {float(theta0[i])!r}."
        )
    if signals is None:
        signals = tuple(s for s in _SIGNALS if s != "sensordata" or (log.sensordata is not None and model.nsensordata))
    else:
        bad = [s for s in signals if s not in _SIGNALS]
        if isinstance(signals, str) or bad or not signals:
            raise ValueError(f"`signals` must be a non-empty list from {list(_SIGNALS)}. Received {signals!r}.")
        if "sensordata" in signals and log.sensordata is None:
            raise ValueError(
                "`signals` includes 'sensordata' but the log has no `sensordata`. Received that combination."
            )
        signals = tuple(signals)
    for name, value, ok in (
        ("validation", validation, isinstance(validation, (int, float)) and 0 <= validation < 1),
        (
            "horizon",
            horizon,
            horizon is None
            or horizon == "auto"
            or (isinstance(horizon, int) and not isinstance(horizon, bool) and horizon >= 1),
        ),
        ("anchor", anchor, anchor in ("auto", "fit", "logged")),
        ("contacts", contacts, contacts in ("cut", "keep")),
        ("n_starts", n_starts, isinstance(n_starts, int) and n_starts >= 0),
        ("max_iter", max_iter, isinstance(max_iter, int) and max_iter >= 0),
        ("fd_step", fd_step, isinstance(fd_step, float) and 0 < fd_step < 0.1),
    ):
        if not ok:
            allowed = {
                "validation": "a number in [0, 1)",
                "horizon": "'auto', None or an int >= 1",
                "anchor": "'auto', 'fit' or 'logged'",
                "contacts": "'cut' or 'keep'",
                "n_starts": "an int >= 0",
                "max_iter": "an int >= 0",
                "fd_step": "a float in (0, 0.1)",
            }[name]
            raise ValueError(f"`{name}` must be {allowed}. Received {value!r}.")
    has_sensors = "sensordata" in signals
    ranges = _latency_ranges(latency, has_sensors)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    show = sys.stderr.isatty() if progress is None else bool(progress)
    bar = Progress(show)
    n_sub = log.n_substeps
    obs_margin = max(ranges["obs"])
    fit_ranges, val_ranges = _split(log, float(validation))
    # The commands in effect before an episode's first logged one are unknown (a real actuator holds whatever it
    # had; sim2real's latency wrapper holds the reset command), so no row is predicted from them: an episode's
    # first segment starts after the longest candidate action latency.
    lead = max(ranges["action"])
    fit_ranges = [
        (first + lead if first == start else first, stop, start, end) for first, stop, start, end in fit_ranges
    ]
    val_ranges = [
        (first + lead if first == start else first, stop, start, end) for first, stop, start, end in val_ranges
    ]
    if not fit_ranges:
        raise LogError("the log has no rows left to fit after the validation split. Received too short a log.")
    pool = ModelPool(model, space)
    # State entries of bodies the parameters do not move (a ball beside an arm) are neither measured nor fitted:
    # with the rows where they touch what moves cut out below, their residuals are independent of the
    # parameters, and their open-loop prediction (a ball bouncing on the floor) would only shorten the segments
    # and add nuisance initial states. A sensor on another body (or the world, which may see any body) keeps them
    # all, and so does contacts="keep" (a kept contact couples the bodies).
    trees = moved_trees(log, model, space, pool, theta0)
    state_mask: np.ndarray | None = None
    on_moved = "sensordata" not in signals or all(t is not None and t in (trees or ()) for t in sensor_trees(model))
    if trees is not None and on_moved and contacts == "cut":
        state_mask = np.isin(state_trees(model), sorted(trees))
        if state_mask.all() or not state_mask.any():
            state_mask = None
    contact_count = 0
    flagged = np.zeros(log.qpos.shape[0], dtype=bool)
    cut_trees: set[int] | None = None  # what the held-out check cuts contacts on (None: it keeps them, as the fit)
    if contacts == "cut":
        flagged = contact_rows(log, model, space, pool, theta0)
        cut_fit = split_ranges(fit_ranges, flagged)
        if cut_fit != fit_ranges:
            fit_ranges = cut_fit
            contact_count = int(flagged.sum())
        if trees is not None and (cut_fit != fit_ranges or not any(flagged[a:b].any() for a, b, _, _ in fit_ranges)):
            cut_trees = trees
    nx = model.nq + model.nv
    auto_horizon = horizon == "auto"
    fixed_horizon: int | None = None if isinstance(horizon, str) else horizon

    def build(h: int | None) -> tuple[Problem, bool]:
        fit_x0 = make_segments(fit_ranges, h, True).count * nx <= _MAX_NUISANCE if anchor == "auto" else anchor == "fit"
        seg = make_segments(fit_ranges, h, fit_x0)
        if seg.count == 0:
            raise LogError(
                "`log` must have at least 2 rows per episode to fit. Received episodes too short to simulate."
            )
        return Problem(log, model, space, seg, signals, fit_x0, obs_margin, nthread, pool, state_mask), fit_x0

    final, fitted = build(fixed_horizon)
    sigma = difference_sigma(final)
    known = dict(noise_std or {})
    names = channel_names(model)
    every_channel = [n for signal in signals for n in names[signal]]
    unknown_names = sorted(set(known) - set(every_channel))
    if unknown_names:
        raise ValueError(f"`noise_std` keys must be channel names {every_channel}. Received unknown {unknown_names}.")
    # Degrees of freedom behind each level: NaN for the model-free start (no chi-square behind it), inf for a given one.
    noise_dof = np.full(len(final.channels), math.nan)
    for c, name in enumerate(final.channels):
        if name in known:
            sigma[c] = float(known[name])
            noise_dof[c] = math.inf
    final.weights = 1.0 / sigma
    lower, upper = space.lower, space.upper

    # ---- global stage: short-horizon multiple shooting, every candidate latency, Sobol starts
    delays = [k * n_sub for k in ranges["action"]]
    combos = [(d, o) for d in delays for o in ranges["obs"]]
    st = State(theta0.copy(), final.anchors(), delays[0], ranges["obs"][0])
    need_global = global_search or len(combos) > 1
    if need_global and max_iter > 0:
        short = max(5, 2 * max(ranges["action"]) + 5, obs_margin + 5)
        g_horizon = short if fixed_horizon is None else min(fixed_horizon, short)
        seg_g = make_segments(fit_ranges, g_horizon, False)
        gprob = Problem(log, model, space, seg_g, signals, False, obs_margin, nthread, pool, state_mask)
        gprob.weights = final.weights
        starts = _starts(space, theta0, n_starts if global_search else 0, rng)
        # Few starts per batch: every start needs its own model copy (~35 ms each), the rollout threads stay busy.
        chunk = max(1, min(8, 4096 // max(1, seg_g.count)))
        scored: list[tuple[float, int, int, np.ndarray]] = []
        for d, o in combos:
            costs = np.concatenate(
                [
                    0.5 * np.sum(gprob.residuals(starts[i : i + chunk], d, o) ** 2, axis=1)
                    for i in range(0, len(starts), chunk)
                ]
            )
            costs[~np.isfinite(costs)] = np.inf
            order = np.argsort(costs)
            for i in order[: 2 if global_search else 1]:
                scored.append((float(costs[i]), d, o, starts[i]))
            bar.step("global", float(costs[order[0]]))
        scored.sort(key=lambda t: t[0])
        best: State | None = None
        for _, d, o, theta in scored[: 2 if global_search else 1]:
            cand = lm(
                gprob,
                State(theta.copy(), gprob.anchors(), d, o),
                lower,
                upper,
                fit_x0=False,
                max_iter=15,
                fd_step=fd_step,
                progress=bar,
                stage="global",
                ftol=1e-6,
                xtol=1e-6,
                # Only a start for the local stage, on another (short-horizon) problem: a step that lowers its ½χ²
                # by under 1 ends it without a Jacobian to confirm (the local stage converges on its own).
                atol=1.0,
            )
            if best is None or cand.cost < best.cost:
                best = cand
        assert best is not None
        st = State(best.theta, final.anchors(), best.delay, best.obs)
    if auto_horizon:
        curve = divergence_curve(
            log,
            model,
            space,
            fit_ranges,
            signals,
            final.weights,
            st.theta,
            st.delay,
            st.obs,
            nthread,
            pool,
            state_mask=state_mask,
        )
        fixed_horizon = divergence_horizon(curve)
        if fixed_horizon is not None:
            final, fitted = build(fixed_horizon)
            final.weights = 1.0 / sigma
            st = State(st.theta, final.anchors(), st.delay, st.obs)
    seg_final = final.seg

    # ---- local stage with noise re-estimation, then latency refinement
    unknowns = space.size + (seg_final.count * final.nxa if fitted else 0)
    lm_kwargs: dict[str, Any] = {"fit_x0": fitted, "fd_step": fd_step, "progress": bar}
    if max_iter > 0:
        # The noise levels are re-estimated from the residuals below, so this first solve only needs to get close.
        loose = not all(name in known for name in final.channels)
        st = lm(
            final, st, lower, upper, max_iter=max_iter, stage="local", atol=1.0 if loose else COST_ATOL, **lm_kwargs
        )

        def reweigh(st: State, loose: bool) -> State:
            """Noise levels re-estimated from the residuals and the problem re-solved with them (twice at most)."""
            for _ in range(2):
                if all(name in known for name in final.channels):
                    break
                new_sigma, new_dof = residual_sigma(final, st.theta, st.delay, st.obs, st.x0, unknowns)
                for c, name in enumerate(final.channels):
                    if name not in known:
                        sigma[c], noise_dof[c] = new_sigma[c], new_dof[c]
                change = float(np.max(np.abs(np.log(final.weights * sigma))))
                old_weights, final.weights = final.weights, 1.0 / sigma
                # Residuals and Jacobians scale per channel with the weights: rescaled, not rolled out again (a
                # whole Jacobian is ~10% of a manipulator fit). Equal to recomputing up to rounding (~1e-16 relative).
                factor = (final.weights / old_weights)[final.channel_of_residual()]
                if st.r is not None and st.jac is not None:
                    st.r, st.jac = st.r * factor, st.jac * factor[:, None]
                if st.last_r is not None and st.prior_jac is not None:
                    st.last_r, st.prior_jac = st.last_r * factor, st.prior_jac * factor[:, None]
                if change < _REWEIGHT_CHANGE:
                    # Weights a little off cost a sliver of efficiency, not consistency (the sandwich covariance
                    # below is computed with the new weights), so the problem is only polished, not solved again.
                    if loose:
                        st = lm(final, st, lower, upper, max_iter=max_iter, stage="polish", **lm_kwargs)
                    break
                st = lm(final, st, lower, upper, max_iter=max_iter, stage="reweight", **lm_kwargs)
                loose = False
            return st

        st = reweigh(st, loose)
        # Latency refinement, repeated while it moves. A delay one control step off is always refitted: the
        # parameters compensate for the delay they were fitted with, so its cost at the current estimate says
        # nothing (journey 4's servo arm, recorded 2 steps late: 82737 there, 298 refitted, against 770 at 3
        # steps, which the short-horizon global stage had picked). Other neighbours (a physics step either way)
        # are refitted only when close: one whose cost at the estimate is more than twice as high does not
        # overtake once refitted.
        tried = {(st.delay, st.obs)}
        for _ in range(len(delays) + len(ranges["obs"])):
            candidates: list[int] = []
            if len(ranges["action"]) > 1:
                lo_d, hi_d = min(delays), max(delays)
                stride = 1 if substep_latency else n_sub
                candidates = [
                    d
                    for d in range(st.delay - n_sub, st.delay + n_sub + 1, stride)
                    if lo_d <= d <= hi_d and d != st.delay
                ]
            trial_costs = []
            for d in candidates:
                r = final.residuals(st.theta, d, st.obs, st.x0)[0]
                trial_costs.append((0.5 * float(r @ r), d, st.obs))
            if len(ranges["obs"]) > 1:
                for o in (st.obs - 1, st.obs + 1):
                    if min(ranges["obs"]) <= o <= max(ranges["obs"]):
                        r = final.residuals(st.theta, st.delay, o, st.x0)[0]
                        trial_costs.append((0.5 * float(r @ r), st.delay, o))
            trial_costs.sort(key=lambda t: t[0])
            whole = [(d, o) for _, d, o in trial_costs if abs(d - st.delay) == n_sub or o != st.obs]
            close = [(d, o) for c, d, o in trial_costs[:1] if c < 2.0 * st.cost]
            best = st
            for d, o in dict.fromkeys(close + whole):
                if (d, o) in tried:
                    continue
                tried.add((d, o))
                # a whole control step away: a few iterations tell (770 -> 298 above), the winner is then finished
                steps = 10 if (d, o) in close else 3
                cand = lm(
                    final, State(st.theta, st.x0, d, o), lower, upper, max_iter=steps, stage="latency", **lm_kwargs
                )
                if cand.cost < best.cost and steps < 10:
                    cand = lm(final, cand, lower, upper, max_iter=10, stage="latency", **lm_kwargs)
                if cand.cost < best.cost:
                    best = cand
            if best is st:
                break
            st = reweigh(best, True)  # the noise levels were estimated with the wrong delay
    iterations, converged = st.iterations, st.converged

    # ---- statistics at the estimate
    if st.r is not None and st.jac is not None:
        r, jac = st.r, st.jac  # the last solve ended on a Jacobian at the estimate
    elif st.last_r is not None and st.prior_jac is not None:
        r, jac = st.last_r, st.prior_jac  # its last step was negligible: the Jacobian one iterate back (see lm)
    else:
        r, jac = final.jacobian(st.theta, st.delay, st.obs, st.x0, fd_steps(st.theta, lower, upper, fd_step), fitted)
    summary = estimate_statistics(final, st.theta, r, jac, lower, upper, fitted, unknowns)
    cost, s2, stderr, ci95 = summary.cost, summary.s2, summary.stderr, summary.ci95
    # Score test of the fixed physics (sysid._omitted): a left-out friction hides from every held-out statistic.
    omitted = (
        omitted_scores(
            final,
            pool.models_for(st.theta)[0],
            signals,
            obs_margin,
            state_mask,
            st.delay,
            st.obs,
            st.x0,
            r,
            jac,
            fitted,
            s2,
        )
        if max_iter > 0
        else {}
    )
    warns = list(summary.warnings)
    for side, chosen, searched in (("action", st.delay / n_sub, ranges["action"]), ("obs", st.obs, ranges["obs"])):
        if len(searched) > 1 and chosen >= max(searched):  # the cost may still fall beyond the range searched
            seconds = convert_time(
                max(searched), "control_steps", "seconds", timestep=model.opt.timestep, substeps=n_sub
            )
            warns.append(
                f"the {side} latency is the largest searched ({max(searched)} control steps, {seconds:.4g} s): the true "
                f"delay may be longer; search further with latency={2 * max(searched)} (sysid fit --latency-max "
                f"{2 * max(searched)})."
            )
    if max_iter > 0 and not converged:
        warns.append(f"the local stage stopped after {iterations} iterations without meeting its tolerances.")
    profiles: tuple[ProfileCheck, ...] = ()
    flat = flat_parameters(st.theta, stderr, ci95, np.stack([lower, upper], axis=1)) if profile else []
    if flat and max_iter > 0:
        optimum = State(st.theta, st.x0, st.delay, st.obs, cost)
        profiles = profile_intervals(final, optimum, lower, upper, flat, s2, ci95, fit_x0=fitted, fd_step=fd_step)
        for check in profiles:
            if check.open:
                warns.append(f"the data barely inform {check.address}: {check.describe()}; excite it more or fix it.")

    # ---- held-out validation
    noise = {name: float(sigma[c]) for c, name in enumerate(final.channels)}
    noise_dof_by_channel = {name: float(noise_dof[c]) for c, name in enumerate(final.channels)}
    trace_problem, trace_x0, source = final, st.x0, "fit"
    val_unknowns = 0
    # Judged as the fit shoots and where it fits: contact rows out, each piece from its own estimated state.
    held = held_out(
        val_ranges,
        flagged,
        cut_trees,
        Setting(
            log,
            model,
            space,
            fixed_horizon,
            signals,
            anchor,
            _MAX_NUISANCE,
            obs_margin,
            nthread,
            pool,
            state_mask,
            final.weights,
            st,
            lower,
            upper,
            fd_step,
            bar,
        ),
    )
    if held is not None:
        trace_problem, trace_x0, source, val_unknowns = held.problem, held.x0, "validation", held.unknowns
    pred, sens = trace_problem.simulate(st.theta, st.delay, trace_x0)
    errors = trace_problem.channel_errors(*trace_problem.raw_residuals(pred, sens, st.obs))
    measured = trace_problem.channel_measurements()
    rows = trace_problem.channel_rows()
    segs = trace_problem.channel_segments()
    fit_percent: dict[str, float] = {}
    whiteness: dict[str, float] = {}
    for c, name in enumerate(trace_problem.channels):
        e, y = errors[c], measured[c]
        spread = float(np.linalg.norm(y - y.mean()))
        fit_percent[name] = 100.0 * (1.0 - float(np.linalg.norm(e)) / spread) if spread > 0 else math.nan
        whiteness[name] = pooled_ljung_box([e[segs[c] == s] for s in np.unique(segs[c])])
    if val_unknowns:  # each held-out piece estimated its own start: its residuals are not white noise (_whiteness)
        whiteness.update(rejudge_low(trace_problem, st, trace_x0, errors, whiteness))
    for name in trace_problem.channels:
        if whiteness[name] < 0.01 and fit_percent[name] < 99.9:
            warns.append(
                f"residuals of {name} are not white (Ljung–Box p={whiteness[name]:.2g}): unmodelled dynamics, a "
                "wrong latency or coloured noise."
            )
    validation_ratio = math.nan
    if source == "validation":
        chi2 = sum(float(np.sum((e * w) ** 2)) for e, w in zip(errors, final.weights, strict=True))
        count = sum(e.size for e in errors)
        validation_ratio = math.sqrt(chi2 / max(1, count - val_unknowns)) / math.sqrt(max(s2, 1e-300))
    quality = assess(
        fit_percent,
        whiteness,
        tuple(space.addresses[int(i)] for i in summary.at_bounds),
        summary.condition,
        not any(w.startswith("not identifiable") for w in warns),
        validation_ratio,
        dict(zip(space.addresses, summary.inflation.tolist(), strict=True)),
        0 if fixed_horizon is None else int(fixed_horizon),
        seg_final.count,
        summary.informative,
        contact_count,
        profiles,
        _jitter_steps(log),
        omitted,
    )
    all_rows = np.unique(np.concatenate(rows))
    index = {int(r_): k for k, r_ in enumerate(all_rows)}
    trace_measured = np.full((all_rows.size, len(trace_problem.channels)), np.nan)
    trace_predicted = np.full_like(trace_measured, np.nan)
    for c in range(len(trace_problem.channels)):
        where = np.array([index[int(r_)] for r_ in rows[c]], dtype=np.intp)
        trace_measured[where, c] = measured[c]
        trace_predicted[where, c] = measured[c] + errors[c]
    bar.close()
    # Latencies leave the fit in seconds: the action delay counts physics steps, the sensor lag control steps.
    timestep = float(model.opt.timestep)
    fitted_latency: dict[str, float] = {}
    if ranges["action"] != [0]:
        fitted_latency["action"] = convert_time(st.delay, "physics_steps", "seconds", timestep=timestep)
    if ranges["obs"] != [0]:
        fitted_latency["obs"] = convert_time(st.obs, "control_steps", "seconds", timestep=timestep, substeps=n_sub)
    truth = log.meta.get("true_params")
    return FitResult(
        addresses=space.addresses,
        estimates=st.theta,
        stderr=stderr,
        ci95=ci95,
        crlb_sd=summary.crlb,
        covariance=summary.covariance,
        correlation=summary.correlation,
        bounds=np.stack([lower, upper], axis=1),
        latency=fitted_latency,
        timestep=timestep,
        control_timestep=timestep * n_sub,
        noise_std=noise,
        noise_dof=noise_dof_by_channel,
        fit_percent=fit_percent,
        whiteness_pvalue=whiteness,
        warnings=tuple(warns),
        condition_number=summary.condition,
        cost=cost,
        n_residuals=summary.n_residuals,
        dof=summary.dof,
        iterations=iterations,
        converged=converged or max_iter == 0,
        wall_time=_time.perf_counter() - started,
        channels=tuple(trace_problem.channels),
        trace_time=log.time[all_rows],
        trace_measured=trace_measured,
        trace_predicted=trace_predicted,
        trace_source=source,
        true_params=dict(truth) if isinstance(truth, Mapping) else None,
        quality=quality,
    )
