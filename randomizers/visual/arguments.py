"""Arguments every visual effect shares: the elements it selects, its one operation and a distribution per channel.

:class:`Product` draws one value per channel (an RGB colour, a light direction) from independent distributions,
so one effect can say ``add=(Uniform(-0.1, 0.1), 0.0, 0.0)``.

Example:
    >>> import numpy as np
    >>> from randomizers.distributions import Constant, Uniform
    >>> product = Product((Uniform(0.0, 1.0), Constant(0.5), Constant(0.25)))
    >>> product.sample(np.random.default_rng(0))[1:].tolist()
    [0.5, 0.25]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from randomizers.distributions import Distribution, as_distribution
from randomizers.effects import Operation

__all__ = ["Product"]

# ----------------------------------------------------------------------------- element selection


def _patterns(select: object, argument: str, owner: str) -> tuple[str, ...]:
    if isinstance(select, str):
        return (select,)
    if isinstance(select, Sequence) and select and all(isinstance(p, str) for p in select):
        return tuple(select)
    raise TypeError(f"`{argument}` of {owner} must be a name pattern or a non-empty list of them. Received {select!r}.")


def _check_name(name: object, owner: str) -> None:
    if name is not None and (not isinstance(name, str) or not name):
        raise TypeError(f"`name` of {owner} must be a non-empty string. Received {name!r}.")


def _check_bool(value: object, argument: str, owner: str) -> None:
    if not isinstance(value, bool):
        raise TypeError(f"`{argument}` of {owner} must be a bool. Received {value!r}.")


def _one_operation(owner: str, **given: object) -> tuple[Operation, object]:
    present = {op: v for op, v in given.items() if v is not None}
    if len(present) != 1:
        raise ValueError(f"{owner} needs exactly one of `scale`, `add` or `set`. Received {sorted(present) or 'none'}.")
    ((operation, raw),) = present.items()
    return operation, raw  # type: ignore[return-value]


# ----------------------------------------------------------------------------- distributions


@dataclass(frozen=True)
class Product(Distribution):
    """Independent components drawn together: ``sample(rng, k * n)`` returns ``n`` rows of one draw
    per component, flattened row after row (component ``j`` of row ``i`` at ``i * k + j``).

    Visual effects use it as their ``distribution`` (e.g. one component per colour channel), so
    the randomiser's ``distribution.sample(generator, binding.draw_count())`` covers them too. Each
    component draws its whole column in turn, so a component never shifts another's values.

    Example:
        >>> import numpy as np
        >>> from randomizers import Constant, Uniform
        >>> d = Product((Uniform(0.0, 1.0), Constant(5.0)))
        >>> d.sample(np.random.default_rng(0), 4).reshape(2, 2)[:, 1].tolist()
        [5.0, 5.0]
        >>> d.sample(np.random.default_rng(0), 3)
        Traceback (most recent call last):
        ...
        ValueError: `size` of Product must be a multiple of its 2 components. Received 3.
    """

    components: tuple[Distribution, ...]

    def __post_init__(self) -> None:
        comps = tuple(self.components) if isinstance(self.components, (tuple, list)) else ()
        if not comps or not all(isinstance(c, Distribution) for c in comps):
            raise TypeError(
                f"`components` of Product must be a non-empty tuple of Distributions. Received {self.components!r}."
            )
        object.__setattr__(self, "components", comps)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        k = len(self.components)
        if size is None:
            return np.array([float(c.sample(rng)) for c in self.components])
        n = int(np.prod(size))
        if n % k:
            raise ValueError(f"`size` of Product must be a multiple of its {k} components. Received {size!r}.")
        rows = n // k
        columns = [np.asarray(c.sample(rng, rows), dtype=np.float64) for c in self.components]
        return np.stack(columns, axis=1).reshape(size)

    def to_config(self) -> dict[str, Any]:
        return {"type": "Product", "components": [c.to_config() for c in self.components]}

    @property
    def support(self) -> tuple[float, float]:
        lows, highs = zip(*(c.support for c in self.components), strict=True)
        return (min(lows), max(highs))


def _channels(value: object, argument: str, owner: str, width: int) -> tuple[Distribution, ...]:
    """One distribution for every channel, or a sequence of ``width`` (numbers or distributions)."""
    if isinstance(value, (list, tuple)):
        if len(value) != width:
            raise ValueError(
                f"`{argument}` of {owner} must be one distribution or a sequence of {width} (one per channel). "
                f"Received {len(value)} entries: {value!r}."
            )
        return tuple(as_distribution(v, f"{argument}[{i}]") for i, v in enumerate(value))
    return (as_distribution(value, argument),) * width


def _shown(dists: tuple[Distribution, ...]) -> Distribution | tuple[Distribution, ...]:
    return dists[0] if all(d == dists[0] for d in dists) else dists


def _check_unit(operation: str, dist: Distribution, argument: str, owner: str, what: str) -> None:
    low, high = dist.support
    if operation == "scale" and low < 0:
        raise ValueError(f"`{argument}` of {owner} must not go below 0 ({what} stay in [0, 1]). Received {dist!r}.")
    if operation == "set" and (low < 0 or high > 1):
        raise ValueError(f"`{argument}` of {owner} must stay within [0, 1] ({what}). Received {dist!r}.")
