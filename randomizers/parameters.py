"""The parameter vocabulary: an address is parsed, resolved against a model, read, written and turned into an
effect here and nowhere else.

An address reads ``field[element]`` or ``field[element][index]``, e.g. ``geom_friction[finger][0]``,
``body_mass[arm]``, ``dof_damping[shoulder]``, ``actuator_gain[wrist]``, ``gravity[z]``; the element may be a
name pattern (``dof_damping[*]``) that expands to one address per matched element. Fields a randomiser effect
owns (:data:`EFFECT_FIELDS`, derived from the registry :data:`FIELD_EFFECTS`) are written
*through that effect's binding*, so a gain change moves a servo's bias and a mass change scales the inertia
exactly as randomisation does; any other numeric ``MjModel`` field of geoms, bodies, joints, dofs, actuators,
sites or tendons (``actuator_biasprm[elbow][1]``, ``geom_solref[pad][0]``) is written directly.

sysid's ``ParameterSpace`` is a :class:`ParameterSet` plus bounds; ``sim2real record --set``, ``FitResult.to_effects``
and the study all build their effects with :func:`effect_for`.

Example:
    >>> import mujoco
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="arm"><joint name="a" damping="0.5"/><geom size=".1"/>'
    ...     '<body><joint name="b" damping="0.2"/><geom size=".1"/></body></body></worldbody></mujoco>')
    >>> space = ParameterSet(model, ["dof_damping[*]"])
    >>> space.addresses, space.nominal.tolist()
    (('dof_damping[a]', 'dof_damping[b]'), [0.5, 0.2])
    >>> space.addresses[1].element
    'b'
    >>> effect_for(Address.parse("geom_friction[pad*][1]"), "scale", 1.2)
    Friction(scale=Constant(value=1.2), geoms='pad*', axis=['torsional'])
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

import mujoco
import numpy as np

from randomizers.addressing import GRAVITY_AXES, Address, element_names, joint_dofs, select
from randomizers.com import BodyComOffset
from randomizers.distributions import Distribution
from randomizers.effects import (
    ActuatorGain,
    Armature,
    ArrayEffect,
    Damping,
    Friction,
    FrictionLoss,
    Gravity,
    Mass,
    Stiffness,
)
from randomizers.tendons import TENDON_EFFECTS

__all__ = [
    "EFFECT_FIELDS",
    "FIELD_EFFECTS",
    "Address",
    "Operation",
    "ParameterBinding",
    "ParameterSet",
    "effect_for",
    "element_names",
    "parse_assignment",
    "select",
]

Operation = Literal["scale", "add", "set"]

_ASSIGNMENT = re.compile(r"^\s*(?P<address>[^=\s]+)\s*=\s*(?P<op>[*+]?)\s*(?P<value>[-+0-9.eE]+|inf|nan)\s*$")
_OPERATION_SIGNS: dict[str, Operation] = {"*": "scale", "+": "add", "": "set"}
# Prefix of a raw MjModel field -> the kind of element its rows belong to (dof_ rows expand per joint).
_RAW_KINDS = {
    "geom_": "geom",
    "body_": "body",
    "jnt_": "joint",
    "dof_": "joint",
    "actuator_": "actuator",
    "site_": "site",
    "tendon_": "tendon",
}


#: The registry of effects that own a model field: a new physics effect is its class plus one line here (YAML
#: configs, ``effect_for``, sysid, ``FitResult.to_effects`` and ``record --set`` all derive from it).
FIELD_EFFECTS: tuple[type[ArrayEffect], ...] = (
    Friction,
    Mass,
    Damping,
    Armature,
    FrictionLoss,
    Stiffness,
    ActuatorGain,
    Gravity,
    BodyComOffset,
    *TENDON_EFFECTS,
)
#: Model fields that a randomiser effect owns, mapped to that effect class.
EFFECT_FIELDS: dict[str, type[ArrayEffect]] = {cls.field: cls for cls in FIELD_EFFECTS}


def effect_for(address: Address, operation: Operation = "set", value: Distribution | float = 1.0) -> ArrayEffect:
    """The randomiser effect that owns ``address``, acting with ``operation`` and ``value`` (a number or any
    distribution).

    Example:
        >>> from randomizers import Uniform
        >>> effect_for(Address.parse("dof_damping[*]"), "scale", Uniform(0.5, 2.0))
        Damping(scale=Uniform(low=0.5, high=2.0), joints='*')
        >>> effect_for(Address.parse("geom_friction[pad]"))
        Traceback (most recent call last):
        ...
        ValueError: `address` 'geom_friction[pad]' needs a component index 0 (sliding), 1 (torsional) or \
