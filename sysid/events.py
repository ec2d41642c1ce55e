"""Contact events in a log: rows the fit leaves out (internal to :func:`sysid.fit`).

A contact that touches the part of the robot the parameters move (a finger brushing the floor, the hand hitting a
ball) makes the open-loop prediction hinge on when and how hard the contact happens. Its sensitivity to the
parameters is then mostly contact timing: the linearisation behind the standard errors fails there, and on
``dmc/manipulator-bring_ball`` the few fits whose multisine drove the hand into the floor or the ball landed up to
16 Cramér–Rao SDs off with intervals a third of the right width. :func:`contact_rows` finds, from the logged
states, the rows where such a contact is active; :func:`split_ranges` cuts the fitted row ranges around them, so
no shooting segment crosses a contact event and the rows in contact do not enter the residual.

Contacts between parts the parameters do not move (a ball rolling on the floor beside an arm whose dampings are
fitted) are kept: they carry no information on the parameters and cannot bias them. When some parameter acts only
through contacts (a friction coefficient, contact softness), every contact row is information and nothing is cut.
"""

from __future__ import annotations

import copy
import math

import mujoco
import numpy as np

from sysid.logs import TrajectoryLog
from sysid.params import ModelPool, ParameterSpace

__all__ = [
    "CONTACT_MARGIN_ROWS",
    "MIN_KEPT_SHARE",
    "MIN_RANGE_ROWS",
    "NEAR_LEVEL",
    "NEAR_REACH",
    "contact_rows",
    "moved_trees",
    "near_contact_rows",
    "sensor_trees",
    "simulated_contact_rows",
    "split_ranges",
    "state_trees",
]

#: Rows on either side of a row with a contact that are also left out: a contact can begin or end between two
#: logged rows, and a noisy logged state can miss it by a row.
CONTACT_MARGIN_ROWS = 2
#: Shortest piece of log kept between two contact events (rows).
MIN_RANGE_ROWS = 6
#: Share of the fitted rows that must remain after cutting out contact events; below it the contacts are kept
#: (a walking robot is in contact all the time).
MIN_KEPT_SHARE = 0.5
#: Distance (model length units) up to which :func:`near_contact_rows` measures the closest approach.
NEAR_REACH = 0.05
#: Noise SDs of that distance within which a row counts as possibly in contact.
NEAR_LEVEL = 3.0
_SAMPLE_ROWS = 40
_REL_STEP = 1e-3


def _contact_pairs(model: mujoco.MjModel, data: mujoco.MjData) -> list[tuple[int, int]]:
    """Kinematic trees of the two bodies of each active contact (-1 for the world)."""
    trees = model.body_treeid
    bodies = model.geom_bodyid
    return [
        (int(trees[bodies[data.contact[i].geom1]]), int(trees[bodies[data.contact[i].geom2]])) for i in range(data.ncon)
    ]


def _set_row(log: TrajectoryLog, model: mujoco.MjModel, data: mujoco.MjData, row: int) -> None:
    data.qpos[:] = log.qpos[row]
    data.qvel[:] = log.qvel[row]
    data.ctrl[:] = log.ctrl[row]
    if model.na and log.act is not None:
        data.act[:] = log.act[row]


def _moved_trees(
    log: TrajectoryLog,
    model: mujoco.MjModel,
    space: ParameterSpace,
    pool: ModelPool,
    theta: np.ndarray,
    rows: np.ndarray,
) -> set[int] | None:
    """Trees whose accelerations change with some parameter at contact-free ``rows``; None when some parameter
    changes nothing there (it acts through contacts, or the rows do not excite it)."""
    steps = _REL_STEP * np.maximum(np.abs(theta), 1e-3 * (space.upper - space.lower))
    table = np.vstack([theta, theta + np.diag(steps)])
    models = pool.models_for(table)
    datas = [mujoco.MjData(m) for m in models]
    moved = np.zeros((space.size, model.nv), dtype=bool)
    for row in rows:
        acc = []
        for m, d in zip(models, datas, strict=True):
            _set_row(log, m, d, int(row))
            mujoco.mj_forward(m, d)
            acc.append(d.qacc.copy())
        base = acc[0]
        for p in range(space.size):
            moved[p] |= np.abs(acc[p + 1] - base) > 1e-9 * (1.0 + np.abs(base))
    if not moved.any(axis=1).all():
        return None
    return {int(t) for t in model.dof_treeid[moved.any(axis=0)]}


