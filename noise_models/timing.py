"""Time: observation and action latency at physics rate, sample-and-hold, control-period jitter.

Time is counted in **physics steps** when the environment has MuJoCo inside (``sim2real`` finds it),
and in **control steps** otherwise; ``seconds=`` is converted with the physics timestep (or the
control period when there is no MuJoCo). Latency values are rounded to whole steps.

* Observations are measured at control-step boundaries and stamped with the physics step they
  were taken at; a sample stamped ``t`` with latency ``d`` (plus per-sample jitter) arrives at
  ``t + d``. The policy gets the newest sample that has arrived; a sample that arrives after a
  newer one (possible with jitter) is dropped, as a robot driver keeping the newest message would.
  The reset observation is delivered at once (there is nothing older).
* Actions: the command the environment writes to the actuators (MuJoCo ``ctrl``) at control step
  ``t`` is sent at the physics step the control step starts at and applied from physics step
  ``send + d`` on — mid control step when ``d`` is not a multiple of the substeps. Until the first
  command arrives the actuators keep the command they had at reset.

Example:
    >>> ObservationLatency(steps=3)
    ObservationLatency(steps=3.0)
    >>> ActionLatency(seconds=0.02)
    ActionLatency(seconds=0.02)
    >>> ObservationLatency(steps=3, seconds=0.01)
    Traceback (most recent call last):
    ...
    ValueError: ObservationLatency takes exactly one of `steps` and `seconds`. Received steps=3, seconds=0.01.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from noise_models.values import FrozenValue, check_value, draw, upper_bound, value_config

__all__ = [
    "TIME_UNITS",
    "ActionLatency",
    "CommandDelay",
    "ControlJitter",
    "ObservationDelay",
    "ObservationLatency",
    "SampleAndHold",
    "TimeModel",
    "convert_time",
    "elapsed_steps",
]

#: The units a span of time is given in at any boundary of the library.
TIME_UNITS = ("seconds", "control_steps", "physics_steps")


def convert_time(value: float, source: str, target: str, *, timestep: float, substeps: int = 1) -> float:
    """Converts a span of time between ``seconds``, ``control_steps`` and ``physics_steps``: the one place where
    a latency or a period changes unit (sysid results, exported effects, the recorder and the wrappers use it).

    Args:
        value: the span, in ``source`` units.
        source, target: units from :data:`TIME_UNITS`.
        timestep: seconds per physics step (``model.opt.timestep``).
        substeps: physics steps per control step.

    Example:
        >>> convert_time(2, "control_steps", "physics_steps", timestep=0.002, substeps=10)
        20.0
        >>> convert_time(2, "control_steps", "seconds", timestep=0.002, substeps=10)
        0.04
        >>> convert_time(0.04, "seconds", "physics_steps", timestep=0.002, substeps=10)
        20.0
        >>> convert_time(1, "steps", "seconds", timestep=0.002)
        Traceback (most recent call last):
        ...
        ValueError: `source` must be one of ['seconds', 'control_steps', 'physics_steps']. Received 'steps'.
    """
    for name, unit in (("source", source), ("target", target)):
        if unit not in TIME_UNITS:
            raise ValueError(f"`{name}` must be one of {list(TIME_UNITS)}. Received {unit!r}.")
    if not (isinstance(timestep, (int, float)) and math.isfinite(timestep) and timestep > 0):
        raise ValueError(f"`timestep` must be a finite number > 0 (seconds per physics step). Received {timestep!r}.")
    if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise ValueError(f"`substeps` must be an int >= 1. Received {substeps!r}.")
    if source == target:
        return float(value)
    physics = float(value) * {"seconds": 1.0 / timestep, "control_steps": float(substeps), "physics_steps": 1.0}[source]
    if target == "physics_steps":
        return physics
    if target == "control_steps":
        return physics / substeps
    return physics * timestep


def elapsed_steps(start: float, now: float, timestep: float) -> int:
    """Whole steps of ``timestep`` seconds between two clock readings: :func:`convert_time`'s seconds →
    steps conversion for the step loop (no argument checks; ``timestep`` was checked when the wrapper bound).

    Example:
        >>> elapsed_steps(0.5, 0.56, 0.002)
        30
    """
    return round((now - start) / timestep)


class TimeModel(FrozenValue):
    """Base of the timing models: immutable, compared by value."""

    stream: ClassVar[str] = ""

    def to_config(self) -> dict[str, Any]:
        """A YAML-ready mapping (``type`` plus fields)."""
        return {"type": type(self).__name__, **{k: value_config(v) for k, v in self._fields().items()}}


def _steps_or_seconds(owner: str, steps: Any, seconds: Any, what: str = "") -> tuple[Any, Any]:
    if (steps is None) == (seconds is None):
        raise ValueError(
            f"{owner} takes exactly one of `steps` and `seconds`{what}. Received steps={steps!r}, seconds={seconds!r}."
        )
    for name, value in (("steps", steps), ("seconds", seconds)):
        if value is not None and math.isinf(upper_bound(check_value(value, name, low=0.0))):
            raise ValueError(
                f"`{name}` must have a bounded support so the buffer size is known (use Uniform, TruncatedNormal, "
                f"Choice...). Received {value!r}."
            )
    return (
        None if steps is None else check_value(steps, "steps", low=0.0),
        None if seconds is None else check_value(seconds, "seconds", low=0.0),
    )


class _Latency(TimeModel):
    def __init__(self, steps: Any = None, *, seconds: Any = None, jitter: Any = None, max_steps: int = 1000) -> None:
        self.steps, self.seconds = _steps_or_seconds(type(self).__name__, steps, seconds)
        self.jitter = check_value(jitter, "jitter", low=0.0, allow_none=True)
        if self.jitter is not None and math.isinf(upper_bound(self.jitter)):
            raise ValueError(f"`jitter` must have a bounded support. Received {jitter!r}.")
        if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1:
            raise ValueError(f"`max_steps` must be an int >= 1. Received {max_steps!r}.")
        self.max_steps = max_steps
        if self.steps is not None:
            self.check_capacity(1.0)
        self._freeze()

    def _fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {"steps": self.steps} if self.steps is not None else {"seconds": self.seconds}
        if self.jitter is not None:
            out["jitter"] = self.jitter
        if self.max_steps != 1000:
            out["max_steps"] = self.max_steps
        return out

    def step_scale(self, timestep: float | None) -> float:
        """Steps per unit of the given values (1 for ``steps``, 1/timestep for ``seconds``)."""
        if self.steps is not None:
            return 1.0
        if timestep is None:
            raise ValueError(
                f"{type(self).__name__}(seconds=...) needs the environment's timestep to count steps, and this "
                "environment exposes none (no MuJoCo model, no `dt`/`control_timestep`); give `steps=` instead."
            )
        return convert_time(1.0, "seconds", "physics_steps", timestep=timestep)

    def check_capacity(self, scale: float) -> int:
        """The longest delay in steps; raises when it exceeds ``max_steps``."""
        value = self.steps if self.steps is not None else self.seconds
        longest = upper_bound(value) * scale + (0.0 if self.jitter is None else upper_bound(self.jitter) * scale)
        longest_steps = math.floor(longest + 0.5)
        if longest_steps > self.max_steps:
            unit = "steps" if self.steps is not None else "seconds"
            raise ValueError(
                f"`{unit}` (plus `jitter`) of {type(self).__name__} can reach {longest_steps} steps, more than the "
                f"buffer holds (`max_steps`={self.max_steps}). Raise `max_steps` or shorten the latency. "
                f"Received {unit}={value!r}, jitter={self.jitter!r}."
            )
        return longest_steps

    def draw_steps(self, rng: np.random.Generator, scale: float) -> int:
        value = self.steps if self.steps is not None else self.seconds
        return math.floor(float(draw(value, rng, 1)[0]) * scale + 0.5)

    def jitter_block(self, rng: np.random.Generator, n: int, scale: float) -> np.ndarray | None:
        if self.jitter is None:
            return None
        return np.floor(draw(self.jitter, rng, n) * scale + 0.5).astype(np.int64)


class ObservationLatency(_Latency):
    """Delays observations by ``steps`` physics steps (or ``seconds``), fixed or drawn per episode.

    Args:
        steps: latency in physics steps (control steps without MuJoCo); number or distribution.
        seconds: latency in seconds instead.
        jitter: extra delay per sample, >= 0, in the same unit (a distribution drawn every step).
        max_steps: the longest delay the buffer accepts (steps); longer latencies are rejected.

    Reported as ``obs_latency_steps`` and (with a timestep) ``obs_latency`` in seconds.

    Example:
        >>> from randomizers import Uniform
        >>> ObservationLatency(steps=Uniform(1, 5), jitter=Uniform(0, 2))
        ObservationLatency(steps=Uniform(low=1.0, high=5.0), jitter=Uniform(low=0.0, high=2.0))
    """

    stream = "obs_latency"


class ActionLatency(_Latency):
    """Delays actuator commands by ``steps`` physics steps (or ``seconds``), fixed or drawn per episode.

    Applied at physics rate: a command can take effect mid control step. Without MuJoCo the whole
    action is delayed by control steps.

    Args:
        steps: latency in physics steps (control steps without MuJoCo); number or distribution.
        seconds: latency in seconds instead.
        jitter: extra delay per command, >= 0, in the same unit.
        max_steps: the longest delay the buffer accepts (steps).

    Reported as ``action_latency_steps`` and (with a timestep) ``action_latency`` in seconds.

    Example:
        >>> ActionLatency(steps=-1)
        Traceback (most recent call last):
        ...
        ValueError: `steps` must be >= 0. Received -1.0.
    """

    stream = "action_latency"


class SampleAndHold(TimeModel):
    """A sensor that updates every ``steps`` physics steps (or ``seconds``) with a ``phase``; between
    updates the last value is held. Updates are taken at the control-step boundary that follows
    the update time.

    Args:
        steps: update period in physics steps (control steps without MuJoCo), > 0.
        seconds: update period in seconds instead.
        phase: time of the first update after reset, in the same unit (>= 0).
        select: observation elements the sensor covers (default all).

    Example:
        >>> SampleAndHold(seconds=0.05)
        SampleAndHold(seconds=0.05, phase=0.0)
    """

    stream = "sample_and_hold"

    def __init__(self, steps: Any = None, *, seconds: Any = None, phase: Any = 0.0, select: Any = None) -> None:
        from noise_models.values import check_selection

        self.steps, self.seconds = _steps_or_seconds("SampleAndHold", steps, seconds)
        for name, value in (("steps", self.steps), ("seconds", self.seconds)):
            if value is not None:
                check_value(value, name, low=0.0, low_open=True)
        self.phase = check_value(phase, "phase", low=0.0)
        self.select = check_selection(select)
        self._freeze()

    def _fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {"steps": self.steps} if self.steps is not None else {"seconds": self.seconds}
        out["phase"] = self.phase
        if self.select is not None:
            out["select"] = self.select
        return out

    def step_scale(self, timestep: float | None) -> float:
        return _Latency.step_scale(self, timestep)  # type: ignore[arg-type]


class ControlJitter(TimeModel):
    """The number of physics substeps per control step varies: ``nominal + round(delta)`` (at least 1),
    ``delta`` drawn every control step. Needs MuJoCo.

    Example:
        >>> from randomizers import Choice
        >>> ControlJitter(delta=Choice((-1, 0, 1)))
        ControlJitter(delta=Choice(values=(-1.0, 0.0, 1.0), p=None))
    """

    stream = "control_jitter"

    def __init__(self, delta: Any) -> None:
        self.delta = check_value(delta, "delta")
        self._freeze()

    def _fields(self) -> dict[str, Any]:
        return {"delta": self.delta}

    def block(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return np.rint(draw(self.delta, rng, n)).astype(np.int64)


# -- runtime buffers -----------------------------------------------------------------------------


class ObservationDelay:
    """Arrival-ordered delay line for observation samples (a preallocated ring of references).

    Example:
        >>> d = ObservationDelay(capacity=4)
        >>> d.reset("s0", 0)
        >>> d.push("s1", arrival=1 + 2)
        >>> d.push("s2", arrival=2 + 2)
        >>> d.read(2), d.read(3), d.read(4)
        ('s0', 's1', 's2')
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._values: list[Any] = [None] * capacity
        self._arrivals: list[int] = [0] * capacity
        self._count = 0
        self._delivered = 0

    def reset(self, sample: Any, now: int) -> None:
        self._values[0] = sample
        self._arrivals[0] = now
        self._count = 1
        self._delivered = 0

    def push(self, sample: Any, arrival: int) -> None:
        n = self._count
        if n - self._delivered >= self.capacity:
            raise RuntimeError(
                f"observation latency buffer overflow: {n - self._delivered} samples in flight, capacity "
                f"{self.capacity}; raise `max_steps` of ObservationLatency."
            )
        slot = n % self.capacity
        self._values[slot] = sample
        self._arrivals[slot] = arrival
        self._count = n + 1

    def read(self, now: int) -> Any:
        """The newest sample that has arrived by ``now`` (never older than the last one read)."""
        cap = self.capacity
        arrivals = self._arrivals
        j = self._count - 1
        delivered = self._delivered
        while j > delivered:
            if arrivals[j % cap] <= now:
                self._delivered = delivered = j
                break
            j -= 1
        return self._values[delivered % cap]


