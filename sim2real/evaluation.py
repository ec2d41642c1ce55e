"""Batched closed-loop evaluation: policies scored on sim, randomised sim, a "real" target and sweeps.

A *condition* is one way of building the environment: the nominal sim, a randomised sim (a config), the
"real" target (a twin with held-out parameters, noise and latency, or measured real-robot returns from
a CSV), a point of a one-parameter sweep or of a two-parameter grid. :func:`evaluate` runs every policy
on every condition for the same ``episodes``; many envs (one parameter sample each) are stepped
together with one batched policy call per control step.

Seeding: episode ``e`` is reset with :func:`episode_seed` ``(seed, e)`` in *every* condition and for
*every* policy, and each effect draws from streams keyed by that seed. So row ``e`` of every result is
the same initial state (common random numbers): gaps between simulated conditions and differences
between policies are paired, and any single (policy, condition, episode) can be replayed alone.
Results do not depend on the batch size, the backend or the number of workers.

Example:
    >>> import sim2real as s2r
    >>> from sim2real.evaluation import evaluate, nominal, randomized, sweep
    >>> from sim2real.agents import ReachController
    >>> conditions = [nominal(), randomized([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))]),
    ...               *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 1.0])]
    >>> result = evaluate({"reach": ReachController()}, "sim2real/arm-reach", conditions,
    ...                   episodes=2, seed=0, max_steps=20)
    >>> [c.name for c in result.conditions]
    ['sim', 'randomized', 'ActuatorGain.scale=0.5', 'ActuatorGain.scale=1']
    >>> result.returns["reach"]["sim"].shape
    (2,)
"""

from __future__ import annotations

import csv
import json
import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CONDITION_KINDS",
    "Condition",
    "Evaluation",
    "episode_seed",
    "evaluate",
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


def _readonly(array: np.ndarray) -> np.ndarray:
    array = np.array(array, copy=True)
    array.setflags(write=False)
    return array


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
        with path.open(newline="") as handle:
            reader = csv.DictReader(handle)
            columns = reader.fieldnames or []
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


# ----------------------------------------------------------------------------------------------- results


def _nested(data: Mapping[str, Mapping[str, Any]], dtype: Any) -> Mapping[str, Mapping[str, np.ndarray]]:
    return _freeze(
        {k: _freeze({c: _readonly(np.asarray(v, dtype=dtype)) for c, v in d.items()}) for k, d in data.items()}
    )


@dataclass(frozen=True)
class Evaluation:
    """Episode returns of every policy on every condition, from :func:`evaluate`.

    ``returns[policy][condition]`` is a read-only ``(episodes,)`` float64 array in episode order (row ``e``
    is the episode reset with ``episode_seed(seed, e)`` in every simulated condition); a measured condition
    holds the measured returns instead, and only for the policies the CSV names. ``successes`` has the same
    layout when the task reports ``info["is_success"]`` (empty otherwise); ``lengths`` holds episode lengths.
    ``draws[condition][address]`` holds the value each episode drew (the same for every policy).

    Attributes:
        task: the task id.
        seed: the root seed.
        episodes: episodes per (policy, simulated condition).
        max_steps: the cap on episode length, or None (the task's own limit).
        policies: policy names, in order.
        conditions: the conditions, in order.
        returns, successes, lengths, draws: see above.
        env_steps: environment steps taken.
        seconds: wall-clock time of the evaluation (not part of :meth:`to_dict`, which is reproducible).
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
        }

    def to_json(self, indent: int | None = 1) -> str:
        """:meth:`to_dict` as JSON text (keys in a fixed order)."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=True)


# ----------------------------------------------------------------------------------------------- engine


def episode_seed(seed: int, episode: int) -> int:
    """The reset seed of episode ``episode`` (a uint32), the same in every condition and for every policy.

    Example:
        >>> episode_seed(0, 0) == episode_seed(0, 0) != episode_seed(0, 1)
        True
    """
    return int(np.random.SeedSequence([int(seed), int(episode)]).generate_state(1)[0])


