"""ADR in training: the controller from a config or the effects, its ranges and entropy in the run's logger.

:func:`~sim2real.agents.train` calls :func:`with_adr` to find the run's controller (an :class:`~randomizers.ADR`
among ``effects``, else one built from ``config.adr``) and :func:`log_adr` to log, once per collected batch, the
entropy (``adr/entropy``, nats per dimension, left out while it is ``-inf``) and every boundary
(``adr/<key>/low``, ``adr/<key>/high``) at the batch's frame count. The final state goes into the checkpoint.

Example:
    >>> from sim2real.agents import PPOConfig
    >>> text = '''
    ... effects: [{type: Damping, scale: [0.0, 4.0]}]
    ... delta: 0.1
    ... t_low: 0.2
    ... t_high: 0.8
    ... '''
    >>> cfg = PPOConfig(frames=1000, adr=text)
    >>> effects, adr = with_adr([], cfg)
    >>> effects, adr.ranges
    ([], {'Damping[joints=*]': (1.0, 1.0)})
    >>> PPOConfig.from_yaml(cfg.to_yaml()) == cfg
    True
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import yaml

from randomizers.adr import ADR

__all__ = ["adr_config_text", "log_adr", "with_adr"]


def adr_config_text(value: object) -> str | None:
    """Validates a config's ``adr`` (None, YAML text or a mapping of :meth:`ADR.config` keys) into canonical YAML.

    Raises:
        ValueError: not YAML of an ADR config, or the ADR it describes is invalid (the ADR's own message).
    """
    if value is None:
        return None
    if isinstance(value, str):
        try:
            data = yaml.safe_load(value)
        except yaml.YAMLError as err:
            raise ValueError(f"`adr` must be YAML of an ADR config. Received text that is not YAML: {err}") from err
    elif isinstance(value, Mapping):
        data = dict(value)
    else:
        raise ValueError(f"`adr` must be None, YAML text or a mapping of an ADR config. Received {value!r}.")
    try:
        adr = ADR.from_config(data)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`adr`: {err}") from err
    return yaml.safe_dump(adr.config(), sort_keys=False)


def with_adr(effects: Sequence[Any], config: Any) -> tuple[list[Any], ADR | None]:
    """Splits the run's ADR controller from ``effects``; without one, builds it from ``config.adr`` (or None).

    Raises:
        ValueError: both ``effects`` and ``config.adr`` bring a controller, or ``effects`` brings two.
    """
    from sim2real.wrapping import _flatten

    flat = _flatten(effects)
    given = [e for e in flat if isinstance(e, ADR)]
    rest = [e for e in flat if not isinstance(e, ADR)]
    text = getattr(config, "adr", None)
    if len(given) > 1 or (given and text is not None):
        raise ValueError(
            "`effects` and `config.adr` must bring one ADR controller between them. "
            f"Received {len(given)} in effects and {'one' if text is not None else 'none'} in the config."
        )
    if given:
        return rest, given[0]
    if text is None:
        return rest, None
    return rest, ADR.from_config(yaml.safe_load(text))


class _ADRLogger:
    """Passes every call to the run's logger; at the first scalar of each new step, logs the ADR ranges too."""

    def __init__(self, log: Any, adr: ADR) -> None:
        self._log = log
        self._adr = adr
        self._step: int | None = None

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        if step is not None and step != self._step:
            self._step = step
            entropy = self._adr.entropy()
            if math.isfinite(entropy):
                self._log.log_scalar("adr/entropy", entropy, step=step)
            for key, (low, high) in self._adr.ranges.items():
                self._log.log_scalar(f"adr/{key}/low", low, step=step)
                self._log.log_scalar(f"adr/{key}/high", high, step=step)
        self._log.log_scalar(name, value, step=step)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._log, name)


def log_adr(log: Any, adr: ADR | None) -> Any:
    """``log`` itself without ADR or logger; else a logger that adds the ADR ranges to every logged step."""
    if log is None or adr is None:
        return log
    return _ADRLogger(log, adr)
