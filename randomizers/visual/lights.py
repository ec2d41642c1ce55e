"""Light effects: position, direction, colours and flags of the model's lights.

Example:
    >>> from randomizers.distributions import Uniform
    >>> Light(scale=Uniform(0.5, 1.5), attribute="diffuse", shared=True).key
    'Light[lights=*]'
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from randomizers.addressing import Address
from randomizers.addressing import select as _select
from randomizers.distributions import Distribution
from randomizers.effects import ArrayEffect, Binding, Schedule
from randomizers.visual.arguments import _one_operation

__all__ = ["Light"]

_LIGHT_ATTRIBUTES = ("pos", "dir", "diffuse", "ambient", "specular", "castshadow", "active")
_LIGHT_FLAGS = ("castshadow", "active")

# ----------------------------------------------------------------------------- lights


class _LightBinding(Binding):
    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self._raw = self._array[self._targets].copy()
        self.nominal = self._raw.astype(np.float64)
        effect: Light = self.effect
        self._attribute = effect.attribute

    def values(self, draws: np.ndarray) -> np.ndarray:
        if self._attribute in _LIGHT_FLAGS:
            on = np.broadcast_to(np.asarray(draws, dtype=np.float64) >= 0.5, self.nominal.shape)
            return on.astype(np.float64)
        out = super().values(draws)
        if self._attribute == "dir":
            vec = out.reshape(-1, 3)
            norm = np.linalg.norm(vec, axis=1, keepdims=True)
            out = (vec / np.where(norm > 0, norm, 1.0)).reshape(-1)
        return out.astype(self._array.dtype).astype(np.float64)

    def restore(self) -> None:
        self._array[self._targets] = self._raw


class Light(ArrayEffect):
    """One attribute of the selected lights.

    Args:
        scale | add | set: the operation and its distribution (a number means a constant).
        lights: name pattern(s) of the lights (default all).
        attribute: ``"diffuse"`` (default), ``"ambient"``, ``"specular"`` (RGB, >= 0), ``"pos"``,
            ``"dir"`` (xyz in the parent body's frame; a perturbed direction is renormalised), or the
            flags ``"castshadow"`` and ``"active"`` (on/off), which take ``set`` only: a draw >= 0.5
            switches the flag on, e.g. ``set=Choice((0.0, 1.0))``.
        shared: one draw for every selected scalar (e.g. one brightness for all lights and channels).
        schedule: ``"reset"`` (default), ``"startup"`` or :class:`~randomizers.Interval`.
        name: stable stream name.

    Reported as ``light_<attribute>[<light>][<channel>]`` (flags: ``light_active[<light>]``, 0 or 1).

    Example:
        >>> from randomizers import Choice, Uniform
        >>> Light(scale=Uniform(0.5, 1.5), lights="key", shared=True)
        Light(scale=Uniform(low=0.5, high=1.5), lights='key', shared=True)
        >>> Light(add=Uniform(-0.2, 0.2), attribute="dir")
        Light(add=Uniform(low=-0.2, high=0.2), lights='*', attribute='dir')
        >>> Light(scale=0.5, attribute="active")
        Traceback (most recent call last):
        ...
        ValueError: `attribute='active'` of Light takes `set` only (a draw >= 0.5 means on). Received scale.
    """

    kind = "light"
    selector = "lights"
    binding_class = _LightBinding

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        lights: str | Sequence[str] = "*",
        attribute: str = "diffuse",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        if attribute not in _LIGHT_ATTRIBUTES:
            raise ValueError(f"`attribute` of Light must be one of {list(_LIGHT_ATTRIBUTES)}. Received {attribute!r}.")
        if attribute in _LIGHT_FLAGS:
            operation, _ = _one_operation("Light", scale=scale, add=add, set=set)
            if operation != "set":
                raise ValueError(
                    f"`attribute={attribute!r}` of Light takes `set` only (a draw >= 0.5 means on). Received {operation}."
                )
        self.attribute = attribute
        self.field = f"light_{attribute}"  # type: ignore[misc]
        self.nonnegative = attribute not in ("pos", "dir")  # type: ignore[misc]
        super().__init__(scale=scale, add=add, set=set, select=lights, shared=shared, schedule=schedule, name=name)
        self._frozen = True

    def _extra_fields(self) -> dict[str, Any]:
        return {} if self.attribute == "diffuse" else {"attribute": self.attribute}

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        chosen = _select(model, self.kind, self.patterns, self.selector)
        if self.attribute in _LIGHT_FLAGS:
            return [i for i, _ in chosen], None, [Address(self.field, n) for _, n in chosen]
        rows = [i for i, _ in chosen for _ in range(3)]
        cols = [c for _ in chosen for c in range(3)]
        return rows, cols, [Address(self.field, n, c) for _, n in chosen for c in range(3)]
