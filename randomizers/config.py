"""Effects from and to YAML (``yaml.safe_load``), validated with errors that name the file and key.

The format is a mapping with an ``effects`` list; each item has ``type`` plus the effect's
keyword arguments. Distributions are a number (constant), ``[low, high]`` (uniform) or a mapping
with ``type``. Schedules are ``reset``, ``startup`` or ``{interval: {steps: N}}`` /
``{interval: {seconds: T}}``.

Example:
    >>> text = '''
    ... effects:
    ...   - type: Friction
    ...     scale: [0.5, 1.5]
    ...     geoms: "finger*"
    ...   - type: Mass
    ...     scale: {type: Uniform, low: 0.8, high: 1.2}
    ...     bodies: arm
    ... '''
    >>> effects = load_effects(text)
    >>> effects[0]
    Friction(scale=Uniform(low=0.5, high=1.5), geoms='finger*')
    >>> load_effects(dump_effects(effects)) == effects
    True
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from randomizers.distributions import Distribution, distribution_from_config
from randomizers.effects import (
    ActuatorGain,
    Armature,
    Damping,
    Effect,
    Friction,
    FrictionLoss,
    Gravity,
    Interval,
    Mass,
    Push,
    Stiffness,
)
from randomizers.visual import VISUAL_EFFECTS

__all__ = ["EFFECT_TYPES", "dump_effects", "effect_to_config", "load_effects"]

EFFECT_TYPES: dict[str, type[Effect]] = {
    cls.__name__: cls
    for cls in (
        *(Friction, Mass, Damping, Armature, FrictionLoss, Stiffness, ActuatorGain, Gravity, Push),
        *VISUAL_EFFECTS,
    )
}
_DISTRIBUTION_ARGS = {"scale", "add", "set", "force", "interval", "rgb1", "rgb2", "roll"}


def _distributions_from_config(value: object, where: str) -> Any:
    """A distribution, or (visual effects) a list with one per channel: ``[[0, 1], 0.5, {type: ...}]``."""
    per_channel = isinstance(value, (list, tuple)) and (
        len(value) != 2 or any(isinstance(v, (list, tuple, Mapping)) for v in value)
    )
    if per_channel:
        return tuple(distribution_from_config(v, f"{where}[{i}]") for i, v in enumerate(value))  # type: ignore[union-attr]
    return distribution_from_config(value, where)


def _schedule_from_config(value: object, where: str) -> Any:
    if value in ("reset", "startup"):
        return value
    if isinstance(value, Mapping) and set(value) == {"interval"} and isinstance(value["interval"], Mapping):
        try:
            return Interval(**value["interval"])
        except (TypeError, ValueError) as err:
            raise ValueError(f"{where}: {err}") from err
    raise ValueError(
        f"{where}: `schedule` must be 'reset', 'startup' or {{interval: {{steps: N}}}} / "
        f"{{interval: {{seconds: T}}}}. Received {value!r}."
    )


def load_effects(source: str | os.PathLike[str] | Mapping[str, Any]) -> list[Effect]:
    """Builds effects from a YAML file path, a YAML string or an already-parsed mapping.

    Raises:
        ValueError: with ``<file>: effects[i].<key>: ...`` naming where the problem is.
    """
    where = "<config>"
    if isinstance(source, Mapping):
        config: Any = source
    else:
        text = str(source)
        if isinstance(source, os.PathLike) or ("\n" not in text and text.endswith((".yaml", ".yml"))):
            path = Path(source)
            if not path.is_file():
                raise FileNotFoundError(f"`config` file {str(path)!r} does not exist.")
            where = str(path)
            text = path.read_text()
        try:
            config = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ValueError(f"{where}: not valid YAML: {err}") from err
    if not isinstance(config, Mapping) or "effects" not in config:
        raise ValueError(f"{where}: the top level must be a mapping with an `effects` list. Received {config!r}.")
    items = config["effects"]
    if not isinstance(items, Sequence) or isinstance(items, str):
        raise ValueError(f"{where}: `effects` must be a list. Received {items!r}.")
    effects = []
    for i, item in enumerate(items):
        key = f"{where}: effects[{i}]"
        if not isinstance(item, Mapping) or item.get("type") not in EFFECT_TYPES:
            got = item.get("type") if isinstance(item, Mapping) else item
            raise ValueError(f"{key}.type must be one of {sorted(EFFECT_TYPES)}. Received {got!r}.")
        kwargs: dict[str, Any] = {}
        for name, value in item.items():
            if name == "type":
                continue
            if name in _DISTRIBUTION_ARGS:
                kwargs[name] = _distributions_from_config(value, f"{key}.{name}")
            elif name == "schedule":
                kwargs[name] = _schedule_from_config(value, f"{key}.schedule")
            else:
                kwargs[name] = value
        cls = EFFECT_TYPES[item["type"]]
        try:
            effects.append(cls(**kwargs))
        except TypeError as err:
            raise ValueError(f"{key}: unknown or missing argument for {cls.__name__}: {err}") from err
        except ValueError as err:
            raise ValueError(f"{key}: {err}") from err
    return effects


def effect_to_config(effect: Effect) -> dict[str, Any]:
    """The YAML mapping of one effect (inverse of :func:`load_effects` for that item)."""
    out: dict[str, Any] = {"type": type(effect).__name__}
    for name, value in effect._fields().items():
        if isinstance(value, Distribution):
            out[name] = value.to_config()
        elif isinstance(value, tuple) and value and all(isinstance(v, Distribution) for v in value):
            out[name] = [v.to_config() for v in value]
        elif isinstance(value, Interval):
            out[name] = {"interval": {k: v for k, v in vars(value).items() if v is not None}}
        else:
            out[name] = value
    return out


def dump_effects(effects: Sequence[Effect]) -> str:
    """YAML text for ``effects`` that :func:`load_effects` reads back to equal effects."""
    return yaml.safe_dump({"effects": [effect_to_config(e) for e in effects]}, sort_keys=False)
