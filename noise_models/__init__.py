"""Sensor and actuator imperfections: noise processes, quantisation, dropout, latency buffers.

numpy only: this package knows nothing of MuJoCo or of environment APIs (see DESIGN.md).
The models themselves arrive with issue #3; nothing here pretends to work before then.
"""

from __future__ import annotations

__all__: list[str] = []
