"""Evaluation specs: the YAML file behind ``sim2real evaluate --config study.yaml --out DIR``.

Format (paths are relative to the YAML file; every key but ``task`` and ``policies`` is optional)::

    task: sim2real/arm-reach   # or model: robot.xml (an MJCF file) or env: package.module:factory (the module
                               #   is also looked for in the working folder and beside this file)
    seed: 0
    episodes: 20            # per (policy, simulated condition)
    max_steps: 100          # cap on episode length (default: the task's limit)
    batch: 64               # envs stepped together
    task_options: {}        # keyword arguments of sim2real.make
    policies:               # name -> {baseline: Class, <kwargs>} | {checkpoint: file.pt} | {constant: [...]} | "baseline"
      scripted: baseline    # the task's scripted baseline
      ppo: {checkpoint: ppo.pt}
      hold: {constant: [0.0, 0.0]}   # the same action every step (sim2real.safety.ConstantAction)
    randomized: randomized.yaml              # a randomisation config (file or inline effects/signals)
    simulators:                              # more simulators by name, e.g. the calibrated one of a fit
      calibrated: calibrated.yaml            #   (sysid fit --export ...): file or inline effects/signals
    real:                                    # the "real" target: a twin ...
      config: twin.yaml                      #   held-out effects/signals (file or inline)
      params: {"dof_damping[shoulder_pitch]": 2.0}   # held-out values written into the model
    # real: {csv: real_returns.csv}          # ... or measured real-robot returns (columns policy,return)
    sweeps:                                  # one-parameter sweeps: an effect, the swept field and its grid
      - {type: Damping, field: scale, values: [0.5, 1.0, 2.0, 4.0]}
      - {type: ObservationLatency, steps: 0, field: steps, low: 0, high: 4, num: 5}
    grids:                                   # two-parameter grids
      - x: {type: Damping, field: scale, values: [0.5, 1, 2]}
        y: {type: ActuatorGain, field: scale, values: [0.5, 1]}
    report: {title: "My study", confidence: 0.95, alpha: 0.1, fraction: 0.8, fit: fit.json}

The nominal simulator (condition ``sim``) is always evaluated.

Example:
    >>> spec = load_spec('''
    ... task: sim2real/arm-reach
    ... episodes: 4
    ... policies: {scripted: baseline}
    ... randomized: {effects: [{type: Damping, scale: [0.5, 2.0]}]}
    ... sweeps: [{type: ActuatorGain, field: scale, values: [0.5, 1.0]}]
    ... ''')
    >>> [c.name for c in spec.conditions], list(spec.policies)
    (['sim', 'randomized', 'ActuatorGain.scale=0.5', 'ActuatorGain.scale=1'], ['scripted'])
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from sim2real.evaluation import Condition, axis_values, grid, measured, nominal, randomized, real, sweep

__all__ = ["EvaluationSpec", "SpecError", "load_spec"]

_TOP_KEYS = (
    "task", "model", "env", "seed", "episodes", "max_steps", "batch", "task_options", "policies", "randomized",
    "simulators", "real", "sweeps", "grids", "report",
)  # fmt: skip
_REPORT_KEYS = ("title", "confidence", "alpha", "fraction", "statistic", "num_resamples", "fit", "notes")


class SpecError(ValueError):
    """An evaluation spec that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class EvaluationSpec:
    """A parsed evaluation spec (see the module docstring for the YAML format)."""

    task: str
    policies: Mapping[str, Any]
    conditions: tuple[Condition, ...]
    seed: int = 0
    episodes: int = 10
    max_steps: int | None = None
    batch: int = 64
    task_options: Mapping[str, Any] = field(default_factory=dict)
    report: Mapping[str, Any] = field(default_factory=dict)
    source: str = "<spec>"

    def visual_effects(self) -> list[Any]:
        """The visual effects (colours, textures, lights, cameras) of the spec's simulated conditions, once each."""
        from randomizers.visual import VISUAL_EFFECTS

        out: list[Any] = []
        for cond in self.conditions:
            for effect in cond.effects:
                if isinstance(effect, VISUAL_EFFECTS) and effect not in out:
                    out.append(effect)
        return out

    def contact_sheet(self, n: int = 8) -> Any:
        """A contact sheet of the spec's visual randomisation (:func:`sim2real.contact_sheet`), or None when the spec
        has no visual effects."""
        effects = self.visual_effects()
        if not effects:
            return None
        from sim2real.sheets import contact_sheet

        return contact_sheet(self.task, effects, n=n, seed=self.seed, size=(64, 64))

    def check(self) -> None:
        """Builds the task's env and every simulated condition's env once (reset, then closed), so a spec whose
        effects do not fit the task's model, or whose ``{constant: [...]}`` policy has the wrong number of values,
        fails before any episode runs, naming the condition or the policy, instead of inside a worker.

        Raises:
            SpecError: ``<file>: policies.<name>.constant ...`` or ``<file>: condition '<name>' ...``.

        Example:
            >>> spec = load_spec("task: dmc/reacher-easy\\npolicies: {hold: {constant: [0, 0, 0]}}")
            >>> spec.check()
            Traceback (most recent call last):
            ...
            sim2real.spec.SpecError: <config>: policies.hold.constant must have 2 values, the action size of 'dmc/reacher-easy'. Received 3: [0.0, 0.0, 0.0].
        """
        import gymnasium as gym

        from sim2real.safety import ConstantAction
        from sim2real.tasks import make

        try:
            env = make(self.task, **self.task_options)
        except (TypeError, ValueError) as err:
            raise SpecError(f"{self.source}: {err}") from err
        try:
            space = env.action_space
        finally:
            env.close()
        size = int(np.prod(space.shape)) if isinstance(space, gym.spaces.Box) else None  # a Discrete action: as is
        for name, policy in self.policies.items():
            if isinstance(policy, ConstantAction) and size is not None and policy.action.size != size:
                raise SpecError(
                    f"{self.source}: policies.{name}.constant must have {size} value{'s' if size != 1 else ''}, the "
                    f"action size of {self.task!r}. Received {policy.action.size}: "
                    f"{[round(float(v), 6) for v in policy.action]}."
                )
        for condition in self.conditions:
            if not condition.simulated:
                continue
            try:
                base = condition.base_env(self.task, **self.task_options)
            except (TypeError, ValueError) as err:
                raise SpecError(f"{self.source}: condition {condition.name!r}: {err}") from err
            env = base
            try:
                env = condition.wrap(base, seed=self.seed)
                env.reset(seed=self.seed)
            except (TypeError, ValueError) as err:
                raise SpecError(
                    f"{self.source}: the effects of condition {condition.name!r} do not fit {self.task!r}: {err}"
                ) from err
            finally:
                env.close()  # the wrapper closes the env it wraps

    def run(
        self,
        *,
        backend: str = "serial",
        workers: int | None = None,
        progress: bool = False,
        safety: Any = None,
        start: int = 0,
    ) -> Any:
        """Evaluates the spec's policies on its conditions (see :func:`sim2real.evaluation.evaluate`; ``safety``
        is its :class:`sim2real.safety.SafetyLimits`, ``start`` the first episode's index)."""
        from sim2real.evaluation import evaluate

        return evaluate(
            dict(self.policies),
            self.task,
            self.conditions,
            episodes=self.episodes,
            seed=self.seed,
            max_steps=self.max_steps,
            batch=self.batch,
            task_options=self.task_options,
            backend=backend,
            workers=workers,
            progress=progress,
            safety=safety,
            start=start,
        )


