"""Named elements of a model: the lookups the effects themselves need (below the effects in the import graph).

The parameter vocabulary (addresses, resolving, reading, writing, effects for an address) is
:mod:`randomizers.parameters`; this module holds only what the effect classes need to find their elements,
so ``effects`` can import it without a cycle. Element selections are name patterns (``fnmatch`` style:
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
from collections.abc import Sequence

import mujoco

__all__ = ["FRICTION_AXES", "GRAVITY_AXES", "element_names", "select"]

#: The components of ``geom_friction``, by column: ``geom_friction[g][i]`` is ``FRICTION_AXES[i]``.
FRICTION_AXES: tuple[str, ...] = ("sliding", "torsional", "rolling")
#: The components of a 3-vector (gravity, positions), by column.
GRAVITY_AXES: tuple[str, ...] = ("x", "y", "z")

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
