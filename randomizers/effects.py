"""Physics effects: what to perturb (a field of named elements), how (scale / add / set) and when.

An effect is an immutable description. :meth:`Effect.bind` resolves it against a compiled
``mujoco.MjModel`` into a :class:`Binding` that snapshots the nominal values once, writes perturbed
values in place (about 1 µs) and restores the nominal bitwise. Effects never touch an environment;
:class:`randomizers.PhysicsRandomizer` drives them and ``sim2real`` wraps environments around that.

Example:
    >>> import mujoco, numpy as np
    >>> from randomizers import Friction, Uniform
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><geom name="floor" type="plane" size="1 1 .1"/>'
    ...     '<body name="arm"><joint name="hinge"/><geom name="finger" size=".1"/></body>'
    ...     '</worldbody></mujoco>')
    >>> effect = Friction(scale=Uniform(0.5, 1.5), geoms="finger")
    >>> binding = effect.bind(model)
    >>> binding.addresses
    ('geom_friction[finger][0]',)
    >>> binding.apply(binding.values(np.array([2.0])))
    >>> float(model.geom_friction[1, 0])
    2.0
    >>> binding.restore()
    >>> float(model.geom_friction[1, 0])
    1.0
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, NamedTuple

import mujoco
import numpy as np

from randomizers.addressing import FRICTION_AXES, GRAVITY_AXES, Address, joint_dofs, select, select_massive
from randomizers.bindings import Binding, _GainBinding, _MassBinding, _SetConstBinding
from randomizers.distributions import Distribution, as_distribution

__all__ = [
    "ActuatorGain",
    "Armature",
    "Binding",
    "Damping",
    "Effect",
    "Friction",
    "FrictionLoss",
    "Gravity",
    "Interval",
    "Mass",
    "Push",
    "PushEvent",
    "Stiffness",
]

Operation = Literal["scale", "add", "set"]
_OPERATIONS: tuple[Operation, ...] = ("scale", "add", "set")
_GRAVITY_AXES = {name: i for i, name in enumerate(GRAVITY_AXES)}
_SCHEDULES = ("startup", "reset")
_unique = set  # the effects' ``set=`` keyword shadows the builtin inside their signatures


@dataclass(frozen=True)
class Interval:
    """Resample every ``steps`` control steps or every ``seconds`` of simulated time (give one).

    Example:
        >>> Interval(steps=0)
        Traceback (most recent call last):
        ...
        ValueError: `Interval` needs exactly one of `steps` (int >= 1) or `seconds` (> 0). \
Received steps=0, seconds=None.
    """

    steps: int | None = None
    seconds: float | None = None

    def __post_init__(self) -> None:
        ok_steps = isinstance(self.steps, int) and not isinstance(self.steps, bool) and self.steps >= 1
        ok_secs = (
            isinstance(self.seconds, (int, float))
            and not isinstance(self.seconds, bool)
            and (math.isfinite(self.seconds) and self.seconds > 0)
        )
        if (self.steps is None) == (self.seconds is None) or not (ok_steps or ok_secs):
            raise ValueError(
                "`Interval` needs exactly one of `steps` (int >= 1) or `seconds` (> 0). "
                f"Received steps={self.steps!r}, seconds={self.seconds!r}."
            )


Schedule = Literal["startup", "reset"] | Interval


def choose_components(owner: str, names: tuple[str, ...], axis: str | Sequence[str]) -> tuple[str, ...]:
    """The components ``axis`` names (one or a list), in field order; an unknown or empty choice is refused."""
    axes = (axis,) if isinstance(axis, str) else tuple(axis)
    if not axes or any(a not in names for a in axes):
        raise ValueError(f"`axis` of {owner} must be one or more of {list(names)}. Received {axis!r}.")
    return tuple(n for n in names if n in axes)


def _check_schedule(schedule: object) -> Schedule:
    if isinstance(schedule, Interval) or schedule in _SCHEDULES:
        return schedule  # type: ignore[return-value]
    raise ValueError(
        f"`schedule` must be 'startup', 'reset' or an Interval(steps=...|seconds=...). Received {schedule!r}."
    )


class Effect:
    """Base of every physics effect: an immutable value with ``key``, ``schedule`` and ``bind``."""

    schedule: Schedule
    name: str | None

    @property
    def key(self) -> str:
        """Stable name keying this effect's random stream (independent of its distribution)."""
        raise NotImplementedError

    def bind(self, model: mujoco.MjModel) -> Any:
        """Resolves the effect against ``model`` (snapshotting nominal values)."""
        raise NotImplementedError

    def _fields(self) -> dict[str, Any]:
        raise NotImplementedError

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self._fields().items())
        return f"{type(self).__name__}({args})"

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other._fields() == self._fields()

    def __hash__(self) -> int:
        return hash((type(self).__name__, repr(self)))

    def __setattr__(self, key: str, value: object) -> None:
        if getattr(self, "_frozen", False):
            raise AttributeError(f"{type(self).__name__} is immutable; build a new effect instead.")
        object.__setattr__(self, key, value)


