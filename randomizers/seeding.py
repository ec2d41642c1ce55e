"""Keyed random streams (re-exported from :mod:`noise_models.seeding`, where they live so that the
numpy-only ``noise_models`` and the MuJoCo-side ``randomizers`` share one seeding scheme).

Example:
    >>> from randomizers.seeding import stream
    >>> import noise_models.seeding
    >>> stream is noise_models.seeding.stream
    True
"""

from __future__ import annotations

from noise_models.seeding import (
    SEPARATOR,
    SeedLike,
    StreamFactory,
    component_key,
    normalize_seed,
    reseeded_root,
    stream,
)

__all__ = ["SEPARATOR", "SeedLike", "StreamFactory", "component_key", "normalize_seed", "reseeded_root", "stream"]
