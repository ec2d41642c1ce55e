"""Procedural textures (flat, checker, gradient, noise) redrawn into ``model.tex_data``, and the uploaders that push
rewritten textures to every live ``mujoco.MjrContext``.

Example:
    >>> PATTERNS
    ('flat', 'checker', 'gradient', 'noise')
    >>> remove = add_texture_uploader(lambda model, ids: None)
    >>> len(texture_uploaders()) >= 1
    True
    >>> remove()
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from typing import Any

import mujoco
import numpy as np

from randomizers.addressing import Address
from randomizers.addressing import select as _select
from randomizers.distributions import Choice, Constant, Distribution, Uniform
from randomizers.effects import Binding, Effect, Schedule, _check_schedule
from randomizers.visual.arguments import (
    Product,
    _channels,
    _check_bool,
    _check_name,
    _check_unit,
    _patterns,
    _shown,
)

__all__ = [
    "PATTERNS",
    "Texture",
    "TextureUploader",
    "add_texture_uploader",
    "render_texture",
    "renderer_uploader",
    "texture_uploaders",
]

#: Procedural texture patterns of :class:`Texture`, in the order ``tex_pattern[...]`` indexes them.
PATTERNS: tuple[str, ...] = ("flat", "checker", "gradient", "noise")
_SEED_HIGH = float(2**31)

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
                Address("tex_pattern", n),
                *(Address("tex_rgb1", n, c) for c in range(3)),
                *(Address("tex_rgb2", n, c) for c in range(3)),
                Address("tex_seed", n),
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
        patterns: tuple[str, ...] = self.effect.patterns_drawn
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
