"""Visual effects: colours, procedural textures, lights and cameras, without recompiling the model.

They are :class:`randomizers.Effect` values like the physics effects, so
:class:`randomizers.PhysicsRandomizer` (and therefore ``sim2real.wrap``) drives them unchanged:
selection by name pattern, ``scale`` / ``add`` / ``set``, schedules, one keyed stream per effect,
every value reported by address (``geom_rgba[palm][0]``, ``light_diffuse[key][1]``,
``cam_fovy[overview]``, ``tex_rgb1[grid][2]``) and a bitwise ``restore_nominal()``.

Colour, light and camera edits are plain writes into ``MjModel`` arrays that the next render reads.
Texture edits rewrite ``model.tex_data`` and must then reach the GPU copy held by every live
``mujoco.MjrContext``: :class:`Texture` calls each function registered with
:func:`add_texture_uploader` (``sim2real`` registers the renderers it finds inside environments;
:func:`renderer_uploader` covers a bare ``mujoco.Renderer``). Contexts created later read the
rewritten data by themselves. Light positions and directions and camera poses reach
``MjData`` (``light_xpos``, ``cam_xpos``...) at the next ``mj_kinematics``/``mj_forward``/``mj_step``.

Example:
    >>> import mujoco, numpy as np
    >>> from randomizers import PhysicsRandomizer, Uniform
    >>> from randomizers.visual import GeomColor, Light
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><light name="top" pos="0 0 2"/>'
    ...     '<geom name="palm" size=".1" rgba=".8 .2 .2 1"/></worldbody></mujoco>')
    >>> r = PhysicsRandomizer([GeomColor(add=Uniform(-0.1, 0.1), geoms="palm"),
    ...                        Light(scale=Uniform(0.5, 1.5), attribute="diffuse", shared=True)], seed=0)
    >>> r.bind(model, mujoco.MjData(model))
    >>> r.begin_episode()
    >>> r.apply()
    >>> sorted(r.current_params)[:4]
    ['geom_rgba[palm][0]', 'geom_rgba[palm][1]', 'geom_rgba[palm][2]', 'light_diffuse[top][0]']
    >>> bool(model.geom_rgba[0, 0] != np.float32(0.8))
    True
    >>> r.restore_nominal()
    >>> model.geom_rgba[0].tolist() == np.array([.8, .2, .2, 1], np.float32).tolist()
    True
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import mujoco
import numpy as np

from randomizers.addressing import select as _select
from randomizers.distributions import Choice, Constant, Distribution, Uniform, as_distribution
from randomizers.effects import ArrayEffect, Binding, Effect, Operation, Schedule, _check_schedule

__all__ = [
    "PATTERNS",
    "VISUAL_EFFECTS",
    "CameraFovy",
    "CameraPose",
    "GeomColor",
    "Light",
    "MaterialColor",
    "Product",
    "Texture",
    "TextureUploader",
    "add_texture_uploader",
    "hsv_to_rgb",
    "render_texture",
    "renderer_uploader",
    "rgb_to_hsv",
    "texture_uploaders",
]

#: Procedural texture patterns of :class:`Texture`, in the order ``tex_pattern[...]`` indexes them.
PATTERNS: tuple[str, ...] = ("flat", "checker", "gradient", "noise")
_SPACES = ("rgb", "hsv")
_LIGHT_ATTRIBUTES = ("pos", "dir", "diffuse", "ambient", "specular", "castshadow", "active")
_LIGHT_FLAGS = ("castshadow", "active")
_SEED_HIGH = float(2**31)
# Geoms whose rgba is MuJoCo's default show their material's colour instead (the renderer's rule).
_DEFAULT_GEOM_RGBA = np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32)

# ----------------------------------------------------------------------------- element selection


def _patterns(select: object, argument: str, owner: str) -> tuple[str, ...]:
    if isinstance(select, str):
        return (select,)
    if isinstance(select, Sequence) and select and all(isinstance(p, str) for p in select):
        return tuple(select)
    raise TypeError(f"`{argument}` of {owner} must be a name pattern or a non-empty list of them. Received {select!r}.")


def _check_name(name: object, owner: str) -> None:
    if name is not None and (not isinstance(name, str) or not name):
        raise TypeError(f"`name` of {owner} must be a non-empty string. Received {name!r}.")


def _check_bool(value: object, argument: str, owner: str) -> None:
    if not isinstance(value, bool):
        raise TypeError(f"`{argument}` of {owner} must be a bool. Received {value!r}.")


def _one_operation(owner: str, **given: object) -> tuple[Operation, object]:
    present = {op: v for op, v in given.items() if v is not None}
    if len(present) != 1:
        raise ValueError(f"{owner} needs exactly one of `scale`, `add` or `set`. Received {sorted(present) or 'none'}.")
    ((operation, raw),) = present.items()
    return operation, raw  # type: ignore[return-value]


# ----------------------------------------------------------------------------- distributions


@dataclass(frozen=True)
class Product(Distribution):
    """Independent components drawn together: ``sample(rng, k * n)`` returns ``n`` rows of one draw
    per component, flattened row after row (component ``j`` of row ``i`` at ``i * k + j``).

    Visual effects use it as their ``distribution`` (e.g. one component per colour channel), so
    the randomiser's ``distribution.sample(generator, binding.draw_count())`` covers them too. Each
    component draws its whole column in turn, so a component never shifts another's values.

    Example:
        >>> import numpy as np
        >>> from randomizers import Constant, Uniform
        >>> d = Product((Uniform(0.0, 1.0), Constant(5.0)))
        >>> d.sample(np.random.default_rng(0), 4).reshape(2, 2)[:, 1].tolist()
        [5.0, 5.0]
        >>> d.sample(np.random.default_rng(0), 3)
        Traceback (most recent call last):
        ...
        ValueError: `size` of Product must be a multiple of its 2 components. Received 3.
    """

    components: tuple[Distribution, ...]

    def __post_init__(self) -> None:
        comps = tuple(self.components) if isinstance(self.components, (tuple, list)) else ()
        if not comps or not all(isinstance(c, Distribution) for c in comps):
            raise TypeError(
                f"`components` of Product must be a non-empty tuple of Distributions. Received {self.components!r}."
            )
        object.__setattr__(self, "components", comps)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        k = len(self.components)
        if size is None:
            return np.array([float(c.sample(rng)) for c in self.components])
        n = int(np.prod(size))
        if n % k:
            raise ValueError(f"`size` of Product must be a multiple of its {k} components. Received {size!r}.")
        rows = n // k
        columns = [np.asarray(c.sample(rng, rows), dtype=np.float64) for c in self.components]
        return np.stack(columns, axis=1).reshape(size)

    def to_config(self) -> dict[str, Any]:
        return {"type": "Product", "components": [c.to_config() for c in self.components]}

    @property
    def support(self) -> tuple[float, float]:
        lows, highs = zip(*(c.support for c in self.components), strict=True)
        return (min(lows), max(highs))


def _channels(value: object, argument: str, owner: str, width: int) -> tuple[Distribution, ...]:
    """One distribution for every channel, or a sequence of ``width`` (numbers or distributions)."""
    if isinstance(value, (list, tuple)):
        if len(value) != width:
            raise ValueError(
                f"`{argument}` of {owner} must be one distribution or a sequence of {width} (one per channel). "
                f"Received {len(value)} entries: {value!r}."
            )
        return tuple(as_distribution(v, f"{argument}[{i}]") for i, v in enumerate(value))
    return (as_distribution(value, argument),) * width


def _shown(dists: tuple[Distribution, ...]) -> Distribution | tuple[Distribution, ...]:
    return dists[0] if all(d == dists[0] for d in dists) else dists


def _check_unit(operation: str, dist: Distribution, argument: str, owner: str, what: str) -> None:
    low, high = dist.support
    if operation == "scale" and low < 0:
        raise ValueError(f"`{argument}` of {owner} must not go below 0 ({what} stay in [0, 1]). Received {dist!r}.")
    if operation == "set" and (low < 0 or high > 1):
        raise ValueError(f"`{argument}` of {owner} must stay within [0, 1] ({what}). Received {dist!r}.")


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
        addresses = [f"{effect.field}[{n}][{c}]" for n in names for c in range(3)]
        super().__init__(effect, model, array, targets, addresses)  # type: ignore[arg-type]
        self.nominal = self.nominal.astype(np.float64)
        self._raw = array[targets].copy()
        self.base = effect._seen_rgb(model, rows)  # (k, 3) float64: what the renderer shows at nominal
        self.rows = rows

    def draw_count(self) -> int:
        return 3 if self.effect.shared else self.size

    def values(self, draws: np.ndarray) -> np.ndarray:
        effect: _ColorEffect = self.effect  # type: ignore[assignment]
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


# ----------------------------------------------------------------------------- lights


class _LightBinding(Binding):
    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self._raw = self._array[self._targets].copy()
        self.nominal = self._raw.astype(np.float64)
        effect: Light = self.effect  # type: ignore[assignment]
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

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[str]]:
        chosen = _select(model, self.kind, self.patterns, self.selector)
        if self.attribute in _LIGHT_FLAGS:
            return [i for i, _ in chosen], None, [f"{self.field}[{n}]" for _, n in chosen]
        rows = [i for i, _ in chosen for _ in range(3)]
        cols = [c for _ in chosen for c in range(3)]
        return rows, cols, [f"{self.field}[{n}][{c}]" for _, n in chosen for c in range(3)]


# ----------------------------------------------------------------------------- cameras


class CameraFovy(ArrayEffect):
    """Vertical field of view of the selected cameras (``cam_fovy``, degrees, kept in (0, 180)).

    Example:
        >>> from randomizers import Uniform
        >>> CameraFovy(scale=Uniform(0.9, 1.1), cameras="overview")
        CameraFovy(scale=Uniform(low=0.9, high=1.1), cameras='overview')
        >>> CameraFovy(set=Uniform(30, 200))
        Traceback (most recent call last):
        ...
        ValueError: `set` of CameraFovy must stay in (0, 180) degrees. Received Uniform(low=30.0, high=200.0).
    """

    field = "cam_fovy"
    kind = "camera"
    selector = "cameras"

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        cameras: str | Sequence[str] = "*",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(scale=scale, add=add, set=set, select=cameras, shared=shared, schedule=schedule, name=name)
        low, high = self.distribution.support
        if self.operation == "set" and (low <= 0 or high >= 180):
            raise ValueError(f"`set` of CameraFovy must stay in (0, 180) degrees. Received {self.distribution!r}.")
        self._frozen = True

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[str]]:
        chosen = _select(model, self.kind, self.patterns, self.selector)
        return [i for i, _ in chosen], None, [f"cam_fovy[{n}]" for _, n in chosen]

    def bind(self, model: mujoco.MjModel) -> Binding:
        """Resolves the cameras; rejects a distribution that could leave (0, 180) degrees for one of them."""
        binding = super().bind(model)
        low, high = self.distribution.support
        ends = np.stack([binding.values(np.array([low])), binding.values(np.array([high]))])
        bad = np.flatnonzero(~((ends > 0) & (ends < 180)).all(axis=0))
        if bad.size:
            k = int(bad[0])
            raise ValueError(
                f"`{self.operation}` of CameraFovy would take {binding.addresses[k]} (nominal "
                f"{float(binding.nominal[k])!r}) outside (0, 180) degrees. Received {self.distribution!r}."
            )
        return binding


def _look_at_quat(eye: np.ndarray, target: np.ndarray, up: np.ndarray, roll: float) -> np.ndarray:
    """Quaternion of a MuJoCo camera (looks along -z, y up) at ``eye`` aimed at ``target``."""
    z = eye - target
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-9:  # looking straight along ``up``: any perpendicular will do
        x = np.cross(np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(roll), math.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.stack([x, y, z], axis=1).reshape(-1))
    return quat


class _PoseBinding(Binding):
    def __init__(self, effect: CameraPose, model: mujoco.MjModel, chosen: list[tuple[int, str]]) -> None:
        self.effect = effect
        self.model = model
        self.rows = np.array([i for i, _ in chosen], dtype=np.intp)
        self.addresses = tuple(
            [f"cam_pos[{n}][{c}]" for _, n in chosen for c in range(3)]
            + [f"cam_quat[{n}][{c}]" for _, n in chosen for c in range(4)]
        )
        self.size = len(self.addresses)
        self._pos = model.cam_pos[self.rows].copy()
        self._quat = model.cam_quat[self.rows].copy()
        self.nominal = np.concatenate([self._pos.reshape(-1), self._quat.reshape(-1)])
        flat = np.zeros((len(self.rows), 9))
        for k, q in enumerate(self._quat):
            mujoco.mju_quat2Mat(flat[k], q)
        mats = flat.reshape(-1, 3, 3)
        self._up = mats[:, :, 1]  # camera y axes in the parent frame
        forward = -mats[:, :, 2]
        if effect.look_at is not None:
            self.targets = np.tile(np.asarray(effect.look_at, dtype=np.float64), (len(self.rows), 1))
        else:
            self.targets = self._default_targets(model, forward)

    def _default_targets(self, model: mujoco.MjModel, forward: np.ndarray) -> np.ndarray:
        # The nominal look-at: the point of the optical axis nearest the model's centre (at the
        # default pose, in the camera's parent body frame); the extent ahead when that is behind.
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        out = np.empty((len(self.rows), 3))
        for k, cam in enumerate(self.rows):
            body = int(model.cam_bodyid[cam])
            rot = data.xmat[body].reshape(3, 3)
            center = rot.T @ (np.asarray(model.stat.center) - data.xpos[body])
            depth = float(forward[k] @ (center - self._pos[k]))
            if depth <= 1e-6:
                depth = float(model.stat.extent)
            out[k] = self._pos[k] + depth * forward[k]
        return out

    def draw_count(self) -> int:
        return 4 if self.effect.shared else 4 * len(self.rows)

    def values(self, draws: np.ndarray) -> np.ndarray:
        effect: CameraPose = self.effect  # type: ignore[assignment]
        d = np.broadcast_to(np.asarray(draws, dtype=np.float64).reshape(-1, 4), (len(self.rows), 4))
        op = effect.operation
        pos = self._pos * d[:, :3] if op == "scale" else self._pos + d[:, :3] if op == "add" else np.array(d[:, :3])
        quats = np.empty((len(self.rows), 4))
        for k in range(len(self.rows)):
            if np.linalg.norm(pos[k] - self.targets[k]) < 1e-9:
                raise ValueError(
                    f"CameraPose drew {self.addresses[3 * k][:-3]} at its look-at point {self.targets[k].tolist()}: "
                    f"the camera cannot aim at itself. Received {op}={_shown(effect.offsets)!r}."
                )
            quats[k] = _look_at_quat(pos[k], self.targets[k], self._up[k], float(d[k, 3]))
        return np.concatenate([pos.reshape(-1), quats.reshape(-1)])

    def apply(self, values: np.ndarray) -> None:
        n = 3 * len(self.rows)
        self.model.cam_pos[self.rows] = values[:n].reshape(-1, 3)
        self.model.cam_quat[self.rows] = values[n:].reshape(-1, 4)

    def restore(self) -> None:
        self.model.cam_pos[self.rows] = self._pos
        self.model.cam_quat[self.rows] = self._quat


class CameraPose(Effect):
    """Camera position perturbed by ``scale``/``add``/``set`` (xyz in the parent body's frame), the
    camera re-aimed at its nominal look-at point (so the scene stays in view), then rolled about
    its optical axis by ``roll`` radians.

    Args:
        scale | add | set: the position operation, one distribution for all three axes (drawn
            independently per axis) or a sequence of three (a number means a constant).
        cameras: name pattern(s) of the cameras (default all).
        roll: roll about the optical axis in radians (default 0).
        look_at: the point to aim at, in the parent body's frame; default: the point of the nominal
            optical axis nearest the model's centre (``model.stat.center``, default pose).
        shared: one draw for all selected cameras instead of one each.
        schedule: ``"reset"`` (default), ``"startup"`` or :class:`~randomizers.Interval`.
        name: stable stream name.

    Reported as ``cam_pos[<camera>][0..2]`` and ``cam_quat[<camera>][0..3]`` (the values written).
    Cameras whose mode aims them at a body (``targetbody``) keep the engine's aim.

    Example:
        >>> from randomizers import Uniform
        >>> CameraPose(add=Uniform(-0.05, 0.05), roll=Uniform(-0.1, 0.1), cameras="overview")
        CameraPose(add=Uniform(low=-0.05, high=0.05), cameras='overview', roll=Uniform(low=-0.1, high=0.1))
        >>> CameraPose(add=0.1, look_at=(0, 0))
        Traceback (most recent call last):
        ...
        ValueError: `look_at` of CameraPose must be None or 3 finite numbers. Received (0, 0).
    """

    def __init__(
        self,
        *,
        scale: Any = None,
        add: Any = None,
        set: Any = None,
        cameras: str | Sequence[str] = "*",
        roll: Distribution | float = 0.0,
        look_at: Sequence[float] | None = None,
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        cls = "CameraPose"
        operation, raw = _one_operation(cls, scale=scale, add=add, set=set)
        offsets = _channels(raw, operation, cls, 3)
        roll_dist = as_distribution(roll, "roll")
        if look_at is not None:
            ok = (
                isinstance(look_at, (list, tuple))
                and len(look_at) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in look_at)
            )
            if not ok:
                raise ValueError(f"`look_at` of {cls} must be None or 3 finite numbers. Received {look_at!r}.")
            look_at = tuple(float(v) for v in look_at)
        _check_bool(shared, "shared", cls)
        _check_name(name, cls)
        self.operation: Operation = operation
        self.offsets = offsets
        self.roll = roll_dist
        self.look_at = look_at
        self.distribution = Product((*offsets, roll_dist))
        self.patterns = _patterns(cameras, "cameras", cls)
        self.shared = shared
        self.schedule = _check_schedule(schedule)
        self.name = name
        self._frozen = True

    def _fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {self.operation: _shown(self.offsets)}
        out["cameras"] = self.patterns[0] if len(self.patterns) == 1 else list(self.patterns)
        if self.roll != Constant(0.0):
            out["roll"] = self.roll
        if self.look_at is not None:
            out["look_at"] = list(self.look_at)
        if self.shared:
            out["shared"] = True
        if self.schedule != "reset":
            out["schedule"] = self.schedule
        if self.name is not None:
            out["name"] = self.name
        return out

    @property
    def key(self) -> str:
        return self.name or f"CameraPose[cameras={'|'.join(self.patterns)}]"

    def bind(self, model: mujoco.MjModel) -> _PoseBinding:
        """Resolves the cameras and snapshots their nominal pose and look-at points."""
        return _PoseBinding(self, model, _select(model, "camera", self.patterns, "cameras"))


# ----------------------------------------------------------------------------- textures

#: ``uploader(model, texture_ids)``: pushes those textures of ``model`` to the GPU copies it knows.
TextureUploader = Callable[[mujoco.MjModel, Sequence[int]], None]
_UPLOADERS: dict[int, TextureUploader] = {}
_TOKENS = itertools.count()


def add_texture_uploader(uploader: TextureUploader) -> Callable[[], None]:
    """Registers ``uploader(model, texture_ids)``, called after every texture write; returns a
    function that unregisters it.

    The uploader must ignore models it does not render, make its GL context current and call
    ``mujoco.mjr_uploadTexture(model, context, texture_id)`` for each id.

    Example:
        >>> calls = []
        >>> remove = add_texture_uploader(lambda model, ids: calls.append(list(ids)))
        >>> remove()
    """
    if not callable(uploader):
        raise TypeError(f"`uploader` must be callable as uploader(model, texture_ids). Received {uploader!r}.")
    token = next(_TOKENS)
    _UPLOADERS[token] = uploader

    def remove() -> None:
        _UPLOADERS.pop(token, None)

    return remove


def texture_uploaders() -> tuple[TextureUploader, ...]:
    """The registered uploaders (a snapshot)."""
    return tuple(_UPLOADERS.values())


def renderer_uploader(renderer: mujoco.Renderer) -> TextureUploader:
    """An uploader for a bare ``mujoco.Renderer`` (register it with :func:`add_texture_uploader`).

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string("<mujoco/>")
        >>> renderer = mujoco.Renderer(model, 8, 8)
        >>> remove = add_texture_uploader(renderer_uploader(renderer))
        >>> remove(); renderer.close()
    """

    def upload(model: mujoco.MjModel, ids: Sequence[int]) -> None:
        context = getattr(renderer, "_mjr_context", None)
        if context is None or renderer.model is not model:
            return
        renderer._gl_context.make_current()
        for texid in ids:
            mujoco.mjr_uploadTexture(model, context, int(texid))

    return upload


def _upload(model: mujoco.MjModel, ids: Sequence[int]) -> None:
    for uploader in tuple(_UPLOADERS.values()):
        uploader(model, ids)


_NOISE_CELLS = 8  # random values per face side (texrepeat tiles them seamlessly)
_NOISE_RES = 128  # the noise field is computed at most this fine, then looked up per texel


def _interpolation(size: int, cells: int) -> np.ndarray:
    """``(size, cells)`` periodic smoothstep interpolation weights (two non-zeros per row)."""
    pos = (np.arange(size, dtype=np.float64) + 0.5) * (cells / size) - 0.5
    i0 = np.floor(pos).astype(np.intp)
    f = pos - i0
    f = f * f * (3 - 2 * f)  # smoothstep: no visible grid lines
    out = np.zeros((size, cells), dtype=np.float32)
    rows = np.arange(size)
    np.add.at(out, (rows, i0 % cells), 1 - f)
    np.add.at(out, (rows, (i0 + 1) % cells), f)
    return out


class _TextureGeometry:
    """One texture's layout and per-texel pattern indices, precomputed at bind so a resample is a
    palette lookup: every pattern mixes ``rgb1`` towards ``rgb2`` in 256 steps, and each texel
    holds the step it shows (flat: 0; checker: 0 or 255; gradient and noise: in between)."""

    def __init__(self, model: mujoco.MjModel, texid: int) -> None:
        self.texid = texid
        self.width = int(model.tex_width[texid])
        self.height = int(model.tex_height[texid])
        self.channels = int(model.tex_nchannel[texid])
        self.adr = int(model.tex_adr[texid])
        self.size = self.width * self.height
        self.nbytes = self.size * self.channels
        self.cube = int(model.tex_type[texid]) != int(mujoco.mjtTexture.mjTEXTURE_2D) and self.height == 6 * self.width
        self.faces, self.rows = (6, self.width) if self.cube else (1, self.height)
        self._steps: dict[str, np.ndarray] = {}
        self._noise: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Per face (row, column) texel centres in [-1, 1]."""
        r = (2 * np.arange(self.rows, dtype=np.float32) + 1) / self.rows - 1
        c = (2 * np.arange(self.width, dtype=np.float32) + 1) / self.width - 1
        return r[:, None], c[None, :]

    def steps(self, pattern: str) -> np.ndarray:
        """``(size,)`` uint8 palette step of every texel for ``checker`` or ``gradient``."""
        if pattern not in self._steps:
            vv, uu = self._grid()
            if pattern == "checker":  # 2x2 squares per face, like MuJoCo's builtin checker
                face = ((vv > 0).astype(np.uint8) + (uu > 0).astype(np.uint8)) % 2 * 255
                out = np.broadcast_to(face, (self.faces, self.rows, self.width))
            elif self.cube:  # by elevation; faces +x -x +y -y +z -z, +y is the sky (as MuJoCo's gradient)
                norm = np.sqrt(1 + uu * uu + vv * vv)
                up = np.stack(np.broadcast_arrays(-vv / norm, -vv / norm, 1 / norm, -1 / norm, -vv / norm, -vv / norm))
                out = np.rint((1 - up) / 2 * 255)  # rgb1 at the zenith, rgb2 at the nadir
            else:  # rgb1 at the top row, rgb2 at the bottom
                out = np.broadcast_to(np.rint((vv + 1) / 2 * 255), (self.rows, self.width))
            self._steps[pattern] = np.ascontiguousarray(out, dtype=np.uint8).reshape(-1)
        return self._steps[pattern]

    def noise_steps(self, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Smooth periodic value noise from ``seed``: (coarse steps, per-texel index into them)."""
        if self._noise is None:
            lr, lc = min(self.rows, _NOISE_RES), min(self.width, _NOISE_RES)
            rows = (np.arange(self.rows) * lr // self.rows)[:, None]
            cols = (np.arange(self.width) * lc // self.width)[None, :]
            faces = np.arange(self.faces)[:, None, None] * (lr * lc)
            mapping = (faces + rows * lc + cols).astype(np.int32 if self.faces * lr * lc < 2**31 else np.intp)
            self._noise = (_interpolation(lr, _NOISE_CELLS), _interpolation(lc, _NOISE_CELLS), mapping.reshape(-1))
        wr, wc, mapping = self._noise
        grid = np.random.Generator(np.random.Philox(seed)).random((self.faces, _NOISE_CELLS, _NOISE_CELLS), np.float32)
        coarse = np.rint(np.clip(wr @ grid @ wc.T, 0.0, 1.0) * 255).astype(np.uint8).reshape(-1)
        return coarse, mapping

    def write(self, out: np.ndarray, pattern: str, rgb1: np.ndarray, rgb2: np.ndarray, seed: int) -> None:
        """Writes the texels into ``out`` (``(size, channels)`` uint8; channels past the third kept)."""
        c1, c2 = np.asarray(rgb1, dtype=np.float64), np.asarray(rgb2, dtype=np.float64)
        palette = np.rint((c1 + (c2 - c1) * (np.arange(256)[:, None] / 255.0)) * 255).astype(np.uint8)
        if self.channels < 3:  # luminance textures get the grey level
            palette = np.rint(palette.mean(axis=1, keepdims=True)).astype(np.uint8)
        width = min(self.channels, 3)
        colours = np.ascontiguousarray(palette[:, :width]).view(f"V{width}").reshape(-1)
        target = out.view(f"V{self.channels}").reshape(-1) if width == self.channels else None
        if pattern == "flat":
            if target is not None:
                target[...] = colours[0]
            else:
                out[:, :width] = palette[0, :width]
            return
        if pattern == "noise":
            coarse, mapping = self.noise_steps(seed)
            colours, index = colours[coarse], mapping  # colour the coarse field, then one lookup per texel
        else:
            index = self.steps(pattern)
        if target is not None:
            np.take(colours, index, out=target)
        else:
            out[:, :width] = np.take(colours, index).view(np.uint8).reshape(-1, width)


def render_texture(
    geometry: _TextureGeometry, pattern: str, rgb1: Sequence[float], rgb2: Sequence[float], seed: int
) -> np.ndarray:
    """The texels (``(n, channels)`` uint8, alpha zero) of one procedural texture: ``rgb1`` mixed
    towards ``rgb2`` (flat: all ``rgb1``; checker: 2x2 squares per face; gradient: ``rgb1`` at the
    top / zenith to ``rgb2`` at the bottom / nadir; noise: smooth periodic value noise from ``seed``)."""
    out = np.zeros((geometry.size, geometry.channels), dtype=np.uint8)
    geometry.write(out, pattern, np.asarray(rgb1), np.asarray(rgb2), seed)
    return out


class _TextureBinding(Binding):
    def __init__(self, effect: Texture, model: mujoco.MjModel, chosen: list[tuple[int, str]]) -> None:
        self.effect = effect
        self.model = model
        self.geometry = [_TextureGeometry(model, i) for i, _ in chosen]
        for g in self.geometry:  # the per-texel work happens here, once, not at every resample
            for pattern in effect.patterns_drawn:
                if pattern in ("checker", "gradient"):
                    g.steps(pattern)
                elif pattern == "noise":
                    g.noise_steps(0)
        self.texids = [i for i, _ in chosen]
        self.addresses = tuple(
            a
            for _, n in chosen
            for a in (
                f"tex_pattern[{n}]",
                *(f"tex_rgb1[{n}][{c}]" for c in range(3)),
                *(f"tex_rgb2[{n}][{c}]" for c in range(3)),
                f"tex_seed[{n}]",
            )
        )
        self.size = len(self.addresses)
        # The model's own textures are not procedural draws: their parameters are reported as NaN.
        self.nominal = np.full(self.size, np.nan)
        self._raw = [model.tex_data[g.adr : g.adr + g.nbytes].copy() for g in self.geometry]

    def draw_count(self) -> int:
        return 8 if self.effect.shared else 8 * len(self.texids)

    def values(self, draws: np.ndarray) -> np.ndarray:
        d = np.broadcast_to(np.asarray(draws, dtype=np.float64).reshape(-1, 8), (len(self.texids), 8)).copy()
        d[:, 0] = np.floor(d[:, 0])
        d[:, 1:7] = np.clip(d[:, 1:7], 0.0, 1.0)
        d[:, 7] = np.floor(d[:, 7])
        return d.reshape(-1)

    def apply(self, values: np.ndarray) -> None:
        patterns: tuple[str, ...] = self.effect.patterns_drawn  # type: ignore[attr-defined]
        v = values.reshape(-1, 8)
        data = self.model.tex_data
        for g, row in zip(self.geometry, v, strict=True):
            view = data[g.adr : g.adr + g.nbytes].reshape(-1, g.channels)
            g.write(view, patterns[int(row[0])], row[1:4], row[4:7], int(row[7]))
        _upload(self.model, self.texids)

    def restore(self) -> None:
        data = self.model.tex_data
        for g, raw in zip(self.geometry, self._raw, strict=True):
            data[g.adr : g.adr + g.nbytes] = raw
        _upload(self.model, self.texids)


class Texture(Effect):
    """Procedural textures written into ``model.tex_data`` (no recompile) and uploaded to every
    registered render context: 2D textures (e.g. the floor's grid) and cube/skybox textures.

    Every draw sets a whole new texture from reported parameters, so logs reproduce it exactly:
    ``tex_pattern[<tex>]`` (index into ``pattern``), ``tex_rgb1[<tex>][0..2]``,
    ``tex_rgb2[<tex>][0..2]`` and ``tex_seed[<tex>]`` (the noise seed). Textures always ``set``:
    the model's own texture has no parameters to scale or add to (they report NaN as nominal), and
    ``restore_nominal()`` brings the original texels back bitwise. The alpha channel is kept.

    Args:
        textures: name pattern(s) of the textures (default all; e.g. ``"grid"``, ``"sky*"``).
        pattern: one of :data:`PATTERNS` or a list to draw from uniformly.
        rgb1: first colour, one distribution per channel or a sequence of three (values in [0, 1]).
        rgb2: second colour (checker squares, gradient end, noise extreme).
        shared: one draw for all selected textures instead of one each.
        schedule: ``"reset"`` (default), ``"startup"`` or :class:`~randomizers.Interval`.
        name: stable stream name.

    Example:
        >>> from randomizers import Uniform
        >>> Texture(textures="grid", pattern=["checker", "noise"])
        Texture(textures='grid', pattern=['checker', 'noise'], rgb1=Uniform(low=0.0, high=1.0), \
rgb2=Uniform(low=0.0, high=1.0))
        >>> Texture(pattern="stripes")
        Traceback (most recent call last):
        ...
        ValueError: `pattern` of Texture must be one of ['flat', 'checker', 'gradient', 'noise'] or a list of them. \
Received 'stripes'.
    """

    def __init__(
        self,
        *,
        textures: str | Sequence[str] = "*",
        pattern: str | Sequence[str] = PATTERNS,
        rgb1: Any = Uniform(0.0, 1.0),  # noqa: B008 - immutable value
        rgb2: Any = Uniform(0.0, 1.0),  # noqa: B008 - immutable value
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        cls = "Texture"
        drawn = (pattern,) if isinstance(pattern, str) else tuple(pattern) if isinstance(pattern, Sequence) else ()
        if not drawn or any(p not in PATTERNS for p in drawn) or len(set(drawn)) != len(drawn):
            raise ValueError(
                f"`pattern` of {cls} must be one of {list(PATTERNS)} or a list of them. Received {pattern!r}."
            )
        colours = {}
        for argument, value in (("rgb1", rgb1), ("rgb2", rgb2)):
            dists = _channels(value, argument, cls, 3)
            for dist in dists:
                _check_unit("set", dist, argument, cls, "colour channels")
            colours[argument] = dists
        _check_bool(shared, "shared", cls)
        _check_name(name, cls)
        self.patterns = _patterns(textures, "textures", cls)
        self.patterns_drawn = drawn
        self.rgb1 = colours["rgb1"]
        self.rgb2 = colours["rgb2"]
        index: Distribution = Constant(0.0) if len(drawn) == 1 else Choice(tuple(float(i) for i in range(len(drawn))))
        self.distribution = Product((index, *self.rgb1, *self.rgb2, Uniform(0.0, _SEED_HIGH)))
        self.shared = shared
        self.schedule = _check_schedule(schedule)
        self.name = name
        self._frozen = True

    def _fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {"textures": self.patterns[0] if len(self.patterns) == 1 else list(self.patterns)}
        out["pattern"] = self.patterns_drawn[0] if len(self.patterns_drawn) == 1 else list(self.patterns_drawn)
        out["rgb1"] = _shown(self.rgb1)
        out["rgb2"] = _shown(self.rgb2)
        if self.shared:
            out["shared"] = True
        if self.schedule != "reset":
            out["schedule"] = self.schedule
        if self.name is not None:
            out["name"] = self.name
        return out

    @property
    def key(self) -> str:
        return self.name or f"Texture[textures={'|'.join(self.patterns)}]"

    def bind(self, model: mujoco.MjModel) -> _TextureBinding:
        """Resolves the textures, snapshots their texels and precomputes the pattern weights."""
        return _TextureBinding(self, model, _select(model, "texture", self.patterns, "textures"))


#: Every visual effect class (``randomizers.config`` registers them for YAML).
VISUAL_EFFECTS: tuple[type[Effect], ...] = (GeomColor, MaterialColor, Texture, Light, CameraPose, CameraFovy)
