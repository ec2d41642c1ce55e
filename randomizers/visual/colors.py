"""Colour effects: the RGB (or HSV) colour of geoms and of materials, and the conversions between the two spaces.

Example:
    >>> import numpy as np
    >>> hsv_to_rgb(rgb_to_hsv(np.array([[0.8, 0.2, 0.2]]))).round(6).tolist()
    [[0.8, 0.2, 0.2]]
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import mujoco
import numpy as np

from randomizers.addressing import Address
from randomizers.addressing import select as _select
from randomizers.effects import Binding, Effect, Operation, Schedule, _check_schedule
from randomizers.visual.arguments import (
    Product,
    _channels,
    _check_bool,
    _check_name,
    _check_unit,
    _one_operation,
    _patterns,
    _shown,
)

__all__ = ["GeomColor", "MaterialColor", "hsv_to_rgb", "rgb_to_hsv"]

_SPACES = ("rgb", "hsv")
# Geoms whose rgba is MuJoCo's default show their material's colour instead (the renderer's rule).
_DEFAULT_GEOM_RGBA = np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32)

# ----------------------------------------------------------------------------- colour conversions


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """Vectorised RGB -> HSV on the last axis, all channels in [0, 1] (hue in turns).

    Example:
        >>> rgb_to_hsv(np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.5]])).round(3).tolist()
        [[0.0, 1.0, 1.0], [0.5, 1.0, 0.5]]
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    mx, mn = rgb.max(axis=-1), rgb.min(axis=-1)
    delta = mx - mn
    safe = np.where(delta > 0, delta, 1.0)
    hue = np.where(mx == r, ((g - b) / safe) % 6.0, np.where(mx == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0))
    hue = np.where(delta > 0, hue / 6.0, 0.0)
    sat = np.where(mx > 0, delta / np.where(mx > 0, mx, 1.0), 0.0)
    return np.stack([hue, sat, mx], axis=-1)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """Vectorised HSV -> RGB on the last axis (inverse of :func:`rgb_to_hsv`).

    Example:
        >>> hsv_to_rgb(np.array([0.5, 1.0, 0.5])).tolist()
        [0.0, 0.5, 0.5]
    """
    hsv = np.asarray(hsv, dtype=np.float64)
    h, s, v = hsv[..., 0] % 1.0, hsv[..., 1], hsv[..., 2]
    sector = np.floor(h * 6.0)
    f = h * 6.0 - sector
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    i = sector.astype(np.int64) % 6
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    return np.stack([r, g, b], axis=-1)


# ----------------------------------------------------------------------------- colours


class _ColorBinding(Binding):
    """RGB channels of the selected rows of an rgba array; values computed over the seen colour."""

    def __init__(
        self, effect: _ColorEffect, model: mujoco.MjModel, array: np.ndarray, rows: np.ndarray, names: list[str]
    ) -> None:
        cols = np.tile(np.arange(3, dtype=np.intp), len(rows))
        targets = (np.repeat(rows, 3), cols)
        addresses = [Address(effect.field, n, c) for n in names for c in range(3)]
        super().__init__(effect, model, array, targets, addresses)
        self.nominal = self.nominal.astype(np.float64)
        self._raw = array[targets].copy()
        self.base = effect._seen_rgb(model, rows)  # (k, 3) float64: what the renderer shows at nominal
        self.rows = rows

    def draw_count(self) -> int:
        return 3 if self.effect.shared else self.size

    def values(self, draws: np.ndarray) -> np.ndarray:
        effect: _ColorEffect = self.effect
        d = np.broadcast_to(np.asarray(draws, dtype=np.float64).reshape(-1, 3), self.base.shape)
        base = rgb_to_hsv(self.base) if effect.space == "hsv" else self.base
        op = effect.operation
        out = base * d if op == "scale" else base + d if op == "add" else np.array(d)
        if effect.space == "hsv":
            out[:, 0] %= 1.0
            out = hsv_to_rgb(np.clip(out, 0.0, 1.0))
        # Reported values are exactly what the float32 model array holds.
        return np.clip(out, 0.0, 1.0).astype(self._array.dtype).astype(np.float64).reshape(-1)

    def restore(self) -> None:
        self._array[self._targets] = self._raw