def _int(config: Mapping[str, Any], key: str, default: Any, low: int, where: str) -> Any:
    value = config.get(key, default)
    if value is None and default is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise SpecError(f"{where}: `{key}` must be an int >= {low}. Received {value!r}.")
    return value


def _policy(name: str, value: Any, task: str, base: Path, where: str) -> Any:
    from sim2real.agents.baselines import BASELINES, baseline_for

    key = f"{where}: policies.{name}"
    if value == "baseline":
        try:
            return baseline_for(task)
        except ValueError as err:
            raise SpecError(f"{key}: {err}") from err
    if isinstance(value, Mapping) and "checkpoint" in value and len(value) == 1:
        path = Path(str(value["checkpoint"]))
        path = path if path.is_absolute() else base / path
        if not path.is_file():
            raise SpecError(f"{key}.checkpoint: file {str(path)!r} does not exist.")
        return str(path)
    if isinstance(value, Mapping) and "constant" in value and len(value) == 1:
        from sim2real.safety import ConstantAction

        try:
            return ConstantAction(value["constant"])
        except (TypeError, ValueError) as err:
            raise SpecError(f"{key}.constant: {err}") from err
    if isinstance(value, Mapping) and "baseline" in value:
        classes = {cls.__name__: cls for cls in BASELINES.values()}
        cls = classes.get(value["baseline"])
        if cls is None:
            raise SpecError(f"{key}.baseline must be one of {sorted(classes)}. Received {value['baseline']!r}.")
        kwargs = {k: v for k, v in value.items() if k != "baseline"}
        try:
            return cls(**kwargs)
        except (TypeError, ValueError) as err:
            raise SpecError(f"{key}: {err}") from err
    raise SpecError(
        f"{key} must be 'baseline', {{baseline: <class>, ...}} or {{checkpoint: <file>}} or {{constant: <action>}}. "
        f"Received {value!r}."
    )


