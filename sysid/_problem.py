"""The simulation-error least-squares problem behind :func:`sysid.fit` (internal).

A log is cut into shooting segments. Every segment starts from an anchor state (the logged state, or a
fitted nuisance initial state) and is rolled out open loop through ``mujoco.rollout`` under the logged
commands, delayed by the action latency. One rollout call carries every (parameter set x segment) pair,
so the residual of B parameter sets, or a whole finite-difference Jacobian, costs one batched,
multi-threaded call.

Rows need not sit on the control grid: a CSV log from a jittery driver clock keeps each sample at its own time
(``log.time``; :func:`sysid.load_csv`). A segment then starts at the physics step nearest its anchor row's time,
commands switch at their grid points as always, and every row is predicted at its own time, between two physics
steps (linear in between: MuJoCo's integrators move the state in whole steps). Interpolating the samples onto the grid
instead leaves an error of the order of jitter x acceleration, which a servo's velocity (its acceleration jumps
at every command) turns into coloured residuals that fail the whiteness check of a right model.
"""

from __future__ import annotations

import copy
import itertools
import os
from dataclasses import dataclass

import mujoco
import mujoco.rollout
import numpy as np

from sysid.logs import TrajectoryLog, channel_names
from sysid.params import ModelPool, ParameterSpace

__all__ = ["Problem", "Segments", "coupled_states", "make_segments"]

_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
_ON_GRID = 1e-6  # physics steps: a row's time this close to its grid point is on the grid (float rounding)
_COUPLINGS = (int(mujoco.mjtEq.mjEQ_JOINT), int(mujoco.mjtEq.mjEQ_TENDON))


def coupled_states(model: mujoco.MjModel, states: np.ndarray) -> np.ndarray:
    """(S, nq+nv) ``states`` moved the least onto the model's joint and tendon equality couplings.

    A logged state carries measurement noise on every joint, so two joints a ``<joint>`` or ``<tendon>`` equality
    ties together (a gripper's two fingers) are logged a noise draw apart although the robot never is: simulated
    from there, the constraint snaps them together in a transient of tens of noise SDs that the true motion never
    had, and a solve of the initial state alone from that start can stop in it (H3's arm7, held-out record seeds
    5, 108 and 115: held-out error 1.75x, 1.87x and 2.79x the in-fit error with the true model). The smallest
    (Euclidean) position correction that satisfies the couplings (a few Gauss-Newton steps on their violation) and
    the velocity's projection onto their null space is a start the robot could have been in. Other equalities
    (connect, weld: bodies, possibly mocap) are left alone; a model without couplings gets ``states`` back as is.

    Example:
        >>> import mujoco, numpy as np
        >>> m = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body><joint name="a" type="slide"/><geom size=".1"/></body>'
        ...     '<body><joint name="b" type="slide"/><geom size=".1"/></body></worldbody>'
        ...     '<equality><joint joint1="a" joint2="b"/></equality></mujoco>')
        >>> coupled_states(m, np.array([[0.01, 0.03, 0.2, 0.0]])).round(6).tolist()
        [[0.02, 0.02, 0.1, 0.1]]
    """
    types = model.eq_type[: model.neq]
    if not np.isin(types, _COUPLINGS).any():
        return states
    dense = copy.copy(model)
    dense.opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    data = mujoco.MjData(dense)
    nq, nv = model.nq, model.nv
    out = np.array(states, dtype=np.float64, copy=True)

    def rows() -> tuple[np.ndarray, np.ndarray]:
        mujoco.mj_forward(dense, data)
        n = data.nefc
        keep = data.efc_type[:n] == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)
        keep[keep] = np.isin(types[data.efc_id[:n][keep]], _COUPLINGS)  # efc_id names an equality only there
        return data.efc_J.reshape(-1, nv)[:n][keep], data.efc_pos[:n][keep]

    for state in out:
        data.qpos[:], data.qvel[:] = state[:nq], state[nq:]
        for _ in range(5):
            jac, violation = rows()
            if not violation.size or float(np.max(np.abs(violation))) <= 1e-12:
                break
            mujoco.mj_integratePos(dense, data.qpos, -np.linalg.pinv(jac) @ violation, 1.0)
        jac, _ = rows()
        if jac.size:
            data.qvel[:] -= np.linalg.pinv(jac) @ (jac @ data.qvel)
        state[:nq], state[nq:] = data.qpos, data.qvel
    return out