@dataclass(frozen=True)
class _Job:
    task: str
    options: Mapping[str, Any]
    conditions: tuple[Condition, ...]  # all with the same calibration params: they share the base envs
    policies: tuple[tuple[str, Any], ...]
    first: int
    count: int
    seed: int
    max_steps: int | None


@dataclass(frozen=True)
class _JobResult:
    condition: str
    first: int
    returns: dict[str, np.ndarray]
    lengths: dict[str, np.ndarray]
    successes: dict[str, np.ndarray]
    draws: dict[str, np.ndarray]
    steps: int


#: Conditions per job: a job builds its envs once and reuses them for each of its conditions.
_CONDITIONS_PER_JOB = 6


def _observation(obs: Any, task: str) -> np.ndarray:
    arr = np.asarray(obs)
    if arr.dtype == object or arr.ndim != 1:
        raise TypeError(
            f"evaluation needs flat vector observations; task {task!r} gives {type(obs).__name__} "
            f"of shape {getattr(arr, 'shape', None)} (use flatten=True)."
        )
    return arr


def _release(env: Any, base: Any) -> None:
    """Peels sim2real's wrappers off ``env`` down to ``base``, restoring its nominal model."""
    while env is not base and hasattr(env, "release"):
        env = env.release()


def _run_job(job: _Job) -> list[_JobResult]:
    """Runs ``job.count`` episodes of every policy on each of the job's conditions, all envs stepped together."""
    from sim2real.agents.policy import as_policy
    from sim2real.tasks import make
    from sim2real.wrapping import wrap

    n = job.count
    params = job.conditions[0].params
    base = [make(job.task, params=dict(params) if params is not None else None, **job.options) for _ in range(n)]
    seeds = [episode_seed(job.seed, job.first + i) for i in range(n)]
    policies = [(name, as_policy(source, task=job.task)) for name, source in job.policies]
    out = []
    restore_threads = _single_torch_thread()
    try:
        for cond in job.conditions:
            envs = [wrap(b, *cond.effects, seed=job.seed) if cond.effects else b for b in base]
            try:
                out.append(_episodes(job, cond, envs, seeds, policies))
            finally:
                for env, b in zip(envs, base, strict=True):
                    _release(env, b)
    finally:
        restore_threads()
        for env in base:
            env.close()
    return out


def _single_torch_thread() -> Callable[[], None]:
    """Torch policies run on one intra-op thread (restored by the returned function): the batches are small,
    and on a busy machine extra threads spin against other processes (an arm-reach evaluation of a PPO actor
    took 22.4 s with 2 threads and 3.4 s with 1 on the 2-core box). One thread also makes the results
    independent of the machine's core count."""
    if "torch" not in sys.modules:
        return lambda: None
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    return lambda: torch.set_num_threads(previous)


def _episodes(
    job: _Job, cond: Condition, envs: list[Any], seeds: list[int], policies: list[tuple[str, Any]]
) -> _JobResult:
    n = len(envs)
    returns: dict[str, np.ndarray] = {}
    lengths: dict[str, np.ndarray] = {}
    successes: dict[str, np.ndarray] = {}
    draws: dict[str, np.ndarray] = {}
    steps = 0
    for p, (name, policy) in enumerate(policies):
        first = [env.reset(seed=s) for env, s in zip(envs, seeds, strict=True)]
        obs = np.stack([_observation(o, job.task) for o, _ in first])
        if p == 0:
            keys = sorted({k for _, info in first for k in info.get("sim2real", {}).get("params", {})})
            for key in keys:
                draws[key] = np.array([float(info["sim2real"]["params"].get(key, math.nan)) for _, info in first])
        total = np.zeros(n)
        length = np.zeros(n, dtype=np.int64)
        done = np.zeros(n, dtype=bool)
        success = np.zeros(n, dtype=bool)
        reports_success = False
        t = 0
        while not done.all() and (job.max_steps is None or t < job.max_steps):
            actions = policy(obs)
            for i in np.flatnonzero(~done):
                o, r, terminated, truncated, info = envs[i].step(actions[i])
                obs[i] = o
                total[i] += float(r)
                length[i] += 1
                if "is_success" in info:
                    reports_success = True
                    success[i] = bool(info["is_success"])
                if terminated or truncated:
                    done[i] = True
            t += 1
        steps += int(length.sum())
        returns[name] = total
        lengths[name] = length
        if reports_success:
            successes[name] = success
    return _JobResult(cond.name, job.first, returns, lengths, successes, draws, steps)


