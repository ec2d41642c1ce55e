"""A task's study profile (``sim2real/data/study/<task>/study.yaml``), the budgets, and the evaluation spec the
study runs: the profile's twin, randomisation, sweeps and grid become an ordinary :mod:`sim2real.spec` mapping, so
the study's conditions are built by the same parser as ``sim2real evaluate --config``."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

__all__ = ["BUDGETS", "DEFAULT_TASK", "PROFILES", "Budget", "StudyProfile", "load_profile", "study_tasks"]

DEFAULT_TASK = "dmc/reacher-easy"
PROFILES = Path(__file__).resolve().parent.parent / "data" / "study"


@dataclass(frozen=True)
class Budget:
    """How much work a study does.

    Attributes:
        name: ``quick``, ``standard`` or ``full``.
        episodes: episodes per (policy, condition).
        max_steps: cap on episode length (None: the task's own limit).
        sweep_points: points kept per sweep (None: all; otherwise both bounds and the nominal first).
        grid_points: points kept per grid axis (None: all).
        log_episodes, log_steps: excitation episodes and control steps recorded on the twin.
        fit_starts: independent sysid multi-starts (seeds), run one after another in the study's process.
        train_frames: frames for policies that must be trained (None: the profile's agent frames).
        retrain: train every policy even when a shipped checkpoint matches.
        num_resamples: bootstrap resamples of every interval.
        precision: the goal half-width of the headline's interval (calibrated - randomized on the twin) as a
            fraction of the nominal return (:mod:`sim2real.study.precision`).
        max_target_episodes: the most episodes of every policy on the twin when the goal asks for more than
            ``episodes`` (keeps the standard study within its wall-time budget).
    """

    name: str
    episodes: int
    max_steps: int | None
    sweep_points: int | None
    grid_points: int | None
    log_episodes: int
    log_steps: int
    fit_starts: int
    train_frames: int | None
    retrain: bool
    num_resamples: int
    precision: float = 0.05
    max_target_episodes: int = 128


BUDGETS: dict[str, Budget] = {
    "quick": Budget("quick", 4, 200, 3, 2, 4, 200, 2, 2_000, False, 500, 0.05, 8),
    # standard: 128 episodes per condition (4x the 32 of issue 15's day), within P7's 180 s for install + study.
    "standard": Budget("standard", 128, None, None, None, 4, 200, 2, None, False, 2_000, 0.05, 256),
    "full": Budget("full", 256, None, None, None, 8, 200, 4, None, True, 5_000, 0.05, 1_024),
}


@dataclass(frozen=True)
class StudyProfile:
    """A task's study configuration (``sim2real/data/study/<task>/study.yaml``).

    Attributes:
        task: the task id.
        twin: the "real" robot as a :class:`sim2real.conditions.Condition` (kind ``real``): held-out ``params``
            plus signal models. It is evaluated *and* recorded for system identification through
            :meth:`~sim2real.conditions.Condition.make_env`, so it exists once.
        randomized: the randomisation chosen without data (effects and signal models).
        calibration_params: the addresses system identification fits.
        excitation: the excitation signal recorded on the twin.
        relative_width, digits: the calibrated ranges' rule (:meth:`sysid.FitResult.to_effects`).
        keep: randomisation kept on top of the fit.
        sweeps, grid: the report's one-parameter sweeps and two-parameter grid (evaluation-spec items).
        agent: the agent config (PPO or SAC) of the shipped checkpoints.
        folder: the profile's folder.
        safety: the safety envelope the study measures and reports (``safety.yaml`` next to ``study.yaml``, a
            :func:`sim2real.safety.load_limits` file), or None when the profile has none.
        adr: the ADR config of the "adr" policy (canonical YAML, :meth:`randomizers.ADR.config` keys; ranges from
            the nominal point), or None when the profile has no ``adr`` section.
        adr_signals: the signal models the "adr" policy trains under besides its ADR ranges.
    """

    task: str
    twin: Any
    randomized: tuple[Any, ...]
    calibration_params: tuple[str, ...]
    excitation: str
    relative_width: float
    digits: int
    keep: tuple[Any, ...]
    sweeps: tuple[Mapping[str, Any], ...]
    grid: Mapping[str, Any] | None
    agent: Any
    folder: Path
    twin_config: Mapping[str, Any]
    adr: str | None = None
    adr_signals: tuple[Any, ...] = ()
    safety: Any = None

    def spec_config(
        self,
        budget: Budget,
        *,
        seed: int,
        policies: Mapping[str, Any],
        simulators: Mapping[str, Any] | None = None,
    ) -> dict[str, Any]:
        """The evaluation spec (a :func:`sim2real.spec.load_spec` mapping) of this profile at ``budget``: the
        nominal sim, the randomised sim, ``simulators`` (e.g. ``{"calibrated": path}``), the twin, the sweeps
        (thinned to ``budget.sweep_points``) and the grid (``budget.grid_points`` per axis)."""
        from randomizers import dump_config

        sweeps = [_thinned(item, budget.sweep_points) for item in self.sweeps]
        grids = []
        if self.grid is not None:
            grids.append({key: _thinned(self.grid[key], budget.grid_points) for key in ("x", "y")})
        config: dict[str, Any] = {
            "task": self.task,
            "seed": seed,
            "episodes": budget.episodes,
            "batch": budget.episodes,
            "policies": dict(policies),
            "randomized": yaml.safe_load(dump_config(list(self.randomized))),
            "real": dict(self.twin_config),
            "sweeps": sweeps,
            "grids": grids,
        }
        if budget.max_steps is not None:
            config["max_steps"] = budget.max_steps
        if simulators:
            config["simulators"] = dict(simulators)
        return config


def _thinned(item: Mapping[str, Any], keep: int | None) -> dict[str, Any]:
    """A sweep or grid axis with its grid as explicit ``values``, at most ``keep`` of them (see :func:`_thin`)."""
    from sim2real.conditions import axis_values

    spec = {k: v for k, v in item.items() if k not in ("low", "high", "num")}
    spec["values"] = _thin(axis_values(item), _nominal(item), keep)
    return spec


def _nominal(spec: Mapping[str, Any]) -> float:
    from sim2real.conditions import _default_nominal

    value = spec.get("nominal")
    return float(value) if value is not None else _default_nominal(spec["field"])


def _thin(values: Sequence[float], nominal: float, keep: int | None) -> list[float]:
    """At most ``keep`` of ``values``: both ends and the nominal first, then from the middle out."""
    values = [float(v) for v in values]
    if keep is None or len(values) <= keep:
        return values
    chosen = {values[0], values[-1]}
    if any(math.isclose(v, nominal) for v in values):
        chosen.add(nominal)
    rest = [v for v in values if v not in chosen]
    while len(chosen) < keep and rest:
        chosen.add(rest.pop(len(rest) // 2))
    return sorted(chosen)


def _slug(task: str) -> str:
    return task.replace("/", "-")


def study_tasks() -> list[str]:
    """Task ids with a bundled study profile."""
    return [str(yaml.safe_load(p.read_text())["task"]) for p in sorted(PROFILES.glob("*/study.yaml"))]


def load_profile(task: str = DEFAULT_TASK) -> StudyProfile:
    """The bundled study profile of ``task``.

    Raises:
        ValueError: no profile for ``task`` (the tasks with one are listed), or an invalid profile (the file and
            the reason are named).
    """
    from randomizers import load_config
    from sim2real.agents import load_agent_config
    from sim2real.spec import load_spec
    from sim2real.twin import sensor_noise_std

    path = PROFILES / _slug(task) / "study.yaml"
    if not path.is_file():
        raise ValueError(f"`task` must be one of {study_tasks()} (tasks with a bundled study). Received {task!r}.")
    data = yaml.safe_load(path.read_text())
    twin = data["twin"]
    twin_config = {"config": {"signals": list(twin.get("signals", []))}, "params": dict(twin["params"])}
    # The twin is parsed exactly as an evaluation spec's `real:` entry is.
    spec = load_spec({"task": data["task"], "policies": {"scripted": "baseline"}, "real": twin_config})
    (condition,) = (c for c in spec.conditions if c.kind == "real")
    try:
        sensor_noise_std(condition)
    except ValueError as err:
        raise ValueError(f"{path}: twin.signals: {err}") from err
    calib = data["calibration"]
    adr = data.get("adr") or {}
    adr_text = None
    if adr:  # the "adr" policy's controller, checked here so a bad profile fails before any work
        from sim2real.agents.adr_training import adr_config_text

        try:
            adr_text = adr_config_text(adr.get("ranges"))
        except ValueError as err:
            raise ValueError(f"{path}: adr.ranges: {str(err).removeprefix('`adr`: ')}") from err
        if adr_text is None:
            raise ValueError(f"{path}: `adr` must have `ranges` (an ADR config). Received keys {sorted(adr)}.")
    return StudyProfile(
        task=str(data["task"]),
        twin=condition,
        randomized=tuple(load_config(data["randomized"])),
        calibration_params=tuple(calib["params"]),
        excitation=str(calib.get("excitation", "multisine")),
        relative_width=float(calib.get("relative_width", 0.1)),
        digits=int(calib.get("digits", 2)),
        keep=tuple(load_config(calib["keep"])) if calib.get("keep") else (),
        sweeps=tuple(data.get("sweeps", [])),
        grid=data.get("grid"),
        agent=load_agent_config(dict(data["agent"])),
        folder=path.parent,
        twin_config=twin_config,
        adr=adr_text,
        adr_signals=tuple(load_config({"signals": adr["signals"]})) if adr.get("signals") else (),
        safety=_safety(path.parent / "safety.yaml"),
    )


def _safety(path: Path) -> Any:
    """The profile's safety envelope (``safety.yaml``), or None without one."""
    from sim2real.safety import load_limits

    return load_limits(path) if path.is_file() else None