def _effects_source(value: Any, base: Path, key: str) -> Any:
    if isinstance(value, str):
        path = Path(value)
        path = path if path.is_absolute() else base / path
        if not path.is_file():
            raise SpecError(f"{key}: file {str(path)!r} does not exist.")
        return path
    if isinstance(value, Mapping):
        return dict(value)
    raise SpecError(f"{key} must be a YAML file name or a mapping with `effects`/`signals`. Received {value!r}.")


def _wrap_errors(key: str, fn: Any, *args: Any, **kwargs: Any) -> Any:
    try:
        return fn(*args, **kwargs)
    except SpecError:
        raise
    except (TypeError, ValueError, KeyError, FileNotFoundError) as err:
        text = str(err)
        raise SpecError(f"{key}: {text}") from err


def _check_measured_names(condition: Condition, policies: Mapping[str, Any], key: str) -> None:
    """Measured returns filed under a name `policies` does not define ('Hold' for 'hold') would be dropped, and
    the report would compare the target on the other policies only; refuse them, with the close names."""
    import difflib

    unknown = sorted(set(condition.returns or {}) - set(policies))
    if unknown:
        close = {n: difflib.get_close_matches(n, list(policies), n=1, cutoff=0.5) for n in unknown}
        hints = "".join(f" ({n!r}: did you mean {c[0]!r}?)" for n, c in close.items() if c)
        raise SpecError(
            f"{key}: every policy of the measured returns must be one of `policies` {sorted(policies)}. "
            f"Received unknown {unknown}.{hints}"
        )


