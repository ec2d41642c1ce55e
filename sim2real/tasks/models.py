"""A per-process cache of compiled task models, and headless copies of them (compiled without textures).

Compiling a task's XML costs far more than copying the compiled model (``sim2real/arm-reach``: about 30 ms
against 3 ms), so each (XML, assets, textures) is compiled once per process and every env gets its own copy:
effects write into models, so no two envs ever share one.

Textures are most of what a copy moves: dm-control's procedural skybox is 11.8 MB of reacher's model and 13.7 MB
of manipulator's. An env that is never rendered (evaluation, batched worlds) can take ``textures=False``: the
model is compiled without its textures (materials keep their colours), which changes no physics field, so
such an env steps bitwise like the textured one (tested) at about a tenth of the copying cost.

Example:
    >>> from sim2real.tasks.arm_reach import ARM_REACH_XML
    >>> model = compiled_model(ARM_REACH_XML, textures=False)
    >>> model.ntex, compiled_model(ARM_REACH_XML).ntex
    (0, 2)
    >>> compiled_model(ARM_REACH_XML) is compiled_model(ARM_REACH_XML)  # a fresh copy every call
    False
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import mujoco

__all__ = ["check_textures", "compiled_model", "headless_spec"]

#: (xml, sorted assets, textures) -> the pristine compiled model that copies are taken from.
_MODELS: dict[tuple[str, tuple[tuple[str, bytes], ...], bool], mujoco.MjModel] = {}


def check_textures(textures: Any, render_mode: Any = None) -> bool:
    """Validates a ``textures`` option (a bool; True whenever the env renders) and returns it.

    Raises:
        TypeError: not a bool.
        ValueError: ``textures=False`` with a ``render_mode``.

    Example:
        >>> check_textures(False, render_mode="rgb_array")
        Traceback (most recent call last):
        ...
        ValueError: `textures` must be True when the env renders (render_mode='rgb_array'). Received False.
    """
    if not isinstance(textures, bool):
        raise TypeError(f"`textures` must be a bool. Received {textures!r}.")
    if not textures and render_mode is not None:
        raise ValueError(f"`textures` must be True when the env renders (render_mode={render_mode!r}). Received False.")
    return textures


def headless_spec(xml: str, assets: Mapping[str, bytes] | None = None) -> mujoco.MjSpec:
    """The model's spec with every texture removed (materials keep their colours and other attributes)."""
    spec = mujoco.MjSpec.from_string(xml, dict(assets or {}))
    for material in spec.materials:
        material.textures = [""] * len(material.textures)
    for texture in list(spec.textures):
        spec.delete(texture)
    return spec


def compiled_model(xml: str, assets: Mapping[str, bytes] | None = None, *, textures: bool = True) -> mujoco.MjModel:
    """A fresh copy of the model compiled from ``xml`` (and ``assets``), compiled once per process.

    Args:
        xml: the MJCF text.
        assets: file name -> contents the XML refers to.
        textures: False compiles the model without textures (see the module docstring).
    """
    key = (xml, tuple(sorted((assets or {}).items())), bool(textures))
    model = _MODELS.get(key)
    if model is None:
        if textures:
            model = mujoco.MjModel.from_xml_string(xml, dict(assets or {}))
        else:
            model = headless_spec(xml, assets).compile()
        _MODELS[key] = model
    return copy.copy(model)  # MjModel's copy is a deep copy (mj_copyModel): the caller owns it
