"""Immutable probability distributions for parameter perturbations.

Every distribution is a frozen dataclass: comparable with ``==``, printable with ``repr`` and safe
to share between environments. All of them draw from an explicit :class:`numpy.random.Generator`
(never the global ``np.random``), so a seeded generator reproduces every value bitwise.

Example:
    >>> import numpy as np
    >>> from randomizers import Uniform
    >>> d = Uniform(0.5, 1.5)
    >>> d
    Uniform(low=0.5, high=1.5)
    >>> d.support
    (0.5, 1.5)
    >>> a = d.sample(np.random.default_rng(0), size=3)
    >>> b = d.sample(np.random.default_rng(0), size=3)
    >>> bool((a == b).all()) and bool(((a >= 0.5) & (a < 1.5)).all())
    True
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = [
    "Choice",
    "Constant",
    "Distribution",
    "LogUniform",
    "MultivariateNormal",
    "Normal",
    "Sampler",
    "TruncatedNormal",
    "Uniform",
    "as_distribution",
    "distribution_from_config",
]


@runtime_checkable
class Sampler(Protocol):
    """Anything with ``sample(rng, size)``; ``noise_models`` accepts these by duck typing."""

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        """Draws values from ``rng``."""
        ...


def _finite(name: str, owner: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"`{name}` of {owner} must be a real number. Received {value!r}.")
    out = float(value)
    if not math.isfinite(out):
        raise ValueError(f"`{name}` of {owner} must be finite. Received {out!r}.")
    return out


class Distribution:
    """Base class: a value distribution with a known support.

    Subclasses implement :meth:`sample` and :attr:`support`. ``support`` is the closed interval that
    contains every possible draw; effects use it to reject ranges that would make a physical
    quantity negative before anything is simulated.
    """

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        """Draws ``size`` values (a float when ``size`` is None) from ``rng``."""
        raise NotImplementedError

    @property
    def support(self) -> tuple[float, float]:
        """(lowest, highest) possible draw; may be infinite."""
        raise NotImplementedError

    def to_config(self) -> dict[str, Any]:
        """A YAML-ready mapping that :func:`distribution_from_config` turns back into ``self``."""
        fields = {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}
        return {"type": type(self).__name__, **{k: v for k, v in fields.items() if v is not None}}


@dataclass(frozen=True)
class Constant(Distribution):
    """Always ``value``.

    Example:
        >>> import numpy as np
        >>> Constant(2.0).sample(np.random.default_rng(0), size=2).tolist()
        [2.0, 2.0]
    """

    value: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "value", _finite("value", "Constant", self.value))

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        if size is None:
            return self.value
        return np.full(size, self.value)

    @property
    def support(self) -> tuple[float, float]:
        return (self.value, self.value)


@dataclass(frozen=True)
class Uniform(Distribution):
    """Uniform on ``[low, high)``.

    Example:
        >>> Uniform(2.0, 1.0)
        Traceback (most recent call last):
        ...
        ValueError: `high` of Uniform must be >= `low`. Received low=2.0, high=1.0.
    """

    low: float
    high: float

    def __post_init__(self) -> None:
        low = _finite("low", "Uniform", self.low)
        high = _finite("high", "Uniform", self.high)
        if high < low:
            raise ValueError(f"`high` of Uniform must be >= `low`. Received low={low!r}, high={high!r}.")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        return rng.uniform(self.low, self.high, size)

    @property
    def support(self) -> tuple[float, float]:
        return (self.low, self.high)


@dataclass(frozen=True)
class LogUniform(Distribution):
    """Log-uniform on ``[low, high)``; both bounds must be > 0.

    Example:
        >>> LogUniform(0.0, 1.0)
        Traceback (most recent call last):
        ...
        ValueError: `low` of LogUniform must be > 0. Received 0.0.
    """

    low: float
    high: float

    def __post_init__(self) -> None:
        low = _finite("low", "LogUniform", self.low)
        high = _finite("high", "LogUniform", self.high)
        if low <= 0:
            raise ValueError(f"`low` of LogUniform must be > 0. Received {low!r}.")
        if high < low:
            raise ValueError(f"`high` of LogUniform must be >= `low`. Received low={low!r}, high={high!r}.")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        return np.exp(rng.uniform(math.log(self.low), math.log(self.high), size))

    @property
    def support(self) -> tuple[float, float]:
        return (self.low, self.high)


@dataclass(frozen=True)
class Normal(Distribution):
    """Gaussian with ``mean`` and ``std`` (unbounded support: effects on non-negative quantities
    reject it; use :class:`TruncatedNormal` there).

    Example:
        >>> Normal(0.0, -1.0)
        Traceback (most recent call last):
        ...
        ValueError: `std` of Normal must be >= 0. Received -1.0.
    """

    mean: float
    std: float

    def __post_init__(self) -> None:
        mean = _finite("mean", "Normal", self.mean)
        std = _finite("std", "Normal", self.std)
        if std < 0:
            raise ValueError(f"`std` of Normal must be >= 0. Received {std!r}.")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        return rng.normal(self.mean, self.std, size)

    @property
    def support(self) -> tuple[float, float]:
        if self.std == 0:
            return (self.mean, self.mean)
        return (-math.inf, math.inf)


@dataclass(frozen=True)
class TruncatedNormal(Distribution):
    """Gaussian ``(mean, std)`` restricted to ``[low, high]`` (sampled by inverting the CDF, so one
    uniform variate per draw and no rejection loop).

    Example:
        >>> import numpy as np
        >>> x = TruncatedNormal(1.0, 0.5, low=0.8, high=1.1).sample(np.random.default_rng(1), size=1000)
        >>> bool(x.min() >= 0.8 and x.max() <= 1.1)
        True
    """

    mean: float
    std: float
    low: float
    high: float

    def __post_init__(self) -> None:
        vals = {k: _finite(k, "TruncatedNormal", getattr(self, k)) for k in ("mean", "std", "low", "high")}
        if vals["std"] <= 0:
            raise ValueError(f"`std` of TruncatedNormal must be > 0. Received {vals['std']!r}.")
        if vals["high"] <= vals["low"]:
            raise ValueError(
                f"`high` of TruncatedNormal must be > `low`. Received low={vals['low']!r}, high={vals['high']!r}."
            )
        for k, v in vals.items():
            object.__setattr__(self, k, v)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        from scipy.special import ndtr, ndtri

        a = ndtr((self.low - self.mean) / self.std)
        b = ndtr((self.high - self.mean) / self.std)
        u = rng.uniform(a, b, size)
        out = np.clip(self.mean + self.std * ndtri(u), self.low, self.high)
        return float(out) if size is None else out

    @property
    def support(self) -> tuple[float, float]:
        return (self.low, self.high)


@dataclass(frozen=True)
class Choice(Distribution):
    """One of ``values`` (with optional probabilities ``p`` summing to 1).

    Example:
        >>> import numpy as np
        >>> Choice((0.5, 1.0, 2.0)).support
        (0.5, 2.0)
        >>> Choice((1.0, 2.0), p=(0.5, 0.6))
        Traceback (most recent call last):
        ...
        ValueError: `p` of Choice must be non-negative and sum to 1. Received (0.5, 0.6).
    """

    values: tuple[float, ...]
    p: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if isinstance(self.values, (str, bytes)) or not isinstance(self.values, Sequence) or not self.values:
            raise ValueError(f"`values` of Choice must be a non-empty sequence of numbers. Received {self.values!r}.")
        values = tuple(_finite("values", "Choice", v) for v in self.values)
        object.__setattr__(self, "values", values)
        if self.p is not None:
            p = tuple(_finite("p", "Choice", v) for v in self.p)
            if len(p) != len(values):
                raise ValueError(
                    f"`p` of Choice must have one entry per value ({len(values)}). Received {len(p)} entries."
                )
            if min(p) < 0 or not math.isclose(sum(p), 1.0, abs_tol=1e-9):
                raise ValueError(f"`p` of Choice must be non-negative and sum to 1. Received {p!r}.")
            object.__setattr__(self, "p", p)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        out = rng.choice(np.asarray(self.values), size=size, p=None if self.p is None else np.asarray(self.p))
        return float(out) if size is None else out

    @property
    def support(self) -> tuple[float, float]:
        return (min(self.values), max(self.values))


def _vector(name: str, value: object, size: int | None, fill: float | None = None) -> tuple[float, ...]:
    if value is None and fill is not None and size is not None:
        return (fill,) * size
    array = np.asarray(value, dtype=np.float64) if not isinstance(value, (str, bytes)) else np.zeros(0)
    if array.ndim != 1 or array.size == 0 or (size is not None and array.size != size):
        want = f"{size} numbers" if size is not None else "a non-empty list of numbers"
        raise ValueError(f"`{name}` of MultivariateNormal must be {want}. Received {value!r}.")
    return tuple(float(v) for v in array)


@dataclass(frozen=True)
class MultivariateNormal(Distribution):
    """A Gaussian vector with ``mean`` (P,) and covariance ``cov`` (P, P), optionally truncated to the box
    ``[low, high]`` (per component; ``None`` means unbounded). One draw is a whole (P,) vector, so correlated
    parameters move together (:class:`randomizers.correlated.Correlated` writes one draw into P addresses).

    Truncation is by rejection (whole vectors, from the same generator); when fewer than one draw in
    ten thousand falls inside the box the draw is clipped to it instead.

    Example:
        >>> import numpy as np
        >>> d = MultivariateNormal((1.0, 2.0), ((0.04, 0.03), (0.03, 0.09)), low=(0.0, 0.0))
        >>> d.sample(np.random.default_rng(0)).shape, d.sample(np.random.default_rng(0), 5).shape
        ((2,), (5, 2))
        >>> MultivariateNormal((0.0,), ((-1.0,),))
        Traceback (most recent call last):
        ...
        ValueError: `cov` of MultivariateNormal must be symmetric positive semi-definite. Received ((-1.0,),).
    """

    mean: tuple[float, ...]
    cov: tuple[tuple[float, ...], ...]
    low: tuple[float, ...] | None = None
    high: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        mean = _vector("mean", self.mean, None)
        size = len(mean)
        try:
            cov = np.asarray(self.cov, dtype=np.float64)
        except (TypeError, ValueError):
            cov = np.zeros(0)
        if cov.shape != (size, size) or not np.isfinite(cov).all() or not np.isfinite(mean).all():
            raise ValueError(
                f"`cov` of MultivariateNormal must be a finite {size}x{size} matrix (one row per mean). "
                f"Received {self.cov!r}."
            )
        if not np.array_equal(cov, cov.T) or np.linalg.eigvalsh(cov).min() < -1e-12 * max(1.0, np.abs(cov).max()):
            raise ValueError(
                f"`cov` of MultivariateNormal must be symmetric positive semi-definite. Received {self.cov!r}."
            )
        low = None if self.low is None else _vector("low", self.low, size)
        high = None if self.high is None else _vector("high", self.high, size)
        lo = np.full(size, -np.inf) if low is None else np.array(low)
        hi = np.full(size, np.inf) if high is None else np.array(high)
        if np.isnan(lo).any() or np.isnan(hi).any() or (hi <= lo).any():
            raise ValueError(
                f"`low` of MultivariateNormal must be below `high` in every component. Received low={self.low!r}, "
                f"high={self.high!r}."
            )
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", tuple(tuple(float(v) for v in row) for row in cov))
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    @property
    def size(self) -> int:
        """P, the length of one draw."""
        return len(self.mean)

    def _box(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.full(self.size, -np.inf) if self.low is None else np.array(self.low)
        hi = np.full(self.size, np.inf) if self.high is None else np.array(self.high)
        return lo, hi

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        count = 1 if size is None else int(np.prod(size))
        mean, cov = np.array(self.mean), np.array(self.cov)
        lo, hi = self._box()
        bounded = self.low is not None or self.high is not None
        out = np.empty((count, self.size))
        filled = 0
        for _ in range(100):
            batch = rng.multivariate_normal(mean, cov, size=max(64, count), method="eigh")
            if bounded:
                batch = batch[((batch >= lo) & (batch <= hi)).all(axis=1)]
            take = min(count - filled, len(batch))
            out[filled : filled + take] = batch[:take]
            filled += take
            if filled == count:
                break
        else:
            out[filled:] = np.clip(rng.multivariate_normal(mean, cov, size=count - filled, method="eigh"), lo, hi)
        if size is None:
            return out[0]
        shape = (size,) if isinstance(size, int) else tuple(size)
        return out.reshape(*shape, self.size)

    @property
    def support(self) -> tuple[float, float]:
        lo, hi = self._box()
        std = np.sqrt(np.diag(np.array(self.cov)))
        lo = np.where(std > 0, lo, np.array(self.mean))
        hi = np.where(std > 0, hi, np.array(self.mean))
        return (float(lo.min()), float(hi.max()))

    def to_config(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": "MultivariateNormal", "mean": list(self.mean), "cov": [list(r) for r in self.cov]}
        for name in ("low", "high"):
            value = getattr(self, name)
            if value is not None:
                out[name] = list(value)
        return out


_SCALAR_TYPES = (Constant, Uniform, LogUniform, Normal, TruncatedNormal, Choice)
_TYPES: dict[str, type[Distribution]] = {cls.__name__: cls for cls in (*_SCALAR_TYPES, MultivariateNormal)}


def as_distribution(value: object, name: str) -> Distribution:
    """Turns a number into :class:`Constant`; passes distributions through; rejects the rest.

    Args:
        value: a real number or a :class:`Distribution`.
        name: the argument name, used in the error message.

    Example:
        >>> as_distribution(1.5, "scale")
        Constant(value=1.5)
        >>> as_distribution("big", "scale")
        Traceback (most recent call last):
        ...
        TypeError: `scale` must be a number or a Distribution (Constant, Uniform, LogUniform, Normal, \
TruncatedNormal, Choice). Received 'big' of type str.
    """
    if isinstance(value, MultivariateNormal):
        raise TypeError(
            f"`{name}` takes one number per draw; a MultivariateNormal draws a vector, so write it into several "
            f"addresses with randomizers.Correlated. Received {value!r}."
        )
    if isinstance(value, Distribution):
        return value
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
        return Constant(float(value))
    raise TypeError(
        f"`{name}` must be a number or a Distribution ({', '.join(c.__name__ for c in _SCALAR_TYPES)}). "
        f"Received {value!r} of type {type(value).__name__}."
    )


def distribution_from_config(config: object, where: str = "distribution") -> Distribution:
    """Builds a distribution from a YAML value: a number, ``[low, high]`` (uniform) or a mapping.

    Args:
        config: ``1.2``, ``[0.8, 1.2]`` or ``{"type": "Normal", "mean": 0, "std": 1}``.
        where: where the value came from (file and key), used in error messages.

    Example:
        >>> distribution_from_config([0.8, 1.2])
        Uniform(low=0.8, high=1.2)
        >>> distribution_from_config({"type": "LogUniform", "low": 0.1, "high": 10})
        LogUniform(low=0.1, high=10.0)
    """
    if isinstance(config, (int, float)) and not isinstance(config, bool):
        return Constant(float(config))
    if isinstance(config, (list, tuple)) and len(config) == 2:
        return Uniform(*config)
    if isinstance(config, Mapping):
        kind = config.get("type")
        if kind not in _TYPES:
            raise ValueError(f"{where}: `type` must be one of {sorted(_TYPES)}. Received {kind!r}.")
        kwargs = {k: (tuple(v) if isinstance(v, list) else v) for k, v in config.items() if k != "type"}
        try:
            return _TYPES[kind](**kwargs)
        except TypeError as err:
            raise ValueError(f"{where}: bad arguments for {kind}: {err}") from err
    raise ValueError(
        f"{where}: a distribution must be a number, a [low, high] pair or a mapping with `type`. Received {config!r}."
    )
