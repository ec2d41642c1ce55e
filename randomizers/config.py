"""Effects from and to YAML (``yaml.safe_load``), validated with errors that name the file and key.

The format is a mapping with an ``effects`` list; each item has ``type`` plus the effect's
keyword arguments. Distributions are a number (constant), ``[low, high]`` (uniform) or a mapping
with ``type``. Schedules are ``reset``, ``startup`` or ``{interval: {steps: N}}`` /
``{interval: {seconds: T}}``. A signal model's ``select`` is observation keys, an index, a list of indices,
a slice in Python's notation (``"0:12"``, ``":6"``, ``"0:12:2"``) or a range as Python prints it
(``"range(0, 12)"``); these strings read back to the very ``slice``/``range``, so the process keeps its random
stream (:func:`noise_models.values.selection_repr` names it) and draws the same values. Quote a slice written by
hand (``select: '6:12'``): YAML 1.1 reads an unquoted ``6:12`` as the base-60 number 372 (``dump_config`` quotes it).

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
import re
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
        elif name == "select":
            out[name] = _select_from_config(value)
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
        try:
            kwargs = _signal_kwargs(item, key)
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
    signals = [_writable_select(item) for item in signals]
    doc: dict[str, Any] = {"effects": [effect_to_config(e) for e in physical]}
    if signals:
        doc["signals"] = signals
    return yaml.safe_dump(doc, sort_keys=False)


_INT = r"\s*(-?\d+)?\s*"
_SLICE = re.compile(f"{_INT}:{_INT}(?::{_INT})?")
_RANGE = re.compile(r"range\(\s*(-?\d+)\s*(?:,\s*(-?\d+)\s*(?:,\s*(-?\d+)\s*)?)?\)")


def _select_to_config(select: object) -> object:
    """A slice as ``"start:stop[:step]"`` (a part left out stays out, a step of 1 stays 1) and a range as its
    repr; any other selection as it is (a tuple as a list)."""
    if isinstance(select, slice):
        parts = ["" if v is None else str(int(v)) for v in (select.start, select.stop, select.step)]
        return ":".join(parts if select.step is not None else parts[:2])
    if isinstance(select, range):
        return repr(select)
    return list(select) if isinstance(select, tuple) else select


def _select_from_config(value: object) -> object:
    """The inverse of :func:`_select_to_config`: a string with ``:`` is a slice, ``range(...)`` a range.

    Example:
        >>> _select_from_config("0:12"), _select_from_config(":6:2"), _select_from_config("range(0, 12, 3)")
        (slice(0, 12, None), slice(None, 6, 2), range(0, 12, 3))
        >>> _select_from_config("0:twelve")
        Traceback (most recent call last):
        ...
        ValueError: `select` must be observation keys, an index, a list of indices, a slice written 'start:stop' or \
'start:stop:step' (integers, each may be left out, step not 0: '0:12', ':6', '0:12:2') or a range written \
'range(start, stop)' or 'range(start, stop, step)'. Received '0:twelve'.
    """
    if isinstance(value, list):
        return tuple(value)
    if not isinstance(value, str) or (":" not in value and not value.startswith("range(")):
        return value  # keys (fnmatch patterns), an index; noise_models checks them
    found = _SLICE.fullmatch(value)
    if found is not None:
        start, stop, step = (None if v is None else int(v) for v in found.groups())
        if step != 0:
            return slice(start, stop, step)
    found = _RANGE.fullmatch(value.strip())
    if found is not None:
        args = [int(v) for v in found.groups() if v is not None]
        if len(args) < 3 or args[2] != 0:
            return range(*args) if len(args) > 1 else range(args[0])
    raise ValueError(
        "`select` must be observation keys, an index, a list of indices, a slice written 'start:stop' or "
        "'start:stop:step' (integers, each may be left out, step not 0: '0:12', ':6', '0:12:2') or a range written "
        f"'range(start, stop)' or 'range(start, stop, step)'. Received {value!r}."
    )


def _writable_select(item: Mapping[str, Any]) -> dict[str, Any]:
    """``item`` (a signal model's :meth:`to_config`) with every ``select`` (its own and its processes') in a form
    YAML holds and :func:`load_config` reads back equal: a slice as ``"0:12"``, a range as ``"range(0, 12)"``.
    The list of a slice's indices would not do: it names another noise stream, so it would draw other values."""
    out = dict(item)
    if "select" in out:
        out["select"] = _select_to_config(out["select"])
    if "processes" in out:
        out["processes"] = [_writable_select(p) for p in out["processes"]]
    return out
