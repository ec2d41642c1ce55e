"""Contact sheets: N randomised first frames of a task in one PNG (``sim2real visualize``).

It builds on the task registry, the wrappers and :class:`~sim2real.pixels.PixelObservation`, so it lives above
all three (the pixel module itself imports none of them).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from randomizers import Effect, load_effects
from randomizers.files import atomic_write, check_suffix
from sim2real.output_paths import check_file
from sim2real.pixels import check_size
from sim2real.tasks import make
from sim2real.wrapping import wrap

__all__ = ["ContactSheet", "contact_sheet"]


@dataclass(frozen=True)
class ContactSheet:
    """N randomised frames of one task and the sheet image made of them.

    Attributes:
        frames: ``(n, height, width, 3)`` uint8, frame ``i`` from ``reset(seed=seed + i)``.
        params: the values in use for each frame (``info["sim2real"]["params"]``).
        image: the rendered sheet, ``(H, W, 3)`` uint8.
        path: where the PNG was written (None when not written).
    """

    frames: np.ndarray
    params: tuple[dict[str, float], ...]
    image: np.ndarray
    path: Path | None


def _effects(effects: Iterable[Effect] | str | os.PathLike[str] | None) -> list[Effect]:
    if effects is None:
        return []
    if isinstance(effects, (str, os.PathLike)):
        return load_effects(Path(effects) if Path(effects).suffix in (".yaml", ".yml") else effects)
    out = list(effects)
    for i, e in enumerate(out):
        if not isinstance(e, Effect):
            raise TypeError(f"`effects[{i}]` must be an effect from randomizers. Received {e!r}.")
    return out


def contact_sheet(
    task: str,
    effects: Iterable[Effect] | str | os.PathLike[str] | None = None,
    *,
    n: int = 16,
    seed: int = 0,
    size: tuple[int, int] = (84, 84),
    camera: int | str | None = None,
    columns: int | None = None,
    out: str | os.PathLike[str] | None = None,
    title: str | None = None,
) -> ContactSheet:
    """Renders ``n`` randomised first frames of ``task`` into a grid (matplotlib, Agg).

    Args:
        task: a task id (``sim2real tasks``).
        effects: effects, or a YAML file/string of them (:func:`randomizers.load_effects`);
            None renders the nominal task.
        n: number of frames; frame ``i`` is the first observation after ``reset(seed=seed + i)``.
        seed: root seed of the effect streams and first reset seed.
        size: ``(height, width)`` of each frame.
        camera: camera name or id (default the model's first camera).
        columns: grid columns (default ``ceil(sqrt(n))``).
        out: PNG path, written atomically (temporary file, then rename; missing folders are created), checked
            before any rendering (:func:`sim2real.output_paths.check_file`); None writes nothing.
        title: sheet title (default: task, effect count and seed).

    Example:
        >>> import sim2real as s2r
        >>> sheet = s2r.contact_sheet("sim2real/arm-reach", [s2r.Light(scale=s2r.Uniform(0.2, 1.5))],
        ...                           n=2, size=(24, 24))
        >>> sheet.frames.shape, sheet.image.dtype, bool((sheet.frames[0] != sheet.frames[1]).any())
        ((2, 24, 24, 3), dtype('uint8'), True)
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"`n` must be an int >= 1. Received {n!r}.")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"`seed` must be an int >= 0. Received {seed!r}.")
    if columns is not None and (isinstance(columns, bool) or not isinstance(columns, int) or columns < 1):
        raise ValueError(f"`columns` must be None or an int >= 1. Received {columns!r}.")
    size = check_size(size)
    if out is not None:
        check_file(out, "`out`")  # before any rendering: a path that cannot be written costs nothing
        check_suffix(out, "`out`", (".png",), "the sheet is a PNG image")
    chosen = _effects(effects)
    env = wrap(make(task, pixels=True, size=size, camera=camera), *chosen, seed=seed)
    frames, params = [], []
    try:
        for i in range(n):
            obs, info = env.reset(seed=seed + i)
            frames.append(obs)
            params.append(dict(info.get("sim2real", {}).get("params", {})))
    finally:
        env.close()
    cols = columns or int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    fig = Figure(figsize=(1.6 * cols, 1.6 * rows + 0.4), dpi=100)
    FigureCanvasAgg(fig)
    for i in range(rows * cols):
        ax = fig.add_subplot(rows, cols, i + 1)
        ax.set_axis_off()
        if i < n:
            ax.imshow(frames[i], interpolation="nearest")
            ax.set_title(f"seed {seed + i}", fontsize=7)
    fig.suptitle(title or f"{task}: {len(chosen)} effect(s), seed {seed}", fontsize=9)
    fig.tight_layout()
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()  # type: ignore[attr-defined]
    path = None
    if out is not None:
        path = Path(out)
        atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))  # missing folders are created
    return ContactSheet(np.stack(frames), tuple(params), image, path)
