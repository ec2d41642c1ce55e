"""Helpers both training loops share (PPO in :mod:`~sim2real.agents.training`, SAC in
:mod:`~sim2real.agents.sac_loop`): the action bounds of a TorchRL env, the progress bar and the logger rows.

Example:
    >>> bar = progress_bar(10, False, "sac")
    >>> bar.update(10); bar.close()
    >>> log_row(None, {"frames": 1.0, "reward": 0.5}, 1)  # no logger: nothing to do
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["env_bounds", "log_row", "progress_bar", "record_row"]


def env_bounds(env: Any) -> tuple[int, int, list[float], list[float]]:
    """``(obs_dim, act_dim, low, high)`` of a TorchRL env with an ``"observation"`` vector and a bounded action.

    Raises:
        TypeError: the action spec is not bounded and continuous.
    """
    obs_dim = int(env.observation_spec["observation"].shape[-1])
    spec = env.action_spec
    low = getattr(getattr(spec, "space", None), "low", None)
    if low is None:
        raise TypeError(f"the env's action spec must be bounded and continuous. Received {type(spec).__name__}.")
    # One world's bounds: a batched env's spec leads with its batch_size (the same box in every world).
    world = (0,) * len(getattr(env, "batch_size", ()))
    low_l = [float(v) for v in spec.space.low[world].flatten()]
    high_l = [float(v) for v in spec.space.high[world].flatten()]
    return obs_dim, len(low_l), low_l, high_l


def progress_bar(total: int, progress: bool, desc: str) -> Any:
    """A tqdm bar on stderr counting frames (disabled when ``progress`` is False)."""
    import sys

    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="frame", disable=not progress, file=sys.stderr, leave=False)


def log_row(log: Any, row: Mapping[str, float], frames: int) -> None:
    """Writes the finite values of a metric row (all but ``"frames"``) to a TorchRL logger, if any."""
    if log is None:
        return
    for key, value in row.items():
        if key != "frames" and math.isfinite(value):
            log.log_scalar(key, value, step=frames)


def record_row(rows: list[dict[str, float]], log: Any, row: dict[str, float], frames: int) -> None:
    """Logs ``row`` (:func:`log_row`) and appends it to ``rows``, holding Ctrl-C and kills until both are done
    (:func:`~sim2real.output_paths.held_signals`): the logger's files of an interrupted run end with whole rows,
    the last of them the one its ``run.json`` counts (``rows`` is what :func:`~sim2real.agents.train` marks)."""
    from sim2real.output_paths import held_signals

    with held_signals():
        log_row(log, row, frames)
        rows.append(row)
