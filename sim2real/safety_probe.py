"""Measuring a safety envelope while episodes run: :class:`SafetyMeter` reads ``MjData`` after every control step.

Six quantities per episode (the names :mod:`sim2real.safety` aggregates and gates on):

* ``joint_limit_hits``: control steps on which a limited hinge/slide joint is beyond its range, or MuJoCo's
  limit constraint of any limited joint is active (within ``jnt_margin``);
* ``effort_ratio``: the peak ``|actuator_force| / limit`` over steps and actuators, where the limit is
  ``actuator_forcerange`` when ``forcelimited``, else ``max|ctrlrange| * |gainprm[0]|`` for a direct-force
  actuator (``gaintype`` fixed, no bias: a motor) with a limited control; other actuators declare no limit and are
  left out (NaN when no actuator has one). The limits are the *nominal* model's, read once: a perturbation that
  makes an actuator push harder than the hardware can shows as a ratio above 1;
* ``contact_force``: the peak, over steps and the declared geoms, of the norm of the net contact force on a geom
  (``mj_contactForce`` of each of its contacts, rotated to the world frame and summed), newtons; NaN when no geoms
  are declared;
* ``ee_speed``: the peak linear speed of a declared site, or of a declared body's centre of mass
  (``mj_objectVelocity``), m/s; NaN without one;
* ``joint_speed_ratio``: the peak, over steps and the declared joints, of ``|qvel_j| / limit_j`` (unitless; above
  1.0 is over a limit), limits in rad/s for hinge joints and m/s for slide joints (:func:`speed_joints`); NaN
  without ``max_joint_speed``. The joint that set each episode's peak (its index in :func:`speed_joints`) is kept
  beside it as ``joint_speed_joint`` (-1.0 while every speed was 0), so a violation can name it;
* ``diverged``: 1.0 when the episode's physics diverged (the wrappers' ``diverged`` flag), else 0.0.

Sampling: once per control step, from ``MjData`` as the step leaves it. Contact forces are solved for that state
(``mj_forward`` on a scratch copy: after dm-control's legacy step the data's ``efc_force`` belongs to the previous
contact set). A peak that lives only between two control samples (inside the substeps) is not seen.

Example:
    >>> import mujoco
    >>> from sim2real.safety import SafetyLimits
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body><joint name="j" type="slide" range="-0.1 0.1"/><geom size=".1"/>'
    ...     '</body></worldbody><actuator><motor joint="j" ctrlrange="-1 1"/></actuator></mujoco>')
    >>> data = mujoco.MjData(model)
    >>> meter = SafetyMeter(model, SafetyLimits(), num_envs=1)
    >>> data.qpos[0], data.ctrl[0] = 0.15, 0.5
    >>> mujoco.mj_forward(model, data)
    >>> meter.observe(0, model, data)
    >>> episode = meter.episode(0, diverged=False)
    >>> episode["joint_limit_hits"], episode["effort_ratio"]
    (1.0, 0.5)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import mujoco
import numpy as np

if TYPE_CHECKING:
    from sim2real.safety import SafetyLimits

__all__ = ["QUANTITIES", "SafetyMeter", "SpeedJoint", "speed_joints"]

#: The per-episode quantities, in report order.
QUANTITIES = ("joint_limit_hits", "effort_ratio", "contact_force", "ee_speed", "joint_speed_ratio", "diverged")

_LIMIT_JOINT = int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT)
# Index pairs of a cross product's components: (a x b)[k] = a[k+1] b[k+2] - a[k+2] b[k+1].
_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])
_SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
#: Control steps :meth:`SafetyMeter.observe_batch` checks at once (each numpy call then covers this many steps of every
#: world). 8, 16, 32 and 64 cost about the same on the study's 128-world reacher batches.
_BLOCK = 16


def _rows(array: np.ndarray, columns: np.ndarray) -> np.ndarray | None:
    """``array[:, columns].T``, the ``(columns, N)`` rows of an ``(N, ...)`` batch array, as a view of it where the
    columns are consecutive (a live view: it shows every step's values), else None (gathered at each step)."""
    if columns.size and np.array_equal(columns, np.arange(columns[0], columns[0] + columns.size)):
        return array[:, int(columns[0]) : int(columns[0]) + columns.size].T
    return None


def actuator_limits(model: mujoco.MjModel) -> np.ndarray:
    """``(nu,)`` force limit of each actuator (NaN where none is declared); see the module docstring.

    Example:
        >>> m = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body></worldbody><actuator>'
        ...     '<motor joint="j" ctrlrange="-2 2" gear="3"/><position joint="j" kp="10" forcerange="-5 5"/>'
        ...     '<position joint="j" kp="10"/></actuator></mujoco>')
        >>> actuator_limits(m).tolist()
        [2.0, 5.0, nan]
    """
    limits = np.full(model.nu, np.nan)
    for i in range(model.nu):
        if model.actuator_forcelimited[i]:
            limits[i] = float(np.abs(model.actuator_forcerange[i]).max())
        elif (
            model.actuator_ctrllimited[i]
            and model.actuator_gaintype[i] == mujoco.mjtGain.mjGAIN_FIXED
            and model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_NONE
        ):
            limits[i] = float(np.abs(model.actuator_ctrlrange[i]).max() * abs(model.actuator_gainprm[i, 0]))
    limits[limits <= 0] = np.nan  # a zero range limits nothing measurable
    return limits


class SpeedJoint(NamedTuple):
    """A joint with a declared speed limit, as :class:`SafetyMeter` measures it."""

    joint: int  #: the joint's id
    name: str  #: its name (``#<id>`` when unnamed)
    dof: int  #: its velocity's index in ``qvel``
    limit: float  #: the allowed ``|qvel|``, in :attr:`unit`
    unit: str  #: ``"rad/s"`` (hinge) or ``"m/s"`` (slide)


_SPEED_UNITS = {int(mujoco.mjtJoint.mjJNT_HINGE): "rad/s", int(mujoco.mjtJoint.mjJNT_SLIDE): "m/s"}
_MULTI_DOF = {int(mujoco.mjtJoint.mjJNT_BALL): ("ball", 3), int(mujoco.mjtJoint.mjJNT_FREE): ("free", 6)}


def speed_joints(model: mujoco.MjModel, limits: SafetyLimits) -> tuple[SpeedJoint, ...]:
    """The joints ``limits.max_joint_speed`` declares, in model order, each with its limit and unit.

    Raises:
        ValueError: a name or pattern that matches no joint (close matches listed), a joint given two limits, or a
            ball or free joint (its velocity has several components: no one speed to hold to a limit).

    Example:
        >>> from sim2real.safety import SafetyLimits
        >>> m = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body><joint name="lift" type="slide"/><geom size=".1"/><body>'
        ...     '<joint name="elbow"/><geom size=".1"/></body></body></worldbody></mujoco>')
        >>> [(j.name, j.limit, j.unit) for j in speed_joints(m, SafetyLimits(joint_speeds=(("elbow", 2.6),
        ...                                                                               ("lift", 0.5))))]
        [('lift', 0.5, 'm/s'), ('elbow', 2.6, 'rad/s')]
    """
    from randomizers.parameters import select  # the one resolver of element names

    if limits.speed_joints:
        pairs: list[tuple[str, float | None]] = [(pattern, limits.max_joint_speed) for pattern in limits.speed_joints]
        argument = "max_joint_speed.joints"
    else:
        pairs = list(limits.joint_speeds)
        argument = "max_joint_speed"
    given: dict[int, tuple[str, float]] = {}
    for pattern, limit in pairs:
        assert limit is not None  # SafetyLimits checks that the one-limit form has its limit
        for jid, name in select(model, "joint", pattern, argument):
            kind = int(model.jnt_type[jid])
            if kind in _MULTI_DOF:
                what, size = _MULTI_DOF[kind]
                raise ValueError(
                    f"`{argument}` must select hinge (rad/s) or slide (m/s) joints; {name!r} is a {what} joint, "
                    f"whose velocity has {size} components and no one speed to limit. Received {pattern!r}."
                )
            if jid in given and limits.joint_speeds:  # the one-limit form may match a joint by two patterns
                raise ValueError(
                    f"`{argument}` gives joint {name!r} two limits ({given[jid][0]!r}: {given[jid][1]!r}, "
                    f"{pattern!r}: {limit!r}); each joint takes one. Received {dict(limits.joint_speeds)!r}."
                )
            given[jid] = (pattern, float(limit))
    return tuple(
        SpeedJoint(jid, name, int(model.jnt_dofadr[jid]), given[jid][1], _SPEED_UNITS[int(model.jnt_type[jid])])
        for jid, name in sorted((j, mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}") for j in given)
    )


def _check_can_touch(model: mujoco.MjModel, geoms: np.ndarray, names: Sequence[str]) -> None:
    """Refuses a contact-force limit on geoms none of which can ever touch anything (contype/conaffinity bits that
    match no geom's, in no ``<pair>``): its force would be 0 at every step and the limit could never fail.

    Raises:
        ValueError: naming the geoms and their bits.
    """
    contype, conaffinity = model.geom_contype, model.geom_conaffinity
    paired = set(model.pair_geom1.tolist()) | set(model.pair_geom2.tolist())
    for g in geoms.tolist():
        others = np.arange(model.ngeom) != g
        if g in paired or bool(np.any(((contype[g] & conaffinity) | (contype & conaffinity[g]))[others])):
            return
    raise ValueError(
        f"`max_contact_force.geoms` must select a geom that can touch something; {list(names)} cannot (their "
        "contype/conaffinity bits match no geom's and no <pair> names them), so the force would be 0 at every step. "
        f"Received geoms {list(names)}."
    )


class SafetyMeter:
    """Per-episode safety quantities of ``num_envs`` envs of one model structure, updated step by step.

    Args:
        model: the nominal model (names are resolved and limits read here, once).
        limits: the envelope; its ``contact_geoms``, ``ee_site``/``ee_body`` and joint speed limits say what to
            measure.
        num_envs: envs measured side by side (index ``i`` of :meth:`observe`).

    Raises:
        ValueError: a geom pattern, site, body or joint that the model does not have (close matches listed), or a
            joint speed limit on a ball or free joint; :meth:`sim2real.safety.SafetyLimits.meter` raises it as a
            ``LimitsError``.
    """

    def __init__(self, model: mujoco.MjModel, limits: SafetyLimits, num_envs: int) -> None:
        from randomizers.parameters import select  # the one resolver of element names

        scalar = [j for j in range(model.njnt) if model.jnt_limited[j] and int(model.jnt_type[j]) in _SCALAR_JOINTS]
        # Plain Python tuples: per step, a few scalar comparisons in Python cost ~2 us where each small numpy call
        # costs several (one arm-reach observe: 66 us with numpy calls, 11 us so).
        self._ranges = tuple(
            (int(model.jnt_qposadr[j]), float(model.jnt_range[j, 0]), float(model.jnt_range[j, 1])) for j in scalar
        )
        self._any_limited = bool(np.any(model.jnt_limited))
        limit = actuator_limits(model)
        self._act = np.flatnonzero(np.isfinite(limit))
        if limits.joint_limit_hits is not None and not self._any_limited:
            names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}" for j in range(model.njnt)]
            raise ValueError(
                f'{limits.source}: `joint_limit_hits` needs a limited joint (a `range` with limited="true" or '
                f"autolimits); none of the model's joints {names} has one, so no step could count. Received "
                f"joint_limit_hits={limits.joint_limit_hits!r}."
            )
        if limits.max_effort_ratio is not None and not self._act.size:
            # Unmeasured, the declared limit would never be checked and every policy would "pass" it.
            names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, k) or f"#{k}" for k in range(model.nu)]
            raise ValueError(
                f"{limits.source}: `max_effort_ratio` needs an actuator with a declared force limit (forcelimited "
                "with a forcerange, or a motor with a limited ctrlrange); none of the model's actuators "
                f"{names} has one. Received max_effort_ratio={limits.max_effort_ratio!r}."
            )
        self._scales = tuple((int(k), 1.0 / float(limit[k])) for k in self._act)
        self._geoms = np.zeros(0, np.intp)
        self._object: tuple[int, int] | None = None
        self._body = self._root = -1  # the end-effector's body and its tree's root (mj_objectVelocity's rows)
        self._speeds: tuple[tuple[int, float], ...] = ()  # (qvel index, limit) of each declared joint
        try:
            if limits.speed_joints or limits.joint_speeds:
                self._speeds = tuple((j.dof, j.limit) for j in speed_joints(model, limits))
            if limits.contact_geoms:
                chosen = select(model, "geom", list(limits.contact_geoms), "max_contact_force.geoms")
                self._geoms = np.asarray([i for i, _ in chosen], np.intp)
                _check_can_touch(model, self._geoms, [name for _, name in chosen])
            if limits.ee_site is not None:
                (sid, _), *_ = select(model, "site", limits.ee_site, "max_ee_speed.site")
                self._object = (int(mujoco.mjtObj.mjOBJ_SITE), sid)
            elif limits.ee_body is not None:
                (bid, _), *_ = select(model, "body", limits.ee_body, "max_ee_speed.body")
                self._object = (int(mujoco.mjtObj.mjOBJ_BODY), bid)
        except ValueError as err:
            raise ValueError(f"{limits.source}: {err}") from err
        if self._object is not None:
            objtype, objid = self._object
            self._body = objid if objtype == int(mujoco.mjtObj.mjOBJ_BODY) else int(model.site_bodyid[objid])
            self._root = int(model.body_rootid[self._body])
        self._force6 = np.zeros(6)
        self._vel6 = np.zeros(6)
        self._net = np.zeros((len(self._geoms), 3))
        self._solved: mujoco.MjData | None = None  # scratch data the contact forces are solved in
        self._n = int(num_envs)
        self._pending = 0  # steps observe_batch has copied out and not yet folded (see bind_batch)
        self.reset()

    def reset(self) -> None:
        """Zeroes every env's accumulators (call at the start of a batch of episodes)."""
        n = self._n  # arrays: observe_batch updates all worlds in one operation, observe one element
        self.hits, self.effort, self.contact, self.speed = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
        self.joint_speed, self.fastest = np.zeros(n), np.full(n, -1, np.intp)  # peak ratio, its joint's index
        if self._pending:  # steps observed since the last fold belong to the episodes reset here
            self._pending = 0
            self._seen[:] = True
            self._partial = False
            self._hit[:] = False

    def observe(self, i: int, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Folds env ``i``'s state after a control step (``model``/``data`` of its physics) into its episode's
        peaks and counts."""
        moving = data if self._object is not None else None
        qvel = data.qvel.tolist() if self._speeds else None
        self._fold(i, model, data.qpos.tolist(), qvel, data.nefc, data.actuator_force, data.ncon, lambda: data, moving)

    def bind_batch(self, batch: Any) -> None:
        """Registers the ``mujoco.batch.Batch`` fields :meth:`observe_batch` reads (before the batch's next call: a
        derived field bound between calls holds zeros until then)."""
        if self._pending:
            self._settle()  # steps of a batch bound before are folded against that batch's models
        names = ["qpos", "nefc", "actuator_force", "ncon"] + (["qvel"] if self._speeds else [])
        if self._object is not None:
            body = self._object[0] == int(mujoco.mjtObj.mjOBJ_BODY)
            names += ["cvel", "subtree_com", "xipos" if body else "site_xpos"]
        self._bound = {name: batch.bind(name) for name in names}
        self._scratch: mujoco.MjData | None = None
        n = self._worlds = len(self._bound["qpos"])
        # The checks of observe, as arrays over all worlds at once.
        self._adrs = np.array([adr for adr, _, _ in self._ranges], np.intp)
        self._lows = np.array([low for _, low, _ in self._ranges])
        self._highs = np.array([high for _, _, high in self._ranges])
        self._act_idx = np.array([k for k, _ in self._scales], np.intp)
        self._act_scale = np.array([scale for _, scale in self._scales])
        self._dofs = np.array([dof for dof, _ in self._speeds], np.intp)
        self._speed_limits = np.array([limit for _, limit in self._speeds])
        # Pending steps: what each step's checks read, copied out of the batch (a few row copies per step); the
        # checks run on _BLOCK steps at once (see observe_batch). Component-major, (components, step, world): each
        # component of a block is one contiguous (step, world) array.
        self._pending = 0
        self._partial = False  # a pending step observed only some worlds (`_seen` says which)
        self._models: Sequence[mujoco.MjModel] = ()
        self._seen: np.ndarray = np.ones((_BLOCK, n), bool)
        self._hit: np.ndarray = np.zeros((_BLOCK, n), bool)  # a joint beyond its range, or its limit constraint active
        self._force = np.empty((self._act_idx.size, _BLOCK, n))
        self._beyond = np.empty((2, self._adrs.size, n), bool)  # below / above each range (scratch)
        self._need = np.empty(n, bool)
        bound = self._bound
        self._q_rows = _rows(bound["qpos"], self._adrs)
        # (pending block, the batch's rows copied into it at each step or None, the batch array and the columns
        # gathered from it at each step where they are not one run)
        self._copies: list[tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]] = []
        if self._act_idx.size:
            force = bound["actuator_force"]
            self._copies.append((self._force, _rows(force, self._act_idx), force, self._act_idx))
        if self._dofs.size:
            qvel = bound["qvel"]
            self._qvel = np.empty((self._dofs.size, _BLOCK, n))
            self._copies.append((self._qvel, _rows(qvel, self._dofs), qvel, self._dofs))
        if self._object is not None:
            self._cvel = np.empty((6, _BLOCK, n))
            self._com = np.empty((3, _BLOCK, n))
            self._point = np.empty((3, _BLOCK, n))
            point = bound["xipos"] if "xipos" in bound else bound["site_xpos"]
            for block, array, column in (
                (self._cvel, bound["cvel"], self._body),
                (self._com, bound["subtree_com"], self._root),
                (self._point, point, self._object[1]),
            ):
                self._copies.append((block, array[:, column].T, array, np.array([column])))  # (3 or 6, N) view

    def observe_batch(
        self,
        worlds: Sequence[int] | np.ndarray | None,
        models: Sequence[mujoco.MjModel],
        data_of: Callable[[int], mujoco.MjData],
    ) -> None:
        """:meth:`observe` for worlds stepped in one ``mujoco.batch.Batch`` (after :meth:`bind_batch`): the same
        quantities, bitwise, from the batch's bound ``(N, ...)`` arrays. ``worlds``: the observed worlds (sorted,
        distinct), or None for all of them.

        Per step, only the rows the checks read are copied out of the batch (joint positions, actuator forces, the
        declared joints' velocities, the end-effector's velocity terms); the checks run on :data:`_BLOCK` steps at once,
        a few numpy operations per quantity for every world and step of the block, when the block is full or an
        episode's quantities are read (:meth:`episode`, :meth:`episodes`). Counts and peaks are sums of ones and maxima,
        so folding a block at once gives what folding its steps one by one gives, to the bit. What needs the step's
        whole state is done at the step: a world's whole ``MjData`` is copied out (``data_of(i)``, ~18 us) only when it
        has constraint rows to look through for a joint limit or contacts with a declared geom. The end-effector speed:
        a block in which a bound of every world's speed (``|lin| + |dif| |ang|`` in 1-norms, above the speed) stays
        below the world's peak sets no peak; otherwise it is screened for all worlds and steps of the block at once (the
        same spatial transform as ``mj_objectVelocity``, in numpy) and computed exactly by ``mj_objectVelocity`` (on a
        scratch ``MjData`` holding the three rows it reads) only where the screened speed comes within a margin of 1e-12
        of the terms' size of the world's peak, the highest screened first: a step below that cannot set a new peak, so
        the peaks are :meth:`observe`'s to the bit."""
        bound = self._bound
        if worlds is None:
            idx = None
            sel: Any = slice(None)
        else:
            idx = np.asarray(worlds, dtype=np.intp).reshape(-1)
            if not idx.size:
                return
            sel = slice(None) if idx.size == self._worlds else idx  # sorted distinct: all of them, in order
        t = self._pending
        self._models = models
        if not isinstance(sel, slice):  # every world's rows are copied; the unobserved ones are masked out
            self._partial = True
            self._seen[t] = False
            self._seen[t, idx] = True
        hit = self._hit[t]
        if self._adrs.size:  # every world's row (a few whole-row operations); the unobserved ones are masked out
            q = self._q_rows if self._q_rows is not None else bound["qpos"][:, self._adrs].T  # (joints, N)
            below, above = self._beyond
            np.less(q, self._lows[:, None], out=below)  # NaN is neither, as in observe's comparisons
            np.greater(q, self._highs[:, None], out=above)
            if len(q) == 1:
                np.logical_or(below[0], above[0], out=hit)
            else:
                below |= above
                np.logical_or.reduce(below, axis=0, out=hit)
        if self._any_limited:
            # The worlds within every range that have constraint rows (nefc >= 0: a bool below it is a False
            # above 0): only there can the limit constraint add a hit.
            need = np.less(hit, bound["nefc"], out=self._need)
            if not isinstance(sel, slice):
                need &= self._seen[t]
            if need.any():
                for i in need.nonzero()[0].tolist():
                    data = data_of(i)
                    if _LIMIT_JOINT in data.efc_type[: data.nefc].tolist():
                        hit[i] = True
        for block, rows, array, columns in self._copies:
            block[:, t] = rows if rows is not None else array[:, columns].T
        if len(self._geoms):
            for k in bound["ncon"][sel].nonzero()[0].tolist():
                i = k if idx is None else int(idx[k])
                value = self._contact_peak(models[i], data_of(i))
                if value > self.contact[i]:
                    self.contact[i] = value
        self._pending = t + 1
        if t + 1 == _BLOCK:
            self._settle()

    def _settle_batch(self) -> None:
        if self._pending:  # observe_batch's last steps, not yet folded
            self._settle()

    def _settle(self) -> None:
        """Folds the pending steps of :meth:`observe_batch` into the counts and peaks."""
        steps = self._pending
        seen = self._seen[:steps] if self._partial else None
        hit = self._hit[:steps]
        if seen is not None:
            hit &= seen
        self.hits += np.count_nonzero(hit, axis=0)  # whole numbers: the same sum as adding 1.0 step by step
        if self._act_idx.size:
            terms = np.abs(self._force[:, :steps])
            terms *= self._act_scale[:, None, None]
            ratio = terms[0]
            for j in range(1, len(terms)):
                # Python's max keeps the first of equal or unordered (NaN) values: replace only where strictly >.
                ratio = np.where(terms[j] > ratio, terms[j], ratio)
            if seen is not None:
                ratio = np.where(seen, ratio, np.nan)  # NaN never sets a peak
            # Step by step a ratio replaces the peak when strictly above it (never a NaN): the block's greatest
            # non-NaN ratio does so at once (ratios are >= +0.0, so no signed zero tells the two apart).
            best = np.fmax.reduce(ratio, axis=0)
            np.copyto(self.effort, best, where=best > self.effort)
        if self._dofs.size:
            self._settle_joint_speeds(steps, seen)
        if self._object is not None:
            self._settle_speeds(steps, seen)
        self._pending = 0
        hit[...] = False  # a step writes its row of joint-limit hits where it has ranges to check
        if self._partial:
            self._seen[:steps] = True
            self._partial = False

    def _settle_joint_speeds(self, steps: int, seen: np.ndarray | None) -> None:
        """The joint speed ratios of the pending steps into their peaks, with the joint that set each: the same
        divisions as :meth:`_fold`'s, the same first-of-equals over joints and over steps."""
        terms = np.abs(self._qvel[:, :steps])
        terms /= self._speed_limits[:, None, None]
        ratio, joint = terms[0], np.zeros(terms.shape[1:], np.intp)
        for j in range(1, len(terms)):
            faster = terms[j] > ratio  # a NaN ratio is never replaced, as in _fold's comparisons
            ratio = np.where(faster, terms[j], ratio)
            joint[faster] = j
        if seen is not None:
            ratio = np.where(seen, ratio, np.nan)  # NaN never sets a peak
        best = np.fmax.reduce(ratio, axis=0)
        first = np.argmax(ratio == best, axis=0)  # the block's first step at its peak (a later equal one sets none)
        new = best > self.joint_speed
        np.copyto(self.joint_speed, best, where=new)
        np.copyto(self.fastest, np.take_along_axis(joint, first[None], axis=0)[0], where=new)

    def _settle_speeds(self, steps: int, seen: np.ndarray | None) -> None:
        """The end-effector speeds of the pending steps into their peaks (see :meth:`observe_batch`)."""
        assert self._object is not None
        objtype, objid = self._object
        cvel, com, point = self._cvel[:, :steps], self._com[:, :steps], self._point[:, :steps]
        ang, lin = cvel[:3], cvel[3:]
        dif = point - com
        work = np.abs(lin)
        scale = np.add.reduce(work)
        np.abs(ang, out=work)
        size = np.add.reduce(work)
        np.abs(dif, out=work)
        size *= np.add.reduce(work)
        scale += size  # >= |lin| + |dif| |ang| >= the speed, the exact one within a few ulps of it
        bound = scale * (1.0 + 2e-12)
        bound += 1e-300
        below = bound < self.speed
        if seen is not None:
            below |= ~seen
        if below.all():  # no step of the block comes near a peak (most blocks once an episode's peaks are set)
            return
        # lin - dif x ang: mj_objectVelocity's transform of the body's spatial velocity to the point.
        moved = lin - (dif[_NEXT] * ang[_PREV] - dif[_PREV] * ang[_NEXT])
        moved *= moved
        reach = np.sqrt(np.add.reduce(moved))
        # MuJoCo's own sums may differ in the last bits (order, fused multiply-adds): far below this margin.
        scale *= 1e-12
        reach += scale
        reach += 1e-300
        candidate = ~(reach < self.speed)  # NaN screens as a candidate: the exact path decides
        if seen is not None:
            candidate &= seen
        when, where = candidate.nonzero()
        if not when.size:
            return
        # Highest screened speed first: once a world's peak is set, its lower steps screen out.
        order = np.argsort(-reach[when, where], kind="stable").tolist()
        when_l, where_l, models, speed = when.tolist(), where.tolist(), self._models, self.speed
        body, root, velocity = self._body, self._root, self._vel6
        moving = self._scratch
        if moving is None:
            moving = self._scratch = mujoco.MjData(models[0])
        xpos = moving.xipos if objtype == int(mujoco.mjtObj.mjOBJ_BODY) else moving.site_xpos
        for k in order:
            t, i = when_l[k], where_l[k]
            if reach[t, i] < speed[i]:
                continue
            moving.cvel[body] = cvel[:, t, i]
            moving.subtree_com[root] = com[:, t, i]
            xpos[objid] = point[:, t, i]
            mujoco.mj_objectVelocity(models[i], moving, objtype, objid, velocity, 0)
            value = math.hypot(velocity[3], velocity[4], velocity[5])
            if value > speed[i]:
                speed[i] = value

    def _fold(
        self,
        i: int,
        model: mujoco.MjModel,
        qpos: list[float],
        qvel: list[float] | None,
        nefc: int,
        force_row: np.ndarray,
        ncon: int,
        full: Callable[[], mujoco.MjData],
        moving: mujoco.MjData | None,
    ) -> None:
        """One step of env ``i`` into its peaks and counts: ``full()`` gives its whole ``MjData`` (asked for only
        to look through constraint rows or contacts), ``moving`` the data ``mj_objectVelocity`` reads."""
        data: mujoco.MjData | None = None
        hit = False
        for adr, low, high in self._ranges:
            value = qpos[adr]
            if value < low or value > high:
                hit = True
                break
        if not hit and self._any_limited and nefc:
            data = full()
            hit = _LIMIT_JOINT in data.efc_type[: data.nefc].tolist()
        if hit:
            self.hits[i] += 1.0
        if self._scales:
            force = force_row.tolist()
            ratio = max(abs(force[k]) * scale for k, scale in self._scales)
            if ratio > self.effort[i]:
                self.effort[i] = ratio
        if qvel is not None:
            # abs(v) / limit: the division observe_batch makes (no reciprocal: a product could differ in the last bit).
            # max keeps the first of equal or unordered (NaN) values; index finds that same first one.
            ratios = [abs(qvel[dof]) / limit for dof, limit in self._speeds]
            ratio = max(ratios)
            if ratio > self.joint_speed[i]:
                self.joint_speed[i], self.fastest[i] = ratio, ratios.index(ratio)
        if len(self._geoms) and ncon:
            peak = self._contact_peak(model, data if data is not None else full())
            if peak > self.contact[i]:
                self.contact[i] = peak
        if moving is not None and self._object is not None:
            velocity = self._vel6
            mujoco.mj_objectVelocity(model, moving, self._object[0], self._object[1], velocity, 0)
            speed = math.hypot(velocity[3], velocity[4], velocity[5])
            if speed > self.speed[i]:
                self.speed[i] = speed

    def _sides(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """``(ncon, G)`` masks: contact ``k`` has declared geom ``g`` as its geom1 / as its geom2."""
        pairs = data.contact.geom[: data.ncon]
        return pairs[:, 0, None] == self._geoms[None, :], pairs[:, 1, None] == self._geoms[None, :]

    def _contact_peak(self, model: mujoco.MjModel, data: mujoco.MjData) -> float:
        side1, side2 = self._sides(data)
        if not (side1.any() or side2.any()):
            return 0.0
        # The forces are solved for the state as it is, in a scratch copy: after dm-control's legacy step
        # (mj_step2, then mj_step1) the contacts are the new state's but efc_force is the previous solve's, and a
        # constraint row that did not exist then reads whatever the arena held (seen: 1.4e146 N).
        data = self._solve(model, data)
        side1, side2 = self._sides(data)
        touching = np.flatnonzero(side1.any(1) | side2.any(1))
        if not len(touching):
            return 0.0
        net = self._net
        net[:] = 0.0
        frames = data.contact.frame
        for k in touching.tolist():
            mujoco.mj_contactForce(model, data, k, self._force6)
            # The contact frame's first row is the normal, from geom1 towards geom2: +f acts on geom2, -f on geom1.
            world = frames[k].reshape(3, 3).T @ self._force6[:3]
            net[side2[k]] += world
            net[side1[k]] -= world
        return float(np.linalg.norm(net, axis=1).max())

    def _solve(self, model: mujoco.MjModel, data: mujoco.MjData) -> mujoco.MjData:
        """``data`` copied into a scratch ``MjData`` and ``mj_forward`` there: contacts and their forces of the
        same state (the env's own data is not touched; its next step is unchanged)."""
        solved = self._solved
        if solved is None or solved.nbuffer != data.nbuffer:
            solved = self._solved = mujoco.MjData(model)
        mujoco.mj_copyData(solved, model, data)
        mujoco.mj_forward(model, solved)
        return solved

    def episode(self, i: int, *, diverged: bool) -> dict[str, float]:
        """Env ``i``'s quantities for the episode observed since :meth:`reset` (see :data:`QUANTITIES`)."""
        self._settle_batch()
        return {
            "joint_limit_hits": float(self.hits[i]),
            "effort_ratio": float(self.effort[i]) if len(self._act) else float("nan"),
            "contact_force": float(self.contact[i]) if len(self._geoms) else float("nan"),
            "ee_speed": float(self.speed[i]) if self._object is not None else float("nan"),
            "joint_speed_ratio": float(self.joint_speed[i]) if self._speeds else float("nan"),
            "diverged": 1.0 if diverged else 0.0,
            **({"joint_speed_joint": float(self.fastest[i])} if self._speeds else {}),
        }

    def episodes(self, diverged: np.ndarray) -> dict[str, np.ndarray]:
        """Every env's quantities as ``{quantity: (num_envs,) float64}``."""
        self._settle_batch()
        nan = np.full(self._n, np.nan)
        return {
            "joint_limit_hits": np.array(self.hits),
            "effort_ratio": np.array(self.effort) if len(self._act) else nan.copy(),
            "contact_force": np.array(self.contact) if len(self._geoms) else nan.copy(),
            "ee_speed": np.array(self.speed) if self._object is not None else nan.copy(),
            "joint_speed_ratio": np.array(self.joint_speed) if self._speeds else nan.copy(),
            "diverged": np.asarray(diverged, dtype=np.float64).copy(),
            **({"joint_speed_joint": self.fastest.astype(np.float64)} if self._speeds else {}),
        }
