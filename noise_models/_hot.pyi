from collections.abc import Callable
from typing import Any

import numpy as np

class Pipe:
    def __init__(
        self,
        pipe: Any,
        fallback: Callable[[np.ndarray], np.ndarray],
        size: int,
        dtype: Any,
        low: np.ndarray | None,
        high: np.ndarray | None,
        block: int,
    ) -> None: ...
    def __call__(self, x: np.ndarray, now: int = ..., /) -> np.ndarray: ...

class NoisyLag:
    samples: int
    def __init__(
        self, pipe: Any, ring: list[np.ndarray], lag: int, samples: int, size: int, dtype: Any, block: int
    ) -> None: ...
    def __call__(self, obs: np.ndarray, now: int = ..., /) -> np.ndarray: ...
