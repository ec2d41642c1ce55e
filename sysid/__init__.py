"""System identification from logged trajectories (issue #5).

Fits the same parameter addresses that :mod:`randomizers` perturbs. Empty until issue #5 lands;
nothing here pretends to work before then.
"""

from __future__ import annotations

__all__: list[str] = []
