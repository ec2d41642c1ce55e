"""The result of :func:`sim2real.evaluation.evaluate`: every policy's episode returns on every condition.

Example:
    >>> import numpy as np
    >>> from sim2real.conditions import nominal, real
    >>> evaluation = Evaluation(
    ...     task="demo", seed=0, episodes=3, max_steps=None, policies=("ppo",),
    ...     conditions=(nominal(), real(params={"body_mass[arm]": 1.2})),
    ...     returns={"ppo": {"sim": np.array([3.0, 2.0, 1.0]), "real": np.array([2.0, 1.0, 0.0])}},
    ...     successes={}, lengths={}, draws={})
    >>> evaluation.table("ppo", ["sim", "real"]).shape, [c.name for c in evaluation.of_kind("real")]
    ((3, 2), ['real'])
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from sim2real.conditions import Condition, _freeze

__all__ = ["Evaluation"]


def _readonly(array: np.ndarray) -> np.ndarray:
    array = np.array(array, copy=True)
    array.setflags(write=False)
    return array


def _nested(data: Mapping[str, Mapping[str, Any]], dtype: Any) -> Mapping[str, Mapping[str, np.ndarray]]:
    return _freeze(
        {k: _freeze({c: _readonly(np.asarray(v, dtype=dtype)) for c, v in d.items()}) for k, d in data.items()}
    )


def _same(a: Any, b: Any) -> bool:
    """Whether two values of an :class:`Evaluation` field are equal: mappings key by key, arrays bitwise (the same
    dtype, shape and values, NaN equal to NaN), anything else by ``==``."""
    if isinstance(a, Mapping) or isinstance(b, Mapping):
        return (
            isinstance(a, Mapping)
            and isinstance(b, Mapping)
            and list(a) == list(b)
            and all(_same(a[k], b[k]) for k in a)
        )
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.dtype == b.dtype and a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
    return bool(a == b)


@dataclass(frozen=True, eq=False)
class Evaluation:
    """Episode returns of every policy on every condition, from :func:`~sim2real.evaluation.evaluate`.

    ``returns[policy][condition]`` is a read-only float64 array in episode order (row ``e`` is the episode reset
    with ``episode_seed(seed, e)`` in every simulated condition), ``(episodes,)`` long unless a condition was run
    for more episodes afterwards (the study's twin: :func:`sim2real.study.precision.extend`); a measured condition
    holds the measured returns instead, and only for the policies the CSV names. ``successes`` has the same
    layout when the task reports ``info["is_success"]`` (empty otherwise); ``lengths`` holds episode lengths.
    ``draws[condition][address]`` holds the value each episode drew (the same for every policy).

    Attributes:
        task: the task id.
        seed: the root seed.
        episodes: episodes per (policy, simulated condition) of the run; a condition extended afterwards holds more
            (the length of its arrays).
        max_steps: the cap on episode length, or None (the task's own limit).
        policies: policy names, in order.
        conditions: the conditions, in order.
        returns, successes, lengths, draws: see above.
        env_steps: environment steps taken.
        seconds: wall-clock time of the evaluation (not part of :meth:`to_dict`, which is reproducible).
        engines: simulated condition -> ``"batched"`` (stepped on :mod:`sim2real.batched`) or ``"per-env"``; how
            it ran, not what it computed (both engines give bitwise the same results), so not part of
            :meth:`to_dict` either.
        fallbacks: simulated condition that ran ``"per-env"`` -> why the batched engine did not run it (e.g.
            ``"no batched kernel for task 'gym/...'"``, ``"engine='per-env' was asked for"``); not part of
            :meth:`to_dict`.
        safety: ``safety[policy][condition][quantity]``, a read-only ``(episodes,)`` float64 array per quantity of
            :data:`sim2real.safety.QUANTITIES`, when ``evaluate`` was given ``safety=`` limits (empty otherwise;
            :meth:`to_dict` has a ``"safety"`` key only when it is not empty); with a joint speed limit also
            ``joint_speed_joint``, the index of the joint at each episode's peak
            (:func:`sim2real.safety_probe.speed_joints`).
    """

    task: str
    seed: int
    episodes: int
    max_steps: int | None
    policies: tuple[str, ...]
    conditions: tuple[Condition, ...]
    returns: Mapping[str, Mapping[str, np.ndarray]]
    successes: Mapping[str, Mapping[str, np.ndarray]]
    lengths: Mapping[str, Mapping[str, np.ndarray]]
    draws: Mapping[str, Mapping[str, np.ndarray]]
    env_steps: int = 0
    seconds: float = field(default=0.0, compare=False)
    engines: Mapping[str, str] = field(default_factory=dict, compare=False)
    safety: Mapping[str, Mapping[str, Mapping[str, np.ndarray]]] = field(default_factory=dict)
    fallbacks: Mapping[str, str] = field(default_factory=dict, compare=False)

    def __eq__(self, other: object) -> bool:
        """Equal when every field but ``seconds``, ``engines`` and ``fallbacks`` (how it ran, not what it computed)
        is: returns, successes, lengths, draws and safety bitwise (two runs of the same seed are; NaN draws too).

        Example:
            >>> from sim2real.conditions import nominal
            >>> def run(seconds: float) -> Evaluation:
            ...     return Evaluation(task="demo", seed=0, episodes=2, max_steps=None, policies=("p",),
            ...                       conditions=(nominal(),), returns={"p": {"sim": np.array([1.0, 2.0])}},
            ...                       successes={}, lengths={}, draws={}, seconds=seconds)
            >>> run(1.0) == run(2.0)
            True
        """
        if not isinstance(other, Evaluation):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self) if f.compare)

    __hash__ = None  # type: ignore[assignment]  # mutable-looking contents (arrays): as before, unhashable

    def engine_summary(self) -> str | None:
        """One line saying which engine stepped the simulated conditions and, for those run per env, why (what
        ``sim2real evaluate`` prints); None when nothing was simulated.

        Example:
            >>> from sim2real.conditions import nominal
            >>> run = Evaluation(task="gym/Arm-v0", seed=0, episodes=1, max_steps=None, policies=("p",),
            ...                  conditions=(nominal(),), returns={}, successes={}, lengths={}, draws={},
            ...                  engines={"sim": "per-env", "dr": "batched"},
            ...                  fallbacks={"sim": "no batched kernel for task 'gym/Arm-v0'"})
            >>> print(run.engine_summary())
            engines: batched for dr; per env for sim (no batched kernel for task 'gym/Arm-v0')
        """
        if not self.engines:
            return None
        parts = []
        batched = [name for name, engine in self.engines.items() if engine == "batched"]
        if batched:
            parts.append(f"batched for {_names(batched)}")
        reasons: dict[str, list[str]] = {}
        for name, engine in self.engines.items():
            if engine != "batched":
                reasons.setdefault(self.fallbacks.get(name, "no reason recorded"), []).append(name)
        if reasons:
            parts.append("per env for " + "; ".join(f"{_names(names)} ({why})" for why, names in reasons.items()))
        return "engines: " + "; ".join(parts)

    def condition(self, name: str) -> Condition:
        """The condition called ``name``."""
        for cond in self.conditions:
            if cond.name == name:
                return cond
        raise KeyError(f"`name` must be one of {[c.name for c in self.conditions]}. Received {name!r}.")

    def of_kind(self, *kinds: str) -> tuple[Condition, ...]:
        """The conditions of the given kinds, in order."""
        return tuple(c for c in self.conditions if c.kind in kinds)

    def sweeps(self) -> dict[str, tuple[Condition, ...]]:
        """Sweep and grid name -> its conditions (in grid order)."""
        out: dict[str, list[Condition]] = {}
        for cond in self.conditions:
            if cond.sweep is not None:
                out.setdefault(cond.sweep, []).append(cond)
        return {k: tuple(v) for k, v in out.items()}

    def table(self, policy: str, conditions: Sequence[str]) -> np.ndarray:
        """``(num_runs, num_conditions)`` returns of ``policy`` (the shape :mod:`sim2real.metrics` takes).

        Raises:
            KeyError: a condition without returns for ``policy``.
            ValueError: conditions with different numbers of runs (use them one at a time).
        """
        if policy not in self.returns:
            raise KeyError(f"`policy` must be one of {list(self.policies)}. Received {policy!r}.")
        columns = []
        for name in conditions:
            if name not in self.returns[policy]:
                raise KeyError(f"no returns for policy {policy!r} on condition {name!r}.")
            columns.append(self.returns[policy][name])
        sizes = {len(c) for c in columns}
        if len(sizes) > 1:
            raise ValueError(f"`conditions` {list(conditions)} have different numbers of runs: {sorted(sizes)}.")
        return np.column_stack(columns)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON-ready, without wall-clock time): reproducible bitwise from the seed."""

        def nested(data: Mapping[str, Mapping[str, np.ndarray]]) -> dict[str, Any]:
            return {k: {c: v.tolist() for c, v in d.items()} for k, d in data.items()}

        return {
            "task": self.task,
            "seed": self.seed,
            "episodes": self.episodes,
            "max_steps": self.max_steps,
            "policies": list(self.policies),
            "conditions": [c.config() for c in self.conditions],
            "returns": nested(self.returns),
            "successes": nested(self.successes),
            "lengths": nested(self.lengths),
            "draws": nested(self.draws),
            "env_steps": self.env_steps,
            **({"safety": {k: nested(d) for k, d in self.safety.items()}} if self.safety else {}),
        }

    def to_json(self, indent: int | None = 1) -> str:
        """:meth:`to_dict` as JSON text (keys in a fixed order)."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=True)


def _names(names: list[str], shown: int = 4) -> str:
    """``names`` joined with commas, the first ``shown`` of them and how many more."""
    if len(names) <= shown:
        return ", ".join(names)
    return f"{', '.join(names[:shown])} and {len(names) - shown} more"