def _row_pairs(log: TrajectoryLog, model: mujoco.MjModel) -> list[list[tuple[int, int]]]:
    return _qpos_pairs(model, log.qpos)


def _qpos_pairs(model: mujoco.MjModel, qpos: np.ndarray) -> list[list[tuple[int, int]]]:
    data = mujoco.MjData(model)
    pairs = []
    for row in range(qpos.shape[0]):
        data.qpos[:] = qpos[row]
        mujoco.mj_fwdPosition(model, data)
        pairs.append(_contact_pairs(model, data))
    return pairs


def _dilate(flagged: np.ndarray) -> np.ndarray:
    if flagged.any() and CONTACT_MARGIN_ROWS:
        kernel = np.ones(2 * CONTACT_MARGIN_ROWS + 1)
        flagged = np.convolve(flagged.astype(float), kernel, mode="same") > 0
    return flagged


def moved_trees(
    log: TrajectoryLog, model: mujoco.MjModel, space: ParameterSpace, pool: ModelPool, theta: np.ndarray
) -> set[int] | None:
    """Kinematic trees whose accelerations some parameter changes, read at logged rows where no contact couples
    two moving trees; None when some parameter changes nothing there (it acts through contacts, or through
    something these rows do not show) — then every tree counts.
    """
    pairs = _row_pairs(log, model)
    free = np.array([all(a == -1 or b == -1 or a == b for a, b in p) for p in pairs])
    candidates = np.flatnonzero(free)
    if candidates.size == 0 or space.size == 0:
        return None
    sample = candidates[np.linspace(0, candidates.size - 1, min(_SAMPLE_ROWS, candidates.size)).round().astype(int)]
    return _moved_trees(log, model, space, pool, theta, np.unique(sample))


def state_trees(model: mujoco.MjModel) -> np.ndarray:
    """(nq + nv,) the kinematic tree of every ``qpos`` and ``qvel`` entry (the log's state columns).

    Example:
        >>> m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><body><freejoint/><geom size=".1"/></body>'
        ...     '<body><joint type="hinge"/><geom size=".1"/></body></worldbody></mujoco>')
        >>> state_trees(m).tolist()
        [0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1]
    """
    widths = np.diff(np.append(model.jnt_qposadr, model.nq))
    qpos_tree = np.repeat(model.dof_treeid[model.jnt_dofadr], widths)
    return np.concatenate([qpos_tree, model.dof_treeid]).astype(np.intp)


def sensor_trees(model: mujoco.MjModel) -> list[int | None]:
    """The kinematic tree each sensor is attached to (through its site, body, joint, geom or camera, and its
    reference frame when it has one); None when it is attached to the world or to something else (it may read
    any body).

    Example:
        >>> m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><site name="w"/><body><joint name="j"/>'
        ...     '<geom size=".1"/><site name="s"/></body></worldbody>'
        ...     '<sensor><touch site="s"/><jointpos joint="j"/><framepos objtype="site" objname="w"/></sensor></mujoco>')
        >>> sensor_trees(m)
        [0, 0, None]
    """
    obj = mujoco.mjtObj
    body_of = {
        int(obj.mjOBJ_SITE): model.site_bodyid,
        int(obj.mjOBJ_BODY): np.arange(model.nbody),
        int(obj.mjOBJ_XBODY): np.arange(model.nbody),
        int(obj.mjOBJ_JOINT): model.jnt_bodyid,
        int(obj.mjOBJ_GEOM): model.geom_bodyid,
        int(obj.mjOBJ_CAMERA): model.cam_bodyid,
    }
    out: list[int | None] = []
    for i in range(model.nsensor):
        trees = set()
        for kind, ident in (
            (model.sensor_objtype[i], model.sensor_objid[i]),
            (model.sensor_reftype[i], model.sensor_refid[i]),
        ):
            if ident < 0 and kind == obj.mjOBJ_UNKNOWN:
                continue
            bodies = body_of.get(int(kind))
            trees.add(None if bodies is None or ident < 0 else int(model.body_treeid[bodies[ident]]))
        tree = trees.pop() if len(trees) == 1 else None
        out.append(None if tree is None or tree < 0 else tree)
    return out


