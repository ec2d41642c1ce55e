"""Noise processes: what can go wrong with one sample of a signal, composable in a pipeline.

Each process is an immutable value (``==``, ``repr``, hashable). Its parameters take a number or a
distribution (drawn once per episode, per selected element unless ``shared=True``); per-step
randomness (white noise, dropouts, spikes...) is pre-drawn in blocks of :data:`BLOCK` steps from the
process's own keyed stream, so enabling one process never shifts another's draws.

Processes run at the signal's rate (one step = one control step for observations and actions);
time constants such as ``Drift(timescale=...)`` and ``Stuck(duration=...)`` count those steps.

Example:
    >>> Gaussian(std=0.01)
    Gaussian(std=0.01)
    >>> Gaussian(std=-1.0)
    Traceback (most recent call last):
    ...
    ValueError: `std` must be >= 0. Received -1.0.
    >>> Dropout(probability=0.1, mode="zero") == Dropout(probability=0.1, mode="zero")
    True
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from noise_models.parts import BLOCK, Compile, Part, _Add, _Block, _block_scale, _Gain
from noise_models.values import (
    FrozenValue,
    Selection,
    check_probability,
    check_selection,
    check_value,
    draw,
    is_sampler,
    value_config,
)

__all__ = [
    "BLOCK",
    "Bias",
    "Deadzone",
    "Drift",
    "Dropout",
    "Gaussian",
    "Outlier",
    "Process",
    "Quantize",
    "Saturate",
    "Scale",
    "Sticky",
    "Stuck",
    "UniformNoise",
]


class Process(FrozenValue):
    """Base of every noise process: immutable, compared by value, with a stable stream name.

    Args (common to every process):
        select: which elements it acts on: None (all), observation key names (fnmatch patterns),
            an index, a slice/range or a list of indices.
        shared: draw one value per episode for all selected elements instead of one each.
        name: report/stream name (default: the process's kind, e.g. ``noise`` for Gaussian).
    """

    stem: ClassVar[str] = ""
    sides: ClassVar[tuple[str, ...]] = ("obs", "action")
    #: parameter fields in draw order, with the report suffix of each ("" = the stem alone)
    params: ClassVar[tuple[tuple[str, str], ...]] = ()

    def __init__(self, *, select: Selection = None, shared: bool = False, name: str | None = None) -> None:
        self.select = check_selection(select)
        if not isinstance(shared, bool):
            raise TypeError(f"`shared` must be a bool. Received {shared!r}.")
        self.shared = shared
        if name is not None and (not isinstance(name, str) or not name or not name.replace("_", "").isalnum()):
            raise ValueError(f"`name` must be a non-empty identifier such as 'imu_noise'. Received {name!r}.")
        self.name = name or self.stem

    def _fields(self) -> dict[str, Any]:
        out = {k: getattr(self, k) for k in self._own_fields()}
        if self.select is not None:
            out["select"] = self.select
        if self.shared:
            out["shared"] = True
        if self.name != self.stem:
            out["name"] = self.name
        return out

    def _own_fields(self) -> tuple[str, ...]:
        return tuple(p for p, _ in self.params)

    def to_config(self) -> dict[str, Any]:
        """A YAML-ready mapping (``type`` plus fields)."""
        out: dict[str, Any] = {"type": type(self).__name__}
        for k, v in self._fields().items():
            out[k] = value_config(v) if k in self._own_fields() else (list(v) if isinstance(v, tuple) else v)
        return out

    def compile(self, ctx: Compile) -> Part:  # pragma: no cover - every subclass overrides
        raise NotImplementedError


# -- additive / multiplicative processes (fused into one affine map per step) -------------------


class Gaussian(Process):
    """White Gaussian noise with standard deviation ``std``.

    Args:
        std: standard deviation (>= 0), a number or a distribution drawn per episode.

    Example:
        >>> Gaussian(std=0.02, select="velocity")
        Gaussian(std=0.02, select='velocity')
    """

    stem = "noise"
    params = (("std", "std"),)

    def __init__(self, std: Any, *, select: Selection = None, shared: bool = False, name: str | None = None) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.std = check_value(std, "std", low=0.0)
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        std = ctx.param("std", "std")
        k = ctx.k
        scale = _block_scale(std, k)

        def draw_into(b: int, out: np.ndarray) -> None:
            ctx.block_rng(b).standard_normal(out=out)
            out *= scale

        def block(b: int) -> np.ndarray:
            w = np.empty((BLOCK, k))
            draw_into(b, w)
            return w

        normals = None
        if ctx.stream is not None:
            key, episode = ctx.stream
            normals = (key, episode, scale)
        return _Block(ctx.idx, ctx.layout.size, block, draw_into, normals)


class UniformNoise(Process):
    """White noise uniform on ``[-half_width, half_width)`` (std = half_width / sqrt(3)).

    Named ``UniformNoise`` so it never shadows the ``Uniform`` distribution its parameters often use.

    Example:
        >>> UniformNoise(half_width=0.01)
        UniformNoise(half_width=0.01)
    """

    stem = "uniform_noise"
    params = (("half_width", "half_width"),)

    def __init__(
        self, half_width: Any, *, select: Selection = None, shared: bool = False, name: str | None = None
    ) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.half_width = check_value(half_width, "half_width", low=0.0)
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        hw = ctx.param("half_width", "half_width")
        k = ctx.k
        scale = _block_scale(hw, k)

        def block(b: int) -> np.ndarray:
            w = ctx.block_rng(b).uniform(-1.0, 1.0, (BLOCK, k))
            w *= scale
            return w

        return _Block(ctx.idx, ctx.layout.size, block)


class Bias(Process):
    """A constant offset for the whole episode (drawn at reset when ``offset`` is a distribution).

    Example:
        >>> from randomizers import Uniform
        >>> Bias(Uniform(-0.02, 0.02))
        Bias(offset=Uniform(low=-0.02, high=0.02))
    """

    stem = "bias"
    params = (("offset", ""),)

    def __init__(self, offset: Any, *, select: Selection = None, shared: bool = False, name: str | None = None) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.offset = check_value(offset, "offset")
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        return _Add(ctx.idx, ctx.layout.size, ctx.param("offset", ""))


class Scale(Process):
    """A multiplicative gain error for the whole episode (``gain`` >= 0).

    Example:
        >>> Scale(gain=1.05)
        Scale(gain=1.05)
    """

    stem = "scale"
    params = (("gain", ""),)

    def __init__(self, gain: Any, *, select: Selection = None, shared: bool = False, name: str | None = None) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.gain = check_value(gain, "gain", low=0.0)
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        return _Gain(ctx.idx, ctx.layout.size, ctx.param("gain", ""))


class Drift(Process):
    """A slowly wandering offset: a random walk, or an Ornstein–Uhlenbeck process with a timescale.

    Starts at 0 every episode.

    Args:
        std: without ``timescale``, the standard deviation of each step's increment (the walk's
            variance grows by ``std**2`` per step); with ``timescale``, the stationary standard
            deviation of the Ornstein–Uhlenbeck process.
        timescale: correlation time in steps (> 0), or None for a random walk.

    Example:
        >>> Drift(std=0.001)
        Drift(std=0.001, timescale=None)
        >>> Drift(std=0.01, timescale=0)
        Traceback (most recent call last):
        ...
        ValueError: `timescale` must be > 0. Received 0.0.
    """

    stem = "drift"
    params = (("std", "std"), ("timescale", "timescale"))

    def __init__(
        self,
        std: Any,
        timescale: Any = None,
        *,
        select: Selection = None,
        shared: bool = False,
        name: str | None = None,
    ) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.std = check_value(std, "std", low=0.0)
        self.timescale = check_value(timescale, "timescale", low=0.0, low_open=True, allow_none=True)
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        std = ctx.param("std", "std")
        k = ctx.k
        state = np.zeros(k)
        if self.timescale is None:

            def walk(b: int) -> np.ndarray:
                steps = ctx.block_rng(b).standard_normal((BLOCK, k)) * std
                total = np.cumsum(steps, axis=0)
                out = total - steps + state  # the value before each step's increment: 0 at reset
                state[:] = out[-1] + steps[-1]
                return out

            return _Block(ctx.idx, ctx.layout.size, walk)

        tau = ctx.param("timescale", "timescale")
        a = np.exp(-1.0 / tau)
        b_coef = std * np.sqrt(1.0 - a * a)

        def ou(b: int) -> np.ndarray:
            eps = ctx.block_rng(b).standard_normal((BLOCK, k)) * b_coef
            out = np.empty((BLOCK, k))
            x = state
            for i in range(BLOCK):  # a linear recursion; once per block, not per step
                out[i] = x
                x = a * x + eps[i]
            state[:] = x
            return out

        return _Block(ctx.idx, ctx.layout.size, ou)


class Outlier(Process):
    """Spikes: with ``probability`` per step and element, add ``±magnitude`` (random sign).

    Args:
        probability: chance of a spike per step and element, in [0, 1].
        magnitude: spike size (>= 0); a distribution is drawn per spike.

    Example:
        >>> Outlier(probability=0.01, magnitude=1.0)
        Outlier(probability=0.01, magnitude=1.0)
    """

    stem = "outlier"
    params = (("probability", "probability"), ("magnitude", "magnitude"))

    def __init__(
        self,
        probability: Any,
        magnitude: Any,
        *,
        select: Selection = None,
        shared: bool = False,
        name: str | None = None,
    ) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.probability = check_probability(probability)
        self.magnitude = check_value(magnitude, "magnitude", low=0.0)
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        p = ctx.param("probability", "probability")
        k = ctx.k
        magnitude = self.magnitude
        if not is_sampler(magnitude):
            ctx.report[ctx.prefix + "_magnitude" + (f"[{ctx.label}]" if ctx.label else "")] = float(magnitude)

        def block(b: int) -> np.ndarray:
            rng = ctx.block_rng(b)
            hit = rng.random((BLOCK, k)) < p
            sign = np.where(rng.random((BLOCK, k)) < 0.5, -1.0, 1.0)
            size = draw(magnitude, rng, BLOCK * k).reshape(BLOCK, k)
            return hit * sign * size

        return _Block(ctx.idx, ctx.layout.size, block)


# -- non-linear processes ----------------------------------------------------------------------


class _Op(Part):
    def get(self, w: np.ndarray) -> np.ndarray:
        return w[self.sel]


class Quantize(Process):
    """Rounds to multiples of ``resolution`` (an encoder's or ADC's step), > 0.

    Example:
        >>> Quantize(resolution=0.001)
        Quantize(resolution=0.001)
    """

    stem = "quantize"
    params = (("resolution", "resolution"),)

    def __init__(
        self, resolution: Any, *, select: Selection = None, shared: bool = False, name: str | None = None
    ) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.resolution = check_value(resolution, "resolution", low=0.0, low_open=True)
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        res = ctx.param("resolution", "resolution")
        inv = 1.0 / res

        class _Quantize(_Op):
            def apply(self, w: np.ndarray, r: int) -> None:
                w[self.sel] = np.round(w[self.sel] * inv) * res

        return _Quantize(ctx.idx, ctx.layout.size)


class Saturate(Process):
    """Clips to ``[low, high]`` (a sensor's or actuator's range).

    Example:
        >>> Saturate(low=-1.0, high=1.0)
        Saturate(low=-1.0, high=1.0)
        >>> Saturate(low=1.0, high=-1.0)
        Traceback (most recent call last):
        ...
        ValueError: `low` must be < `high`. Received low=1.0, high=-1.0.
    """

    stem = "saturate"
    params = (("low", "low"), ("high", "high"))

    def __init__(
        self, low: Any, high: Any, *, select: Selection = None, shared: bool = False, name: str | None = None
    ) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.low = check_value(low, "low")
        self.high = check_value(high, "high")
        if not is_sampler(self.low) and not is_sampler(self.high) and not self.low < self.high:
            raise ValueError(f"`low` must be < `high`. Received low={self.low!r}, high={self.high!r}.")
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        lo = ctx.param("low", "low")
        hi = np.maximum(ctx.param("high", "high"), lo)

        class _Saturate(_Op):
            def apply(self, w: np.ndarray, r: int) -> None:
                w[self.sel] = np.clip(w[self.sel], lo, hi)

        return _Saturate(ctx.idx, ctx.layout.size)


class Dropout(Process):
    """Lost samples: with ``probability`` per step and element the value is lost and replaced by the
    last delivered value (``mode="hold"``) or by 0 (``mode="zero"``). Before any value was delivered
    in the episode, ``hold`` gives 0.

    Example:
        >>> Dropout(probability=0.05)
        Dropout(probability=0.05, mode='hold')
        >>> Dropout(probability=0.05, mode="last")
        Traceback (most recent call last):
        ...
        ValueError: `mode` must be one of ['hold', 'zero']. Received 'last'.
    """

    stem = "dropout"
    params = (("probability", "probability"),)

    def __init__(
        self,
        probability: Any,
        mode: str = "hold",
        *,
        select: Selection = None,
        shared: bool = False,
        name: str | None = None,
    ) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.probability = check_probability(probability)
        if mode not in ("hold", "zero"):
            raise ValueError(f"`mode` must be one of ['hold', 'zero']. Received {mode!r}.")
        self.mode = mode
        self._freeze()

    def _own_fields(self) -> tuple[str, ...]:
        return ("probability", "mode")

    def compile(self, ctx: Compile) -> Part:
        p = ctx.param("probability", "probability")
        k = ctx.k
        hold = self.mode == "hold"

        class _Dropout(_Op):
            mask = np.zeros((BLOCK, k), dtype=bool)
            last = np.zeros(k)

            def refill(self, block: int) -> None:
                self.mask = ctx.block_rng(block).random((BLOCK, k)) < p

            def apply(self, w: np.ndarray, r: int) -> None:
                m = self.mask[r]
                v = w[self.sel]
                if m.any():
                    v[m] = self.last[m] if hold else 0.0
                    w[self.sel] = v
                if hold:
                    self.last = v.copy()

        return _Dropout(ctx.idx, ctx.layout.size)


class Stuck(Process):
    """A sensor that freezes: with ``probability`` per step and element it sticks at its last value
    for ``duration`` steps (a number or a distribution drawn per event, rounded, at least 1).

    Example:
        >>> Stuck(probability=0.001, duration=20)
        Stuck(probability=0.001, duration=20.0)
    """

    stem = "stuck"
    params = (("probability", "probability"), ("duration", "duration"))

    def __init__(
        self,
        probability: Any,
        duration: Any,
        *,
        select: Selection = None,
        shared: bool = False,
        name: str | None = None,
    ) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.probability = check_probability(probability)
        self.duration = check_value(duration, "duration", low=1.0)
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        p = ctx.param("probability", "probability")
        k = ctx.k
        duration = self.duration
        if not is_sampler(duration):
            ctx.report[ctx.prefix + "_duration" + (f"[{ctx.label}]" if ctx.label else "")] = float(duration)

        class _Stuck(_Op):
            onset = np.zeros((BLOCK, k), dtype=bool)
            length = np.ones((BLOCK, k), dtype=np.int64)
            count = np.zeros(k, dtype=np.int64)
            held: np.ndarray | None = None

            def refill(self, block: int) -> None:
                rng = ctx.block_rng(block)
                self.onset = rng.random((BLOCK, k)) < p
                d = draw(duration, rng, BLOCK * k).reshape(BLOCK, k)
                self.length = np.maximum(np.rint(d), 1).astype(np.int64)

            def apply(self, w: np.ndarray, r: int) -> None:
                v = w[self.sel]
                if self.held is not None:
                    start = self.onset[r] & (self.count == 0)
                    if start.any():
                        self.count[start] = self.length[r][start]
                    stuck = self.count > 0
                    if stuck.any():
                        v[stuck] = self.held[stuck]
                        w[self.sel] = v
                        self.count[stuck] -= 1
                self.held = v.copy()

        return _Stuck(ctx.idx, ctx.layout.size)


class Deadzone(Process):
    """Commands with magnitude below ``width`` have no effect (become 0); larger ones pass unchanged.

    Action side only.

    Example:
        >>> Deadzone(width=0.05)
        Deadzone(width=0.05)
    """

    stem = "deadzone"
    sides = ("action",)
    params = (("width", "width"),)

    def __init__(self, width: Any, *, select: Selection = None, shared: bool = False, name: str | None = None) -> None:
        super().__init__(select=select, shared=shared, name=name)
        self.width = check_value(width, "width", low=0.0)
        self._freeze()

    def compile(self, ctx: Compile) -> Part:
        width = ctx.param("width", "width")

        class _Deadzone(_Op):
            def apply(self, w: np.ndarray, r: int) -> None:
                v = w[self.sel]
                v[np.abs(v) < width] = 0.0
                w[self.sel] = v

        return _Deadzone(ctx.idx, ctx.layout.size)


class Sticky(Process):
    """With ``probability`` per step, the previous command is repeated instead of the new one
    (all selected elements together). Action side only.

    Example:
        >>> Sticky(probability=0.25)
        Sticky(probability=0.25)
    """

    stem = "sticky"
    sides = ("action",)
    params = (("probability", "probability"),)

    def __init__(
        self, probability: Any, *, select: Selection = None, shared: bool = False, name: str | None = None
    ) -> None:
        super().__init__(select=select, shared=True, name=name)
        if not isinstance(shared, bool):
            raise TypeError(f"`shared` must be a bool. Received {shared!r}.")
        self.probability = check_probability(probability)
        self._freeze()

    def _fields(self) -> dict[str, Any]:
        out = super()._fields()
        out.pop("shared", None)
        return out

    def compile(self, ctx: Compile) -> Part:
        p = float(ctx.param("probability", "probability")[0])

        class _Sticky(_Op):
            repeat = np.zeros(BLOCK, dtype=bool)
            prev: np.ndarray | None = None

            def refill(self, block: int) -> None:
                self.repeat = ctx.block_rng(block).random(BLOCK) < p

            def apply(self, w: np.ndarray, r: int) -> None:
                if self.repeat[r] and self.prev is not None:
                    w[self.sel] = self.prev
                self.prev = w[self.sel].copy()

        return _Sticky(ctx.idx, ctx.layout.size)


PROCESS_TYPES: dict[str, type[Process]] = {
    cls.__name__: cls
    for cls in (
        Gaussian,
        UniformNoise,
        Bias,
        Scale,
        Drift,
        Outlier,
        Quantize,
        Saturate,
        Dropout,
        Stuck,
        Deadzone,
        Sticky,
    )
}
