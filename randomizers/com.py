"""Centre-of-mass offsets of bodies (``body_ipos``): an unmodelled payload, a battery mounted off-centre.

Example:
    >>> import mujoco
    >>> from randomizers import PhysicsRandomizer, Uniform
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="arm"><joint name="a"/><geom size=".1" pos=".2 0 0"/></body>'
    ...     '</worldbody></mujoco>')
    >>> r = PhysicsRandomizer([BodyComOffset(add=Uniform(-0.01, 0.01), bodies="arm", axis=["x", "z"])], seed=0)
    >>> r.bind(model, mujoco.MjData(model))
    >>> r.begin_episode(); r.apply()
    >>> sorted(r.current_params)
    ['body_ipos[arm][0]', 'body_ipos[arm][2]']
    >>> r.restore_nominal(); model.body_ipos[1].tolist()
    [0.2, 0.0, 0.0]
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from randomizers.addressing import GRAVITY_AXES, Address, select_massive
from randomizers.distributions import Distribution
from randomizers.effects import ArrayEffect, Binding, Schedule, choose_components

__all__ = ["BodyComOffset"]


class _ComBinding(Binding):
    # The centre of mass enters the inertia-derived constants (dof_M0, invweights, actuator_acc0).
    set_const_inputs = frozenset(("body_ipos",))
    needs_set_const = True

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        model = self.model
        # MuJoCo compiles a body whose centre of mass sits at its frame origin as "simple" (a diagonal mass-matrix
        # block, dof_simplenum); moving the centre of mass breaks that, and mj_setConst refuses a simple body
        # whose frames no longer coincide. While the effect is bound, its bodies take MuJoCo's general path
        # (the compiled dynamics are the same, only the shortcut is off); restore() puts the flags back bitwise.
        self._simple_nominal = model.body_simple.copy()
        self._simplenum_nominal = model.dof_simplenum.copy()
        rows = np.unique(self._targets[0])
        dofs = np.bincount(model.dof_bodyid, minlength=model.nbody)
        locked = [int(b) for b in rows if self._simple_nominal[b] and dofs[b] > 1]
        if locked:
            names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"#{b}" for b in locked]
            raise ValueError(
                f"BodyComOffset cannot move the centre of mass of {names}: MuJoCo compiled "
                f"{'these bodies' if len(names) > 1 else 'this body'} as 'simple' (frames coincide, several dofs), "
                'so the mass matrix has no entries for the coupling an offset creates. Add simple="false" to the '
                "<body> in the MJCF (MjSpec: body.simple = False) or leave it out of `bodies`. "
                f"Received bodies={self.effect.patterns!r}."
            )
        simple = self._simple_nominal.copy()
        simple[rows] = 0
        self._simple = simple
        self._simplenum = _simple_dof_runs(simple, model.dof_bodyid)

    def apply(self, values: np.ndarray) -> None:
        self.model.body_simple[:] = self._simple
        self.model.dof_simplenum[:] = self._simplenum
        super().apply(values)

    def restore(self) -> None:
        super().restore()
        self.model.body_simple[:] = self._simple_nominal
        self.model.dof_simplenum[:] = self._simplenum_nominal


def _simple_dof_runs(body_simple: np.ndarray, dof_bodyid: np.ndarray) -> np.ndarray:
    """``dof_simplenum`` for the given simple-body flags: how many consecutive dofs from each dof on belong to
    simple bodies (as MuJoCo's compiler counts them)."""
    runs = np.zeros(len(dof_bodyid), dtype=np.int32)
    following = 0
    for i in range(len(dof_bodyid) - 1, -1, -1):
        following = following + 1 if body_simple[dof_bodyid[i]] else 0
        runs[i] = following
    return runs


class BodyComOffset(ArrayEffect):
    """Shifts bodies' centres of mass (``body_ipos``, body frame, metres) along ``axis``; the randomiser runs
    ``mujoco.mj_setConst`` afterwards. Offsets may be negative. The world body and bodies of zero mass (no centre
    of mass to move) are never selected; a pattern matching massless bodies only is refused.

    Args:
        scale | add | set: the operation and its distribution (``add`` is the usual one: an offset in metres).
        bodies: name pattern(s) of the bodies (default all).
        axis: ``"x"``, ``"y"``, ``"z"`` or a list of them (default all three); reported as
            ``body_ipos[<body>][0|1|2]``.
        shared: one draw for every selected body and axis instead of one each.
        schedule: ``"reset"`` (default), ``"startup"`` or :class:`~randomizers.Interval`.
        name: stable stream name.

    Example:
        >>> from randomizers import Uniform
        >>> BodyComOffset(add=Uniform(-0.01, 0.01), bodies="hand", axis="z")
        BodyComOffset(add=Uniform(low=-0.01, high=0.01), bodies='hand', axis=['z'])
        >>> BodyComOffset(add=0.01, axis="w")
        Traceback (most recent call last):
        ...
        ValueError: `axis` of BodyComOffset must be one or more of ['x', 'y', 'z']. Received 'w'.
    """

    field = "body_ipos"
    kind = "body"
    selector = "bodies"
    nonnegative = False
    binding_class = _ComBinding
    components = ("axis", GRAVITY_AXES)

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        bodies: str | Sequence[str] = "*",
        axis: str | Sequence[str] = GRAVITY_AXES,
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        self.axes = choose_components("BodyComOffset", GRAVITY_AXES, axis)
        super().__init__(scale=scale, add=add, set=set, select=bodies, shared=shared, schedule=schedule, name=name)
        self._frozen = True

    def _extra_fields(self) -> dict[str, Any]:
        return {} if self.axes == GRAVITY_AXES else {"axis": list(self.axes)}

    def _select(self, model: mujoco.MjModel) -> list[tuple[int, str]]:
        why = "a body of mass 0 has no centre of mass to move (the offset would be reported and change nothing)."
        return select_massive(model, self.patterns, self.selector, "BodyComOffset", why)

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        return self._component_targets(model)