class _ColorEffect(Effect):
    field: ClassVar[str]
    kind: ClassVar[str]
    selector: ClassVar[str]

    def __init__(
        self,
        *,
        scale: Any = None,
        add: Any = None,
        set: Any = None,
        select: str | Sequence[str] = "*",
        space: str = "rgb",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        cls = type(self).__name__
        operation, raw = _one_operation(cls, scale=scale, add=add, set=set)
        if space not in _SPACES:
            raise ValueError(f"`space` of {cls} must be one of {list(_SPACES)}. Received {space!r}.")
        dists = _channels(raw, operation, cls, 3)
        checked = dists if space == "rgb" else dists[1:]  # hue wraps around, any value is valid
        what = "colour channels" if space == "rgb" else "saturation and value"
        for dist in checked:
            _check_unit(operation, dist, operation, cls, what)
        _check_bool(shared, "shared", cls)
        _check_name(name, cls)
        self.operation: Operation = operation
        self.channels = dists
        self.distribution = Product(dists)
        self.patterns = _patterns(select, self.selector, cls)
        self.space = space
        self.shared = shared
        self.schedule = _check_schedule(schedule)
        self.name = name
        self._frozen = True

    def _fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {self.operation: _shown(self.channels)}
        out[self.selector] = self.patterns[0] if len(self.patterns) == 1 else list(self.patterns)
        if self.space != "rgb":
            out["space"] = self.space
        if self.shared:
            out["shared"] = True
        if self.schedule != "reset":
            out["schedule"] = self.schedule
        if self.name is not None:
            out["name"] = self.name
        return out

    @property
    def key(self) -> str:
        if self.name is not None:
            return self.name
        space = "" if self.space == "rgb" else f",space={self.space}"
        return f"{type(self).__name__}[{self.selector}={'|'.join(self.patterns)}{space}]"

    def _seen_rgb(self, model: mujoco.MjModel, rows: np.ndarray) -> np.ndarray:
        return np.asarray(getattr(model, self.field)[rows, :3], dtype=np.float64)

    def bind(self, model: mujoco.MjModel) -> _ColorBinding:
        """Resolves the selection and snapshots the nominal colours of ``model``."""
        chosen = _select(model, self.kind, self.patterns, self.selector)
        rows = np.array([i for i, _ in chosen], dtype=np.intp)
        return _ColorBinding(self, model, getattr(model, self.field), rows, [n for _, n in chosen])


class GeomColor(_ColorEffect):
    """Geom colours (``geom_rgba``, RGB channels; alpha untouched), in RGB or HSV.

    Args:
        scale | add | set: the operation, with one distribution for every channel (drawn
            independently per channel) or a sequence of three, one per channel (R, G, B or H, S, V;
            a number means a constant). Results are clipped to [0, 1]; in HSV the hue (in turns)
            wraps around instead.
        geoms: name pattern(s) of the geoms (default all).
        space: ``"rgb"`` or ``"hsv"``. ``add=(Uniform(-.05, .05), 0, 0), space="hsv"`` jitters
            hue only; ``scale=(1, 1, Uniform(.7, 1.3)), space="hsv"`` changes brightness only.
        shared: one draw for all selected geoms (a group keeps one colour) instead of one each.
        schedule: ``"reset"`` (default), ``"startup"`` or :class:`~randomizers.Interval`.
        name: stable stream name (defaults to the class name and selection).

    A geom that shows its material's colour (MuJoCo's rule: it has a material and the default
    rgba ``0.5 0.5 0.5 1``) is perturbed from that colour, so ``scale``/``add`` stay relative to
    what is seen. Reported as ``geom_rgba[<geom>][0..2]``.

    Example:
        >>> from randomizers import Uniform
        >>> GeomColor(add=(Uniform(-0.05, 0.05), 0.0, 0.0), geoms="finger*", space="hsv")
        GeomColor(add=(Uniform(low=-0.05, high=0.05), Constant(value=0.0), Constant(value=0.0)), \
geoms='finger*', space='hsv')
        >>> GeomColor(set=Uniform(0.0, 2.0))
        Traceback (most recent call last):
        ...
        ValueError: `set` of GeomColor must stay within [0, 1] (colour channels). Received Uniform(low=0.0, high=2.0).
    """

    field = "geom_rgba"
    kind = "geom"
    selector = "geoms"

    def __init__(
        self,
        *,
        scale: Any = None,
        add: Any = None,
        set: Any = None,
        geoms: str | Sequence[str] = "*",
        space: str = "rgb",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(
            scale=scale, add=add, set=set, select=geoms, space=space, shared=shared, schedule=schedule, name=name
        )

    def _seen_rgb(self, model: mujoco.MjModel, rows: np.ndarray) -> np.ndarray:
        rgba = model.geom_rgba[rows]
        mat = model.geom_matid[rows]
        uses_material = (mat >= 0) & (rgba == _DEFAULT_GEOM_RGBA).all(axis=1)
        seen = rgba[:, :3].astype(np.float64)
        seen[uses_material] = model.mat_rgba[mat[uses_material], :3]
        return seen


class MaterialColor(_ColorEffect):
    """Material colours (``mat_rgba``, RGB channels), in RGB or HSV; same arguments as
    :class:`GeomColor` with ``materials`` selecting by material name. Every geom using the
    material (and its default rgba) changes with it. Reported as ``mat_rgba[<material>][0..2]``.

    Example:
        >>> from randomizers import Uniform
        >>> MaterialColor(scale=(1.0, 1.0, Uniform(0.7, 1.3)), materials="link", space="hsv", shared=True)
        MaterialColor(scale=(Constant(value=1.0), Constant(value=1.0), Uniform(low=0.7, high=1.3)), \
materials='link', space='hsv', shared=True)
    """

    field = "mat_rgba"
    kind = "material"
    selector = "materials"

    def __init__(
        self,
        *,
        scale: Any = None,
        add: Any = None,
        set: Any = None,
        materials: str | Sequence[str] = "*",
        space: str = "rgb",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(
            scale=scale, add=add, set=set, select=materials, space=space, shared=shared, schedule=schedule, name=name
        )
