"""Parameters (a constant or anything with ``sample(rng)``) and signal layouts with selections.

Any parameter of a noise model takes a plain number or a distribution. Distributions are accepted by
duck typing — ``randomizers.Uniform`` and friends work, and so does any object with a
``sample(rng)`` or ``sample(rng, size)`` method; when it also has a ``support`` ``(low, high)`` the
range is checked when the model is built.

Example:
    >>> import numpy as np
    >>> check_value(0.01, "std", low=0.0)
    0.01
    >>> check_value(-1.0, "std", low=0.0)
    Traceback (most recent call last):
    ...
    ValueError: `std` must be >= 0. Received -1.0.
    >>> layout = Layout(6, keys=(("position", slice(0, 3), (3,)), ("velocity", slice(3, 6), (3,))))
    >>> layout.resolve("velocity", "select").tolist()
    [3, 4, 5]
    >>> layout.resolve(slice(0, 2), "select").tolist()
    [0, 1]
"""

from __future__ import annotations

import difflib
import fnmatch
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "FrozenValue",
    "Layout",
    "Selection",
    "check_probability",
    "check_value",
    "draw",
    "is_sampler",
    "value_config",
]

Selection = None | str | int | slice | range | Sequence[str] | Sequence[int]


class FrozenValue:
    """Immutable value semantics for models: ``repr`` and ``==`` from ``_fields()``, hashable, frozen after
    ``_freeze()``."""

    _frozen = False

    def _fields(self) -> dict[str, Any]:  # pragma: no cover - every subclass overrides
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self._fields().items())})"

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self._fields() == other._fields()

    def __hash__(self) -> int:
        return hash((type(self).__name__, repr(self)))

    def __setattr__(self, key: str, value: object) -> None:
        if self._frozen:
            raise AttributeError(f"{type(self).__name__} is immutable; build a new one instead.")
        super().__setattr__(key, value)

    def _freeze(self) -> None:
        object.__setattr__(self, "_frozen", True)


def is_sampler(value: object) -> bool:
    """True for objects with a callable ``sample`` (distributions)."""
    return callable(getattr(value, "sample", None))


def _bound_text(low: float | None, high: float | None, low_open: bool) -> str:
    if low is not None and high is not None:
        return f"in [{low:g}, {high:g}]"
    if low is not None:
        return f"> {low:g}" if low_open else f">= {low:g}"
    return f"<= {high:g}"


def check_value(
    value: object,
    name: str,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    allow_none: bool = False,
) -> Any:
    """Validates a parameter: a finite number in range, or a sampler whose support is in range.

    Returns the number as a float (or the sampler unchanged).

    Raises:
        TypeError: neither a number nor a sampler.
        ValueError: out of range (the message names the argument, the range and the value).
    """
    if value is None and allow_none:
        return None
    if is_sampler(value):
        support = getattr(value, "support", None)
        if isinstance(support, tuple) and len(support) == 2:
            lo, hi = float(support[0]), float(support[1])
            bad_low = low is not None and (lo <= low if low_open else lo < low)
            bad_high = high is not None and hi > high
            if bad_low or bad_high:
                raise ValueError(
                    f"`{name}` must be {_bound_text(low, high, low_open)}, but {value!r} can draw values in "
                    f"[{lo:g}, {hi:g}]. Received {value!r}."
                )
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(
            f"`{name}` must be a number or a distribution with sample(rng, size) (e.g. randomizers.Uniform). "
            f"Received {value!r} of type {type(value).__name__}."
        )
    out = float(value)
    if not math.isfinite(out):
        raise ValueError(f"`{name}` must be finite. Received {out!r}.")
    bad_low = low is not None and (out <= low if low_open else out < low)
    if bad_low or (high is not None and out > high):
        raise ValueError(f"`{name}` must be {_bound_text(low, high, low_open)}. Received {out!r}.")
    return out


def check_probability(value: object, name: str = "probability") -> Any:
    """A probability: a number or sampler with support in [0, 1].

    Example:
        >>> check_probability(1.5)
        Traceback (most recent call last):
        ...
        ValueError: `probability` must be in [0, 1]. Received 1.5.
    """
    return check_value(value, name, low=0.0, high=1.0)


def upper_bound(value: object) -> float:
    """The largest value a parameter can take (``inf`` for samplers without a finite support)."""
    if is_sampler(value):
        support = getattr(value, "support", None)
        if isinstance(support, tuple) and len(support) == 2:
            return float(support[1])
        return math.inf
    return float(value)  # type: ignore[arg-type]


