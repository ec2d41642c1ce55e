"""Evaluation conditions: the ways of building the environment that :func:`sim2real.evaluation.evaluate` scores.

A :class:`Condition` is the nominal sim (:func:`nominal`), a randomised sim (:func:`randomized`), the "real"
target as a twin with held-out parameters (:func:`real`) or as measured returns (:func:`measured`), or a point of
a one-parameter sweep (:func:`sweep`) or a two-parameter grid (:func:`grid`). Conditions are frozen and pickle (a
:class:`FrozenMap` holds their mappings), so they travel to worker processes.

Example:
    >>> [c.name for c in sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 2.0])]
    ['ActuatorGain.scale=0.5', 'ActuatorGain.scale=1', 'ActuatorGain.scale=2']
    >>> real(params={"body_mass[arm]": 1.2}).params
    FrozenMap({'body_mass[arm]': 1.2})
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CONDITION_KINDS",
    "Condition",
    "FrozenMap",
    "axis_values",
    "grid",
    "measured",
    "nominal",
    "randomized",
    "real",
    "sweep",
]

#: What a condition stands for; the report groups conditions by kind.
CONDITION_KINDS: tuple[str, ...] = ("nominal", "randomized", "real", "measured", "sweep", "grid")

_SWEEP_KEYS = ("field", "values", "low", "high", "num", "name", "nominal")


class FrozenMap(Mapping[str, Any]):
    """A read-only mapping that pickles (``MappingProxyType`` does not), so conditions and results travel to
    worker processes."""

    __slots__ = ("_data",)
    _data: dict[str, Any]

    def __init__(self, data: Mapping[str, Any]) -> None:
        object.__setattr__(self, "_data", dict(data))

    def __getitem__(self, key: str) -> Any:
        return self._data[key]

    def __iter__(self) -> Any:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("FrozenMap is read-only")

    def __reduce__(self) -> tuple[Any, ...]:
        return (FrozenMap, (self._data,))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Mapping) and dict(self._data) == dict(other)

    def __hash__(self) -> int:
        return hash(tuple(sorted(self._data.items(), key=lambda kv: kv[0])))

    def __repr__(self) -> str:
        return f"FrozenMap({self._data!r})"


def _freeze(mapping: Mapping[str, Any]) -> Mapping[str, Any]:
    return FrozenMap(mapping)


@dataclass(frozen=True)
class Condition:
    """One way of building the evaluation environment.

    Attributes:
        name: unique label (``"sim"``, ``"randomized"``, ``"real"``, ``"Damping.scale=2"``...).
        kind: one of :data:`CONDITION_KINDS`.
        effects: physics effects and signal models applied with :func:`sim2real.wrap`.
        params: a calibration ``{address: value}`` written into the model before the effects (see
            :func:`sim2real.make`).
        returns: ``kind == "measured"`` only: policy name -> measured episode returns.
        successes: ``kind == "measured"`` only: policy name -> measured successes (may be empty).
        sweep: the sweep or grid this point belongs to (``kind`` ``"sweep"`` / ``"grid"``).
        axes: the swept parameter label(s), e.g. ``("Damping.scale",)``; two for a grid.
        value: the coordinate(s) of this point on ``axes``.
        nominal: the coordinate(s) of the unperturbed simulator on ``axes`` (1 for a scale, 0 for an offset).
        hidden: the report reveals this condition's configuration only in an appendix (a "real" twin).
        description: one line for the report.
    """

    name: str
    kind: str
    effects: tuple[Any, ...] = ()
    params: Mapping[str, float] | None = None
    returns: Mapping[str, tuple[float, ...]] | None = None
    successes: Mapping[str, tuple[bool, ...]] | None = None
    sweep: str | None = None
    axes: tuple[str, ...] = ()
    value: tuple[float, ...] = ()
    nominal: tuple[float, ...] = ()
    hidden: bool = False
    description: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"`name` must be a non-empty string. Received {self.name!r}.")
        if self.kind not in CONDITION_KINDS:
            raise ValueError(f"`kind` must be one of {list(CONDITION_KINDS)}. Received {self.kind!r}.")
        if (self.kind == "measured") != (self.returns is not None):
            raise ValueError(
                f"`returns` must be given exactly when kind == 'measured'. Received kind {self.kind!r} "
                f"with returns={'given' if self.returns is not None else None}."
            )
        object.__setattr__(self, "effects", tuple(self.effects))
        if self.params is not None:
            object.__setattr__(self, "params", _freeze({str(k): float(v) for k, v in self.params.items()}))
        if self.returns is not None:
            object.__setattr__(self, "returns", _freeze({k: tuple(map(float, v)) for k, v in self.returns.items()}))
            object.__setattr__(
                self, "successes", _freeze({k: tuple(map(bool, v)) for k, v in (self.successes or {}).items()})
            )

    @property
    def simulated(self) -> bool:
        """True when the condition is run in simulation (everything but measured returns)."""
        return self.kind != "measured"

    def wrap(self, env: Any, *, seed: Any = 0) -> Any:
        """``env`` with this condition's effects (:func:`sim2real.wrap`; ``env`` itself when there are none).
        ``env`` must hold the condition's ``params`` already (see :meth:`make_env`)."""
        self._require_simulated()
        if not self.effects:
            return env
        from sim2real.wrapping import wrap

        return wrap(env, *self.effects, seed=seed)

    def make_env(self, task: str, *, seed: Any = 0, **options: Any) -> Any:
        """The environment this condition evaluates on: ``sim2real.make(task, params=self.params, **options)``
        wrapped with the effects. The evaluation, the study's twin recording and users build it this one way.

        Example:
            >>> twin = real([], params={"dof_damping[shoulder]": 0.03})
            >>> env = twin.make_env("dmc/reacher-easy")
            >>> from sim2real.physics import find_physics
            >>> float(find_physics(env).model.dof_damping[0])
            0.03
        """
        return self.wrap(self.base_env(task, **options), seed=seed)

    def base_env(self, task: str, **options: Any) -> Any:
        """``sim2real.make(task, params=self.params, **options)``: the env before the effects (conditions with the
        same ``params`` can share it, one :meth:`wrap` after another)."""
        self._require_simulated()
        from sim2real.tasks import make

        return make(task, params=dict(self.params) if self.params is not None else None, **options)

    def _require_simulated(self) -> None:
        if not self.simulated:
            raise ValueError(f"condition {self.name!r} holds measured returns; it has no environment.")

    def config(self) -> dict[str, Any]:
        """The condition as plain data (effects as their YAML config), for reports and JSON."""
        from randomizers import Effect
        from randomizers.config import effect_to_config

        out: dict[str, Any] = {"name": self.name, "kind": self.kind}
        if self.effects:
            out["effects"] = [effect_to_config(e) if isinstance(e, Effect) else e.to_config() for e in self.effects]
        if self.params is not None:
            out["params"] = dict(self.params)
        if self.returns is not None:
            out["returns"] = {k: list(v) for k, v in self.returns.items()}
        if self.sweep is not None:
            out.update(sweep=self.sweep, axes=list(self.axes), value=list(self.value), nominal=list(self.nominal))
        if self.hidden:
            out["hidden"] = True
        if self.description:
            out["description"] = self.description
        return out