def _policies(policies: Any) -> tuple[tuple[str, Any], ...]:
    from sim2real.agents.policy import BatchedPolicy, as_policy

    if isinstance(policies, Mapping):
        items = [(str(k), v) for k, v in policies.items()]
    else:
        seq = list(policies) if isinstance(policies, (list, tuple)) else [policies]
        items = [(as_policy(p).name, p) for p in seq]
    if not items:
        raise ValueError("`policies` must name at least one policy. Received none.")
    names = [n for n, _ in items]
    if len(set(names)) != len(names):
        raise ValueError(f"`policies` must have unique names. Received {names}.")
    # Workers rebuild the policy from its source (a checkpoint path, a module, a baseline...).
    return tuple((n, p.source if isinstance(p, BatchedPolicy) and p.source is not None else p) for n, p in items)


def evaluate(
    policies: Any,
    task: str,
    conditions: Sequence[Condition],
    *,
    episodes: int = 10,
    seed: int = 0,
    max_steps: int | None = None,
    batch: int = 64,
    task_options: Mapping[str, Any] | None = None,
    backend: str = "serial",
    workers: int | None = None,
    progress: bool = False,
) -> Evaluation:
    """Scores every policy on every condition with batched closed-loop episodes.

    Args:
        policies: ``{name: policy}`` or a list of policies (named by :func:`sim2real.agents.as_policy`); a
            policy is a TorchRL module, a checkpoint (path), a scripted baseline or a callable obs -> action.
        task: the task id (see ``sim2real tasks``).
        conditions: from :func:`nominal`, :func:`randomized`, :func:`real`, :func:`measured`,
            :func:`sweep` and :func:`grid`; names must be unique.
        episodes: episodes per (policy, simulated condition).
        seed: root seed; episode ``e`` is reset with :func:`episode_seed` ``(seed, e)`` everywhere.
        max_steps: cap on episode length (default: the task's own limit).
        batch: envs stepped together (one batched policy call per control step).
        task_options: keyword arguments for :func:`sim2real.make`.
        backend: ``"serial"`` (in this process), ``"local"`` (process pool) or ``"ray"``; results are the same.
        workers: processes for the ``local``/``ray`` backends (default: CPU count).
        progress: show a progress bar.

    Raises:
        ValueError: bad counts, duplicate names, an unknown backend.
        sim2real.agents.CheckpointError: (a ``ValueError``) a checkpoint path that is broken, tampered with or
            trained on another task; raised before any episode runs.
    """
    for argument, value, low in (("episodes", episodes, 1), ("batch", batch, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"`{argument}` must be an int >= {low}. Received {value!r}.")
    if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1):
        raise ValueError(f"`max_steps` must be None or an int >= 1. Received {max_steps!r}.")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"`seed` must be an int >= 0. Received {seed!r}.")
    conditions = tuple(conditions)
    if not conditions or not all(isinstance(c, Condition) for c in conditions):
        raise TypeError(
            "`conditions` must be a non-empty list of Condition (from nominal(), randomized(), real(), measured(), "
            f"sweep(), grid()). Received {conditions!r}."
        )
    names = [c.name for c in conditions]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"`conditions` must have unique names. Received duplicates {duplicates}.")
    named = _policies(policies)
    paths = [source for _, source in named if isinstance(source, (str, os.PathLike))]
    if paths:  # a broken, tampered or foreign checkpoint fails here, before any worker starts
        from sim2real.agents.checkpoint import check_checkpoints

        check_checkpoints(paths, task, dict(task_options or {}))
    policy_names = tuple(n for n, _ in named)
    options = _freeze(dict(task_options or {}))
    groups: dict[Any, list[Condition]] = {}
    for cond in conditions:
        if cond.simulated:
            key = None if cond.params is None else tuple(sorted(cond.params.items()))
            groups.setdefault(key, []).append(cond)
    jobs = [
        _Job(
            task,
            options,
            tuple(group[i : i + _CONDITIONS_PER_JOB]),
            named,
            first,
            min(batch, episodes - first),
            int(seed),
            max_steps,
        )
        for group in groups.values()
        for first in range(0, episodes, batch)
        for i in range(0, len(group), _CONDITIONS_PER_JOB)
    ]
    start = time.perf_counter()
    results = _dispatch(jobs, backend, workers, progress)
    seconds = time.perf_counter() - start
    return _collect(task, int(seed), episodes, max_steps, policy_names, conditions, results, seconds)


