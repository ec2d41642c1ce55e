"""A safety envelope under perturbation: test the extremes in simulation before the hardware sees them.

:func:`sim2real.evaluation.evaluate` with ``safety=`` a :class:`SafetyLimits` measures, for every episode of every
policy on every simulated condition (the sweeps included), the quantities of :mod:`sim2real.safety_probe`: joint
limit hits, peak actuator effort over its limit, peak contact force on declared geoms, divergence, peak
end-effector speed, peak joint speed over its limit. :meth:`SafetyTable.build` aggregates them per policy x
condition (worst case over the episodes and CVaR, the mean of the worst ``alpha`` fraction) and per sweep (worst
over every point's episodes) and checks the declared limits; ``sim2real evaluate --safety limits.yaml`` exits 3
when one is violated, so a CI can gate on it.

The limits file (every key optional; a quantity without a limit is still measured and reported)::

    joint_limit_hits: 0                          # control steps per episode with a limited joint at/over its range
    max_effort_ratio: 1.0                        # peak |actuator_force| / the actuator's declared limit
    max_contact_force: {geoms: "finger*", newtons: 50}   # net contact force on each matching geom (a list works)
    max_ee_speed: {site: grip, m_per_s: 1.5}     # or {body: hand, m_per_s: 1.5}; the limit may be left out
    max_joint_speed: {joints: "elbow*", limit: 2.0}  # one limit for every matching joint (a list works), or
    #                {shoulder: 2.2, elbow: 2.6}    # a limit per joint; rad/s for a hinge joint, m/s for a slide
    divergences: 0                               # diverged episodes per policy x condition
    statistic: worst                             # what a limit gates: worst (default) or cvar
    alpha: 0.1                                   # CVaR tail fraction

A value is a violation when it is *above* its limit (a clamped actuator reaches a ratio of exactly 1.0: set
``max_effort_ratio: 0.95`` to flag saturation). ``divergences`` always gates on the count of diverged episodes.
``max_joint_speed`` is measured as ``joint_speed_ratio``, the peak of ``|qvel| / limit`` over the declared joints
(unitless, gated at 1.0; a violation names the joint at the peak and its speed, e.g. ``elbow 3.1 rad/s over 2.6``,
when :meth:`SafetyTable.build` is given the model). Ball and free joints have no one speed and are refused.

Example:
    >>> import numpy as np
    >>> from sim2real.conditions import nominal
    >>> from sim2real.evaluation_results import Evaluation
    >>> limits = load_limits({"joint_limit_hits": 0, "divergences": 0})
    >>> hits = np.array([0.0, 0.0, 4.0, 0.0])
    >>> quantities = {"joint_limit_hits": hits, "effort_ratio": np.full(4, 0.5), "contact_force": np.full(4, np.nan),
    ...               "ee_speed": np.full(4, np.nan), "diverged": np.zeros(4)}
    >>> evaluation = Evaluation(task="demo", seed=0, episodes=4, max_steps=None, policies=("slam",),
    ...     conditions=(nominal(),), returns={"slam": {"sim": np.zeros(4)}}, successes={}, lengths={}, draws={},
    ...     safety={"slam": {"sim": quantities}})
    >>> table = SafetyTable.build(evaluation, limits)
    >>> table.passed, [v.message for v in table.violations]
    (False, ["policy 'slam' on 'sim': joint_limit_hits worst 4 > limit 0 (episode 2; 1 of 4 episodes over 0, 95% \
interval of the rate 4.56%-69.9%)"])
    >>> [row.verdict for row in table.rows if row.quantity == "diverged"]  # within its limit, on 4 episodes only
    ['within: 0 of 4 episodes diverged, 95% interval of the rate 0%-49%']
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.safety_probe import QUANTITIES, SafetyMeter, SpeedJoint, speed_joints

if TYPE_CHECKING:
    from sim2real.metrics import Estimate

__all__ = [
    "QUANTITIES",
    "ConstantAction",
    "LimitsError",
    "SafetyLimits",
    "SafetyMeter",
    "SafetyRow",
    "SafetyTable",
    "SafetyViolation",
    "load_limits",
    "physics_substeps",
]

#: Unit of each quantity, as the report prints it.
UNITS = {"joint_limit_hits": "steps", "effort_ratio": "", "contact_force": "N", "ee_speed": "m/s",
         "joint_speed_ratio": "", "diverged": ""}  # fmt: skip
#: The limits file's keys.
LIMIT_KEYS = (
    "joint_limit_hits", "max_effort_ratio", "max_contact_force", "max_ee_speed", "max_joint_speed", "divergences",
    "statistic", "alpha",
)  # fmt: skip
#: What a joint speed limit is in, for messages.
_SPEED_UNITS = "rad/s for a hinge joint, m/s for a slide joint"
STATISTICS = ("worst", "cvar")


class LimitsError(ValueError):
    """A limits file that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class SafetyLimits:
    """A declared safety envelope (see the module docstring for the YAML form, :func:`load_limits` to read it).

    Attributes:
        joint_limit_hits: allowed control steps per episode with a joint at/over its range, or None (no limit).
        max_effort_ratio: allowed peak ``|actuator_force| / limit``, or None.
        contact_geoms: fnmatch patterns of the geoms whose contact force is measured (empty: not measured).
        max_contact_force: allowed peak net contact force on one of them, newtons, or None.
        ee_site: the site whose speed is measured, or None.
        ee_body: the body whose speed is measured (when no site is given), or None.
        max_ee_speed: allowed peak speed, m/s, or None.
        divergences: allowed diverged episodes per policy x condition, or None.
        statistic: ``"worst"`` or ``"cvar"``, what the limits gate.
        alpha: CVaR tail fraction in (0, 1].
        speed_joints: fnmatch patterns of the joints that share the one speed limit ``max_joint_speed`` (the
            ``{joints: ..., limit: ...}`` form; empty otherwise).
        max_joint_speed: that limit (rad/s for a hinge joint, m/s for a slide joint), or None.
        joint_speeds: ``(joint name or pattern, limit)`` pairs (the per-joint form; empty otherwise).
        source: where the limits came from (a file name), for messages.
    """

    joint_limit_hits: int | None = None
    max_effort_ratio: float | None = None
    contact_geoms: tuple[str, ...] = ()
    max_contact_force: float | None = None
    ee_site: str | None = None
    ee_body: str | None = None
    max_ee_speed: float | None = None
    divergences: int | None = None
    statistic: str = "worst"
    alpha: float = 0.1
    speed_joints: tuple[str, ...] = ()
    max_joint_speed: float | None = None
    joint_speeds: tuple[tuple[str, float], ...] = ()
    source: str = field(default="<limits>", compare=False)

    def __post_init__(self) -> None:
        for name, value in (("joint_limit_hits", self.joint_limit_hits), ("divergences", self.divergences)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
                raise LimitsError(f"{self.source}: `{name}` must be an int >= 0. Received {value!r}.")
        for name, number in (
            ("max_effort_ratio", self.max_effort_ratio),
            ("max_contact_force.newtons", self.max_contact_force),
            ("max_ee_speed.m_per_s", self.max_ee_speed),
        ):
            if number is not None and not _positive(number):
                raise LimitsError(f"{self.source}: `{name}` must be a number > 0. Received {number!r}.")
        if self.statistic not in STATISTICS:
            raise LimitsError(
                f"{self.source}: `statistic` must be one of {list(STATISTICS)}. Received {self.statistic!r}."
            )
        if isinstance(self.alpha, bool) or not isinstance(self.alpha, (int, float)) or not 0 < self.alpha <= 1:
            raise LimitsError(f"{self.source}: `alpha` must be a number in (0, 1]. Received {self.alpha!r}.")
        if self.max_contact_force is not None and not self.contact_geoms:
            raise LimitsError(f"{self.source}: `max_contact_force.geoms` must name the geoms the limit is on.")
        if self.max_ee_speed is not None and self.ee_site is None and self.ee_body is None:
            raise LimitsError(f"{self.source}: `max_ee_speed` must name a `site` or a `body`.")
        self._check_joint_speeds()

    def _check_joint_speeds(self) -> None:
        where = self.source
        if self.joint_speeds and (self.speed_joints or self.max_joint_speed is not None):
            raise LimitsError(f"{where}: `max_joint_speed` takes {{joints: ..., limit: ...}} or a mapping joint -> "
                              "limit, not both.")  # fmt: skip
        if self.speed_joints or self.max_joint_speed is not None:
            if not self.speed_joints:
                raise LimitsError(f"{where}: `max_joint_speed.joints` must name the joints the limit is on.")
            if not all(isinstance(j, str) and j for j in self.speed_joints):
                raise LimitsError(f"{where}: `max_joint_speed.joints` must be a joint name pattern or a list of them. "
                                  f"Received {list(self.speed_joints)!r}.")  # fmt: skip
            if not _positive(self.max_joint_speed):
                raise LimitsError(f"{where}: `max_joint_speed.limit` must be a number > 0 ({_SPEED_UNITS}). "
                                  f"Received {self.max_joint_speed!r}.")  # fmt: skip
        for pair in self.joint_speeds:
            if not (isinstance(pair, tuple) and len(pair) == 2 and isinstance(pair[0], str) and pair[0]):
                raise LimitsError(f"{where}: `joint_speeds` must hold (joint name, limit) pairs. Received {pair!r}.")
            if not _positive(pair[1]):
                raise LimitsError(f"{where}: `max_joint_speed.{pair[0]}` must be a number > 0 ({_SPEED_UNITS}). "
                                  f"Received {pair[1]!r}.")  # fmt: skip

    def limit(self, quantity: str) -> float | None:
        """The declared limit of ``quantity`` (one of :data:`QUANTITIES`), or None."""
        value = {
            "joint_limit_hits": self.joint_limit_hits,
            "effort_ratio": self.max_effort_ratio,
            "contact_force": self.max_contact_force,
            "ee_speed": self.max_ee_speed,
            "joint_speed_ratio": 1.0 if self.speed_joints or self.joint_speeds else None,  # each joint's own limit
            "diverged": self.divergences,
        }[quantity]
        return None if value is None else float(value)

    def meter(self, model: Any, num_envs: int) -> SafetyMeter:
        """A :class:`SafetyMeter` of ``num_envs`` envs of ``model`` (names resolved, limits read).

        Raises:
            LimitsError: a geom pattern, site, body or joint the model does not have (close matches listed), or a
                joint speed limit on a ball or free joint.
        """
        try:
            return SafetyMeter(model, self, num_envs)
        except ValueError as err:
            raise LimitsError(str(err)) from err

    def to_dict(self) -> dict[str, Any]:
        """The limits in the file's form (keys left out when not declared)."""
        out: dict[str, Any] = {}
        if self.joint_limit_hits is not None:
            out["joint_limit_hits"] = self.joint_limit_hits
        if self.max_effort_ratio is not None:
            out["max_effort_ratio"] = self.max_effort_ratio
        if self.contact_geoms:
            out["max_contact_force"] = {"geoms": list(self.contact_geoms), "newtons": self.max_contact_force}
        if self.ee_site is not None or self.ee_body is not None:
            where = {"site": self.ee_site} if self.ee_site is not None else {"body": self.ee_body}
            out["max_ee_speed"] = {**where, "m_per_s": self.max_ee_speed}
        if self.speed_joints:
            out["max_joint_speed"] = {"joints": list(self.speed_joints), "limit": self.max_joint_speed}
        elif self.joint_speeds:
            out["max_joint_speed"] = dict(self.joint_speeds)
        if self.divergences is not None:
            out["divergences"] = self.divergences
        out["statistic"], out["alpha"] = self.statistic, self.alpha
        return out


def _positive(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value) and value > 0


def _sub(value: Any, key: str, allowed: tuple[str, ...], where: str) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise LimitsError(f"{where}: `{key}` must be a mapping with keys among {list(allowed)}. Received {value!r}.")
    unknown = sorted(set(map(str, value)) - set(allowed))
    if unknown:
        raise LimitsError(f"{where}: `{key}` keys must be among {list(allowed)}. Received unknown {unknown}.")
    return dict(value)


def load_limits(source: str | os.PathLike[str] | Mapping[str, Any]) -> SafetyLimits:
    """Reads a limits file (a YAML path, YAML text or a mapping; format in the module docstring).

    Raises:
        LimitsError: (a ``ValueError``) naming the file, the key, what is allowed and what was received.
        FileNotFoundError: the file does not exist.

    Example:
        >>> load_limits("max_ee_speed: {site: ee, m_per_s: 1.5}").max_ee_speed
        1.5
        >>> load_limits("max_contact_force: {geoms: 'finger*', newtons: -1}")
        Traceback (most recent call last):
        ...
        sim2real.safety.LimitsError: <config>: `max_contact_force.newtons` must be a number > 0. Received -1.
    """
    from randomizers.config import _read  # the one YAML reader of configs: file path, text or mapping

    try:
        config, where = _read(source)
    except ValueError as err:
        raise LimitsError(str(err)) from err
    if not isinstance(config, Mapping):
        raise LimitsError(f"{where}: the top level must be a mapping with keys among {list(LIMIT_KEYS)}. "
                          f"Received {config!r}.")  # fmt: skip
    unknown = sorted(set(map(str, config)) - set(LIMIT_KEYS))
    if unknown:
        raise LimitsError(f"{where}: keys must be among {list(LIMIT_KEYS)}. Received unknown {unknown}.")
    kwargs: dict[str, Any] = {
        k: config[k]
        for k in ("joint_limit_hits", "max_effort_ratio", "divergences", "statistic", "alpha")
        if k in config
    }
    if "max_contact_force" in config:
        item = _sub(config["max_contact_force"], "max_contact_force", ("geoms", "newtons"), where)
        geoms = item.get("geoms")
        patterns = [geoms] if isinstance(geoms, str) else geoms
        if not isinstance(patterns, list) or not patterns or not all(isinstance(g, str) and g for g in patterns):
            raise LimitsError(
                f"{where}: `max_contact_force.geoms` must be a geom name pattern or a list of them. Received {geoms!r}."
            )
        kwargs["contact_geoms"] = tuple(patterns)
        kwargs["max_contact_force"] = item.get("newtons")
    if "max_ee_speed" in config:
        item = _sub(config["max_ee_speed"], "max_ee_speed", ("site", "body", "m_per_s"), where)
        named = [k for k in ("site", "body") if k in item]
        if len(named) != 1 or not isinstance(item[named[0]], str) or not item[named[0]]:
            raise LimitsError(
                f"{where}: `max_ee_speed` must name exactly one `site` or `body` (a name). "
                f"Received {dict((k, item[k]) for k in named) or 'neither'}."
            )
        kwargs[f"ee_{named[0]}"] = item[named[0]]
        kwargs["max_ee_speed"] = item.get("m_per_s")
    if "max_joint_speed" in config:
        kwargs.update(_joint_speed(config["max_joint_speed"], where))
    return SafetyLimits(**kwargs, source=where)


def _joint_speed(value: Any, where: str) -> dict[str, Any]:
    """``max_joint_speed``'s two forms as :class:`SafetyLimits` keywords: ``{joints: <pattern(s)>, limit: x}``
    (recognised by its ``joints`` key) or a mapping joint name -> limit."""
    if not isinstance(value, Mapping) or not value:
        raise LimitsError(f"{where}: `max_joint_speed` must be {{joints: <pattern or list>, limit: <number>}} or a "
                          f"mapping joint name -> limit ({_SPEED_UNITS}). Received {value!r}.")  # fmt: skip
    if "joints" in value or "limit" in value:
        item = _sub(value, "max_joint_speed", ("joints", "limit"), where)
        joints = item.get("joints")
        patterns = [joints] if isinstance(joints, str) else joints
        if not isinstance(patterns, list) or not patterns or not all(isinstance(j, str) and j for j in patterns):
            raise LimitsError(f"{where}: `max_joint_speed.joints` must be a joint name pattern or a list of them. "
                              f"Received {joints!r}.")  # fmt: skip
        return {"speed_joints": tuple(patterns), "max_joint_speed": item.get("limit")}
    return {"joint_speeds": tuple((str(name), limit) for name, limit in value.items())}


# ------------------------------------------------------------------------------------------------ aggregation


def physics_substeps(env: Any) -> int | None:
    """Physics steps per control step of ``env`` (its ``control_timestep`` over the model's ``opt.timestep``),
    or None when either is unknown: how many physics steps a once-per-control-step safety sample covers.

    Example:
        >>> import sim2real
        >>> physics_substeps(sim2real.make("dmc/reacher-easy"))
        1
    """
    from sim2real.physics import find_physics

    handle = find_physics(env)
    control = getattr(getattr(env, "unwrapped", env), "control_timestep", None)
    if handle is None or not isinstance(control, (int, float)) or not control > 0:
        return None
    return max(1, round(float(control) / float(handle.model.opt.timestep)))


def cvar_upper(values: np.ndarray, alpha: float) -> float:
    """Mean of the worst (largest) ``ceil(alpha * n)`` values: CVaR of a quantity where larger is worse.

    Example:
        >>> cvar_upper(np.arange(20.0), 0.1)
        18.5
    """
    values = np.sort(np.asarray(values, dtype=np.float64))
    k = max(1, math.ceil(alpha * len(values) - 1e-12))
    return float(values[-k:].mean())


@dataclass(frozen=True)
class SafetyRow:
    """One quantity of one policy on one condition (or over one sweep's points).

    Attributes:
        policy: the policy.
        condition: the condition's name, or the sweep's name when ``kind == "sweep"``.
        kind: ``"condition"`` or ``"sweep"`` (the worst over every point of a sweep or grid).
        quantity: one of :data:`QUANTITIES`.
        worst: the largest per-episode value (for ``diverged``: the number of diverged episodes).
        cvar: the mean of the worst ``alpha`` fraction of episodes (for ``diverged``: the fraction diverged).
        where: the episode of the worst value: ``"episode 3"``, or ``"<point> episode 3"`` for a sweep.
        episodes: episodes aggregated.
        limit: the declared limit, or None.
        violated: whether the gated statistic is above the limit.
        point: the condition holding the worst episode (for a sweep, its point; for ``diverged``, the point with the
            most diverged episodes); the condition itself on a condition row.
        over: episodes whose value is above the limit (for ``diverged``: the diverged episodes), or None without a
            limit.
        over_rate: the rate of such episodes with its 95% Wilson interval (a
            :class:`~sim2real.metrics.Estimate`), or None without a limit: a row within its limit on 4 episodes
            still allows a rate up to 49%.
        peak: for ``joint_speed_ratio``, the joint at the worst episode's peak, its speed and limit
            (``"elbow 3.1 rad/s over 2.6"``); ``""`` otherwise or when the table was built without the model.
    """

    policy: str
    condition: str
    kind: str
    quantity: str
    worst: float
    cvar: float
    where: str
    episodes: int
    limit: float | None
    violated: bool
    point: str = ""
    over: int | None = None
    over_rate: Estimate | None = None
    peak: str = ""

    @property
    def verdict(self) -> str:
        """The check of this row in words, with the interval of the rate of episodes over the limit, e.g.
        ``VIOLATED: 3 of 4 episodes over 0.95, 95% interval of the rate 30%-95%``; ``""`` without a limit."""
        if self.limit is None or self.over is None or self.over_rate is None:
            return ""
        head = "VIOLATED" if self.violated else "within"
        return f"{head}: {_over(self.over, self.episodes, self.limit, self.over_rate, self.quantity)}"


@dataclass(frozen=True)
class SafetyViolation:
    """A declared limit exceeded by one policy on one condition; :attr:`message` is the one line the CLI prints."""

    policy: str
    condition: str
    quantity: str
    statistic: str
    value: float
    limit: float
    where: str
    over: int | None = None
    episodes: int | None = None
    over_rate: Estimate | None = None
    peak: str = ""  # the joint at a joint speed peak (see SafetyRow.peak)

    @property
    def message(self) -> str:
        """E.g. ``policy 'slam' on 'sim': joint_limit_hits worst 4 > limit 0 (episode 2; 1 of 4 episodes over 0,
        95% interval of the rate 4.56%-69.9%)``."""
        unit = UNITS[self.quantity]
        suffix = f" {unit}" if unit and unit != "steps" else ""
        name = "divergences" if self.quantity == "diverged" else self.quantity
        rate = ""
        if self.over is not None and self.episodes is not None and self.over_rate is not None:
            rate = f"; {_over(self.over, self.episodes, self.limit, self.over_rate, self.quantity)}"
            if self.quantity == "diverged":  # `where` already says how many of how many
                rate = f"; 95% interval of the rate {_pct(self.over_rate.low)}-{_pct(self.over_rate.high)}"
        return (
            f"policy {self.policy!r} on {self.condition!r}: {name} {self.statistic} {_fmt(self.value)}{suffix} "
            f"> limit {_fmt(self.limit)}{suffix} ({self.where}{f': {self.peak}' if self.peak else ''}{rate})"
        )


def _fmt(value: float) -> str:
    return f"{value:.4g}"


def _pct(value: float) -> str:
    return f"{100 * value:.3g}%"


def _over(over: int, episodes: int, limit: float, rate: Estimate, quantity: str) -> str:
    """``3 of 4 episodes over 0.95, 95% interval of the rate 30%-95%``."""
    what = "diverged" if quantity == "diverged" else f"over {_fmt(limit)}"
    return f"{over} of {episodes} episodes {what}, 95% interval of the rate {_pct(rate.low)}-{_pct(rate.high)}"


def _over_rate(values: np.ndarray, quantity: str, limit: float | None) -> tuple[int | None, Estimate | None]:
    """Episodes over ``limit`` (diverged ones for ``diverged``) and their rate with a 95% Wilson interval."""
    if limit is None or not len(values):
        return None, None
    from sim2real.metrics import success_rate  # the one Wilson interval

    over = values > 0.5 if quantity == "diverged" else values > limit
    (rate,) = success_rate(over.astype(np.float64)[:, None])
    return int(over.sum()), rate


@dataclass(frozen=True)
class SafetyTable:
    """The safety section: every measured quantity per policy x condition and per sweep, and the violations.

    Attributes:
        limits: the envelope checked.
        rows: one :class:`SafetyRow` per (policy, condition or sweep, measured quantity), in evaluation order.
        violations: the limits exceeded (on conditions; a sweep row is marked when one of its points is).
        substeps: physics steps per control step of the task (the quantities are sampled once per control step,
            so with 1 every physics step is seen; with more, a peak inside the substeps is not), or None (unknown).
    """

    limits: SafetyLimits
    rows: tuple[SafetyRow, ...]
    violations: tuple[SafetyViolation, ...]
    substeps: int | None = None

    @property
    def passed(self) -> bool:
        """True when no declared limit is exceeded."""
        return not self.violations

    @classmethod
    def build(
        cls, evaluation: Any, limits: SafetyLimits, *, substeps: int | None = None, model: Any = None
    ) -> SafetyTable:
        """Aggregates ``evaluation.safety`` (from :func:`~sim2real.evaluation.evaluate` with ``safety=limits``);
        ``substeps`` (physics steps per control step, :func:`physics_substeps`) says what the sampling sees;
        ``model`` (the task's ``MjModel``, optional) names the joint at each joint speed peak.

        Raises:
            ValueError: the evaluation carries no safety measurements, or ``substeps`` is not an int >= 1.
            LimitsError: ``model`` lacks a joint the limits declare a speed for.
        """
        if substeps is not None and (isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1):
            raise ValueError(f"`substeps` must be None or an int >= 1. Received {substeps!r}.")
        safety: Mapping[str, Mapping[str, Mapping[str, np.ndarray]]] = evaluation.safety
        if not safety:
            raise ValueError("`evaluation` has no safety measurements: run evaluate(..., safety=limits).")
        joints: tuple[SpeedJoint, ...] = ()
        if model is not None and (limits.speed_joints or limits.joint_speeds):
            try:
                joints = speed_joints(model, limits)
            except ValueError as err:
                raise LimitsError(f"{limits.source}: {err}") from err
        rows: list[SafetyRow] = []
        violations: list[SafetyViolation] = []
        sweeps = evaluation.sweeps()
        for policy in evaluation.policies:
            measured = safety.get(policy, {})
            done: set[str] = set()
            for cond in evaluation.conditions:
                if cond.name not in measured:
                    continue
                if cond.sweep is None:
                    parts = [(cond.name, measured[cond.name])]
                    name, kind = cond.name, "condition"
                elif cond.sweep in done:
                    continue
                else:
                    done.add(cond.sweep)
                    parts = [(c.name, measured[c.name]) for c in sweeps[cond.sweep] if c.name in measured]
                    name, kind = cond.sweep, "sweep"
                for quantity in QUANTITIES:
                    row, found = _row(policy, name, kind, quantity, parts, limits, joints)
                    if row is not None:
                        rows.append(row)
                        violations.extend(found)
        return cls(limits, tuple(rows), tuple(violations), substeps)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the limits, every row (non-finite numbers as None) and the violation lines."""

        def num(value: float | None) -> float | None:
            return None if value is None or not math.isfinite(value) else float(value)

        return {
            "limits": self.limits.to_dict(),
            "passed": self.passed,
            "rows": [
                {
                    "policy": r.policy,
                    "condition": r.condition,
                    "kind": r.kind,
                    "quantity": r.quantity,
                    "unit": UNITS[r.quantity],
                    "worst": num(r.worst),
                    "cvar": num(r.cvar),
                    "where": r.where,
                    "point": r.point,
                    "episodes": r.episodes,
                    "limit": num(r.limit),
                    "violated": r.violated,
                    "episodes_over_limit": r.over,
                    "over_limit_rate": None
                    if r.over_rate is None
                    else {
                        "value": r.over_rate.value,
                        "low": r.over_rate.low,
                        "high": r.over_rate.high,
                        "confidence": r.over_rate.confidence,
                        "method": r.over_rate.method,
                    },
                    "verdict": r.verdict,
                    **({"peak": r.peak} if r.peak else {}),
                }
                for r in self.rows
            ],
            "violations": [v.message for v in self.violations],
            **({} if self.substeps is None else {"physics_steps_per_sample": self.substeps}),
        }


def _row(
    policy: str,
    name: str,
    kind: str,
    quantity: str,
    parts: Sequence[tuple[str, Mapping[str, np.ndarray]]],
    limits: SafetyLimits,
    joints: Sequence[SpeedJoint] = (),
) -> tuple[SafetyRow | None, list[SafetyViolation]]:
    """The row of ``quantity`` over ``parts`` (one condition, or a sweep's points) and its violations."""
    if not parts or not all(quantity in m for _, m in parts):
        return None, []  # measured before the quantity existed
    arrays = [np.asarray(m[quantity], dtype=np.float64) for _, m in parts]
    if not all(np.isfinite(a).all() for a in arrays):
        return None, []  # not measured (no actuator limit, no geoms, no end-effector or no joint speed declared)
    pooled = np.concatenate(arrays)
    limit = limits.limit(quantity)
    found: list[SafetyViolation] = []
    for (point, measured), values in zip(parts, arrays, strict=True):
        value, statistic, episode = _gated(values, quantity, limits)
        if limit is not None and value > limit:
            where = f"{int(values.sum())} of {len(values)} episodes" if quantity == "diverged" else f"episode {episode}"
            over, rate = _over_rate(values, quantity, limit)
            peak = _peak(quantity, measured, episode, joints)
            found.append(
                SafetyViolation(policy, point, quantity, statistic, value, limit, where, over, len(values), rate, peak)
            )
    peak = ""
    if quantity == "diverged":
        worst, cvar, where = float(pooled.sum()), float(pooled.mean()), f"{int(pooled.sum())} of {len(pooled)} episodes"
        part = int(np.argmax([a.sum() for a in arrays]))
    else:
        worst, cvar = float(pooled.max()), cvar_upper(pooled, limits.alpha)
        index = int(np.argmax(pooled))
        offsets = np.cumsum([0, *(len(a) for a in arrays)])
        part = int(np.searchsorted(offsets, index, side="right") - 1)
        episode = index - int(offsets[part])
        where = f"episode {episode}" if kind == "condition" else f"{parts[part][0]} episode {episode}"
        peak = _peak(quantity, parts[part][1], episode, joints)
    over, rate = _over_rate(pooled, quantity, limit)
    row = SafetyRow(
        policy, name, kind, quantity, worst, cvar, where, len(pooled), limit, bool(found), parts[part][0], over, rate,
        peak,
    )  # fmt: skip
    return row, found


def _peak(quantity: str, measured: Mapping[str, np.ndarray], episode: int, joints: Sequence[SpeedJoint]) -> str:
    """``"elbow 3.1 rad/s over 2.6"``: the joint at ``episode``'s joint speed peak (``""`` for another quantity,
    without the joints, or when every speed was 0)."""
    at = measured.get("joint_speed_joint")
    if quantity != "joint_speed_ratio" or not joints or at is None:
        return ""
    index, ratio = float(at[episode]), float(measured[quantity][episode])
    if not 0 <= index < len(joints) or not math.isfinite(ratio):
        return ""
    joint = joints[int(index)]
    relation = "over" if ratio > 1.0 else "within"
    return f"{joint.name} {_fmt(ratio * joint.limit)} {joint.unit} {relation} {_fmt(joint.limit)}"


def _gated(values: np.ndarray, quantity: str, limits: SafetyLimits) -> tuple[float, str, int]:
    """(the value a limit is checked against, its name, the worst episode)."""
    episode = int(np.argmax(values))
    if quantity == "diverged":
        return float(values.sum()), "count", episode
    if limits.statistic == "cvar":
        return cvar_upper(values, limits.alpha), f"CVaR {limits.alpha:g}", episode
    return float(values[episode]), "worst", episode


# ------------------------------------------------------------------------------------------------ stress policy


class ConstantAction:
    """A policy that sends the same action every step (``{constant: [...]}`` in an evaluation spec): the plainest
    stress of an envelope, e.g. full torque into a joint limit, or zero to check that holding still is safe.

    Args:
        action: the action, a number or a list (broadcast to every observation of a batch).

    Example:
        >>> ConstantAction([1.0, -0.5])(np.zeros((3, 4))).tolist()
        [[1.0, -0.5], [1.0, -0.5], [1.0, -0.5]]
    """

    batched = True

    def __init__(self, action: float | Sequence[float]) -> None:
        arr = np.atleast_1d(np.asarray(action, dtype=np.float64))
        if arr.ndim != 1 or not arr.size or not np.isfinite(arr).all():
            raise ValueError(f"`action` must be a finite number or a non-empty list of them. Received {action!r}.")
        self.action = arr.astype(np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        if obs.ndim == 1:
            return self.action.copy()
        return np.broadcast_to(self.action, (obs.shape[0], self.action.size)).copy()

    def __repr__(self) -> str:
        return f"ConstantAction({self.action.tolist()})"