# ----------------------------------------------------------------------------------------------- builders


def _effect_list(effects: Any, argument: str) -> tuple[Any, ...]:
    from sim2real.wrapping import _flatten

    if effects is None:
        return ()
    if isinstance(effects, (str, os.PathLike, Mapping)):
        from randomizers import load_config

        return tuple(load_config(effects))
    try:
        return tuple(_flatten(effects if isinstance(effects, (list, tuple)) else [effects]))
    except TypeError as err:
        raise TypeError(f"`{argument}`: {err}") from err


def nominal(name: str = "sim") -> Condition:
    """The nominal simulator, no effects."""
    return Condition(name, "nominal", description="nominal simulator")


def randomized(effects: Any, name: str = "randomized", description: str = "") -> Condition:
    """A randomised simulator: ``effects`` is a list of effects/models, a YAML config path or a mapping."""
    return Condition(name, "randomized", _effect_list(effects, "effects"), description=description or "randomised sim")


def real(
    effects: Any = (),
    *,
    params: Mapping[str, float] | None = None,
    name: str = "real",
    hidden: bool = True,
    description: str = "",
) -> Condition:
    """The "real" target as a simulated twin: held-out ``params`` written into the model plus ``effects``
    (noise, latency, randomisation) given as a list, a YAML config path or a mapping."""
    return Condition(
        name,
        "real",
        _effect_list(effects, "effects"),
        params=params,
        hidden=hidden,
        description=description or "simulated twin with held-out parameters",
    )