class ArrayEffect(Effect):
    """An effect on one model array: ``scale``, ``add`` or ``set`` with a distribution.

    Subclasses define the element kind, the selection argument and the array they write.
    """

    field: ClassVar[str]
    kind: ClassVar[str]
    selector: ClassVar[str]
    nonnegative: ClassVar[bool] = True
    #: the field is singular at 0 (a moving body needs mass): draws must keep it > 0 where it is nominally > 0
    positive: ClassVar[bool] = False
    binding_class: ClassVar[type[Binding]] = Binding
    #: (keyword, names): how an address's component index picks the component (``geom_friction[g][1]`` ->
    #: ``axis="torsional"``); None when the field has one value per element.
    components: ClassVar[tuple[str, tuple[str, ...]] | None] = None

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        select: str | Sequence[str] = "*",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        cls = type(self).__name__
        given = {op: v for op, v in (("scale", scale), ("add", add), ("set", set)) if v is not None}
        if len(given) != 1:
            raise ValueError(f"{cls} needs exactly one of `scale`, `add` or `set`. Received {sorted(given) or 'none'}.")
        ((operation, raw),) = given.items()
        dist = as_distribution(raw, operation)
        low, high = dist.support
        if self.positive and operation in ("scale", "set") and low <= 0:
            raise ValueError(
                f"`{operation}` of {cls} must be > 0 over its whole support ({self.field} of 0 is singular). "
                f"Received {dist!r} with support [{low}, {high}]."
            )
        if self.nonnegative and operation in ("scale", "set") and low < 0:
            raise ValueError(
                f"`{operation}` of {cls} must not go below 0 ({self.field} must stay non-negative). "
                f"Received {dist!r} with support [{low}, {high}]."
            )
        if isinstance(select, str):
            patterns: tuple[str, ...] = (select,)
        elif isinstance(select, Sequence) and select and all(isinstance(p, str) for p in select):
            patterns = tuple(select)
        else:
            raise TypeError(
                f"`{self.selector}` of {cls} must be a name pattern or a non-empty list of them. Received {select!r}."
            )
        if not isinstance(shared, bool):
            raise TypeError(f"`shared` of {cls} must be a bool. Received {shared!r}.")
        if name is not None and (not isinstance(name, str) or not name):
            raise TypeError(f"`name` of {cls} must be a non-empty string. Received {name!r}.")
        self.operation: Operation = operation  # type: ignore[assignment]
        self.distribution = dist
        self.patterns = patterns
        self.shared = shared
        self.schedule = _check_schedule(schedule)
        self.name = name

    def _fields(self) -> dict[str, Any]:
        sel = self.patterns[0] if len(self.patterns) == 1 else list(self.patterns)
        out: dict[str, Any] = {self.operation: self.distribution, self.selector: sel}
        out.update(self._extra_fields())
        if self.shared:
            out["shared"] = True
        if self.schedule != "reset":
            out["schedule"] = self.schedule
        if self.name is not None:
            out["name"] = self.name
        return out

    def _extra_fields(self) -> dict[str, Any]:
        return {}

    @property
    def key(self) -> str:
        """``name`` if given, else the effect's kind, selection, extra fields and operation, e.g.
        ``Mass[bodies=torso]`` for ``scale`` and ``Mass[bodies=torso,op=add]``: never its position among
        other effects, so adding one never renames (and so never shifts the draws of) another.
        ``scale`` keeps the bare name streams have always had."""
        if self.name is not None:
            return self.name
        extra = "".join(f",{k}={v}" for k, v in self._extra_fields().items())
        op = "" if self.operation == "scale" else f",op={self.operation}"
        return f"{type(self).__name__}[{self.selector}={'|'.join(self.patterns)}{extra}{op}]"

    def _array(self, model: mujoco.MjModel) -> np.ndarray:
        return getattr(model, self.field)

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        """Flat (rows, cols, addresses) of every scalar this effect writes."""
        chosen = self._select(model)
        rows = [i for i, _ in chosen]
        return rows, None, [Address(self.field, n) for _, n in chosen]

    def _select(self, model: mujoco.MjModel) -> list[tuple[int, str]]:
        """The selected elements, ``(id, name)`` in model order."""
        return select(model, self.kind, self.patterns, self.selector, exclude=self._excluded(model))

    def _excluded(self, model: mujoco.MjModel) -> tuple[int, ...]:
        return ()

    def _component_targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        """(rows, cols, addresses) over the selected elements times the chosen components ``self.axes``."""
        assert self.components is not None
        names = self.components[1]
        rows, cols, addresses = [], [], []
        for eid, ename in self._select(model):
            for axis in self.axes:  # type: ignore[attr-defined]
                rows.append(eid)
                cols.append(names.index(axis))
                addresses.append(Address(self.field, ename, names.index(axis)))
        return rows, cols, addresses

    def bind(self, model: mujoco.MjModel) -> Binding:
        """Resolves the selection and snapshots the nominal values of ``model``.

        Raises:
            ValueError: no element matches (close matches listed), or ``add`` would make a
                non-negative quantity negative (a positive one zero or negative) for some element.
        """
        rows, cols, addresses = self._targets(model)
        targets = (
            (np.asarray(rows, dtype=np.intp),)
            if cols is None
            else (np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp))
        )
        binding = self.binding_class(self, model, self._array(model), targets, addresses)
        if self.positive and self.operation == "add":
            low = self.distribution.support[0]
            reached = np.where(binding.nominal > 0, binding.nominal + low, np.inf)
            worst = int(np.argmin(reached))
            if reached[worst] <= 0:
                raise ValueError(
                    f"`add` of {type(self).__name__} would make {binding.addresses[worst]} zero or negative "
                    f"({self.field} of 0 is singular): nominal {float(binding.nominal[worst])!r} + lowest draw "
                    f"{low!r} <= 0. Received {self.distribution!r}."
                )
        if self.nonnegative and self.operation == "add":
            low = self.distribution.support[0]
            worst = int(np.argmin(binding.nominal))
            if binding.nominal[worst] + low < 0:
                raise ValueError(
                    f"`add` of {type(self).__name__} would make {binding.addresses[worst]} negative: nominal "
                    f"{float(binding.nominal[worst])!r} + lowest draw {low!r} < 0. Received {self.distribution!r}."
                )
        return binding


