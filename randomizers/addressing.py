"""Addresses and named elements of a model: what the effects themselves need (below them in the import graph).

An :class:`Address` is parsed here and only here; resolving it against a model, reading, writing and turning it
into an effect is :mod:`randomizers.parameters` (which re-exports :class:`Address`). Effects build their report
addresses as :class:`Address` objects, so no address is ever formatted by hand and parsed back. Element selections are name patterns (``fnmatch`` style:
``finger*``, ``*``, or a list of them).

Example:
    >>> import mujoco
    >>> model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom name="floor" size="1 1 .1" '
    ...                                        'type="plane"/><geom size=".1"/></worldbody></mujoco>')
    >>> element_names(model, "geom")
    ['floor', '#1']
    >>> FRICTION_AXES[1]
    'torsional'
"""

from __future__ import annotations

import difflib
import fnmatch
import re
from collections.abc import Sequence

import mujoco

__all__ = ["FRICTION_AXES", "GRAVITY_AXES", "Address", "element_names", "joint_dofs", "select", "select_massive"]

#: The components of ``geom_friction``, by column: ``geom_friction[g][i]`` is ``FRICTION_AXES[i]``.
FRICTION_AXES: tuple[str, ...] = ("sliding", "torsional", "rolling")
#: The components of a 3-vector (gravity, positions), by column.
GRAVITY_AXES: tuple[str, ...] = ("x", "y", "z")

_ADDRESS = re.compile(r"^(?P<field>[A-Za-z_][A-Za-z0-9_]*)\[(?P<element>[^\[\]]+)\](?:\[(?P<component>\d+)\])?$")


class Address(str):
    """One scalar simulator parameter: ``field[element]`` plus an optional ``component`` (the column of a multi-column field).

    An address *is* its text (a ``str``): it compares equal to, hashes like and serialises as
    ``"geom_friction[finger][0]"``, so it can key dicts, reports and JSON, while carrying its parsed parts.

    Example:
        >>> address = Address.parse("geom_friction[finger][0]")
        >>> address, address.field, address.element, address.component
        ('geom_friction[finger][0]', 'geom_friction', 'finger', 0)
        >>> str(Address("body_mass", "arm")), Address("body_mass", "arm") == "body_mass[arm]"
        ('body_mass[arm]', True)
    """

    field: str
    element: str
    component: int | None

    def __new__(cls, field: str, element: str, component: int | None = None) -> Address:
        text = f"{field}[{element}]" if component is None else f"{field}[{element}][{component}]"
        self = super().__new__(cls, text)
        object.__setattr__(self, "field", field)
        object.__setattr__(self, "element", element)
        object.__setattr__(self, "component", component)
        return self

    def __getnewargs__(self) -> tuple[str, str, int | None]:  # type: ignore[override]
        return (self.field, self.element, self.component)

    def __setattr__(self, key: str, value: object) -> None:
        raise AttributeError("Address is immutable; build a new one instead.")

    def __repr__(self) -> str:  # an address prints as its text, in messages and in reprs of what holds it
        return str.__repr__(self)

    def __str__(self) -> str:
        return str.__str__(self)

    @classmethod
    def parse(cls, text: str | Address) -> Address:
        """Parses ``field[element]`` or ``field[element][index]`` (an :class:`Address` is returned as it is).

        Example:
            >>> Address.parse("mass of arm")
            Traceback (most recent call last):
            ...
            ValueError: `address` must look like 'field[element]' or 'field[element][index]', \
e.g. 'geom_friction[finger][0]'. Received 'mass of arm'.
        """
        if isinstance(text, Address):
            return text
        match = _ADDRESS.match(text.strip()) if isinstance(text, str) else None
        if match is None:
            raise ValueError(
                "`address` must look like 'field[element]' or 'field[element][index]', "
                f"e.g. 'geom_friction[finger][0]'. Received {text!r}."
            )
        component = match.group("component")
        return cls(match.group("field"), match.group("element"), None if component is None else int(component))


_OBJ = {
    "geom": mujoco.mjtObj.mjOBJ_GEOM,
    "body": mujoco.mjtObj.mjOBJ_BODY,
    "joint": mujoco.mjtObj.mjOBJ_JOINT,
    "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
    "site": mujoco.mjtObj.mjOBJ_SITE,
    "material": mujoco.mjtObj.mjOBJ_MATERIAL,
    "light": mujoco.mjtObj.mjOBJ_LIGHT,
    "camera": mujoco.mjtObj.mjOBJ_CAMERA,
    "texture": mujoco.mjtObj.mjOBJ_TEXTURE,
    "tendon": mujoco.mjtObj.mjOBJ_TENDON,
}
_PLURAL = {"body": "bodies"}
_COUNT = {
    "geom": "ngeom",
    "body": "nbody",
    "joint": "njnt",
    "actuator": "nu",
    "site": "nsite",
    "material": "nmat",
    "light": "nlight",
    "camera": "ncam",
    "texture": "ntex",
    "tendon": "ntendon",
}