def sample_offsets(log: TrajectoryLog) -> np.ndarray | None:
    """(T,) how far each row's time is from its control-grid point (in physics steps; the grid of an episode
    starts at its first row), or None when every row is on the grid, or when some row is half a control step or
    more off (not a jittery grid: such a log is fitted row by row as before)."""
    dt, h, n_sub = log.control_timestep, log.timestep, log.n_substeps
    offset = np.empty(log.num_steps)
    for a, b in log.episode_bounds():
        grid = log.time[a] + dt * np.arange(b - a)
        offset[a:b] = (log.time[a:b] - grid) / h
    peak = float(np.max(np.abs(offset)))
    if peak <= _ON_GRID or peak >= 0.5 * n_sub:
        return None
    return offset


@dataclass(frozen=True)
class Segments:
    """Shooting segments: anchor row, rows covered, and the episode each belongs to (all shape (S,))."""

    start: np.ndarray
    length: np.ndarray
    episode_start: np.ndarray
    episode_stop: np.ndarray

    @property
    def count(self) -> int:
        return int(self.start.shape[0])


def make_segments(ranges: list[tuple[int, int, int, int]], horizon: int | None, fitted_anchor: bool) -> Segments:
    """Cuts row ranges ``(first, stop, episode_start, episode_stop)`` into segments of ``horizon`` rows.

    With logged anchors a segment anchored at row ``a`` predicts rows ``a+1 .. a+n`` (the next segment
    re-anchors at ``a+n``); with fitted anchors it covers rows ``a .. a+n-1``.
    """
    start, length, e0, e1 = [], [], [], []
    for first, stop, ep_start, ep_stop in ranges:
        span = (stop - 1 - first) if not fitted_anchor else (stop - first)
        if span < 1:
            continue
        step = span if horizon is None else horizon
        count = max(1, round(span / step))
        edges = np.linspace(0, span, count + 1).round().astype(int)
        for lo, hi in itertools.pairwise(edges):
            if hi > lo:
                start.append(first + lo)
                length.append(hi - lo)
                e0.append(ep_start)
                e1.append(ep_stop)
    as_int = lambda v: np.asarray(v, dtype=np.intp)  # noqa: E731
    return Segments(as_int(start), as_int(length), as_int(e0), as_int(e1))


