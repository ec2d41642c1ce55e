"""Bindings: an effect resolved against one ``MjModel`` (target indices, nominal snapshot, writes).

A binding snapshots the nominal values once, writes perturbed values in place and restores the
nominal bitwise. A binding whose writes feed ``mujoco.mj_setConst`` names those arrays in
``set_const_inputs``; :class:`randomizers.PhysicsRandomizer` then runs it through
:class:`randomizers.setconst.SetConst`, which decides from those names which derived fields it
recomputes and restores.

Example:
    >>> import mujoco, numpy as np
    >>> from randomizers import Mass
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="arm"><joint/><geom size=".1"/></body></worldbody></mujoco>')
    >>> binding = Mass(scale=2.0).bind(model)
    >>> sorted(binding.set_const_inputs)
    ['body_inertia', 'body_mass']
    >>> nominal = model.body_inertia[1].copy()
    >>> binding.apply(binding.values(np.array([1.0])))  # scale 1 writes the nominal back bitwise
    >>> bool((model.body_inertia[1] == nominal).all())
    True
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

import mujoco
import numpy as np

from randomizers.addressing import Address

if TYPE_CHECKING:
    from randomizers.effects import ArrayEffect  # noqa: F401 - named in a base-class subscript, as a string

__all__ = ["Binding"]


class BoundEffect(Protocol):
    """What a :class:`Binding` reads of its effect: whether one draw is shared, and how draws combine."""

    @property
    def shared(self) -> bool: ...

    @property
    def operation(self) -> str: ...


#: The effect class a binding belongs to (physics bindings: an ArrayEffect; visual ones: their own effects).
EffectT = TypeVar("EffectT", bound=BoundEffect)


class Binding(Generic[EffectT]):
    """An effect resolved against one model: target indices, nominal snapshot, in-place writes.

    Attributes:
        addresses: one parameter address per scalar target, in write order.
        nominal: the values found at bind time (never modified).
        set_const_inputs: the model arrays :meth:`apply` writes that ``mujoco.mj_setConst`` reads
            (empty when it need not run).
        needs_set_const: whether ``mujoco.mj_setConst`` must run after :meth:`apply`.
    """

    set_const_inputs: frozenset[str] = frozenset()

    def __init__(
        self,
        effect: EffectT,
        model: mujoco.MjModel,
        array: np.ndarray,
        targets: tuple[np.ndarray, ...],
        addresses: Sequence[Address],
    ) -> None:
        self.effect: EffectT = effect
        self.model = model
        self._array = array
        self._targets = targets
        self.addresses: tuple[Address, ...] = tuple(addresses)
        self.nominal: np.ndarray = array[targets].copy()
        self.size = len(self.addresses)

    @property
    def needs_set_const(self) -> bool:
        return bool(self.set_const_inputs)

    def draw_count(self) -> int:
        """How many scalars one sample needs (1 when the effect's draw is shared)."""
        return 1 if self.effect.shared else self.size

    def values(self, draws: np.ndarray) -> np.ndarray:
        """Absolute values for the targets given raw draws (scale / add / set over the nominal)."""
        op = self.effect.operation
        if op == "scale":
            return self.nominal * draws
        if op == "add":
            return self.nominal + draws
        return np.broadcast_to(draws, self.nominal.shape).astype(np.float64)

    def apply(self, values: np.ndarray) -> None:
        """Writes ``values`` into the model in place."""
        self._array[self._targets] = values

    def restore(self) -> None:
        """Writes the nominal snapshot back (bitwise)."""
        self._array[self._targets] = self.nominal


class _MassBinding(Binding):
    set_const_inputs = frozenset(("body_mass", "body_inertia"))

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        rows = self._targets[0]
        self._rows = rows
        self._inertia_nominal = self.model.body_inertia[rows].copy()
        # Scaling mass at fixed geometry scales the inertia tensor by the same ratio (uniform density);
        # a massless body keeps its inertia. The ratio is taken against the nominal mass so that the
        # nominal mass gives a ratio of exactly 1 and the nominal inertia bitwise.
        self._positive = self.nominal > 0
        self._divisor = np.where(self._positive, self.nominal, 1.0)

    def apply(self, values: np.ndarray) -> None:
        super().apply(values)
        ratio = np.where(self._positive, values / self._divisor, 1.0)
        self.model.body_inertia[self._rows] = self._inertia_nominal * ratio[:, None]

    def restore(self) -> None:
        super().restore()
        self.model.body_inertia[self._rows] = self._inertia_nominal


class _GainBinding(Binding):
    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        rows = self._targets[0]
        model = self.model
        self._rows = rows
        bias = model.actuator_biasprm[rows]
        gain = model.actuator_gainprm[rows, 0]
        affine = model.actuator_biastype[rows] == mujoco.mjtBias.mjBIAS_AFFINE
        # Position servos carry -kp in biasprm[1] and velocity servos -kv in biasprm[2]; a gain
        # change must move both or the servo's set point drifts.
        self._pos = np.flatnonzero(affine & (bias[:, 1] == -gain) & (gain != 0))
        self._vel = np.flatnonzero(affine & (bias[:, 1] == 0) & (bias[:, 2] == -gain) & (gain != 0))
        self._bias_nominal = bias.copy()

    def apply(self, values: np.ndarray) -> None:
        super().apply(values)
        if self._pos.size:
            self.model.actuator_biasprm[self._rows[self._pos], 1] = -values[self._pos]
        if self._vel.size:
            self.model.actuator_biasprm[self._rows[self._vel], 2] = -values[self._vel]

    def restore(self) -> None:
        super().restore()
        self.model.actuator_biasprm[self._rows] = self._bias_nominal


class _SetConstBinding(Binding["ArrayEffect"]):
    """A binding on one array ``mj_setConst`` reads (the effect's ``field``, e.g. ``dof_armature``)."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.set_const_inputs = frozenset((self.effect.field,))