def contact_rows(
    log: TrajectoryLog,
    model: mujoco.MjModel,
    space: ParameterSpace,
    pool: ModelPool,
    theta: np.ndarray,
) -> np.ndarray:
    """(T,) bool: rows with a contact on a kinematic tree the parameters move (dilated by
    :data:`CONTACT_MARGIN_ROWS`); all False when the parameters act through contacts or there are none.

    Args:
        log: the trajectory log.
        model: the model being fitted (not modified).
        space: the fitted parameters.
        pool: model copies for ``space`` (written here).
        theta: parameter values at which the trees are found.
    """
    pairs = _row_pairs(log, model)
    flagged = np.zeros(len(pairs), dtype=bool)
    if not any(pairs):
        return flagged
    trees = moved_trees(log, model, space, pool, theta)
    if trees is None:
        return flagged
    for row, p in enumerate(pairs):
        if any(a in trees or b in trees for a, b in p):
            flagged[row] = True
    return _dilate(flagged)


def simulated_contact_rows(
    model: mujoco.MjModel, rows: np.ndarray, qpos: np.ndarray, trees: set[int], n_rows: int
) -> np.ndarray:
    """(n_rows,) bool: log rows where a *simulated* state (``qpos[i]`` predicted for row ``rows[i]``) has a contact
    on one of ``trees`` (dilated by :data:`CONTACT_MARGIN_ROWS`).

    A body the fit neither measures nor estimates (a free ball beside an arm) is simulated from its noisy logged
    state, so its simulated contacts with the hand come rows earlier or later than the logged ones: the held-out
    check leaves out the rows where either shows one.

    Example:
        >>> m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom type="plane" size="1 1 .1"/><body>'
        ...     '<joint type="slide" axis="0 0 1"/><geom size=".1"/></body></worldbody></mujoco>')
        >>> heights = np.array([[0.5], [0.2], [0.05], [0.3], [0.6], [0.7], [0.8], [0.9]])
        >>> simulated_contact_rows(m, np.arange(2, 10), heights, {0}, 12).nonzero()[0].tolist()
        [2, 3, 4, 5, 6]
    """
    flagged = np.zeros(n_rows, dtype=bool)
    for row, p in zip(rows, _qpos_pairs(model, qpos), strict=True):
        if any(a in trees or b in trees for a, b in p):
            flagged[int(row)] = True
    return _dilate(flagged)