def measured(source: str | os.PathLike[str] | Mapping[str, Sequence[float]], name: str = "real") -> Condition:
    """Measured real-robot episode returns: a CSV with columns ``policy,return`` (optional ``success``) or a
    mapping policy name -> returns.

    Raises:
        ValueError: a CSV without those columns, or a non-finite return (naming the file and line).
    """
    successes: dict[str, list[bool]] = {}
    if isinstance(source, Mapping):
        returns = {str(k): [float(x) for x in v] for k, v in source.items()}
        where = "returns"
    else:
        where = str(source)
        path = Path(source)
        if not path.is_file():
            raise FileNotFoundError(f"`source` file {where!r} does not exist.")
        returns = {}
        with path.open(newline="", encoding="utf-8-sig") as handle:  # a BOM (Excel) is not part of `policy`
            reader = csv.DictReader(handle)
            reader.fieldnames = columns = [c.strip() for c in reader.fieldnames or []]
            if "policy" not in columns or "return" not in columns:
                raise ValueError(f"{where}: the CSV must have columns `policy` and `return`. Received {columns}.")
            for line, row in enumerate(reader, start=2):
                try:
                    value = float(row["return"])
                except (TypeError, ValueError):
                    value = math.nan
                if not math.isfinite(value):
                    raise ValueError(f"{where}:{line}: `return` must be a finite number. Received {row['return']!r}.")
                returns.setdefault(row["policy"], []).append(value)
                if "success" in columns and row.get("success") not in (None, ""):
                    flag = str(row["success"]).strip().lower()
                    if flag not in ("0", "1", "true", "false"):
                        raise ValueError(
                            f"{where}:{line}: `success` must be one of 0, 1, true, false. Received {row['success']!r}."
                        )
                    successes.setdefault(row["policy"], []).append(flag in ("1", "true"))
    for policy, values in returns.items():
        if not values or not all(math.isfinite(v) for v in values):
            raise ValueError(
                f"{where}: the returns of policy {policy!r} must be finite and non-empty. Received {values}."
            )
    return Condition(
        name,
        "measured",
        returns={k: tuple(v) for k, v in returns.items()},
        successes={k: tuple(v) for k, v in successes.items()},
        description="measured returns" if isinstance(source, Mapping) else f"measured returns ({Path(where).name})",
    )


def _template(effect: Any) -> dict[str, Any]:
    from randomizers import Effect
    from randomizers.config import effect_to_config

    if isinstance(effect, Mapping):
        return {k: v for k, v in effect.items() if k not in _SWEEP_KEYS}
    if isinstance(effect, Effect):
        return effect_to_config(effect)
    if hasattr(effect, "to_config"):
        return dict(effect.to_config())
    raise TypeError(
        "`effect` must be an effect from `randomizers`, a model from `noise_models` or its YAML mapping "
        f"(e.g. {{'type': 'Damping', 'scale': 1.0}}). Received {type(effect).__name__}."
    )


def _set_field(config: dict[str, Any], path: str, value: float) -> dict[str, Any]:
    out = json.loads(json.dumps(config))  # deep copy of plain YAML data
    node: Any = out
    parts = path.split(".")
    for part in parts[:-1]:
        node = node[int(part)] if isinstance(node, list) else node.get(part)
        if node is None:
            raise ValueError(f"`field` {path!r} does not exist in {config}.")
    last = parts[-1]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return out


def _build_one(config: Mapping[str, Any]) -> Any:
    from randomizers import load_config
    from randomizers.config import SIGNAL_TYPES

    key = "signals" if config.get("type") in SIGNAL_TYPES else "effects"
    return load_config({key: [dict(config)]})[0]


def _grid_values(values: Any, argument: str) -> np.ndarray:
    if isinstance(values, Mapping):
        missing = {"low", "high", "num"} - set(values)
        if missing:
            raise ValueError(f"`{argument}` as a mapping needs low, high and num. Missing {sorted(missing)}.")
        num = values["num"]
        if isinstance(num, bool) or not isinstance(num, int) or num < 2:
            raise ValueError(f"`{argument}.num` must be an int >= 2. Received {num!r}.")
        return np.linspace(float(values["low"]), float(values["high"]), num)
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1 or arr.size < 2 or not np.all(np.isfinite(arr)) or np.any(np.diff(arr) <= 0):
        raise ValueError(
            f"`{argument}` must be at least 2 finite, strictly increasing values (both bounds included). "
            f"Received {values!r}."
        )
    return arr