2 (rolling), e.g. 'geom_friction[pad][0]'. Received index None.
    """
    cls = EFFECT_FIELDS.get(address.field)
    if cls is None:
        raise ValueError(
            f"`address` field must be one of {sorted(EFFECT_FIELDS)} (the fields an effect owns). "
            f"Received {address.field!r} in {str(address)!r}."
        )
    kwargs: dict[str, Any] = {operation: value}
    if cls.kind == "axis":  # the elements are the components themselves (gravity[z])
        kwargs[cls.selector] = "".join(GRAVITY_AXES) if address.element == "*" else address.element
    else:
        kwargs[cls.selector] = address.element
    components = getattr(cls, "components", None)
    if components is not None:
        keyword, names = components
        if address.component is None or address.component >= len(names):
            choices = ", ".join(f"{i} ({n})" for i, n in enumerate(names))
            choices = choices.replace(f", {len(names) - 1} (", f" or {len(names) - 1} (")
            raise ValueError(
                f"`address` {str(address)!r} needs a component index {choices}, "
                f"e.g. '{address.field}[{address.element}][0]'. Received index {address.component!r}."
            )
        kwargs[keyword] = names[address.component]
    return cls(**kwargs)


def parse_assignment(text: str, argument: str = "--set") -> tuple[Address, Operation, float]:
    """``ADDRESS=*X`` (scale), ``ADDRESS=+X`` (add) or ``ADDRESS=X`` (set), for command lines.

    Example:
        >>> parse_assignment("dof_damping[*]=*1.3")
        ('dof_damping[*]', 'scale', 1.3)
        >>> parse_assignment("dof_damping=*2")
        Traceback (most recent call last):
        ...
        ValueError: `--set` must look like 'dof_damping[*]=*1.3' (scale), 'dof_damping[*]=+0.1' (add) or \
