"""Whether the single-env hot path runs compiled, and its compiled pieces.

sim2real ships two optional C extensions (built by ``setup.py`` when a C compiler is there): ``noise_models._hot``
(one noise pipeline's step, and the observation noise + fixed-lag ring) and ``sim2real.wrappers._hotstep`` (the fused
wrapper layer's step). They run the same arithmetic on the same state as the Python closures they replace, bitwise
(``tests/test_compiled.py``), with no Python bytecode or numpy dispatch per step. Without them, or with the environment
variable ``SIM2REAL_PURE_PYTHON=1`` (read at each episode's start), every step runs the Python code.

Example:
    >>> import os
    >>> from noise_models import compiled
    >>> compiled.enabled() == (compiled.available() and os.environ.get("SIM2REAL_PURE_PYTHON", "") in ("", "0"))
    True
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from noise_models.parts import BLOCK

try:
    from noise_models import _hot
except ImportError:  # pragma: no cover - built without a C compiler
    _hot = None  # type: ignore[assignment]

if TYPE_CHECKING:
    from noise_models.fused import Pipeline

__all__ = ["ENV", "available", "enabled", "noisy_lag", "pipe"]

#: The environment variable that turns the compiled hot path off ("1"; unset, "" or "0": on where built).
ENV = "SIM2REAL_PURE_PYTHON"


def available() -> bool:
    """Whether the extensions were built with this install."""
    return _hot is not None


def enabled() -> bool:
    """Whether episodes starting now step compiled: the extensions are built and ``SIM2REAL_PURE_PYTHON`` is not set
    to anything but "" or "0"."""
    return _hot is not None and os.environ.get(ENV, "") in ("", "0")


def _float(dtype: np.dtype) -> bool:
    return dtype in (np.float32, np.float64) and dtype.isnative


def pipe(pipeline: Pipeline, fallback: Callable[[np.ndarray], np.ndarray]) -> Any:
    """``fallback`` (``hot_pipe(pipeline)``) compiled, or ``fallback`` itself when that is not possible: the compiled
    step handles one add and the whole-signal clip of a float32/float64 signal and hands everything else (a new block,
    a gain, the guarded clip, another array type) to ``fallback``. Callable as ``(x)`` or ``(x, now)``."""
    if not enabled() or not _float(pipeline.dtype):
        return fallback
    low, high = pipeline.low, pipeline.high
    if (low is None) != (high is None):
        return fallback
    return _hot.Pipe(pipeline, fallback, pipeline.layout.size, pipeline.dtype, low, high, BLOCK)


def noisy_lag(pipeline: Pipeline, ring: list[np.ndarray], lag: int, samples: int) -> Any:
    """``SignalCorruptor._hot_noisy_lag`` compiled (``samples``: the episode's count so far), or None when that is not
    possible. Callable as ``(obs)`` or ``(obs, now)``; its ``samples`` attribute counts as the closure's ``k``."""
    if not enabled() or not _float(pipeline.dtype) or type(ring) is not list:
        return None
    return _hot.NoisyLag(pipeline, ring, lag, samples, pipeline.layout.size, pipeline.dtype, BLOCK)
