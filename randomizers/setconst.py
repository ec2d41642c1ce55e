"""What ``mujoco.mj_setConst`` writes, and running it without clobbering what an env or the nominal owns.

``mj_setConst`` recomputes every derived constant of an ``MjModel`` from its inputs. After a mass,
inertia or armature draw only some of those outputs really change (inverse weights, ``dof_M0``,
``actuator_acc0``, subtree masses and centres of mass); the rest are functions of the kinematics and
of the model's structure. Some of the latter are edited by environments at run time: a mocap-driven
arm writes its weld's relative pose into ``eq_data``, which ``mj_setConst`` recomputes from ``qpos0``.

:class:`SetConst` therefore splits the outputs in two, by what the bound effects write:

* **derived** outputs (they depend on an array an effect writes) are recomputed by every run,
  snapshotted at bind and written back bitwise by :meth:`SetConst.restore`;
* **kept** outputs (they do not) are saved before every run and written back after it, so
  ``mj_setConst`` never changes them: an env's run-time edits survive and the nominal stays bitwise.

The list of outputs is MuJoCo's own: ``MJSETCONST_ARRAYS`` in ``include/mujoco/mjxmacro.h`` of MuJoCo
3.17.0, every array with ``mjSC_OUT`` in some group (``tests/test_setconst.py`` checks it against the
header of the installed wheel). The scalars it writes (``ngravcomp``, ``npolygonmax``,
``nmeshdegmax``, ``flg_gravcomp``, ``flg_surfacevel``, ``flg_adhesion``) depend only on gravity
compensation, meshes, surface velocities and adhesion, which no effect writes, so a run rewrites
them unchanged. MuJoCo 3.17's ``mj_setConst`` does not touch ``model.stat``.

``mj_setConst`` needs an ``MjData`` to compute in (it sets the state to ``qpos0``, then ``qpos_spring``, and
computes everything it reads from them). Making one costs ~0.3 ms of Python binding, more than the model copy of
a batched world, so the scratch is shared, per thread, by every :class:`SetConst` whose model has the same sizes
and starts a fresh ``MjData`` the same way (same sleep policy and flags; models with mocap bodies or plugins,
whose fresh data depends on their values, keep their own); ``tests/test_setconst.py`` checks bitwise equality
with a scratch of the model's own.

Example:
    >>> import mujoco
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="arm"><joint/><geom size=".1"/></body></worldbody></mujoco>')
    >>> sc = SetConst(model, {"body_mass"})
    >>> "dof_M0" in sc.derived, "body_sameframe" in sc.kept
    (True, True)
    >>> model.body_mass[1] *= 2
    >>> sc.run()
    >>> model.body_mass[1] /= 2
    >>> sc.restore()
    >>> bool((model.body_subtreemass == mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="arm"><joint/><geom size=".1"/></body></worldbody></mujoco>'
    ...     ).body_subtreemass).all())
    True
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

import mujoco
import numpy as np

__all__ = ["DERIVED_FROM", "OUTPUTS", "SetConst"]

# inert0: the inertia matrix in qpos0 and what is solved from it
_INERTIA_MATRIX = (
    "body_invweight0",
    "dof_invweight0",
    "dof_M0",
    "flexedge_invweight0",
    "tendon_invweight0",
    "actuator_acc0",
)
# spring: kinematics in qpos_spring (the implicit flex metric factor)
_FLEX_METRIC = ("efm0_dofid", "efm0_L_rownnz", "efm0_L_rowadr", "efm0_L_colind", "efm0_L", "efmC_perm")

#: Every ``MjModel`` array ``mj_setConst`` writes, by group (MuJoCo 3.17.0 ``MJSETCONST_ARRAYS``).
OUTPUTS: tuple[str, ...] = (
    # fixed: independent of the configuration
    "body_treeid",
    "body_sameframe",
    "body_subtreemass",
    "body_margin",
    "body_contype",
    "body_conaffinity",
    "bvh_aabb",
    "jnt_actuatorid",
    "tree_bodyadr",
    "tree_bodynum",
    "tree_dofadr",
    "tree_dofnum",
    "tree_sleep_policy",
    "geom_sameframe",
    "geom_size",
    "geom_aabb",
    "geom_rbound",
    "geom_fluid",
    "site_sameframe",
    "flex_vertedgeadr",
    "flex_vertedgenum",
    "flex_vertedge",
    "flex_vertmetric",
    "flexedge_J_rownnz",
    "flexedge_J_rowadr",
    "flexedge_J_colind",
    "flexvert_J_rownnz",
    "flexvert_J_rowadr",
    "flexvert_J_colind",
    "tendon_actuatorid",
    "tendon_treenum",
    "tendon_treeid",
    "ten_J_rownnz",
    "ten_J_rowadr",
    "ten_J_colind",
    # kin0: kinematics in qpos0
    "dof_length",
    "cam_poscom0",
    "cam_pos0",
    "cam_mat0",
    "light_poscom0",
    "light_pos0",
    "light_dir0",
    "flexedge_length0",
    "eq_data",
    "tendon_length0",
    "actuator_length0",
    *_INERTIA_MATRIX,
    *_FLEX_METRIC,
)

_SUBTREE_COM = ("cam_poscom0", "light_poscom0")
# Everything solved from the inertia matrix in qpos0 (masses, inertias, inertial frames, armature).
_MASS_MATRIX = (*_INERTIA_MATRIX, *_FLEX_METRIC)

#: For each input an effect may write, the outputs of ``mj_setConst`` that depend on it (read off
#: ``engine_setconst.c``: subtree masses and centres of mass, the inertia matrix in ``qpos0`` and what
#: is solved from it, the mass-weighted flex metric; the inertial frame also sets the same-frame
#: flags, joint lengths and body bounding volumes). An input missing here makes every output derived.
DERIVED_FROM: dict[str, tuple[str, ...]] = {
    "body_mass": ("body_subtreemass", "flex_vertmetric", *_SUBTREE_COM, *_MASS_MATRIX),
    "body_inertia": _INERTIA_MATRIX,
    "dof_armature": _MASS_MATRIX,
    "body_ipos": (
        "body_sameframe",
        "geom_sameframe",
        "site_sameframe",
        "bvh_aabb",
        "dof_length",
        *_SUBTREE_COM,
        *_MASS_MATRIX,
    ),
}
DERIVED_FROM["body_iquat"] = DERIVED_FROM["body_ipos"]


# Per thread: scratch key -> MjData (mj_setConst runs without the GIL, so threads must not share a scratch).
_LOCAL = threading.local()
_MAX_SCRATCH = 8  # distinct model layouts kept per thread; more clears the cache (a scratch is remade on demand)
_SIZE_NAMES: list[str] = []  # the integer size fields of MjModel (nq, nv, ..., narena, nbuffer)
_Key = tuple[tuple[int, ...], int, int, bytes]  # sizes, enable and disable flags, tree sleep policies
_PRESENT: dict[tuple[int, ...], tuple[str, ...]] = {}  # sizes -> the OUTPUTS a model with them has (non-empty)


def _scratch_key(model: mujoco.MjModel) -> _Key | None:
    """What a fresh ``MjData`` of ``model`` depends on, as far as ``mj_setConst`` reads it: the sizes (the layout),
    the flags and sleep policy its reset reads. None for a model whose fresh data depends on more of its values
    (mocap bodies start at ``body_pos``, plugins initialise their own state): those keep a scratch of their own."""
    if model.nmocap or model.nplugin:
        return None
    if not _SIZE_NAMES:
        _SIZE_NAMES.extend(n for n in dir(mujoco.MjModel) if n.startswith("n") and isinstance(getattr(model, n), int))
    sizes = tuple([getattr(model, n) for n in _SIZE_NAMES])
    opt = model.opt
    return sizes, opt.enableflags, opt.disableflags, model.tree_sleep_policy.tobytes()


def _shared_scratch(model: mujoco.MjModel, key: _Key) -> mujoco.MjData:
    """This thread's scratch ``MjData`` for models with ``key`` (made for ``model`` on first use)."""
    cache: dict[_Key, mujoco.MjData] | None = getattr(_LOCAL, "scratch", None)
    if cache is None:
        cache = _LOCAL.scratch = {}
    data = cache.get(key)
    if data is None:
        if len(cache) >= _MAX_SCRATCH:
            cache.clear()
        data = cache[key] = mujoco.MjData(model)
    return data