class Problem:
    """Weighted simulation-error residuals of a log under a parameter space.

    Args:
        log: the trajectory log (validated against ``model``).
        model: the model (never modified; copies are written).
        space: the fitted parameters.
        segments: shooting segments.
        signals: which measured signals enter the residual (``"qpos"``, ``"qvel"``, ``"sensordata"``).
        fitted_anchor: initial states are nuisance parameters (True) or the logged states (False).
        obs_margin: sensor rows with segment index below this are skipped (room for observation latency).
        nthread: rollout threads.
        state_mask: (nq + nv,) bool, the state entries that count (default all): their ``qpos``/``qvel`` channels
            enter the residual and their initial states are fitted. The rest are still simulated (from the
            logged anchor) but neither measured nor fitted — a body the parameters do not move.
    """

    def __init__(
        self,
        log: TrajectoryLog,
        model: mujoco.MjModel,
        space: ParameterSpace,
        segments: Segments,
        signals: tuple[str, ...],
        fitted_anchor: bool,
        obs_margin: int,
        nthread: int | None,
        pool: ModelPool | None = None,
        state_mask: np.ndarray | None = None,
    ) -> None:
        self.log = log
        self.model = model
        self.space = space
        self.seg = segments
        self.fitted_anchor = fitted_anchor
        self.n_sub = log.n_substeps
        self.nq, self.nv, self.na = model.nq, model.nv, model.na
        self.nx = self.nq + self.nv
        mask = np.ones(self.nx, dtype=bool) if state_mask is None else np.asarray(state_mask, dtype=bool)
        self.x_dims = np.flatnonzero(mask)  # fitted initial-state entries
        self.nxa = int(self.x_dims.size)
        self.pool = pool or ModelPool(model, space)
        self.nthread = max(1, nthread or os.cpu_count() or 1)
        self._datas = [mujoco.MjData(model) for _ in range(self.nthread)]
        self.L = int(segments.length.max())
        names = channel_names(model)
        # Measured channels: state channels (qpos, qvel columns) and sensor channels.
        state_cols: list[int] = []
        self.channels: list[str] = []
        if "qpos" in signals:
            state_cols += [i for i in range(self.nq) if mask[i]]
            self.channels += [n for i, n in enumerate(names["qpos"]) if mask[i]]
        if "qvel" in signals:
            state_cols += [self.nq + i for i in range(self.nv) if mask[self.nq + i]]
            self.channels += [n for i, n in enumerate(names["qvel"]) if mask[self.nq + i]]
        self.state_cols = np.asarray(state_cols, dtype=np.intp)
        self.use_sensors = "sensordata" in signals and log.sensordata is not None and model.nsensordata > 0
        if self.use_sensors:
            self.channels += names["sensordata"]
        self.n_state_ch = len(state_cols)
        self.n_sens_ch = model.nsensordata if self.use_sensors else 0
        logged_state = np.concatenate([log.qpos, log.qvel], axis=1)
        self.logged_state = logged_state
        # Gather indices for state residuals: (segment, index within the segment, absolute row).
        seg_s, j_s = [], []
        for s in range(segments.count):
            n = int(segments.length[s])
            js = np.arange(0, n) if fitted_anchor else np.arange(1, n + 1)
            seg_s.append(np.full(js.size, s))
            j_s.append(js)
        self.s_seg = np.concatenate(seg_s)
        self.s_j = np.concatenate(j_s)
        self.s_row = segments.start[self.s_seg] + self.s_j
        self.y_state = (
            logged_state[self.s_row][:, self.state_cols] if self.n_state_ch else np.zeros((self.s_row.size, 0))
        )
        seg_y, j_y = [], []
        for s in range(segments.count):
            js = np.arange(obs_margin, int(segments.length[s]))
            seg_y.append(np.full(js.size, s))
            j_y.append(js)
        self.y_seg = np.concatenate(seg_y) if self.use_sensors else np.zeros(0, np.intp)
        self.y_j = np.concatenate(j_y) if self.use_sensors else np.zeros(0, np.intp)
        self.y_row = segments.start[self.y_seg] + self.y_j
        self.y_sens = log.sensordata[self.y_row] if self.use_sensors else np.zeros((0, 0))  # type: ignore[index]
        self.n_res = self.s_row.size * self.n_state_ch + self.y_row.size * self.n_sens_ch
        self.weights = np.ones(self.n_state_ch + self.n_sens_ch)
        # Template full-physics state (mocap, plugin state, ... from the model's defaults).
        data = mujoco.MjData(model)
        self.nstate = mujoco.mj_stateSize(model, _SPEC)
        self._template = np.empty(self.nstate)
        mujoco.mj_getState(model, data, self._template, _SPEC)
        self._controls: dict[int, np.ndarray] = {}
        # Rows off the grid: a segment starts at the physics step nearest its anchor row's time (the rollout stays
        # on the physics steps its commands switch at) and runs one control step longer, so its last row can be
        # read after its grid point.
        self.offset = sample_offsets(log)
        self.extra = 0 if self.offset is None else self.n_sub + 1
        self._shift = np.zeros(segments.count, dtype=np.intp)
        self._position = np.zeros(0)
        if self.offset is not None:
            self._shift = np.round(self.offset[segments.start]).astype(np.intp)
            rows = np.minimum(segments.start[:, None] + np.arange(self.L + 1)[None, :], log.num_steps - 1)
            # (S, L+1) physics steps from the segment's start at which each of its rows was sampled
            self._position = np.arange(self.L + 1)[None, :] * self.n_sub + self.offset[rows] - self._shift[:, None]
        # The last single-set rollout (values, delay, x0, states, sensors): Levenberg–Marquardt asks for the
        # Jacobian right where it accepted a trial step, so its base rows need not be rolled out again.
        self._last: tuple[np.ndarray, int, np.ndarray, np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ rollout plumbing
    def anchors(self) -> np.ndarray:
        """(S, nx) logged states at the segment anchors."""
        return self.logged_state[self.seg.start].copy()

    def _initial_states(self, x0: np.ndarray) -> np.ndarray:
        states = np.tile(self._template, (x0.shape[0], 1))
        states[:, 0] = self.log.time[self.seg.start]
        if self.offset is not None:  # the physics step the segment starts at
            states[:, 0] -= (self.offset[self.seg.start] - self._shift) * self.log.timestep
        states[:, 1 : 1 + self.nx] = x0
        if self.na and self.log.act is not None:
            states[:, 1 + self.nx : 1 + self.nx + self.na] = self.log.act[self.seg.start]
        return states

    def controls(self, delay: int) -> np.ndarray:
        """(S, L*n_sub, nu) physics-step commands under an action delay of ``delay`` physics steps."""
        cached = self._controls.get(delay)
        if cached is not None:
            return cached
        n_sub, seg = self.n_sub, self.seg
        steps = np.arange(self.L * n_sub + self.extra)
        absolute = seg.start[:, None] * n_sub + self._shift[:, None] + steps[None, :]
        source = np.floor_divide(absolute - delay, n_sub)
        source = np.clip(source, seg.episode_start[:, None], seg.episode_stop[:, None] - 1)
        out = np.ascontiguousarray(self.log.ctrl[source])
        self._controls[delay] = out
        return out

    def rollout(
        self, models: list[mujoco.MjModel], states: np.ndarray, controls: np.ndarray, segs: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rolls out rows; returns predicted states (R, L+1, nx) and sensors (R, L, ns) at control rows.

        ``segs`` (R,) is the shooting segment of each row (default: the segments in order, repeated), which
        says at what times its rows were sampled when they are off the grid."""
        nstep = self.L * self.n_sub + self.extra
        state_out, sensor_out = mujoco.rollout.rollout(
            models, self._datas, states, controls, nstep=nstep, persistent_pool=False
        )
        if self.offset is not None:
            segs = np.tile(np.arange(self.seg.count), states.shape[0] // self.seg.count) if segs is None else segs
            return self._at_sample_times(states, state_out, sensor_out, self._position[segs])
        pred = np.empty((states.shape[0], self.L + 1, self.nx))
        pred[:, 0] = states[:, 1 : 1 + self.nx]
        pred[:, 1:] = state_out[:, self.n_sub - 1 :: self.n_sub, 1 : 1 + self.nx]
        sens = sensor_out[:, :: self.n_sub] if self.use_sensors else np.zeros((states.shape[0], self.L, 0))
        return pred, sens

    def _at_sample_times(
        self, states: np.ndarray, state_out: np.ndarray, sensor_out: np.ndarray, position: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """States and sensors at fractional physics steps ``position`` (R, L+1) of each rollout row."""
        full = np.concatenate([states[:, None, 1 : 1 + self.nx], state_out[:, :, 1 : 1 + self.nx]], axis=1)
        rows = np.arange(full.shape[0])[:, None]
        low = np.clip(np.floor(position).astype(np.intp), 0, full.shape[1] - 2)
        w = (position - low)[..., None]
        pred = (1.0 - w) * full[rows, low] + w * full[rows, low + 1]
        if not self.use_sensors:
            return pred, np.zeros((states.shape[0], self.L, 0))
        # sensor_out[:, i] is read at the state before step i, as full[:, i]. A row's sensors are read at the time
        # of the row they are simulated at: with a fitted observation latency, not at the logged row's own jitter.
        low = np.minimum(low[:, : self.L], sensor_out.shape[1] - 2)
        w = (position[:, : self.L] - low)[..., None]
        return pred, (1.0 - w) * sensor_out[rows, low] + w * sensor_out[rows, low + 1]

    def simulate(self, values: np.ndarray, delay: int, x0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Predictions for B parameter sets: states (B, S, L+1, nx), sensors (B, S, L, ns)."""
        values = np.atleast_2d(values)
        b, s = values.shape[0], self.seg.count
        models = self.pool.models_for(values)
        rows_models = [m for m in models for _ in range(s)]
        x0 = self.anchors() if x0 is None else x0
        states = np.tile(self._initial_states(x0), (b, 1))
        controls = np.tile(self.controls(delay), (b, 1, 1))
        pred, sens = self.rollout(rows_models, states, controls)
        if b == 1:
            self._last = (values[0].copy(), delay, np.array(x0), pred, sens)
        return pred.reshape(b, s, self.L + 1, self.nx), sens.reshape(b, s, self.L, -1)

    def substep_qpos(self, values: np.ndarray, delay: int, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions after every physics step of one parameter set's rollout, and the log row each one reaches
        (the first row at or after it): (K, nq) and (K,) over the rows the segments cover (for event checks: a
        bounce can begin and end between two logged rows)."""
        models = self.pool.models_for(np.atleast_2d(values))
        s, n_sub = self.seg.count, self.n_sub
        state_out, _ = mujoco.rollout.rollout(
            [models[0]] * s,
            self._datas,
            self._initial_states(x0),
            self.controls(delay),
            nstep=self.L * n_sub + self.extra,
            persistent_pool=False,
        )
        steps = np.arange(self.L * n_sub + self.extra)
        reach = self.seg.start[:, None] + (steps[None, :] + n_sub) // n_sub  # after step k: row start + ceil((k+1)/n)
        last = self.seg.start + self.seg.length + (0 if self.fitted_anchor else 1)
        keep = reach < last[:, None]
        return state_out[:, :, 1 : 1 + self.nq][keep], reach[keep]

    def _cached(self, values: np.ndarray, delay: int, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The last single-set rollout if it was of exactly these values, delay and initial states."""
        last = self._last
        if last is None or last[1] != delay or not np.array_equal(last[0], values) or not np.array_equal(last[2], x0):
            return None
        return last[3], last[4]

    # ------------------------------------------------------------------ residuals
    def raw_residuals(self, pred: np.ndarray, sens: np.ndarray, obs_delay: int) -> tuple[np.ndarray, np.ndarray]:
        """Unweighted prediction errors: states (B, Ns, Cs) and sensors (B, Ny, Cy)."""
        r_state = pred[:, self.s_seg, self.s_j][..., self.state_cols] - self.y_state
        if self.use_sensors:
            r_sens = sens[:, self.y_seg, self.y_j - obs_delay] - self.y_sens
        else:
            r_sens = np.zeros((pred.shape[0], 0, 0))
        return r_state, r_sens

    def weighted(self, r_state: np.ndarray, r_sens: np.ndarray) -> np.ndarray:
        """(B, N) residual vectors weighted by 1/sigma per channel."""
        w = self.weights
        parts = [(r_state * w[: self.n_state_ch]).reshape(r_state.shape[0], -1)]
        if self.use_sensors:
            parts.append((r_sens * w[self.n_state_ch :]).reshape(r_sens.shape[0], -1))
        return np.concatenate(parts, axis=1)

    def residuals(self, values: np.ndarray, delay: int, obs_delay: int, x0: np.ndarray | None = None) -> np.ndarray:
        """(B, N) weighted residuals of B parameter sets."""
        pred, sens = self.simulate(values, delay, x0)
        return self.weighted(*self.raw_residuals(pred, sens, obs_delay))

    def jacobian(
        self,
        values: np.ndarray,
        delay: int,
        obs_delay: int,
        x0: np.ndarray | None,
        steps: np.ndarray,
        fit_x0: bool,
        fit_params: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Residual (N,) and forward-difference Jacobian (N, P [+ S*nxa]) in one batched rollout (the
        initial-state columns: the fitted entries ``x_dims`` of each segment, segment after segment)."""
        p, s, nx, nxa, dims = self.space.size, self.seg.count, self.nx, self.nxa, self.x_dims
        x0 = self.anchors() if x0 is None else x0
        sets = [values]
        if fit_params:
            sets += [values + np.eye(p)[i] * steps[i] for i in range(p)]
        table = np.vstack(sets)
        models = self.pool.models_for(table)
        # The base rows were usually just rolled out (the accepted trial step): reused, bitwise the same.
        cached = self._cached(values, delay, x0) if table.shape[0] > 1 or fit_x0 else None
        first = 0 if cached is None else 1
        row_models = [m for m in models[first:] for _ in range(s)]
        base_states = self._initial_states(x0)
        states = [np.tile(base_states, (table.shape[0] - first, 1))]
        controls = [np.tile(self.controls(delay), (table.shape[0] - first, 1, 1))]
        x_steps = np.zeros(nx)
        if fit_x0:
            scale = np.maximum(np.abs(x0).max(axis=0), 1e-2)
            x_steps = 1e-6 * scale
            pert = np.repeat(base_states, nxa, axis=0)  # row s*nxa + i perturbs state dims[i] of segment s
            pert[np.arange(s * nxa), 1 + np.tile(dims, s)] += np.tile(x_steps[dims], s)
            states.append(pert)
            controls.append(np.repeat(self.controls(delay), nxa, axis=0))
            row_models += [models[0]] * (s * nxa)
        segs = [np.tile(np.arange(s), table.shape[0] - first)]
        if fit_x0:
            segs.append(np.repeat(np.arange(s), nxa))
        pred, sens = self.rollout(row_models, np.vstack(states), np.concatenate(controls), np.concatenate(segs))
        if cached is not None:
            pred, sens = np.concatenate([cached[0], pred]), np.concatenate([cached[1], sens])
        n_sets = table.shape[0]
        main_pred = pred[: n_sets * s].reshape(n_sets, s, self.L + 1, nx)
        main_sens = sens[: n_sets * s].reshape(n_sets, s, self.L, -1)
        res = self.weighted(*self.raw_residuals(main_pred, main_sens, obs_delay))
        r0 = res[0]
        columns = []
        if fit_params:
            columns.append(((res[1:] - r0) / steps[:, None]).T)
        if fit_x0:
            xp = pred[n_sets * s :].reshape(s, nxa, self.L + 1, nx)
            xs = sens[n_sets * s :].reshape(s, nxa, self.L, -1)
            block = np.zeros((r0.size, s * nxa))
            for k in range(s):
                p_k = np.repeat(main_pred[:1], nxa, axis=0)
                s_k = np.repeat(main_sens[:1], nxa, axis=0)
                p_k[:, k] = xp[k]
                s_k[:, k] = xs[k]
                r_k = self.weighted(*self.raw_residuals(p_k, s_k, obs_delay))
                block[:, k * nxa : (k + 1) * nxa] = ((r_k - r0) / x_steps[dims][:, None]).T
            columns.append(block)
        return r0, np.concatenate(columns, axis=1) if columns else np.zeros((r0.size, 0))

    # ------------------------------------------------------------------ channel bookkeeping
    def channel_of_residual(self) -> np.ndarray:
        """(N,) channel index of every entry of the weighted residual vector."""
        parts = [np.tile(np.arange(self.n_state_ch), self.s_row.size)]
        if self.use_sensors:
            parts.append(self.n_state_ch + np.tile(np.arange(self.n_sens_ch), self.y_row.size))
        return np.concatenate(parts)

    def residual_keys(self) -> tuple[np.ndarray, np.ndarray]:
        """(N,) shooting segment and (N,) log row of every entry of the weighted residual vector."""
        seg = [np.repeat(self.s_seg, self.n_state_ch)]
        row = [np.repeat(self.s_row, self.n_state_ch)]
        if self.use_sensors:
            seg.append(np.repeat(self.y_seg, self.n_sens_ch))
            row.append(np.repeat(self.y_row, self.n_sens_ch))
        return np.concatenate(seg), np.concatenate(row)

    def segment_rows(self) -> list[np.ndarray]:
        """Per shooting segment, the indices of its entries in the weighted residual vector (cached)."""
        cached: list[np.ndarray] | None = getattr(self, "_segment_rows", None)
        if cached is None:
            seg = self.residual_keys()[0]
            order = np.argsort(seg, kind="stable")
            cuts = np.searchsorted(seg[order], np.arange(1, self.seg.count))
            cached = list(np.split(order, cuts))
            self._segment_rows = cached
        return cached

    def channel_errors(self, r_state: np.ndarray, r_sens: np.ndarray) -> list[np.ndarray]:
        """Per channel, the unweighted errors of one parameter set, in row order."""
        out = [r_state[0, :, c] for c in range(self.n_state_ch)]
        if self.use_sensors:
            out += [r_sens[0, :, c] for c in range(self.n_sens_ch)]
        return out

    def channel_measurements(self) -> list[np.ndarray]:
        """Per channel, the measured values entering the residual, in row order."""
        out = [self.y_state[:, c] for c in range(self.n_state_ch)]
        if self.use_sensors:
            out += [self.y_sens[:, c] for c in range(self.n_sens_ch)]
        return out

    def channel_rows(self) -> list[np.ndarray]:
        out = [self.s_row] * self.n_state_ch
        if self.use_sensors:
            out += [self.y_row] * self.n_sens_ch
        return out

    def channel_segments(self) -> list[np.ndarray]:
        out = [self.s_seg] * self.n_state_ch
        if self.use_sensors:
            out += [self.y_seg] * self.n_sens_ch
        return out