def load_spec(source: str | os.PathLike[str] | Mapping[str, Any], *, task: str | None = None) -> EvaluationSpec:
    """Parses an evaluation spec from a YAML file path, YAML text or a mapping.

    ``task`` (a task id, ``"model:<path>"`` or ``"env:<module:factory>"``, e.g. the command line's
    ``--task``/``--model``/``--env``) replaces the spec's ``task:``/``model:``/``env:``, which it then need not
    name; the policies are read for that task.

    Raises:
        SpecError: with ``<file>: <key>: ...`` naming where the problem is.
        FileNotFoundError: the spec file does not exist.
    """
    from randomizers.config import _read  # the one YAML reader of configs: file path, text or mapping

    try:
        config, where = _read(source)
    except ValueError as err:
        raise SpecError(str(err)) from err
    base = Path(where).resolve().parent if where != "<config>" else Path.cwd()
    if not isinstance(config, Mapping):
        raise SpecError(f"{where}: the top level must be a mapping. Received {config!r}.")
    unknown = sorted(set(config) - set(_TOP_KEYS))
    if unknown:
        raise SpecError(f"{where}: keys must be among {list(_TOP_KEYS)}. Received unknown {unknown}.")
    from sim2real.sources import SourceError, source_from_config

    try:  # exactly one of task:, model: (an MJCF file, relative to this YAML) and env: (module:factory)
        task = task if task is not None else source_from_config(config, where, base).id
    except SourceError as err:
        raise SpecError(str(err)) from err
    policies_cfg = config.get("policies")
    if not isinstance(policies_cfg, Mapping) or not policies_cfg:
        raise SpecError(f"{where}: `policies` must be a non-empty mapping name -> policy. Received {policies_cfg!r}.")
    policies = {str(name): _policy(str(name), value, task, base, where) for name, value in policies_cfg.items()}

    conditions: list[Condition] = [nominal()]
    if "randomized" in config:
        key = f"{where}: randomized"
        conditions.append(_wrap_errors(key, randomized, _effects_source(config["randomized"], base, key)))
    simulators = config.get("simulators", {}) or {}
    if not isinstance(simulators, Mapping):
        raise SpecError(
            f"{where}: `simulators` must be a mapping name -> effects file or mapping. Received {simulators!r}."
        )
    for name, value in simulators.items():
        key = f"{where}: simulators.{name}"
        if not isinstance(name, str) or name in ("sim", "randomized", "real"):
            raise SpecError(f"{key}: a simulator name must be a string other than 'sim', 'randomized' and 'real'.")
        conditions.append(
            _wrap_errors(key, randomized, _effects_source(value, base, key), name=name, description=f"{name} sim")
        )
    if "real" in config:
        key = f"{where}: real"
        value = config["real"]
        if isinstance(value, Mapping) and "csv" in value:
            path = Path(str(value["csv"]))
            condition = _wrap_errors(f"{key}.csv", measured, path if path.is_absolute() else base / path)
            _check_measured_names(condition, policies, f"{key}.csv")
            conditions.append(condition)
        elif isinstance(value, Mapping) and set(value) <= {"config", "params", "hidden"}:
            effects = _effects_source(value["config"], base, f"{key}.config") if "config" in value else ()
            params = value.get("params")
            if params is not None and not isinstance(params, Mapping):
                raise SpecError(f"{key}.params must be a mapping address -> value. Received {params!r}.")
            conditions.append(_wrap_errors(key, real, effects, params=params, hidden=bool(value.get("hidden", True))))
        else:
            raise SpecError(
                f"{key} must be {{csv: <file>}} or a mapping with `config`, `params` and `hidden`. Received {value!r}."
            )
    for list_key, build in (("sweeps", _sweep), ("grids", _grid)):
        items = config.get(list_key, [])
        if not isinstance(items, list):
            raise SpecError(f"{where}: `{list_key}` must be a list. Received {items!r}.")
        for i, item in enumerate(items):
            key = f"{where}: {list_key}[{i}]"
            if not isinstance(item, Mapping):
                raise SpecError(f"{key} must be a mapping. Received {item!r}.")
            conditions.extend(_wrap_errors(key, build, item))
    names = [c.name for c in conditions]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise SpecError(f"{where}: condition names must be unique. Received duplicates {duplicates}.")

    report = config.get("report", {}) or {}
    if not isinstance(report, Mapping) or set(report) - set(_REPORT_KEYS):
        raise SpecError(
            f"{where}: `report` must be a mapping with keys among {list(_REPORT_KEYS)}. Received {report!r}."
        )
    report = dict(report)
    if "fit" in report:
        path = Path(str(report["fit"]))
        path = path if path.is_absolute() else base / path
        if not path.is_file():
            raise SpecError(f"{where}: report.fit: file {str(path)!r} does not exist.")
        report["fit"] = str(path)
    options = config.get("task_options", {}) or {}
    if not isinstance(options, Mapping):
        raise SpecError(f"{where}: `task_options` must be a mapping. Received {options!r}.")
    seed = _int(config, "seed", 0, 0, where)
    return EvaluationSpec(
        task=task,
        policies=MappingProxyType(policies),
        conditions=tuple(conditions),
        seed=seed,
        episodes=_int(config, "episodes", 10, 1, where),
        max_steps=_int(config, "max_steps", None, 1, where),
        batch=_int(config, "batch", 64, 1, where),
        task_options=MappingProxyType(dict(options)),
        report=MappingProxyType(report),
        source=where,
    )


def _sweep(item: Mapping[str, Any]) -> tuple[Condition, ...]:
    if "field" not in item:
        raise ValueError(f"`field` must name the swept argument. Received keys {sorted(item)}.")
    return sweep(dict(item), item["field"], axis_values(item), nominal=item.get("nominal"), name=item.get("name"))


def _grid(item: Mapping[str, Any]) -> tuple[Condition, ...]:
    if set(item) - {"x", "y", "name"} or not {"x", "y"} <= set(item):
        raise ValueError(f"a grid must have `x` and `y` (and optionally `name`). Received keys {sorted(item)}.")
    return grid(item["x"], item["y"], name=item.get("name"))