def element_names(model: mujoco.MjModel, kind: str) -> list[str]:
    """Names of every element of ``kind``; unnamed ones are called ``#<id>`` so they stay addressable."""
    obj = _OBJ[kind]
    names = []
    for i in range(getattr(model, _COUNT[kind])):
        name = mujoco.mj_id2name(model, obj, i)
        names.append(name if name else f"#{i}")
    return names


def select(
    model: mujoco.MjModel,
    kind: str,
    patterns: str | Sequence[str],
    argument: str,
    exclude: Sequence[int] = (),
) -> list[tuple[int, str]]:
    """Elements of ``kind`` whose names match any pattern, in model order, as ``(id, name)``.

    Args:
        model: the compiled model.
        kind: ``"geom"``, ``"body"``, ``"joint"``, ``"actuator"``, ``"site"``, ``"material"``, ``"light"``,
            ``"camera"``, ``"texture"`` or ``"tendon"``.
        patterns: one fnmatch pattern or a list of them.
        argument: the user-facing argument name, for error messages.
        exclude: ids never selected (e.g. the world body for masses).

    Raises:
        ValueError: a pattern matches nothing; the message lists close matches and the known names.
    """
    if isinstance(patterns, str):
        patterns = [patterns]
    names = element_names(model, kind)
    chosen: dict[int, str] = {}
    for pattern in patterns:
        hits = [i for i, n in enumerate(names) if i not in exclude and fnmatch.fnmatchcase(n, pattern)]
        if not hits:
            candidates = [n for i, n in enumerate(names) if i not in exclude]
            close = difflib.get_close_matches(pattern, candidates, n=3, cutoff=0.5)
            hint = f" Close matches: {', '.join(repr(c) for c in close)}." if close else ""
            plural = _PLURAL.get(kind, kind + "s")
            shown = ", ".join(repr(c) for c in candidates[:40]) + (" ..." if len(candidates) > 40 else "")
            known = f"Known {plural}: {shown}." if candidates else f"The model has no {plural}."
            raise ValueError(f"`{argument}` pattern {pattern!r} matches no {kind} in the model.{hint} {known}")
        for i in hits:
            chosen[i] = names[i]
    return sorted(chosen.items())


def select_massive(
    model: mujoco.MjModel, patterns: Sequence[str], argument: str, effect: str, reason: str
) -> list[tuple[int, str]]:
    """Bodies whose names match any pattern and whose mass is above 0 (never the world body), as ``(id, name)``.

    A body of mass 0 (only sites, or geoms of zero density) is left out: an effect on its mass or centre of mass
    would be reported but change nothing physical (or write a mass with no inertia, which MuJoCo's compiler
    refuses for a moving body). A pattern that matches massless bodies only is refused, naming them.

    Args:
        model: the compiled model.
        patterns: fnmatch patterns of body names.
        argument: the user-facing argument name (``"bodies"``).
        effect: the effect's class name, for the message.
        reason: why a massless body cannot take the effect, for the message.

    Raises:
        ValueError: a pattern matches no body, or massless bodies only.

    Example:
        >>> m = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body name="arm"><joint/><geom size=".1"/>'
        ...     '<body name="tip"><site name="s"/></body></body></worldbody></mujoco>')
        >>> select_massive(m, ["*"], "bodies", "Mass", "")
        [(1, 'arm')]
        >>> select_massive(m, ["tip"], "bodies", "Mass", "it has no inertia for a mass to go with.")
        Traceback (most recent call last):
        ...
        ValueError: `bodies` of Mass pattern 'tip' matches massless bodies only ('tip'): it has no inertia for a \
mass to go with. Give them mass and inertia in the MJCF (an <inertial> element with mass and diaginertia, or geoms \
with a density) or leave them out of `bodies`. Received 'tip'.
    """
    out: dict[int, str] = {}
    for pattern in patterns:
        chosen = select(model, "body", pattern, argument, exclude=(0,))
        massive = [(i, n) for i, n in chosen if model.body_mass[i] > 0]
        if not massive:
            names = ", ".join(repr(n) for _, n in chosen)
            raise ValueError(
                f"`{argument}` of {effect} pattern {pattern!r} matches massless bodies only ({names}): {reason} "
                "Give them mass and inertia in the MJCF (an <inertial> element with mass and diaginertia, or geoms "
                f"with a density) or leave them out of `{argument}`. Received {pattern!r}."
            )
        out.update(massive)
    return sorted(out.items())


def joint_dofs(model: mujoco.MjModel, joint: int) -> int:
    """The degrees of freedom of joint ``joint``: 6 for a free joint, 3 for a ball joint, else 1.

    ``model.jnt_type`` holds numpy ints, which do not match mujoco's enum members as dict keys, so the type is
    compared as an int (a dict keyed by the enum once gave a free joint one dof, and an effect on ``dof_damping``
    reached only the first of its six).

    Example:
        >>> m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><body><freejoint/><geom size=".1"/></body>'
        ...                                    '<body><joint type="ball"/><geom size=".1"/></body></worldbody></mujoco>')
        >>> [joint_dofs(m, j) for j in range(m.njnt)]
        [6, 3]
    """
    kind = int(model.jnt_type[joint])
    return 6 if kind == int(mujoco.mjtJoint.mjJNT_FREE) else 3 if kind == int(mujoco.mjtJoint.mjJNT_BALL) else 1
