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

import difflib
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from randomizers.correlated import Correlated
from randomizers.distributions import Distribution, distribution_from_config
from randomizers.effects import Effect, Interval, Push
from randomizers.parameters import FIELD_EFFECTS
from randomizers.visual import VISUAL_EFFECTS

__all__ = [
    "EFFECT_TYPES",
    "SIGNAL_TYPES",
    "dump_config",
    "dump_effects",
    "effect_to_config",
    "load_config",
    "load_effects",
    "load_signals",
]

#: Every effect type a YAML ``effects:`` list may name: the field effects of
#: :data:`randomizers.parameters.FIELD_EFFECTS` (register a new physics effect there), then the others.
EFFECT_TYPES: dict[str, type[Effect]] = {
    cls.__name__: cls for cls in (*FIELD_EFFECTS, Push, Correlated, *VISUAL_EFFECTS)
}
_DISTRIBUTION_ARGS = {"scale", "add", "set", "force", "interval", "rgb1", "rgb2", "roll", "distribution"}


def _distributions_from_config(value: object, where: str) -> Any:
    """A distribution, or (visual effects) a list with one per channel: ``[[0, 1], 0.5, {type: ...}]``."""
    per_channel = isinstance(value, (list, tuple)) and (
        len(value) != 2 or any(isinstance(v, (list, tuple, Mapping)) for v in value)
    )
    if per_channel:
        items: Sequence[Any] = value  # type: ignore[assignment]
        return tuple(distribution_from_config(v, f"{where}[{i}]") for i, v in enumerate(items))
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


def _read(source: str | os.PathLike[str] | Mapping[str, Any]) -> tuple[Any, str]:
    where = "<config>"
    if isinstance(source, Mapping):
        config: Any = source
    else:
        text = str(source)
        if isinstance(source, os.PathLike) or ("\n" not in text and text.endswith((".yaml", ".yml"))):
            path = Path(source)
            if not path.is_file():
                state = "is a folder, not a file" if path.is_dir() else "does not exist"
                raise FileNotFoundError(f"`config` file {str(path)!r} {state}.")
            where = str(path)
            text = path.read_text()
        try:
            config = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ValueError(f"{where}: not valid YAML: {err}") from err
    return config, where


#: The top-level keys of a randomisation config: physics effects, and the signal models :func:`load_config` reads.
CONFIG_KEYS = ("effects", "signals")


def _check_top_keys(config: Mapping[str, Any], where: str) -> None:
    """A key that is neither ``effects`` nor ``signals`` (a typo such as ``signal:``) would be ignored, and the
    models under it silently never applied; refuse it."""
    unknown = [str(k) for k in config if k not in CONFIG_KEYS]
    if unknown:
        close = {k: difflib.get_close_matches(k, CONFIG_KEYS, n=1) for k in unknown}
        hints = "".join(f" ({k!r}: did you mean {c[0]!r}?)" for k, c in close.items() if c)
        raise ValueError(
            f"{where}: the top-level keys must be among {list(CONFIG_KEYS)}. Received unknown {unknown}.{hints}"
        )


def load_effects(source: str | os.PathLike[str] | Mapping[str, Any]) -> list[Effect]:
    """Builds effects from a YAML file path, a YAML string or an already-parsed mapping.

    Raises:
        ValueError: with ``<file>: effects[i].<key>: ...`` naming where the problem is.
    """
    config, where = _read(source)
    if not isinstance(config, Mapping) or "effects" not in config:
        raise ValueError(f"{where}: the top level must be a mapping with an `effects` list. Received {config!r}.")
    _check_top_keys(config, where)
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


def _signal_types() -> dict[str, type]:
    import noise_models

    return {n: getattr(noise_models, n) for n in SIGNAL_TYPES}


#: Signal-model types a ``signals:`` list may name (noise_models), and their processes.
SIGNAL_TYPES: tuple[str, ...] = (
    "ObservationNoise",
    "ActionNoise",
    "ObservationLatency",
    "ActionLatency",
    "SampleAndHold",
    "ControlJitter",
)
_SIGNAL_VALUE_ARGS = {
    "std", "half_width", "offset", "gain", "timescale", "probability", "magnitude", "resolution", "low", "high",
    "duration", "width", "steps", "seconds", "jitter", "phase", "delta",
}  # fmt: skip


def _signal_value(value: object, where: str) -> Any:
    """A number stays a number (reported as one value); ``[low, high]`` or ``{type: ...}`` is a distribution."""
    if value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)):
        return value
    return distribution_from_config(value, where)