def _dispatch(jobs: list[_Job], backend: str, workers: int | None, progress: bool) -> list[_JobResult]:
    if backend == "serial":
        from tqdm.auto import tqdm

        runs = [_run_job(job) for job in tqdm(jobs, desc="evaluate", disable=not progress, leave=False)]
    else:
        from sim2real.parallel import run_tasks

        runs = list(run_tasks(_run_job, jobs, backend=backend, workers=workers, progress=progress, desc="evaluate"))
    return [res for run in runs for res in run]


def _collect(
    task: str,
    seed: int,
    episodes: int,
    max_steps: int | None,
    policies: tuple[str, ...],
    conditions: tuple[Condition, ...],
    results: Sequence[_JobResult],
    seconds: float,
) -> Evaluation:
    returns: dict[str, dict[str, np.ndarray]] = {p: {} for p in policies}
    lengths: dict[str, dict[str, np.ndarray]] = {p: {} for p in policies}
    successes: dict[str, dict[str, np.ndarray]] = {p: {} for p in policies}
    draws: dict[str, dict[str, np.ndarray]] = {}
    by_condition: dict[str, list[_JobResult]] = {}
    for res in results:
        by_condition.setdefault(res.condition, []).append(res)
    steps = 0
    for cond in conditions:
        if not cond.simulated:
            assert cond.returns is not None and cond.successes is not None
            for p in policies:
                if p in cond.returns:
                    returns[p][cond.name] = np.asarray(cond.returns[p])
                if p in cond.successes:
                    successes[p][cond.name] = np.asarray(cond.successes[p])
            continue
        parts = sorted(by_condition[cond.name], key=lambda r: r.first)
        steps += sum(r.steps for r in parts)
        for p in policies:
            returns[p][cond.name] = np.concatenate([r.returns[p] for r in parts])
            lengths[p][cond.name] = np.concatenate([r.lengths[p] for r in parts])
            if all(p in r.successes for r in parts):
                successes[p][cond.name] = np.concatenate([r.successes[p] for r in parts])
        keys = sorted({k for r in parts for k in r.draws})
        if keys:
            draws[cond.name] = {
                k: np.concatenate([r.draws.get(k, np.full(len(r.returns[policies[0]]), math.nan)) for r in parts])
                for k in keys
            }
    return Evaluation(
        task=task,
        seed=seed,
        episodes=episodes,
        max_steps=max_steps,
        policies=policies,
        conditions=conditions,
        returns=_nested(returns, np.float64),
        successes=_nested(successes, bool),
        lengths=_nested(lengths, np.int64),
        draws=_nested(draws, np.float64),
        env_steps=steps,
        seconds=seconds,
    )