class SetConst:
    """Runs ``mj_setConst`` on one model after effects wrote ``inputs``, keeping what they do not own.

    Args:
        model: the compiled model (its current values are the nominal snapshot of the derived outputs).
        inputs: names of the model arrays the effects write (e.g. ``{"body_mass", "body_inertia"}``).

    Attributes:
        derived: outputs recomputed by :meth:`run` and written back by :meth:`restore`.
        kept: outputs :meth:`run` leaves exactly as they were before it.
    """

    def __init__(self, model: mujoco.MjModel, inputs: Iterable[str]) -> None:
        inputs = set(inputs)
        self._key = _scratch_key(model)
        present = None if self._key is None else _PRESENT.get(self._key[0])
        if present is None:
            present = tuple(f for f in OUTPUTS if np.size(getattr(model, f, ())) > 0)
            if self._key is not None:  # which outputs a model has follows from its sizes
                _PRESENT[self._key[0]] = present
        known = not inputs - DERIVED_FROM.keys()
        derived = {f for i in inputs for f in DERIVED_FROM[i]} if known else set(OUTPUTS)
        self.model = model
        self.derived: tuple[str, ...] = tuple(f for f in present if f in derived)
        self.kept: tuple[str, ...] = tuple(f for f in present if f not in derived)
        self._nominal = {f: getattr(model, f).copy() for f in self.derived}
        # Buffers by name, the arrays read off the model on every run: views kept here would not follow the model
        # through a pickle or a deep copy of the randomiser.
        self._saved = {f: np.empty_like(getattr(model, f)) for f in self.kept}
        # Made now, as a fresh MjData of the model as it is at bind (its mocap bodies at their nominal poses).
        self._scratch = mujoco.MjData(model) if self._key is None else None

    def run(self) -> None:
        """``mj_setConst`` on a scratch ``MjData``; the kept outputs hold what they held before."""
        model, saved, key = self.model, self._saved, self._key
        scratch = self._scratch if key is None else _shared_scratch(model, key)
        for f, buf in saved.items():
            np.copyto(buf, getattr(model, f))
        try:
            mujoco.mj_setConst(model, scratch)
        except Exception:
            if key is not None:  # a failed run may leave the scratch's stack marked: the next run starts afresh
                _LOCAL.scratch.pop(key, None)
            raise
        for f, buf in saved.items():
            np.copyto(getattr(model, f), buf)

    def restore(self) -> None:
        """Writes the nominal snapshot of every derived output back (bitwise)."""
        for f, snapshot in self._nominal.items():
            np.copyto(getattr(self.model, f), snapshot)