def near_contact_rows(
    log: TrajectoryLog, model: mujoco.MjModel, trees: set[int], reach: float = NEAR_REACH, level: float = NEAR_LEVEL
) -> np.ndarray:
    """(T,) bool: rows where a body of ``trees`` comes within ``level`` noise SDs of touching a body of another
    tree (or the world) in the logged states, dilated by :data:`CONTACT_MARGIN_ROWS`.

    A contact of a few tenths of a millimetre is invisible under a millimetre of position noise: on a
    ``dmc/manipulator-bring_ball`` log the ball touched the thumb a row where its logged distance was +1.0 mm, and
    that row sat 10 noise SDs off in the held-out check. The noise SD of the closest distance is estimated from the
    series itself (its differences of order 2–6, the smallest estimate), as the fit estimates its channels'.

    Args:
        log: the trajectory log.
        model: the model (not modified).
        trees: kinematic trees the parameters move.
        reach: distance (model length units) up to which the closest approach is measured.
        level: noise SDs of distance that count as touching.

    Example:
        >>> m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom type="plane" size="1 1 .1"/><body>'
        ...     '<joint type="slide" axis="0 0 1"/><geom size=".1"/></body></worldbody></mujoco>')
        >>> z = 0.15 - 0.001 * np.arange(60) + np.random.default_rng(0).normal(0, 1e-3, 60)  # 1 mm a row and noise
        >>> int(np.flatnonzero(z < 0.1).min())  # the first logged row in contact (the sphere's radius is 0.1)
        51
        >>> log = TrajectoryLog(time=0.01 * np.arange(60), qpos=z[:, None], qvel=np.zeros((60, 1)),
        ...     ctrl=np.zeros((60, 0)), meta={"timestep": 0.01, "control_timestep": 0.01})
        >>> int(near_contact_rows(log, m, {0}).nonzero()[0].min())
        48
    """
    wide = copy.deepcopy(model)
    wide.geom_margin[:] = model.geom_margin + reach
    data = mujoco.MjData(wide)
    tree_of = model.body_treeid[model.geom_bodyid]
    closest = np.full(log.qpos.shape[0], np.inf)
    for row in range(log.qpos.shape[0]):
        data.qpos[:] = log.qpos[row]
        mujoco.mj_fwdPosition(wide, data)
        for i in range(data.ncon):
            a, b = int(tree_of[data.contact[i].geom1]), int(tree_of[data.contact[i].geom2])
            if a != b and (a in trees or b in trees):
                closest[row] = min(closest[row], float(data.contact[i].dist))
    seen = np.isfinite(closest)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], seen.astype(np.int8), [0]])))
    runs = [closest[lo:hi] for lo, hi in zip(edges[::2], edges[1::2], strict=True)]
    estimates = []
    for k in range(2, 7):
        dk = [np.diff(r, k) for r in runs if r.size >= k + 1]
        flat = np.concatenate(dk) if dk else np.zeros(0)
        if flat.size >= 8:
            estimates.append(math.sqrt(float(np.mean(flat**2)) / math.comb(2 * k, k)))
    if not estimates:
        return _dilate(closest < 0)
    return _dilate(closest < level * min(estimates))


def split_ranges(
    ranges: list[tuple[int, int, int, int]], flagged: np.ndarray, min_kept_share: float = MIN_KEPT_SHARE
) -> list[tuple[int, int, int, int]]:
    """Cuts row ranges ``(first, stop, episode_start, episode_stop)`` around ``flagged`` rows.

    Pieces shorter than :data:`MIN_RANGE_ROWS` are dropped; each piece keeps its episode's bounds (the commands
    before it are still the episode's). Returns ``ranges`` unchanged when nothing is flagged inside them or when
    fewer than ``min_kept_share`` of their rows would remain (0: cut whatever is left, even to nothing).

    Example:
        >>> flagged = np.zeros(40, dtype=bool)
        >>> flagged[15:20] = True
        >>> split_ranges([(2, 40, 0, 40)], flagged)
        [(2, 15, 0, 40), (20, 40, 0, 40)]
        >>> split_ranges([(2, 40, 0, 40)], np.ones(40, dtype=bool))
        [(2, 40, 0, 40)]
    """
    out: list[tuple[int, int, int, int]] = []
    total = kept = 0
    for first, stop, e0, e1 in ranges:
        total += stop - first
        keep = ~flagged[first:stop]
        edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
        for lo, hi in zip(edges[::2], edges[1::2], strict=True):
            if hi - lo >= MIN_RANGE_ROWS:
                out.append((first + int(lo), first + int(hi), e0, e1))
                kept += int(hi - lo)
    if kept == total or kept < min_kept_share * total:
        return list(ranges)
    return out