def axis_values(spec: Mapping[str, Any]) -> Any:
    """The grid of a sweep or grid-axis mapping: its ``values``, else ``{low, high, num}``."""
    return spec["values"] if "values" in spec else {k: spec[k] for k in ("low", "high", "num") if k in spec}


def _default_nominal(path: str) -> float:
    last = path.split(".")[-1]
    return 1.0 if last in ("scale", "gain") else 0.0


def _axis(effect: Any, field_path: str, values: Any, nominal_value: float | None, argument: str):
    template = _template(effect)
    if not isinstance(field_path, str) or not field_path:
        raise ValueError(f"`field` must name the swept argument, e.g. 'scale'. Received {field_path!r}.")
    _set_field(template, field_path, 0.0)  # validates the path
    grid_values = _grid_values(values, argument)
    nom = _default_nominal(field_path) if nominal_value is None else float(nominal_value)
    if not np.any(np.isclose(grid_values, nom, rtol=0.0, atol=1e-12)):
        grid_values = np.sort(np.append(grid_values, nom))  # the radius is measured from the nominal point
    label = f"{template.get('type', 'effect')}.{field_path}"
    return template, label, grid_values, nom


def sweep(
    effect: Any,
    field: str,
    values: Any,
    *,
    nominal: float | None = None,
    name: str | None = None,
    base: Any = (),
) -> tuple[Condition, ...]:
    """A one-parameter sweep: one condition per value of ``effect``'s argument ``field``.

    Args:
        effect: an effect or model, or its YAML mapping (``{"type": "Damping", "scale": 1.0}``); the other
            arguments (e.g. ``joints``) are kept at every point.
        field: the swept argument; a dotted path reaches into processes, e.g. ``"processes.0.std"``.
        values: strictly increasing values including both bounds, or ``{"low", "high", "num"}`` (linspace).
        nominal: the unperturbed value (default 1 for ``scale``/``gain``, else 0); added to the grid when
            missing, since robustness radii are measured from it.
        name: sweep label (default ``"<Type>.<field>"``).
        base: effects applied at every point besides the swept one.

    Example:
        >>> [c.name for c in sweep({"type": "Damping", "scale": 1.0}, "scale", {"low": 0.5, "high": 2.0, "num": 3})]
        ['Damping.scale=0.5', 'Damping.scale=1', 'Damping.scale=1.25', 'Damping.scale=2']
    """
    template, label, grid_values, nom = _axis(effect, field, values, nominal, "values")
    name = name or label
    extra = _effect_list(base, "base")
    return tuple(
        Condition(
            f"{name}={v:g}",
            "sweep",
            (*extra, _build_one(_set_field(template, field, float(v)))),
            sweep=name,
            axes=(label,),
            value=(float(v),),
            nominal=(nom,),
            description=f"{label} = {v:g}",
        )
        for v in grid_values
    )


def grid(
    x: Mapping[str, Any],
    y: Mapping[str, Any],
    *,
    name: str | None = None,
    base: Any = (),
) -> tuple[Condition, ...]:
    """A two-parameter grid: ``x`` and ``y`` are mappings ``{"effect", "field", "values"[, "nominal"]}`` as
    for :func:`sweep` (or the effect's YAML mapping with ``field`` and ``values`` keys). Points are
    ordered x-major: ``(x0, y0), (x0, y1), ...``."""
    axes = []
    for argument, spec in (("x", x), ("y", y)):
        if not isinstance(spec, Mapping) or "field" not in spec or not ({"values", "low"} & set(spec)):
            raise ValueError(
                f"`{argument}` must be a mapping with `field` and `values` (or low/high/num). Received {spec!r}."
            )
        effect = spec.get("effect", spec)
        axes.append(_axis(effect, spec["field"], axis_values(spec), spec.get("nominal"), f"{argument}.values"))
    (tx, lx, gx, nx), (ty, ly, gy, ny) = axes
    name = name or f"{lx} x {ly}"
    extra = _effect_list(base, "base")
    out = []
    for vx in gx:
        for vy in gy:
            out.append(
                Condition(
                    f"{name}@({vx:g},{vy:g})",
                    "grid",
                    (
                        *extra,
                        _build_one(_set_field(tx, x["field"], float(vx))),
                        _build_one(_set_field(ty, y["field"], float(vy))),
                    ),
                    sweep=name,
                    axes=(lx, ly),
                    value=(float(vx), float(vy)),
                    nominal=(nx, ny),
                    description=f"{lx} = {vx:g}, {ly} = {vy:g}",
                )
            )
    return tuple(out)