class Friction(ArrayEffect):
    """Contact friction of geoms (``geom_friction``): sliding, torsional and/or rolling coefficients.

    Args:
        scale | add | set: the operation and its distribution (a number means a constant).
        geoms: name pattern(s) of the geoms to perturb (default all).
        axis: ``"sliding"``, ``"torsional"``, ``"rolling"`` or a list of them (default sliding).
        shared: one draw for all selected geoms instead of one each.
        schedule: ``"reset"`` (default), ``"startup"`` or :class:`Interval`.
        name: stable stream name (defaults to the class name and selection).

    Example:
        >>> from randomizers import Friction, Uniform
        >>> Friction(scale=Uniform(0.5, 1.5), geoms="finger*")
        Friction(scale=Uniform(low=0.5, high=1.5), geoms='finger*')
        >>> Friction(scale=Uniform(-0.5, 1.5))
        Traceback (most recent call last):
        ...
        ValueError: `scale` of Friction must not go below 0 (geom_friction must stay non-negative). \
Received Uniform(low=-0.5, high=1.5) with support [-0.5, 1.5].
    """

    field = "geom_friction"
    kind = "geom"
    selector = "geoms"
    components = ("axis", FRICTION_AXES)

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        geoms: str | Sequence[str] = "*",
        axis: str | Sequence[str] = "sliding",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        self.axes = choose_components("Friction", FRICTION_AXES, axis)
        super().__init__(scale=scale, add=add, set=set, select=geoms, shared=shared, schedule=schedule, name=name)
        self._frozen = True

    def _extra_fields(self) -> dict[str, Any]:
        return {} if self.axes == ("sliding",) else {"axis": list(self.axes)}

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        return self._component_targets(model)