class CommandDelay:
    """Arrival-ordered command buffer at physics rate (a preallocated ring of command arrays).

    At physics step ``s`` the applied command is the newest-sent command that has arrived by ``s``.

    Example:
        >>> import numpy as np
        >>> d = CommandDelay(capacity=8, size=1)
        >>> d.reset(np.zeros(1))
        >>> d.push(np.ones(1), arrival=3)           # sent at 0, 3 steps late
        >>> [(float(c[0]), n) for c, n in d.segments(0, 5)]
        [(0.0, 3), (1.0, 2)]
    """

    def __init__(self, capacity: int, size: int) -> None:
        self.capacity = capacity
        self._values = np.zeros((capacity, size))
        self._arrivals = [0] * capacity
        self._count = 0
        self._current = 0

    def reset(self, initial: np.ndarray) -> None:
        self._values[0] = initial
        self._arrivals[0] = -1
        self._count = 1
        self._current = 0

    def push(self, command: np.ndarray, arrival: int) -> None:
        n = self._count
        if n - self._current >= self.capacity:
            raise RuntimeError(
                f"action latency buffer overflow: {n - self._current} commands in flight, capacity "
                f"{self.capacity}; raise `max_steps` of ActionLatency."
            )
        slot = n % self.capacity
        self._values[slot] = command
        self._arrivals[slot] = arrival
        self._count = n + 1

    def segments(self, start: int, n: int) -> list[tuple[np.ndarray, int]]:
        """``(command, steps)`` pieces covering physics steps ``start .. start + n - 1``."""
        cap = self.capacity
        arrivals = self._arrivals
        values = self._values
        end = start + n
        current = self._current
        pos = start
        out: list[tuple[np.ndarray, int]] = []
        count = self._count
        if count == current + 1 or (count == current + 2 and arrivals[(current + 1) % cap] <= start):
            # The common case (fixed latency): at most one new command, arriving by ``start``.
            if count == current + 2:
                current += 1
                self._current = current
            return [(values[current % cap], n)]
        due = [(arrivals[j % cap], j) for j in range(current + 1, count) if arrivals[j % cap] < end]
        if len(due) > 1:
            due.sort()  # only with jitter can arrivals leave send order
        # In arrival order, a newer command replaces the current one from its arrival on; one that
        # arrives after a newer command was applied is never used.
        for arrival, j in due:
            if j <= current:
                continue
            if arrival > pos:
                out.append((values[current % cap], arrival - pos))
                pos = arrival
            current = j
        if pos < end:
            out.append((values[current % cap], end - pos))
        self._current = current
        return out


def sample_and_hold_updates(prev: int, now: int, period: float, phase: float) -> bool:
    """Whether an update time ``phase + m * period`` falls in ``(prev, now]`` (or ``now`` is the reset).

    Example:
        >>> [sample_and_hold_updates(t - 1, t, 3.0, 0.0) for t in range(1, 7)]
        [False, False, True, False, False, True]
    """
    if now < phase:
        return False
    return math.floor((now - phase) / period) > math.floor((prev - phase) / period) or prev < phase <= now
