"""What a noise process compiles into for one episode: :class:`Compile` (its draws, streams and layout) and the
:class:`Part` it returns, the affine ones (a gain, an offset, a block of per-step draws) fused by
:mod:`noise_models.fused` into one ``x * G + F`` stage; :data:`BLOCK` steps of per-step randomness are drawn at once.

Example:
    >>> import numpy as np
    >>> part = Part(np.array([1, 2]), 4)
    >>> part.sel, part.kind
    (slice(1, 3, None), 'op')
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from noise_models.values import Layout, draw, is_sampler

if TYPE_CHECKING:
    from noise_models.processes import Process

__all__ = ["BLOCK", "Compile", "Part"]

#: Steps of per-step randomness drawn at once (one block costs about as much as a few steps).
BLOCK = 256


class Compile:
    """What a process needs to turn itself into this episode's runtime part."""

    def __init__(
        self,
        process: Process,
        prefix: str,
        layout: Layout,
        idx: np.ndarray,
        rng: np.random.Generator,
        block_rng: Callable[[int], np.random.Generator],
        report: dict[str, float],
        label: str = "",
        stream: tuple[list[int], int] | None = None,
    ) -> None:
        self.label = label
        #: ``(Philox key, episode)`` of ``block_rng``'s stream, when it is a keyed Philox stream
        #: (:meth:`noise_models.seeding.StreamFactory.philox_key`): block ``b`` is the draws of any Philox generator
        #: set to that key, counter ``[0, 0, 1 + b, episode]`` and an empty buffer. Lets code that refills many
        #: streams at once draw them with one generator (see :attr:`_Block.normals`).
        self.stream = stream
        self.process = process
        self.prefix = prefix
        self.layout = layout
        self.idx = idx
        self.k = int(idx.size)
        self.rng = rng
        self.block_rng = block_rng
        self.report = report

    def param(self, field: str, suffix: str) -> np.ndarray:
        """Draws parameter ``field`` for this episode (one value per selected element) and reports it."""
        value = getattr(self.process, field)
        stem = self.prefix + (f"_{suffix}" if suffix else "")
        if not is_sampler(value) or self.process.shared:
            one = float(draw(value, self.rng, 1)[0])
            self.report[stem + (f"[{self.label}]" if self.label else "")] = one
            return np.full(self.k, one)
        values = draw(value, self.rng, self.k)
        for i, v in zip(self.idx.tolist(), values.tolist(), strict=True):
            self.report[stem + self.layout.label(i)] = v
        return values


class Part:
    """One process compiled for an episode. ``kind`` is ``gain``, ``add``, ``block`` or ``op``."""

    kind = "op"

    def __init__(self, idx: np.ndarray, size: int) -> None:
        self.idx = idx
        # A contiguous selection is a slice: in-place work on a view, no gather/scatter.
        full = idx.size == size
        contiguous = idx.size > 0 and int(idx[-1]) - int(idx[0]) + 1 == idx.size
        self.sel: slice | np.ndarray = slice(int(idx[0]), int(idx[-1]) + 1) if contiguous or full else idx

    def refill(self, block: int) -> None:
        """Pre-draws the per-step randomness of block number ``block``."""

    def apply(self, w: np.ndarray, r: int) -> None:
        """Transforms the fresh working array ``w`` in place at step ``r`` of the current block."""


class _Gain(Part):
    kind = "gain"

    def __init__(self, idx: np.ndarray, size: int, gain: np.ndarray) -> None:
        super().__init__(idx, size)
        self.gain = gain


class _Add(Part):
    kind = "add"

    def __init__(self, idx: np.ndarray, size: int, offset: np.ndarray) -> None:
        super().__init__(idx, size)
        self.offset = offset
        self._rows: np.ndarray | None = None

    def rows(self) -> np.ndarray:
        """``offset`` repeated over a block's ``(BLOCK, k)`` rows (made at the first call): a block plus it is one
        contiguous loop instead of one short broadcast loop per row (the same sums)."""
        if self._rows is None:
            self._rows = np.broadcast_to(self.offset, (BLOCK, self.idx.size)).copy()
        return self._rows


class _Block(Part):
    """Additive per-step randomness: ``block(b)`` returns a (BLOCK, k) array; ``draw_into(b, out)``, where a process
    has one, writes the same values into a C-contiguous (BLOCK, k) float64 ``out`` instead."""

    kind = "block"

    def __init__(
        self,
        idx: np.ndarray,
        size: int,
        block: Callable[[int], np.ndarray],
        draw_into: Callable[[int, np.ndarray], None] | None = None,
        normals: tuple[list[int], int, float | np.ndarray] | None = None,
    ) -> None:
        super().__init__(idx, size)
        self.block = block
        self.draw_into = draw_into
        #: Where ``draw_into(b, out)`` is the keyed stream's standard normals times a scale: ``(Philox key, episode,
        #: scale)``, for :func:`noise_models.fused.next_blocks` to draw many worlds' blocks with one generator and no
        #: Python call per world (the same values: a Philox generator set to the key, counter ``[0, 0, 1 + b,
        #: episode]`` and an empty buffer, ``standard_normal(out=out)``, ``out *= scale``).
        self.normals = normals


def _block_scale(values: np.ndarray, k: int) -> float | np.ndarray:
    """What a ``(BLOCK, k)`` block of unit draws is multiplied by for per-entry scales ``values``: one float when
    every entry has the same (a constant or shared parameter: a contiguous multiply by a scalar), else ``values``
    repeated over the block's rows (a contiguous multiply instead of one short broadcast loop per row). The products
    are those of ``block * values`` either way."""
    values = np.asarray(values, dtype=np.float64)
    bits = values.view(np.uint64)
    if bool((bits == bits[0]).all()):  # bit for bit (0.0 and -0.0 are not the same scale)
        return float(values[0])
    return np.broadcast_to(values, (BLOCK, k)).copy()