class Mass(ArrayEffect):
    """Body masses (``body_mass``) with the inertia tensor scaled by the same ratio; the randomiser
    runs ``mujoco.mj_setConst`` afterwards so derived quantities stay consistent. The world body and
    bodies of zero mass (only sites, or zero-density geoms) are never selected: such a body has no inertia
    to scale, a mass set on it would have none (MuJoCo's compiler refuses that on a moving body) and a scale
    would leave it at 0; a pattern matching massless bodies only is refused. Zero mass is singular, so
    ``scale`` and ``set`` must be > 0 over their whole support and ``add`` must keep every body above 0
    (checked when bound); fields ``mj_setConst`` derives are restored with the masses.

    Example:
        >>> from randomizers import Mass, Uniform
        >>> Mass(scale=Uniform(0.8, 1.2), bodies="arm*")
        Mass(scale=Uniform(low=0.8, high=1.2), bodies='arm*')
        >>> Mass(scale=Uniform(0.0, 2.0))
        Traceback (most recent call last):
        ...
        ValueError: `scale` of Mass must be > 0 over its whole support (body_mass of 0 is singular). \
Received Uniform(low=0.0, high=2.0) with support [0.0, 2.0].
    """

    field = "body_mass"
    kind = "body"
    selector = "bodies"
    positive = True
    binding_class = _MassBinding

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        bodies: str | Sequence[str] = "*",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(scale=scale, add=add, set=set, select=bodies, shared=shared, schedule=schedule, name=name)
        self._frozen = True

    def _select(self, model: mujoco.MjModel) -> list[tuple[int, str]]:
        why = "a body of mass 0 has no inertia for a new mass to go with, and a scaled 0 stays 0."
        return select_massive(model, self.patterns, self.selector, "Mass", why)


class _DofEffect(ArrayEffect):
    """Per-degree-of-freedom joint properties, selected by joint name."""

    kind = "joint"
    selector = "joints"

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        joints: str | Sequence[str] = "*",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(scale=scale, add=add, set=set, select=joints, shared=shared, schedule=schedule, name=name)
        self._frozen = True

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        chosen = select(model, self.kind, self.patterns, self.selector)
        rows, addresses = [], []
        for jid, jname in chosen:
            count = joint_dofs(model, jid)
            start = int(model.jnt_dofadr[jid])
            for k in range(count):
                rows.append(start + k)
                addresses.append(Address(self.field, jname, k if count > 1 else None))
        return rows, None, addresses


class Damping(_DofEffect):
    """Joint damping (``dof_damping``), per degree of freedom of the selected joints.

    Example:
        >>> from randomizers import Damping, LogUniform
        >>> Damping(scale=LogUniform(0.5, 2.0))
        Damping(scale=LogUniform(low=0.5, high=2.0), joints='*')
    """

    field = "dof_damping"


class Armature(_DofEffect):
    """Rotor inertia added to each selected joint's degrees of freedom (``dof_armature``); like
    :class:`Mass` it changes the mass matrix, so the randomiser runs ``mj_setConst`` after it."""

    field = "dof_armature"
    binding_class = _SetConstBinding