def _signal_kwargs(item: Mapping[str, Any], key: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, value in item.items():
        if name in ("type", "processes"):
            continue
        if name in _SIGNAL_VALUE_ARGS:
            out[name] = _signal_value(value, f"{key}.{name}")
        elif name == "select" and isinstance(value, list):
            out[name] = tuple(value)
        else:
            out[name] = value
    return out


def load_signals(source: str | os.PathLike[str] | Mapping[str, Any]) -> list[Any]:
    """Builds noise and latency models (:mod:`noise_models`) from the ``signals:`` list of a YAML config.

    Example:
        >>> load_signals('''
        ... signals:
        ...   - type: ObservationNoise
        ...     select: velocity
        ...     processes:
        ...       - {type: Gaussian, std: 0.01}
        ...       - {type: Bias, offset: [-0.02, 0.02]}
        ...   - {type: ActionLatency, seconds: 0.02}
        ... ''')
        [ObservationNoise(Gaussian(std=0.01), Bias(offset=Uniform(low=-0.02, high=0.02)), select='velocity'), \
ActionLatency(seconds=0.02)]

    Raises:
        ValueError: with ``<file>: signals[i].<key>: ...`` naming where the problem is.
    """
    config, where = _read(source)
    return _load_signals(config, where)


def _load_signals(config: Any, where: str) -> list[Any]:
    import noise_models

    if not isinstance(config, Mapping):
        raise ValueError(f"{where}: the top level must be a mapping. Received {config!r}.")
    items = config.get("signals", [])
    if not isinstance(items, Sequence) or isinstance(items, str):
        raise ValueError(f"{where}: `signals` must be a list. Received {items!r}.")
    types = _signal_types()
    out = []
    for i, item in enumerate(items):
        key = f"{where}: signals[{i}]"
        if not isinstance(item, Mapping) or item.get("type") not in types:
            got = item.get("type") if isinstance(item, Mapping) else item
            raise ValueError(f"{key}.type must be one of {sorted(types)}. Received {got!r}.")
        kwargs = _signal_kwargs(item, key)
        try:
            if item["type"] in ("ObservationNoise", "ActionNoise"):
                processes = item.get("processes")
                if not isinstance(processes, Sequence) or isinstance(processes, str) or not processes:
                    raise ValueError(f"`processes` must be a non-empty list. Received {processes!r}.")
                built = []
                for j, proc in enumerate(processes):
                    pkey = f"{key}.processes[{j}]"
                    if not isinstance(proc, Mapping) or proc.get("type") not in noise_models.PROCESS_TYPES:
                        got = proc.get("type") if isinstance(proc, Mapping) else proc
                        raise ValueError(
                            f"{pkey}.type must be one of {sorted(noise_models.PROCESS_TYPES)}. Received {got!r}."
                        )
                    try:
                        built.append(noise_models.PROCESS_TYPES[proc["type"]](**_signal_kwargs(proc, pkey)))
                    except (TypeError, ValueError) as err:
                        raise ValueError(f"{pkey}: {err}") from err
                out.append(types[item["type"]](*built, **kwargs))
            else:
                out.append(types[item["type"]](**kwargs))
        except TypeError as err:
            raise ValueError(f"{key}: unknown or missing argument for {item['type']}: {err}") from err
        except ValueError as err:
            text = str(err)
            raise ValueError(text if text.startswith(where) else f"{key}: {text}") from err
    return out


def load_config(source: str | os.PathLike[str] | Mapping[str, Any]) -> list[Any]:
    """Effects (``effects:``) and signal models (``signals:``) of one YAML config, ready for ``sim2real.wrap``.

    Example:
        >>> [type(m).__name__ for m in load_config("effects: [{type: Damping, scale: [0.5, 2.0]}]\\n"
        ...                                         "signals: [{type: ObservationLatency, steps: 2}]")]
        ['Damping', 'ObservationLatency']
    """
    config, where = _read(source)
    if not isinstance(config, Mapping) or not ({"effects", "signals"} & set(config)):
        raise ValueError(
            f"{where}: the top level must be a mapping with an `effects` and/or a `signals` list. Received {config!r}."
        )
    _check_top_keys(config, where)
    effects = load_effects(source) if "effects" in config else []
    return [*effects, *_load_signals(config, where)]


def dump_config(effects: Sequence[Any]) -> str:
    """YAML text with ``effects:`` and ``signals:`` lists that :func:`load_config` reads back to equal models."""
    physical = [e for e in effects if isinstance(e, Effect)]
    signals = [e.to_config() for e in effects if not isinstance(e, Effect)]
    for item in signals:
        _check_writable_select(item)
    doc: dict[str, Any] = {"effects": [effect_to_config(e) for e in physical]}
    if signals:
        doc["signals"] = signals
    return yaml.safe_dump(doc, sort_keys=False)


def _check_writable_select(item: Mapping[str, Any]) -> None:
    """Refuses a ``select`` YAML cannot hold (a slice or range: ``load_config`` has no form for one, and the list of
    its indices would name another noise stream, so draw other values) before ``yaml`` fails on it."""
    for part in [item, *item.get("processes", ())]:
        select = part.get("select")
        if isinstance(select, (slice, range)):
            raise ValueError(
                f"`select` of {part['type']} must be observation keys, an index or a list of indices to be written "
                f"to YAML (a config has no slice form). Received {select!r}."
            )