'dof_damping[*]=0.5' (set). Received 'dof_damping=*2'.
    """
    match = _ASSIGNMENT.match(text) if isinstance(text, str) else None
    address = value = None
    if match is not None:
        try:
            address, value = Address.parse(match["address"]), float(match["value"])
        except ValueError:
            address = None
    if match is None or address is None or value is None or not math.isfinite(value):
        raise ValueError(
            f"`{argument}` must look like 'dof_damping[*]=*1.3' (scale), 'dof_damping[*]=+0.1' (add) or "
            f"'dof_damping[*]=0.5' (set). Received {text!r}."
        )
    if address.field not in EFFECT_FIELDS:
        raise ValueError(
            f"`{argument}` field must be one of {sorted(EFFECT_FIELDS)}. Received {address.field!r} in {text!r}."
        )
    return address, _OPERATION_SIGNS[match["op"]], value


class _RawBinding:
    """Direct writes into one numeric model array (fields no randomiser effect covers)."""

    def __init__(
        self, model: mujoco.MjModel, field: str, rows: list[int], cols: list[int] | None, names: list[Address]
    ) -> None:
        self.field = field
        self._array: np.ndarray = getattr(model, field)
        rows_ = np.asarray(rows, np.intp)
        self._targets = (rows_,) if cols is None else (rows_, np.asarray(cols, np.intp))
        self.addresses = tuple(names)
        self.nominal = self._array[self._targets].astype(np.float64).copy()
        self.needs_set_const = field.startswith("body_") or field in ("dof_armature", "tendon_armature", "jnt_qpos0")
        self.set_const_inputs = frozenset((field,)) if self.needs_set_const else frozenset()

    def apply(self, values: np.ndarray) -> None:
        self._array[self._targets] = values

    def restore(self) -> None:
        self._array[self._targets] = self.nominal


def _raw_binding(model: mujoco.MjModel, address: Address) -> _RawBinding:
    array = getattr(model, address.field, None)
    kind = next((k for p, k in _RAW_KINDS.items() if address.field.startswith(p)), None)
    text = str(address)
    if kind is None or not isinstance(array, np.ndarray) or array.dtype.kind != "f":
        raise ValueError(
            f"`params` entry {text!r} must address a numeric MjModel field of geoms, bodies, joints, dofs, "
            f"actuators, sites or tendons (e.g. {', '.join(sorted(EFFECT_FIELDS))}, actuator_biasprm). "
            f"Received field {address.field!r}."
        )
    if array.ndim == 2 and address.component is None:
        raise ValueError(
            f"`params` entry {text!r} needs a component index: {address.field} has {array.shape[1]} columns, "
            f"e.g. '{address.field}[{address.element}][0]'. Received no index."
        )
    if address.component is not None and (array.ndim == 1 or address.component >= array.shape[1]):
        width = 1 if array.ndim == 1 else array.shape[1]
        raise ValueError(
            f"`params` entry {text!r} has index {address.component}, but {address.field} has {width} column(s)"
            f"{' (give no index)' if array.ndim == 1 else ''}. Received index {address.component}."
        )
    rows: list[int] = []
    names: list[Address] = []
    for eid, name in select(model, kind, address.element, "params"):
        if address.field.startswith("dof_"):
            count = joint_dofs(model, eid)
            rows.extend(int(model.jnt_dofadr[eid]) + k for k in range(count))
            names.extend(Address(address.field, name, k if count > 1 else None) for k in range(count))
        else:
            rows.append(eid)
            names.append(Address(address.field, name, address.component))
    cols = None if address.component is None else [address.component] * len(rows)
    return _RawBinding(model, address.field, rows, cols, names)


def _bind(model: mujoco.MjModel, address: Address) -> tuple[Any, list[int]]:
    """A binding covering ``address`` and which of its scalars the address selects."""
    binding: Any
    if address.field not in EFFECT_FIELDS:
        binding = _raw_binding(model, address)
        return binding, list(range(len(binding.addresses)))
    binding = effect_for(address).bind(model)
    keep = list(range(len(binding.addresses)))
    if address.component is not None and getattr(EFFECT_FIELDS[address.field], "components", None) is None:
        # A per-element effect over multi-dof joints: the index picks the dof.
        keep = [i for i, a in enumerate(binding.addresses) if a.component == address.component]
        if not keep:
            raise ValueError(
                f"`params` entry {str(address)!r} has index {address.component}, but {address.field} of "
                f"{address.element!r} has no such component. Received index {address.component}."
            )
    return binding, keep


class ParameterSet:
    """Scalar parameters expanded from address patterns, with their nominal values, a reader and a writer.

    Args:
        model: the compiled model the addresses refer to (never modified).
        params: addresses or address patterns (``Address`` or text), e.g. ``["dof_damping[*]",
            "actuator_gain[elbow]"]``; wildcards expand to one scalar per matched element, in model order.

    Attributes:
        addresses: (P,) expanded :class:`Address` objects.
        nominal: (P,) values found in ``model``.
        origin: (P,) index of the ``params`` entry each address came from.
        effects: (P,) whether each parameter is written through an effect (else a raw field write).
    """

    def __init__(self, model: mujoco.MjModel, params: Sequence[str | Address]) -> None:
        if isinstance(params, str) or not isinstance(params, Sequence) or not params:
            raise ValueError(
                "`params` must be a non-empty list of parameter addresses, e.g. ['dof_damping[*]']. "
                f"Received {params!r}."
            )
        self.model = model
        self._specs: list[tuple[Address, list[int]]] = []
        addresses: list[Address] = []
        nominal: list[float] = []
        origin: list[int] = []
        parsed: list[Address] = []
        for k, text in enumerate(params):
            if not isinstance(text, str):
                raise ValueError(f"`params` entries must be addresses. Received {text!r} at position {k}.")
            address = Address.parse(text)
            parsed.append(address)
            try:
                binding, keep = _bind(model, address)
            except ValueError as err:
                if str(err).startswith("`params`"):
                    raise
                raise ValueError(f"`params` entry {str(text)!r}: {err}") from err
            for i in keep:
                name = binding.addresses[i]  # an Address built by the binding: never re-parsed
                if name in addresses:
                    raise ValueError(
                        f"`params` must name each parameter once. Received {str(name)!r} twice (from {str(text)!r})."
                    )
                addresses.append(name)
                nominal.append(float(binding.nominal[i]))
                origin.append(k)
            self._specs.append((address, keep))
        self.params = tuple(parsed)
        self.addresses: tuple[Address, ...] = tuple(addresses)
        self.nominal = np.array(nominal)
        self.origin = np.array(origin, dtype=np.intp)
        self.size = len(addresses)

    def values_from(self, values: Mapping[str, float] | Sequence[float] | np.ndarray | None, name: str) -> np.ndarray:
        """A (P,) vector from ``{address: value}`` (missing ones nominal), a sequence, or None (nominal)."""
        if values is None:
            return self.nominal.copy()
        if isinstance(values, Mapping):
            unknown = sorted(set(values) - set(self.addresses))
            if unknown:
                raise ValueError(
                    f"`{name}` keys must be fitted addresses {[str(a) for a in self.addresses]}. "
                    f"Received unknown {unknown}."
                )
            return np.array([float(values.get(a, n)) for a, n in zip(self.addresses, self.nominal, strict=True)])
        array = np.asarray(values, dtype=np.float64)
        if array.shape != (self.size,):
            raise ValueError(f"`{name}` must have shape ({self.size},) (one per parameter). Received {array.shape}.")
        return array

    def read(self, model: mujoco.MjModel) -> np.ndarray:
        """The (P,) values ``model`` holds now."""
        return self.bind(model).nominal.copy()

    def bind(self, model: mujoco.MjModel) -> ParameterBinding:
        """The parameters resolved against ``model`` (a copy of the original, or the original itself)."""
        return ParameterBinding(self, model)

    def writer(self, model: mujoco.MjModel) -> Callable[[np.ndarray], None]:
        """A function writing a (P,) value vector into ``model`` (``mj_setConst`` after body or armature edits)."""
        binding = self.bind(model)
        scratch = mujoco.MjData(model) if binding.needs_set_const else None

        def write(values: np.ndarray) -> None:
            binding.apply(values)
            if scratch is not None:
                mujoco.mj_setConst(model, scratch)

        return write

    def write(self, model: mujoco.MjModel, values: Mapping[str, float] | Sequence[float] | np.ndarray) -> None:
        """Writes ``values`` (see :meth:`values_from`) into ``model`` once."""
        self.writer(model)(self.values_from(values, "values"))


class ParameterBinding:
    """A :class:`ParameterSet` resolved against one model: writes a (P,) vector in place, restores bitwise.

    Attributes:
        addresses: (P,) the set's addresses.
        nominal: (P,) the values found at bind time.
        needs_set_const: whether ``mujoco.mj_setConst`` must run after :meth:`apply` (the caller runs it).
    """

    def __init__(self, space: ParameterSet, model: mujoco.MjModel) -> None:
        self.model = model
        self.addresses = space.addresses
        self._parts: list[tuple[Any, np.ndarray, list[int], slice]] = []
        start = 0
        for address, keep in space._specs:
            binding = _bind(model, address)[0]
            full = binding.nominal.astype(np.float64).copy()
            self._parts.append((binding, full, keep, slice(start, start + len(keep))))
            start += len(keep)
        self.nominal = np.array([float(full[i]) for _, full, keep, _ in self._parts for i in keep])
        self.needs_set_const = any(binding.needs_set_const for binding, *_ in self._parts)
        #: the model arrays :meth:`apply` writes that ``mj_setConst`` reads
        self.set_const_inputs: frozenset[str] = frozenset().union(
            *(getattr(b, "set_const_inputs", frozenset()) for b, *_ in self._parts)
        )

    def apply(self, values: np.ndarray) -> None:
        """Writes ``values`` (P,) into the model (effects' side writes included, e.g. inertia with mass)."""
        for binding, full, keep, part in self._parts:
            full[keep] = values[part]
            binding.apply(full)

    def restore(self) -> None:
        """Writes the nominal snapshot back, bitwise."""
        for binding, *_ in self._parts:
            binding.restore()