def draw(value: Any, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` float64 values of a parameter (a constant is repeated without touching ``rng``)."""
    if not is_sampler(value):
        return np.full(n, float(value))
    try:
        raw = value.sample(rng, n)
    except TypeError:  # a bare ``sample(rng)``: one call per value
        raw = [value.sample(rng) for _ in range(n)]
    out = np.asarray(raw, dtype=np.float64)
    if out.shape != (n,):
        out = np.broadcast_to(out, (n,)).copy()
    return out


def value_config(value: Any) -> Any:
    """A YAML-ready form of a parameter (distributions via their ``to_config``)."""
    to_config = getattr(value, "to_config", None)
    if callable(to_config):
        return to_config()
    return value if not is_sampler(value) else repr(value)


def selection_repr(select: Selection) -> str:
    """A short label for a selection, used in report names (``obs_noise_std[velocity]``)."""
    if select is None:
        return ""
    if isinstance(select, str):
        return select
    if isinstance(select, (int, np.integer)):
        return str(int(select))
    if isinstance(select, (slice, range)):
        start = "" if select.start is None else str(select.start)
        stop = "" if select.stop is None else str(select.stop)
        step = "" if select.step in (None, 1) else f":{select.step}"
        return f"{start}:{stop}{step}"
    return ",".join(str(s) for s in select)


def check_selection(select: object, name: str = "select") -> Selection:
    """Validates the form of a selection (its names are checked against a layout later)."""
    if select is None or isinstance(select, (str, slice, range)):
        return select
    if isinstance(select, (int, np.integer)) and not isinstance(select, bool):
        return int(select)
    if isinstance(select, (list, tuple)) and select:
        if all(isinstance(s, str) for s in select):
            return tuple(select)
        if all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in select):
            return tuple(int(s) for s in select)
    raise TypeError(
        f"`{name}` must be None (everything), observation key names (str or list of str, fnmatch patterns "
        f"allowed), an index, a slice/range, or a list of indices. Received {select!r}."
    )


@dataclass(frozen=True)
class Layout:
    """Where each named part of a signal sits in its flat vector.

    Attributes:
        size: length of the flat signal.
        keys: ``(name, slice, shape)`` per named part (dict observations, or the parts a flattened
            dm-control observation was built from); empty for plain vectors.
        low: finite lower bounds of the declared space (None when unbounded).
        high: finite upper bounds of the declared space (None when unbounded).
        dict_signal: True when the signal is a dict (report names then use ``[key][j]``).
    """

    size: int
    keys: tuple[tuple[str, slice, tuple[int, ...]], ...] = ()
    low: np.ndarray | None = field(default=None, compare=False)
    high: np.ndarray | None = field(default=None, compare=False)
    dict_signal: bool = False

    def resolve(self, select: Selection, name: str = "select") -> np.ndarray:
        """Sorted flat indices a selection picks.

        Raises:
            ValueError: unknown key (close matches listed) or index out of range.
        """
        n = self.size
        if select is None:
            return np.arange(n)
        if isinstance(select, (slice, range)):
            sl = select if isinstance(select, slice) else slice(select.start, select.stop, select.step)
            out = np.arange(n)[sl]
            if out.size == 0:
                raise ValueError(f"`{name}` selects no element of a signal of size {n}. Received {select!r}.")
            return out
        items: Sequence[Any] = (select,) if isinstance(select, (str, int)) else select
        if all(isinstance(s, str) for s in items):
            known = [k for k, _, _ in self.keys]
            picked: list[int] = []
            for pattern in items:
                hits = [sl for k, sl, _ in self.keys if fnmatch.fnmatchcase(k, pattern)]
                if not hits:
                    if not known:
                        raise ValueError(
                            f"`{name}` names key {pattern!r}, but this signal is a plain vector without named "
                            f"parts; select indices or a slice instead. Received {select!r}."
                        )
                    close = difflib.get_close_matches(pattern, known, n=3, cutoff=0.5)
                    hint = f" Close matches: {', '.join(map(repr, close))}." if close else ""
                    raise ValueError(
                        f"`{name}` names key {pattern!r}, which the signal does not have. Known keys: "
                        f"{', '.join(map(repr, known))}.{hint}"
                    )
                for sl in hits:
                    picked.extend(range(sl.start, sl.stop))
            return np.array(sorted(set(picked)), dtype=np.int64)
        idx = np.array(items, dtype=np.int64)
        bad = idx[(idx < -n) | (idx >= n)]
        if bad.size:
            raise ValueError(
                f"`{name}` index {int(bad[0])} is out of range for a signal of size {n}. Received {select!r}."
            )
        return np.array(sorted(set((idx % n).tolist())), dtype=np.int64)

    def label(self, index: int) -> str:
        """The report suffix of flat element ``index``: ``[3]`` or, for dict signals, ``[key][j]``."""
        if self.dict_signal:
            for key, sl, _ in self.keys:
                if sl.start <= index < sl.stop:
                    return f"[{key}][{index - sl.start}]"
        return f"[{index}]"
