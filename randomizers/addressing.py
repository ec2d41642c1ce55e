"""Parameter addresses: "which field of which named element", shared by randomizers, sysid and reports.

An address reads ``field[element]`` or ``field[element][index]``, e.g. ``geom_friction[finger][0]``,
``body_mass[arm]``, ``dof_damping[shoulder]``, ``actuator_gain[wrist]``, ``gravity[z]``. Element
selections in effects are name patterns (``fnmatch`` style: ``finger*``, ``*``, or a list of them).

Example:
    >>> Address.parse("geom_friction[finger][0]")
    Address(field='geom_friction', element='finger', index=0)
    >>> str(Address("body_mass", "arm"))
    'body_mass[arm]'
"""

from __future__ import annotations

import difflib
import fnmatch
import re
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco

__all__ = ["Address", "element_names", "select"]

_ADDRESS = re.compile(r"^(?P<field>[A-Za-z_][A-Za-z0-9_]*)\[(?P<element>[^\[\]]+)\](?:\[(?P<index>\d+)\])?$")

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
}


@dataclass(frozen=True)
class Address:
    """One scalar simulator parameter: ``field[element]`` plus an optional component ``index``."""

    field: str
    element: str
    index: int | None = None

    def __str__(self) -> str:
        base = f"{self.field}[{self.element}]"
        return base if self.index is None else f"{base}[{self.index}]"

    @classmethod
    def parse(cls, text: str) -> Address:
        """Parses ``field[element]`` or ``field[element][index]``.

        Example:
            >>> Address.parse("mass of arm")
            Traceback (most recent call last):
            ...
            ValueError: `address` must look like 'field[element]' or 'field[element][index]', \
e.g. 'geom_friction[finger][0]'. Received 'mass of arm'.
        """
        match = _ADDRESS.match(text.strip()) if isinstance(text, str) else None
        if match is None:
            raise ValueError(
                "`address` must look like 'field[element]' or 'field[element][index]', "
                f"e.g. 'geom_friction[finger][0]'. Received {text!r}."
            )
        index = match.group("index")
        return cls(match.group("field"), match.group("element"), None if index is None else int(index))


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
            ``"camera"`` or ``"texture"``.
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
