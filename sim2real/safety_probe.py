"""Measuring a safety envelope while episodes run: :class:`SafetyMeter` reads ``MjData`` after every control step.

Five quantities per episode (the names :mod:`sim2real.safety` aggregates and gates on):

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
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

if TYPE_CHECKING:
    from sim2real.safety import SafetyLimits

__all__ = ["QUANTITIES", "SafetyMeter"]

#: The per-episode quantities, in report order.
QUANTITIES = ("joint_limit_hits", "effort_ratio", "contact_force", "ee_speed", "diverged")

_LIMIT_JOINT = int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT)
# Index pairs of a cross product's components: (a x b)[k] = a[k+1] b[k+2] - a[k+2] b[k+1].
_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])
_SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


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


class SafetyMeter:
    """Per-episode safety quantities of ``num_envs`` envs of one model structure, updated step by step.

    Args:
        model: the nominal model (names are resolved and limits read here, once).
        limits: the envelope; its ``contact_geoms`` and ``ee_site``/``ee_body`` say what to measure.
        num_envs: envs measured side by side (index ``i`` of :meth:`observe`).

    Raises:
        ValueError: a geom pattern, site or body that the model does not have (close matches listed);
            :meth:`sim2real.safety.SafetyLimits.meter` raises it as a ``LimitsError``.
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
        self._scales = tuple((int(k), 1.0 / float(limit[k])) for k in self._act)
        self._geoms = np.zeros(0, np.intp)
        self._object: tuple[int, int] | None = None
        try:
            if limits.contact_geoms:
                chosen = select(model, "geom", list(limits.contact_geoms), "max_contact_force.geoms")
                self._geoms = np.asarray([i for i, _ in chosen], np.intp)
            if limits.ee_site is not None:
                (sid, _), *_ = select(model, "site", limits.ee_site, "max_ee_speed.site")
                self._object = (int(mujoco.mjtObj.mjOBJ_SITE), sid)
            elif limits.ee_body is not None:
                (bid, _), *_ = select(model, "body", limits.ee_body, "max_ee_speed.body")
                self._object = (int(mujoco.mjtObj.mjOBJ_BODY), bid)
        except ValueError as err:
            raise ValueError(f"{limits.source}: {err}") from err
        self._force6 = np.zeros(6)
        self._vel6 = np.zeros(6)
        self._net = np.zeros((len(self._geoms), 3))
        self._solved: mujoco.MjData | None = None  # scratch data the contact forces are solved in
        self._n = int(num_envs)
        self.reset()

    def reset(self) -> None:
        """Zeroes every env's accumulators (call at the start of a batch of episodes)."""
        n = self._n  # arrays: observe_batch updates all worlds in one operation, observe one element
        self.hits, self.effort, self.contact, self.speed = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)

    def observe(self, i: int, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Folds env ``i``'s state after a control step (``model``/``data`` of its physics) into its episode's
        peaks and counts."""
        moving = data if self._object is not None else None
        self._fold(i, model, data.qpos.tolist(), data.nefc, data.actuator_force, data.ncon, lambda: data, moving)

    def bind_batch(self, batch: Any) -> None:
        """Registers the ``mujoco.batch.Batch`` fields :meth:`observe_batch` reads (before the batch's next call: a
        derived field bound between calls holds zeros until then)."""
        names = ["qpos", "nefc", "actuator_force", "ncon"]
        if self._object is not None:
            body = self._object[0] == int(mujoco.mjtObj.mjOBJ_BODY)
            names += ["cvel", "subtree_com", "xipos" if body else "site_xpos"]
        self._bound = {name: batch.bind(name) for name in names}
        self._scratch: mujoco.MjData | None = None
        self._worlds = len(self._bound["qpos"])
        # The checks of observe, as arrays over all worlds at once.
        self._adrs = np.array([adr for adr, _, _ in self._ranges], np.intp)
        self._lows = np.array([low for _, low, _ in self._ranges])
        self._highs = np.array([high for _, _, high in self._ranges])
        self._act_idx = np.array([k for k, _ in self._scales], np.intp)
        self._act_scale = np.array([scale for _, scale in self._scales])

    def observe_batch(
        self,
        worlds: Sequence[int] | np.ndarray,
        models: Sequence[mujoco.MjModel],
        data_of: Callable[[int], mujoco.MjData],
    ) -> None:
        """:meth:`observe` for worlds stepped in one ``mujoco.batch.Batch`` (after :meth:`bind_batch`): the same
        quantities, bitwise, from the batch's bound ``(N, ...)`` arrays, a few numpy operations per quantity for all
        ``worlds``. A world's whole ``MjData`` is copied out (``data_of(i)``, ~18 us) only when it has constraint
        rows to look through for a joint limit or contacts with a declared geom. The end-effector speed is screened
        for all worlds at once (the same spatial transform as ``mj_objectVelocity``, in numpy) and computed exactly
        by ``mj_objectVelocity`` (on a scratch ``MjData`` holding the three arrays it reads) only for the worlds
        whose screened speed comes within a margin of 1e-12 of the terms' size of their peak: a world below that
        cannot set a new peak, so the peaks are :meth:`observe`'s to the bit."""
        bound = self._bound
        idx = np.asarray(worlds, dtype=np.intp).reshape(-1)
        if not idx.size:
            return
        every = idx.size == self._worlds  # sorted distinct worlds: all of them, in order (views, no copies)
        sel: Any = slice(None) if every else idx

        def at(mask: np.ndarray) -> np.ndarray:  # the worlds where ``mask`` (over the observed ones) holds
            return np.flatnonzero(mask) if every else idx[mask]

        if self._adrs.size:
            q = bound["qpos"][sel][:, self._adrs]
            hit = ((q < self._lows) | (q > self._highs)).any(axis=1)  # NaN is neither, as in observe's comparisons
        else:
            hit = np.zeros(idx.size, bool)
        if self._any_limited:
            for k in np.flatnonzero(~hit & (bound["nefc"][sel] != 0)).tolist():
                data = data_of(int(idx[k]))
                hit[k] = _LIMIT_JOINT in data.efc_type[: data.nefc].tolist()
        if hit.any():
            self.hits[at(hit)] += 1.0
        if self._act_idx.size:
            terms = np.abs(bound["actuator_force"][sel][:, self._act_idx]) * self._act_scale
            ratio = terms[:, 0]
            for j in range(1, terms.shape[1]):
                # Python's max keeps the first of equal or unordered (NaN) values: replace only where strictly >.
                ratio = np.where(terms[:, j] > ratio, terms[:, j], ratio)
            peak = ratio > self.effort[sel]
            if peak.any():
                self.effort[at(peak)] = ratio[peak]
        if len(self._geoms):
            for k in np.flatnonzero(bound["ncon"][sel] != 0).tolist():
                i = int(idx[k])
                value = self._contact_peak(models[i], data_of(i))
                if value > self.contact[i]:
                    self.contact[i] = value
        if self._object is not None:
            self._speeds(idx, sel, models)

    def _speeds(self, idx: np.ndarray, sel: Any, models: Sequence[mujoco.MjModel]) -> None:
        """The end-effector speed of the worlds ``idx`` (``sel`` of the batch) into their peaks (see
        :meth:`observe_batch`)."""
        assert self._object is not None
        bound = self._bound
        objtype, objid = self._object
        body = objid if objtype == int(mujoco.mjtObj.mjOBJ_BODY) else int(models[0].site_bodyid[objid])
        root = int(models[0].body_rootid[body])
        point_all = bound["xipos"] if "xipos" in bound else bound["site_xpos"]
        cvel = bound["cvel"][sel, body]
        dif = point_all[sel, objid] - bound["subtree_com"][sel, root]
        ang, lin = cvel[:, :3], cvel[:, 3:]
        # lin - dif x ang: mj_objectVelocity's transform of the body's spatial velocity to the point.
        moved = lin - (dif[:, _NEXT] * ang[:, _PREV] - dif[:, _PREV] * ang[:, _NEXT])
        screened = np.einsum("ij,ij->i", moved, moved)
        scale = np.abs(lin).sum(axis=1) + np.abs(dif).sum(axis=1) * np.abs(ang).sum(axis=1)  # >= the terms' norms
        # MuJoCo's own sums may differ in the last bits (order, fused multiply-adds): far below this margin.
        reach = np.sqrt(screened) + 1e-12 * scale + 1e-300
        candidates = np.flatnonzero(~(reach < self.speed[sel]))  # NaN screens as a candidate: the exact path decides
        velocity = self._vel6
        for k in candidates.tolist():
            i = int(idx[k])
            moving = self._scratch
            if moving is None:
                moving = self._scratch = mujoco.MjData(models[i])
            moving.cvel[...] = bound["cvel"][i]
            moving.subtree_com[...] = bound["subtree_com"][i]
            (moving.xipos if "xipos" in bound else moving.site_xpos)[...] = point_all[i]
            mujoco.mj_objectVelocity(models[i], moving, objtype, objid, velocity, 0)
            speed = math.hypot(velocity[3], velocity[4], velocity[5])
            if speed > self.speed[i]:
                self.speed[i] = speed

    def _fold(
        self,
        i: int,
        model: mujoco.MjModel,
        qpos: list[float],
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
        return {
            "joint_limit_hits": float(self.hits[i]),
            "effort_ratio": float(self.effort[i]) if len(self._act) else float("nan"),
            "contact_force": float(self.contact[i]) if len(self._geoms) else float("nan"),
            "ee_speed": float(self.speed[i]) if self._object is not None else float("nan"),
            "diverged": 1.0 if diverged else 0.0,
        }

    def episodes(self, diverged: np.ndarray) -> dict[str, np.ndarray]:
        """Every env's quantities as ``{quantity: (num_envs,) float64}``."""
        nan = np.full(self._n, np.nan)
        return {
            "joint_limit_hits": np.array(self.hits),
            "effort_ratio": np.array(self.effort) if len(self._act) else nan.copy(),
            "contact_force": np.array(self.contact) if len(self._geoms) else nan.copy(),
            "ee_speed": np.array(self.speed) if self._object is not None else nan.copy(),
            "diverged": np.asarray(diverged, dtype=np.float64).copy(),
        }