class FrictionLoss(_DofEffect):
    """Dry (Coulomb) joint friction of each selected joint's degrees of freedom (``dof_frictionloss``)."""

    field = "dof_frictionloss"


class Stiffness(ArrayEffect):
    """Joint spring stiffness (``jnt_stiffness``), one value per selected joint."""

    field = "jnt_stiffness"
    kind = "joint"
    selector = "joints"

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        joints: str | Sequence[str] = "*",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(scale=scale, add=add, set=set, select=joints, shared=shared, schedule=schedule, name=name)
        self._frozen = True


class ActuatorGain(ArrayEffect):
    """Actuator gain (``actuator_gainprm[:, 0]``): the torque constant of a motor, ``kp`` of a
    position servo, ``kv`` of a velocity servo. For servos the matching bias term moves with it, so
    a position servo still holds its set point. Reported as ``actuator_gain[<name>]``.

    Example:
        >>> from randomizers import ActuatorGain, Uniform
        >>> ActuatorGain(scale=Uniform(0.9, 1.1), actuators="shoulder")
        ActuatorGain(scale=Uniform(low=0.9, high=1.1), actuators='shoulder')
    """

    field = "actuator_gain"
    kind = "actuator"
    selector = "actuators"
    binding_class = _GainBinding

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        actuators: str | Sequence[str] = "*",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(scale=scale, add=add, set=set, select=actuators, shared=shared, schedule=schedule, name=name)
        self._frozen = True

    def _array(self, model: mujoco.MjModel) -> np.ndarray:
        return model.actuator_gainprm

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        rows, _, addresses = super()._targets(model)
        return rows, [0] * len(rows), addresses


class Gravity(ArrayEffect):
    """Gravity vector components (``opt.gravity``), reported as ``gravity[x|y|z]``; may be negative.

    Example:
        >>> from randomizers import Gravity, Uniform
        >>> Gravity(scale=Uniform(0.95, 1.05), axes="z")
        Gravity(scale=Uniform(low=0.95, high=1.05), axes='z')
    """

    field = "gravity"
    kind = "axis"
    selector = "axes"
    nonnegative = False

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        axes: str = "xyz",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        if (
            not isinstance(axes, str)
            or not axes
            or any(a not in _GRAVITY_AXES for a in axes)
            or len(_unique(axes)) != len(axes)
        ):
            raise ValueError(f"`axes` of Gravity must be distinct letters from 'xyz'. Received {axes!r}.")
        super().__init__(scale=scale, add=add, set=set, select=axes, shared=shared, schedule=schedule, name=name)
        self._frozen = True

    def _array(self, model: mujoco.MjModel) -> np.ndarray:
        return model.opt.gravity

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        axes = sorted(self.patterns[0], key=_GRAVITY_AXES.__getitem__)
        return [_GRAVITY_AXES[a] for a in axes], None, [Address("gravity", a) for a in axes]


