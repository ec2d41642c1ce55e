"""Per-API wrappers. :func:`sim2real.wrap` picks the right one; use these directly if you prefer.

``RandomizePhysics`` (gymnasium), ``RandomizePhysicsDmEnv`` (dm_env) and
``RandomizePhysicsTransform`` (TorchRL, imported lazily so gymnasium users never load torch) apply
physics effects; ``CorruptSignals``, ``CorruptSignalsDmEnv`` and ``CorruptSignalsTransform`` apply
the noise and timing models of :mod:`noise_models`. ``RandomizeAndCorrupt``, ``RandomizeAndCorruptDmEnv`` and
``RandomizeAndCorruptTransform`` (TorchRL, lazily) do both in one layer, bitwise as the two stacked
(:mod:`sim2real.wrappers.fused`); :func:`sim2real.wrap` uses them when it is given both.
"""

from __future__ import annotations

from typing import Any

from sim2real.wrappers.dm import RandomizePhysicsDmEnv
from sim2real.wrappers.fused import RandomizeAndCorrupt, RandomizeAndCorruptDmEnv
from sim2real.wrappers.gym import RandomizePhysics
from sim2real.wrappers.signals import CorruptSignals, CorruptSignalsDmEnv

__all__ = [
    "CorruptSignals",
    "CorruptSignalsDmEnv",
    "CorruptSignalsTransform",
    "RandomizeAndCorrupt",
    "RandomizeAndCorruptDmEnv",
    "RandomizeAndCorruptTransform",
    "RandomizePhysics",
    "RandomizePhysicsDmEnv",
    "RandomizePhysicsTransform",
]


def __getattr__(name: str) -> Any:
    if name in ("RandomizePhysicsTransform", "CorruptSignalsTransform"):
        from sim2real.wrappers import torchrl

        return getattr(torchrl, name)
    if name == "RandomizeAndCorruptTransform":
        from sim2real.wrappers import fused_torchrl

        return fused_torchrl.RandomizeAndCorruptTransform
    raise AttributeError(f"module 'sim2real.wrappers' has no attribute {name!r}")
