"""Shooting-segment length from the data (internal to :func:`sysid.fit`).

A fit by simulation error is only as good as its open-loop predictions: when the simulation drifts away from
the log faster than the parameters explain (an arm held up by feedback whose loop the log replays open loop,
an unstable pose, chaotic contacts), one long segment makes the cost surface rugged and its linearisation — the
standard errors — meaningless. :func:`divergence_horizon` rolls the current model out from the logged states and
finds how many control steps it stays within a few noise levels of the log (or, on a stiff servo whose noisy
logged start alone puts the prediction many noise levels off, within a few times that start's response); the fit
then cuts the log into segments of that length, each with its own fitted initial state.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sysid._problem import Problem, Segments
from sysid.logs import TrajectoryLog
from sysid.params import ModelPool, ParameterSpace

__all__ = ["DIVERGENCE_LEVEL", "MIN_HORIZON", "divergence_curve", "divergence_horizon", "start_response"]

#: Median RMS prediction error (in noise SDs over the channels) at which the open-loop prediction counts as
#: diverged; below it the error is still mostly noise plus a parameter mismatch that the fit can remove.
DIVERGENCE_LEVEL = 3.0
#: Shortest automatic segment (control steps): shorter segments leave too little to fit after their own state.
MIN_HORIZON = 8
_MAX_LEAD = 200


def divergence_curve(
    log: TrajectoryLog,
    model: mujoco.MjModel,
    space: ParameterSpace,
    ranges: list[tuple[int, int, int, int]],
    signals: tuple[str, ...],
    weights: np.ndarray,
    theta: np.ndarray,
    delay: int,
    obs_delay: int,
    nthread: int | None,
    pool: ModelPool,
    max_lead: int = _MAX_LEAD,
    state_mask: np.ndarray | None = None,
) -> np.ndarray:
    """Median over anchors of the RMS weighted error at lead 1, 2, … (open loop from logged states).

    ``state_mask`` (bool over ``qpos``/``qvel`` entries) limits the RMS to the channels of what the parameters
    move: a ball bouncing beside an arm diverges within a few steps but says nothing about the arm, and would
    otherwise cut the arm's log into needlessly short segments.

    Returns:
        (K,) error per lead, K = min(max_lead, longest fitted range - 1), in noise SDs, or in units of
        :func:`start_response` when that is larger.
    """
    longest = max(stop - first for first, stop, _, _ in ranges)
    lead = int(min(max_lead, longest - 1))
    if lead < 1:
        return np.zeros(0)
    # Overlapping segments from anchors every lead/8 rows: the median at each lead is over many starts, so one
    # event (a contact, a bounce) near one anchor does not decide the horizon.
    stride = max(1, lead // 8)
    start, length, e0, e1 = [], [], [], []
    for first, stop, ep_start, ep_stop in ranges:
        for a in range(first, stop - 1, stride):
            start.append(a)
            length.append(min(lead, stop - 1 - a))
            e0.append(ep_start)
            e1.append(ep_stop)
    seg = Segments(*(np.asarray(v, dtype=np.intp) for v in (start, length, e0, e1)))
    problem = Problem(log, model, space, seg, signals, False, 0, nthread, pool, state_mask)
    problem.weights = weights
    pred, sens = problem.simulate(theta, delay)
    r_state, r_sens = problem.raw_residuals(pred, sens, obs_delay)
    if problem.n_state_ch:
        z = r_state[0] * weights[: problem.n_state_ch]
        j = problem.s_j
    else:
        z = r_sens[0] * weights[problem.n_state_ch :]
        j = problem.y_j + 1
    rms = np.sqrt(np.mean(z**2, axis=1))
    out = np.full(lead, np.nan)
    for k in range(1, lead + 1):
        at = rms[j == k]
        if at.size:
            out[k - 1] = float(np.median(at))
    # The curve counts in units of the start's own response at lead 1 when that exceeds the noise: a stiff servo
    # turns a logged start one noise SD off the true state into an acceleration, so its prediction is already many
    # noise SDs off one control step on, with no parameter wrong. The fit's segments start from fitted states,
    # which absorb that response; growth beyond it still counts (an unstable pose amplifies any start error).
    out /= max(
        1.0,
        start_response(log, model, space, seg, signals, weights, theta, delay, nthread, pool, state_mask),
    )
    # A lead no segment reaches (the last, shorter segment) repeats the previous value.
    for k in range(1, lead):
        if np.isnan(out[k]):
            out[k] = out[k - 1]
    return out


def start_response(
    log: TrajectoryLog,
    model: mujoco.MjModel,
    space: ParameterSpace,
    seg: Segments,
    signals: tuple[str, ...],
    weights: np.ndarray,
    theta: np.ndarray,
    delay: int,
    nthread: int | None,
    pool: ModelPool,
    state_mask: np.ndarray | None = None,
) -> float:
    """Median over the anchors of ``seg`` of the RMS weighted change of the measured state one control step on
    when the start moves by one draw of the measurement noise (1.0 when no state entry is measured).

    The draw comes from a generator of its own (seed 0), so the horizon of a fit does not depend on its seed.
    """
    state_signals = tuple(s for s in signals if s != "sensordata")
    if not state_signals:
        return 1.0
    one = Segments(seg.start, np.ones_like(seg.length), seg.episode_start, seg.episode_stop)
    step = Problem(log, model, space, one, state_signals, False, 0, nthread, pool, state_mask)
    if not step.n_state_ch:
        return 1.0
    step.weights = weights
    x0 = step.anchors()
    moved = x0.copy()
    draws = np.random.default_rng(0).standard_normal((x0.shape[0], step.n_state_ch))
    moved[:, step.state_cols] += draws / weights[: step.n_state_ch]
    base = step.raw_residuals(*step.simulate(theta, delay, x0), 0)[0][0]
    off = step.raw_residuals(*step.simulate(theta, delay, moved), 0)[0][0]
    change = (off - base) * weights[: step.n_state_ch]
    return float(np.median(np.sqrt(np.mean(change**2, axis=1))))


def divergence_horizon(curve: np.ndarray, level: float = DIVERGENCE_LEVEL) -> int | None:
    """The segment length (control steps) for a divergence ``curve``: the last lead before it first exceeds
    ``level`` (at least :data:`MIN_HORIZON`); None (whole episodes) when it never does.

    Example:
        >>> import numpy as np
        >>> divergence_horizon(np.array([1.0, 1.5, 2.0, 2.9, 3.5, 9.0]))
        8
        >>> divergence_horizon(np.linspace(1, 40, 60))
        8
        >>> divergence_horizon(1.0 + 0.02 * np.arange(60)) is None
        True
        >>> divergence_horizon(np.concatenate([np.ones(30), np.full(30, 5.0)]))
        30
    """
    over = np.flatnonzero(~(curve <= level))  # NaN counts as diverged
    if over.size == 0:
        return None
    return max(MIN_HORIZON, int(over[0]))
