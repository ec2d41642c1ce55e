"""Per-API wrappers. :func:`sim2real.wrap` picks the right one; use these directly if you prefer.

``RandomizePhysics`` (gymnasium), ``RandomizePhysicsDmEnv`` (dm_env) and
``RandomizePhysicsTransform`` (TorchRL, imported lazily so gymnasium users never load torch).
"""

from __future__ import annotations

from typing import Any

from sim2real.wrappers.dm import RandomizePhysicsDmEnv
from sim2real.wrappers.gym import RandomizePhysics

__all__ = ["RandomizePhysics", "RandomizePhysicsDmEnv", "RandomizePhysicsTransform"]


def __getattr__(name: str) -> Any:
    if name == "RandomizePhysicsTransform":
        from sim2real.wrappers.torchrl import RandomizePhysicsTransform

        return RandomizePhysicsTransform
    raise AttributeError(f"module 'sim2real.wrappers' has no attribute {name!r}")
