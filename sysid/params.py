"""Fitted parameters: the addresses of :mod:`randomizers.parameters` plus search bounds.

:class:`ParameterSpace` is a :class:`randomizers.parameters.ParameterSet` (addresses resolved against a model,
nominal values, a writer) with bounds; resolving, reading and writing live in :mod:`randomizers.parameters`
alone. ``EFFECT_FIELDS`` and ``effect_for`` are re-exported from there.

Example:
    >>> import mujoco
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body><joint name="a" damping="0.5"/><geom size=".1"/>'
    ...     '<body><joint name="b" damping="0.2"/><geom size=".1"/></body></body></worldbody></mujoco>')
    >>> space = ParameterSpace(model, ["dof_damping[*]"])
    >>> space.addresses, space.nominal.tolist()
    (('dof_damping[a]', 'dof_damping[b]'), [0.5, 0.2])
    >>> space.lower.tolist(), space.upper.tolist()
    ([0.05, 0.02], [5.0, 2.0])
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from randomizers.parameters import EFFECT_FIELDS, Address, ParameterSet, effect_for

__all__ = ["EFFECT_FIELDS", "Address", "ParameterSpace", "effect_for"]


class ParameterSpace(ParameterSet):
    """Scalar parameters expanded from address patterns, with nominal values, bounds and writers.

    Args:
        model: the compiled model the addresses refer to (never modified).
        params: address patterns, e.g. ``["dof_damping[*]", "actuator_gain[elbow]"]``; wildcards expand to one
            scalar per matched element, in model order.
        bounds: ``{address or pattern: (low, high)}`` or a list of ``(low, high)`` aligned with ``params``.
            Missing entries default to ``[nominal / 10, nominal * 10]`` for a positive nominal; parameters
            with a zero or negative nominal need explicit bounds.

    Attributes:
        addresses: (P,) expanded addresses.
        nominal: (P,) values found in ``model``.
        lower, upper: (P,) bounds.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        params: Sequence[str],
        bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None = None,
    ) -> None:
        super().__init__(model, params)
        self.lower, self.upper = self._bounds(params, bounds)

    def _bounds(
        self, params: Sequence[str], bounds: Mapping[str, Sequence[float]] | Sequence[Sequence[float]] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        lower = np.full(self.size, np.nan)
        upper = np.full(self.size, np.nan)
        if bounds is None:
            pass
        elif isinstance(bounds, Mapping):
            used = set()
            for i, address in enumerate(self.addresses):
                for key in (address, params[self.origin[i]]):
                    if key in bounds:
                        lower[i], upper[i] = self._pair(bounds[key], key)
                        used.add(key)
                        break
            unknown = sorted(set(bounds) - used)
            if unknown:
                raise ValueError(
                    f"`bounds` keys must be entries of `params` or expanded addresses {list(self.addresses)}. "
                    f"Received unknown key(s) {unknown}."
                )
        elif isinstance(bounds, Sequence) and len(bounds) == len(params):
            for i in range(self.size):
                k = int(self.origin[i])
                lower[i], upper[i] = self._pair(bounds[k], params[k])
        else:
            raise ValueError(
                "`bounds` must be a mapping {address: (low, high)} or a list of (low, high) with one pair per "
                f"`params` entry ({len(params)}). Received {bounds!r}."
            )
        for i, address in enumerate(self.addresses):
            if np.isnan(lower[i]):
                value = float(self.nominal[i])
                if value <= 0:
                    raise ValueError(
                        f"`bounds` must be given for {address!r}: its nominal value is {value!r}, so there is no "
                        "default range (defaults are [nominal/10, nominal*10]). Received none."
                    )
                lower[i], upper[i] = value / 10.0, value * 10.0
        return lower, upper

    @staticmethod
    def _pair(value: Any, key: str) -> tuple[float, float]:
        try:
            low, high = (float(v) for v in value)
        except (TypeError, ValueError):
            raise ValueError(f"`bounds[{key!r}]` must be a pair (low, high). Received {value!r}.") from None
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise ValueError(f"`bounds[{key!r}]` must be finite with low < high. Received ({low!r}, {high!r}).")
        return low, high


class ModelPool:
    """Copies of a model, one per parameter set of a batch, each with its own writer (grown on demand)."""

    def __init__(self, model: mujoco.MjModel, space: ParameterSpace) -> None:
        self.base = model
        self.space = space
        self.models: list[mujoco.MjModel] = []
        self.writers: list[Callable[[np.ndarray], None]] = []
        self._datas: list[mujoco.MjData] = []

    def models_for(self, values: np.ndarray) -> list[mujoco.MjModel]:
        """One model per row of ``values`` (B, P), written in place."""
        values = np.atleast_2d(values)
        while len(self.models) < values.shape[0]:
            model = copy.copy(self.base)
            self.models.append(model)
            self.writers.append(self.space.writer(model))
        for i, row in enumerate(values):
            self.writers[i](row)
        return self.models[: values.shape[0]]
