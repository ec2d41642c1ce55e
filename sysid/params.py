"""Fitted parameters: addresses resolved against a model, bounds, and writes into model copies.

Addresses are the ones :mod:`randomizers` uses (``dof_damping[*]``, ``geom_friction[finger][0]``,
``actuator_gain[shoulder]``, ``body_mass[arm]``, ``gravity[z]``, ...). Fields that a randomiser effect
covers are resolved *through that effect's binding* (so a gain change moves a servo's bias and a mass
change scales the inertia exactly as randomisation does); any other numeric ``MjModel`` field of geoms,
bodies, joints, dofs, actuators or sites (e.g. ``actuator_biasprm[elbow][1]``, ``geom_solref[pad][0]``) is
written directly.

Example:
    >>> import mujoco
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body><joint name="a" damping="0.5"/><geom size=".1"/>'
    ...     '<body><joint name="b" damping="0.2"/><geom size=".1"/></body></body></worldbody></mujoco>')
    >>> space = ParameterSpace(model, ["dof_damping[*]"])
    >>> space.addresses, space.nominal.tolist()
    (('dof_damping[a]', 'dof_damping[b]'), [0.5, 0.2])
    >>> space.lower.tolist(), space.upper.tolist()
    ([0.05, 0.02], [5.0, 2.0])
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from randomizers.addressing import Address, select
from randomizers.config import EFFECT_TYPES
from randomizers.effects import ArrayEffect

__all__ = ["EFFECT_FIELDS", "ParameterSpace", "effect_for"]

#: Model fields that a randomiser effect owns, mapped to that effect class.
EFFECT_FIELDS: dict[str, type[ArrayEffect]] = {
    cls.field: cls  # type: ignore[attr-defined]
    for cls in EFFECT_TYPES.values()
    if isinstance(cls, type)
    and issubclass(cls, ArrayEffect)
    and isinstance(getattr(cls, "field", None), str)
    and getattr(cls, "kind", None) in ("geom", "body", "joint", "actuator", "axis")
}
_FRICTION_AXIS_NAMES = ("sliding", "torsional", "rolling")
_RAW_KINDS = {
    "geom_": "geom",
    "body_": "body",
    "jnt_": "joint",
    "dof_": "joint",
    "actuator_": "actuator",
    "site_": "site",
}
_SIGNED_FIELDS = ("gravity", "actuator_biasprm", "body_pos", "body_ipos", "geom_pos", "jnt_pos", "site_pos")


class _RawBinding:
    """Direct writes into one numeric model array (fields no randomiser effect covers)."""

    def __init__(self, model: mujoco.MjModel, field: str, rows: list[int], cols: list[int] | None, names: list[str]):
        self.model = model
        self.field = field
        self._array: np.ndarray = getattr(model, field)
        self._targets = (np.asarray(rows, np.intp),) if cols is None else (np.asarray(rows, np.intp), np.asarray(cols))
        self.addresses = tuple(names)
        self.nominal = self._array[self._targets].astype(np.float64).copy()
        self.needs_set_const = field.startswith("body_") or field in ("dof_armature", "jnt_qpos0")

    def apply(self, values: np.ndarray) -> None:
        self._array[self._targets] = values


def _raw_targets(model: mujoco.MjModel, address: Address, text: str) -> tuple[list[int], list[int] | None, list[str]]:
    array = getattr(model, address.field, None)
    kind = next((k for p, k in _RAW_KINDS.items() if address.field.startswith(p)), None)
    if kind is None or not isinstance(array, np.ndarray) or array.dtype.kind != "f":
        known = sorted(EFFECT_FIELDS)
        raise ValueError(
            f"`params` entry {text!r} must address a numeric MjModel field of geoms, bodies, joints, dofs, "
            f"actuators or sites (e.g. {', '.join(known)}, actuator_biasprm). Received field {address.field!r}."
        )
    if array.ndim == 2 and address.index is None:
        raise ValueError(
            f"`params` entry {text!r} needs a component index: {address.field} has {array.shape[1]} columns, "
            f"e.g. '{address.field}[{address.element}][0]'. Received no index."
        )
    if address.index is not None and (array.ndim == 1 or address.index >= array.shape[1]):
        width = 1 if array.ndim == 1 else array.shape[1]
        raise ValueError(
            f"`params` entry {text!r} has index {address.index}, but {address.field} has {width} column(s)"
            f"{' (give no index)' if array.ndim == 1 else ''}. Received index {address.index}."
        )
    chosen = select(model, kind, address.element, "params")
    rows: list[int] = []
    names: list[str] = []
    for eid, name in chosen:
        if address.field.startswith("dof_"):
            start = int(model.jnt_dofadr[eid])
            count = {mujoco.mjtJoint.mjJNT_FREE: 6, mujoco.mjtJoint.mjJNT_BALL: 3}.get(model.jnt_type[eid], 1)
            for k in range(count):
                rows.append(start + k)
                names.append(f"{address.field}[{name}]" + (f"[{k}]" if count > 1 else ""))
        else:
            rows.append(eid)
            names.append(f"{address.field}[{name}]")
    if address.index is not None:
        names = [f"{n}[{address.index}]" for n in names]
        return rows, [address.index] * len(rows), names
    return rows, None, names


def effect_for(address: Address, operation: str = "set", value: float = 1.0) -> ArrayEffect:
    """The randomiser effect that owns ``address``, acting with ``operation`` (scale/add/set) and ``value``.

    Example:
        >>> effect_for(Address.parse("dof_damping[*]"), "scale", 1.3)
        Damping(scale=Constant(value=1.3), joints='*')
    """
    cls = EFFECT_FIELDS[address.field]
    kwargs: dict[str, Any] = {operation: value}
    if address.field == "gravity":
        kwargs["axes"] = "xyz" if address.element == "*" else address.element
    else:
        kwargs[cls.selector] = address.element
    if address.field == "geom_friction":
        if address.index is None or address.index > 2:
            raise ValueError(
                f"`params` entry {str(address)!r} needs a friction component index 0 (sliding), 1 (torsional) or "
                f"2 (rolling), e.g. 'geom_friction[{address.element}][0]'. Received index {address.index!r}."
            )
        kwargs["axis"] = _FRICTION_AXIS_NAMES[address.index]
    return cls(**kwargs)


class ParameterSpace:
    """Scalar parameters expanded from address patterns, with nominal values, bounds and writers.

    Args:
        model: the compiled model the addresses refer to (never modified).
        params: address patterns, e.g. ``["dof_damping[*]", "actuator_gain[elbow]"]``; wildcards expand to one
            scalar per matched element, in model order.
        bounds: ``{address or pattern: (low, high)}`` or a list of ``(low, high)`` aligned with ``params``.
            Missing entries default to ``[nominal / 10, nominal * 10]`` for a positive nominal; parameters
            with a zero or negative nominal need explicit bounds.

    Attributes:
        addresses: (P,) expanded addresses.
        nominal: (P,) values found in ``model``.
        lower, upper: (P,) bounds.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        params: Sequence[str],
        bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None = None,
    ) -> None:
        if isinstance(params, str) or not isinstance(params, Sequence) or not params:
            raise ValueError(
                "`params` must be a non-empty list of parameter addresses, e.g. ['dof_damping[*]']. "
                f"Received {params!r}."
            )
        self.model = model
        self._specs: list[tuple[str, Address, bool]] = []  # (text, address, via effect)
        addresses: list[str] = []
        nominal: list[float] = []
        origin: list[int] = []
        self._binding_slots: list[list[int]] = []  # per spec: position of each param in that spec's binding
        for k, text in enumerate(params):
            if not isinstance(text, str):
                raise ValueError(f"`params` entries must be address strings. Received {text!r} at position {k}.")
            address = Address.parse(text)
            via_effect = address.field in EFFECT_FIELDS
            try:
                binding = self._bind(model, address, via_effect, text)
            except ValueError as err:
                if str(err).startswith("`params`"):
                    raise
                raise ValueError(f"`params` entry {text!r}: {err}") from err
            keep = list(range(len(binding.addresses)))
            if via_effect and address.index is not None and address.field != "geom_friction":
                keep = [i for i, a in enumerate(binding.addresses) if a.endswith(f"[{address.index}]")]
                if not keep:
                    raise ValueError(
                        f"`params` entry {text!r} has index {address.index}, but {address.field} of "
                        f"{address.element!r} has no such component. Received index {address.index}."
                    )
            for i in keep:
                name = binding.addresses[i]
                if name in addresses:
                    raise ValueError(
                        f"`params` must name each parameter once. Received {name!r} twice (from {text!r})."
                    )
                addresses.append(name)
                nominal.append(float(binding.nominal[i]))
                origin.append(k)
            self._specs.append((text, address, via_effect))
            self._binding_slots.append(keep)
        self.addresses: tuple[str, ...] = tuple(addresses)
        self.nominal = np.array(nominal)
        self.origin = np.array(origin)
        self.size = len(addresses)
        self.lower, self.upper = self._bounds(params, bounds)

    @staticmethod
    def _bind(model: mujoco.MjModel, address: Address, via_effect: bool, text: str) -> Any:
        if via_effect:
            return effect_for(address).bind(model)
        rows, cols, names = _raw_targets(model, address, text)
        return _RawBinding(model, address.field, rows, cols, names)

    def _bounds(
        self, params: Sequence[str], bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        lower = np.full(self.size, np.nan)
        upper = np.full(self.size, np.nan)
        if bounds is None:
            pass
        elif isinstance(bounds, Mapping):
            used = set()
            for i, address in enumerate(self.addresses):
                for key in (address, params[self.origin[i]]):
                    if key in bounds:
                        lower[i], upper[i] = self._pair(bounds[key], key)
                        used.add(key)
                        break
            unknown = sorted(set(bounds) - used)
            if unknown:
                raise ValueError(
                    f"`bounds` keys must be entries of `params` or expanded addresses {list(self.addresses)}. "
                    f"Received unknown key(s) {unknown}."
                )
        elif isinstance(bounds, Sequence) and len(bounds) == len(params):
            for i in range(self.size):
                k = int(self.origin[i])
                lower[i], upper[i] = self._pair(bounds[k], params[k])
        else:
            raise ValueError(
                "`bounds` must be a mapping {address: (low, high)} or a list of (low, high) with one pair per "
                f"`params` entry ({len(params)}). Received {bounds!r}."
            )
        for i, address in enumerate(self.addresses):
            if np.isnan(lower[i]):
                value = float(self.nominal[i])
                if value <= 0:
                    raise ValueError(
                        f"`bounds` must be given for {address!r}: its nominal value is {value!r}, so there is no "
                        "default range (defaults are [nominal/10, nominal*10]). Received none."
                    )
                lower[i], upper[i] = value / 10.0, value * 10.0
        return lower, upper

    @staticmethod
    def _pair(value: Any, key: str) -> tuple[float, float]:
        try:
            low, high = (float(v) for v in value)
        except (TypeError, ValueError):
            raise ValueError(f"`bounds[{key!r}]` must be a pair (low, high). Received {value!r}.") from None
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise ValueError(f"`bounds[{key!r}]` must be finite with low < high. Received ({low!r}, {high!r}).")
        return low, high

    def values_from(self, values: Mapping[str, float] | Sequence[float] | np.ndarray | None, name: str) -> np.ndarray:
        """A (P,) vector from ``{address: value}`` (missing ones nominal), a sequence, or None (nominal)."""
        if values is None:
            return self.nominal.copy()
        if isinstance(values, Mapping):
            unknown = sorted(set(values) - set(self.addresses))
            if unknown:
                raise ValueError(
                    f"`{name}` keys must be fitted addresses {list(self.addresses)}. Received unknown {unknown}."
                )
            return np.array([float(values.get(a, n)) for a, n in zip(self.addresses, self.nominal, strict=True)])
        array = np.asarray(values, dtype=np.float64)
        if array.shape != (self.size,):
            raise ValueError(f"`{name}` must have shape ({self.size},) (one per parameter). Received {array.shape}.")
        return array

    def writer(self, model: mujoco.MjModel) -> Callable[[np.ndarray], None]:
        """A function writing a (P,) value vector into ``model`` (a copy of the original)."""
        bindings = [self._bind(model, address, via, text) for text, address, via in self._specs]
        slices: list[tuple[Any, np.ndarray, list[int], slice]] = []
        start = 0
        for binding, keep in zip(bindings, self._binding_slots, strict=True):
            full = binding.nominal.astype(np.float64).copy()
            slices.append((binding, full, keep, slice(start, start + len(keep))))
            start += len(keep)
        set_const = any(b.needs_set_const for b in bindings)
        scratch = mujoco.MjData(model) if set_const else None

        def write(values: np.ndarray) -> None:
            for binding, full, keep, part in slices:
                full[keep] = values[part]
                binding.apply(full)
            if set_const:
                mujoco.mj_setConst(model, scratch)

        return write


class ModelPool:
    """Copies of a model, one per parameter set of a batch, each with its own writer (grown on demand)."""

    def __init__(self, model: mujoco.MjModel, space: ParameterSpace) -> None:
        self.base = model
        self.space = space
        self.models: list[mujoco.MjModel] = []
        self.writers: list[Callable[[np.ndarray], None]] = []
        self._datas: list[mujoco.MjData] = []

    def models_for(self, values: np.ndarray) -> list[mujoco.MjModel]:
        """One model per row of ``values`` (B, P), written in place."""
        values = np.atleast_2d(values)
        while len(self.models) < values.shape[0]:
            model = copy.copy(self.base)
            self.models.append(model)
            self.writers.append(self.space.writer(model))
        for i, row in enumerate(values):
            self.writers[i](row)
        return self.models[: values.shape[0]]