class Push(Effect):
    """Random external pushes: every ``interval`` control steps a force of magnitude ``force`` (N) in
    a uniformly random direction is applied to one of the selected bodies (through
    ``data.xfrc_applied``) for ``duration`` control steps.

    Args:
        force: force magnitude distribution in newtons (>= 0).
        interval: control steps between the end of one push and the start of the next (>= 1).
        duration: control steps a push lasts (int >= 1).
        bodies: name pattern(s) of candidate bodies (the world, bodies welded to it and mocap bodies excluded:
            a force on them moves nothing).
        planar: push only in the x-y plane.
        name: stable stream name.

    Example:
        >>> from randomizers import Push, Uniform
        >>> Push(force=Uniform(0.0, 2.0), interval=Uniform(20, 60), bodies="hand")
        Push(force=Uniform(low=0.0, high=2.0), interval=Uniform(low=20.0, high=60.0), duration=1, bodies='hand')
    """

    schedule: Schedule = "reset"

    def __init__(
        self,
        *,
        force: Distribution | float,
        interval: Distribution | float,
        duration: int = 1,
        bodies: str | Sequence[str] = "*",
        planar: bool = False,
        name: str | None = None,
    ) -> None:
        self.force = as_distribution(force, "force")
        self.interval = as_distribution(interval, "interval")
        if self.force.support[0] < 0:
            raise ValueError(f"`force` of Push must not go below 0. Received {self.force!r}.")
        if self.interval.support[0] < 1:
            raise ValueError(f"`interval` of Push must be >= 1 control step. Received {self.interval!r}.")
        if isinstance(duration, bool) or not isinstance(duration, int) or duration < 1:
            raise ValueError(f"`duration` of Push must be an int >= 1. Received {duration!r}.")
        self.duration = duration
        self.patterns = (bodies,) if isinstance(bodies, str) else tuple(bodies)
        self.planar = bool(planar)
        self.name = name
        self._frozen = True

    def _fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {"force": self.force, "interval": self.interval, "duration": self.duration}
        out["bodies"] = self.patterns[0] if len(self.patterns) == 1 else list(self.patterns)
        if self.planar:
            out["planar"] = True
        if self.name is not None:
            out["name"] = self.name
        return out

    @property
    def key(self) -> str:
        return self.name or f"Push[bodies={'|'.join(self.patterns)}]"

    def bind(self, model: mujoco.MjModel) -> PushBinding:
        return PushBinding(self, model)


class PushEvent(NamedTuple):
    """One push: the control step it started, the body and the force vector (N, world frame)."""

    step: int
    body: str
    force: tuple[float, float, float]


class PushBinding:
    """Per-episode push schedule; ``step`` is an integer compare except on push steps."""

    def __init__(self, effect: Push, model: mujoco.MjModel) -> None:
        self.effect = effect
        chosen = select(model, "body", effect.patterns, "bodies", exclude=(0,))
        # A force on a body welded to the world (or a mocap body) moves nothing: such a push would be reported
        # but never felt, so those bodies are no candidates.
        movable = [(i, n) for i, n in chosen if model.body_weldid[i] != 0 and model.body_mocapid[i] < 0]
        if not movable:
            names = ", ".join(repr(n) for _, n in chosen)
            raise ValueError(
                f"`bodies` of Push selects only bodies that cannot move (welded to the world or mocap): {names}. "
                f"Received {effect.patterns[0] if len(effect.patterns) == 1 else list(effect.patterns)!r}."
            )
        chosen = movable
        self.body_ids = np.array([i for i, _ in chosen], dtype=np.intp)
        self.body_names = [n for _, n in chosen]
        self.t = 0
        self.next_on = -1
        self.next_off = -1
        self.active: int | None = None
        self.events: list[PushEvent] = []

    def begin(self, gen: np.random.Generator) -> None:
        self.gen = gen
        self.t = 0
        self.events = []
        self.active = None
        self.next_off = -1
        self.next_on = self._draw_gap()

    def _draw_gap(self) -> int:
        return self.t + max(1, round(float(self.effect.interval.sample(self.gen))))

    def step(self, data: mujoco.MjData) -> bool:
        """Advances one control step; returns True when a push started or ended."""
        self.t += 1
        if self.t == self.next_off and self.active is not None:
            data.xfrc_applied[self.active, :3] = 0.0
            self.active = None
            self.next_on = self._draw_gap()
            return True
        if self.t != self.next_on:
            return False
        gen = self.gen
        k = int(gen.integers(len(self.body_ids)))
        direction = gen.normal(size=3)
        if self.effect.planar:
            direction[2] = 0.0
        norm = float(np.linalg.norm(direction)) or 1.0
        force = direction / norm * float(self.effect.force.sample(gen))
        body = int(self.body_ids[k])
        data.xfrc_applied[body, :3] = force
        self.active = body
        self.next_off = self.t + self.effect.duration
        self.events.append(PushEvent(self.t, self.body_names[k], tuple(force.tolist())))
        return True

    def restore(self, data: mujoco.MjData | None) -> None:
        if data is not None and self.active is not None:
            data.xfrc_applied[self.active, :3] = 0.0
        self.active = None
