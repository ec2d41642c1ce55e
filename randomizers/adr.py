"""Automatic domain randomisation (ADR): ranges that widen while the policy copes and narrow when it does not.

The algorithm is the one of OpenAI et al. 2019 (*Solving Rubik's Cube with a Robot Hand*, section 5): every
randomised dimension ``i`` keeps a range ``[low_i, high_i]`` that starts at a nominal point. With probability
``p_boundary`` an episode *pins* one dimension (chosen uniformly) at one of its two boundaries (chosen uniformly)
while every other dimension is drawn from its current range. The episode's metric goes into that boundary's
buffer; when the buffer holds ``m`` results their mean is taken and the buffer cleared: a mean ``>= t_high``
moves the boundary outwards by ``delta`` (never past the dimension's hard limit), a mean ``<= t_low`` moves it
inwards (never past the initial range, so the nominal start is always drawn from). Results of unpinned episodes only count frames.

Here a *dimension* is one effect: its distribution (``Uniform`` or ``LogUniform``) gives the hard limits and the
range replaces its bounds in every episode (a non-shared effect draws each target from the same range; a pinned
one writes the boundary into every target). ``LogUniform`` dimensions move in log space (``delta`` is then a
step of the natural log, i.e. a factor ``exp(delta)``). A :class:`~randomizers.Correlated` effect (a fit's
posterior) is one dimension too: the scale ``s`` of its standard deviations, range ``[0, s]`` from 0 (the mean
alone) up to the hard limit 1 (its own covariance); only ``s`` moves, an unpinned episode draws from
``N(mean, s^2 cov)`` in its box and a pinned one at ``s`` standard deviations in a random direction.

:class:`ADR` is the controller (ranges, buffers, history). It holds no generator: the boundary choice of an
episode is drawn by the environment side (:class:`randomizers.adr_randomizer.ADRRandomizer`) from its own keyed
stream, so one controller can serve many environments, each with its own pins.

Example:
    >>> from randomizers import Damping, Mass, Uniform
    >>> adr = ADR([Damping(scale=Uniform(0.0, 4.0)), Mass(scale=Uniform(0.5, 2.0))],
    ...           delta=0.25, m=2, t_low=0.2, t_high=0.8)
    >>> adr.ranges["Damping[joints=*]"], adr.entropy()
    ((1.0, 1.0), -inf)
    >>> pin = Pin("Damping[joints=*]", "high", 1.0)
    >>> adr.record(pin, metric=1.0, frames=100), adr.record(pin, metric=0.9, frames=100)
    (False, True)
    >>> adr.ranges["Damping[joints=*]"], adr.frames
    ((1.0, 1.25), 200)
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from randomizers.config import effect_to_config, load_effects
from randomizers.correlated import Correlated
from randomizers.distributions import Distribution, LogUniform, MultivariateNormal, Uniform
from randomizers.effects import ArrayEffect, Effect

__all__ = ["ADR", "METRICS", "ADRHistory", "Episode", "EpisodeResult", "Pin"]

Side = Literal["low", "high"]
_SIDES: tuple[Side, Side] = ("low", "high")
#: Named metrics: ``"auto"`` is success when the episode reports one (1.0/0.0), else its return.
METRICS = ("auto", "return", "success")
_STATE_VERSION = 1


@dataclass(frozen=True)
class Pin:
    """An episode's pinned boundary: dimension ``key`` held at ``value``, its ``side`` ("low" or "high")."""

    key: str
    side: Side
    value: float


@dataclass(frozen=True)
class Episode:
    """What a metric sees of one finished episode.

    Attributes:
        episode_return: the sum of rewards.
        length: control steps taken.
        success: the task's success flag at the last step (``info["success"]`` / ``info["is_success"]``),
            None when the task does not define one.
    """

    episode_return: float
    length: int
    success: bool | None = None


@dataclass(frozen=True)
class EpisodeResult:
    """One finished episode as the controller records it: its pin (or None), metric and frames.

    A worker's copy of the controller (:meth:`ADR.worker_copy`) collects these instead of applying them; the
    driver hands them back with :meth:`ADR.apply_results`.
    """

    pin: Pin | None
    metric: float
    frames: int


@dataclass(frozen=True)
class ADRHistory:
    """The ranges after every change, for plots: row ``j`` holds the state once ``frames[j]`` frames were recorded.

    Attributes:
        keys: the dimensions (effect keys), D of them.
        frames: (N,) frames counted when each row was taken: the steps of the episodes reported so far (an episode
            counts when it ends; the first row is the start, 0 or the count it resumed from).
        low: (N, D) lower boundaries.
        high: (N, D) upper boundaries.
        entropy: (N,) :meth:`ADR.entropy` of each row (nats per dimension).
    """

    keys: tuple[str, ...]
    frames: tuple[int, ...]
    low: tuple[tuple[float, ...], ...]
    high: tuple[tuple[float, ...], ...]
    entropy: tuple[float, ...]


def _real(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"`{name}` of ADR must be a real number. Received {value!r}.")
    out = float(value)
    if not math.isfinite(out):
        raise ValueError(f"`{name}` of ADR must be finite. Received {value!r}.")
    return out


def _yaml_number(value: object) -> object:
    # PyYAML (YAML 1.1) reads ``1e-3`` without a dot as a string.
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _entropy(log: bool, low: float, high: float) -> float:
    # Differential entropy of the range's own distribution: log(width) for Uniform (the paper's measure);
    # for LogUniform, log(log(high/low)) + (log low + log high) / 2. A point range has -inf.
    if high <= low:
        return -math.inf
    if not log:
        return math.log(high - low)
    return math.log(math.log(high / low)) + 0.5 * (math.log(low) + math.log(high))


class ADR:
    """Automatic domain randomisation over ``effects``: one range per effect, moved by episode results.

    Args:
        effects: the effects ADR drives, each drawing from ``Uniform`` or ``LogUniform``; their bounds are the hard
            limits (e.g. ``Mass(scale=Uniform(0.5, 2.0))`` never leaves [0.5, 2.0] times the nominal mass).
        delta: step of a boundary move (per dimension: a mapping effect key -> step); in log units for LogUniform.
        t_low: a boundary whose buffer mean is ``<= t_low`` narrows.
        t_high: a boundary whose buffer mean is ``>= t_high`` widens; must be > ``t_low``.
        p_boundary: probability that an episode pins a boundary, in [0, 1] (paper: 0.5).
        m: results per boundary buffer before it is evaluated (and cleared).
        metric: ``"auto"`` (success when the task reports one, else return), ``"return"``, ``"success"``, or a
            callable ``Episode -> float``.
        initial: start of each range, per effect key: a point or ``(low, high)``. Default: the nominal point
            (``scale`` 1.0, ``add`` 0.0); a ``set`` effect needs one.

    Raises:
        TypeError: an effect that is not a physics effect, a metric of the wrong kind.
        ValueError: a distribution ADR cannot move, a bad threshold, probability, buffer size, step or start.

    Example:
        >>> from randomizers import Damping, Gravity, Normal
        >>> ADR([Damping(scale=Uniform(0.5, 2.0))], delta=0.1, t_low=0.8, t_high=0.5)
        Traceback (most recent call last):
        ...
        ValueError: `t_low` of ADR must be < `t_high`. Received t_low=0.8, t_high=0.5.
        >>> ADR([Gravity(add=Normal(0.0, 0.1))], delta=0.1, t_low=0.2, t_high=0.8)
        Traceback (most recent call last):
        ...
        ValueError: `effects[0]` of ADR must draw from Uniform or LogUniform (ADR moves their bounds), or be a \
Correlated effect (ADR scales its covariance). Received Gravity(add=Normal(mean=0.0, std=0.1), axes='xyz').
    """

    def __init__(
        self,
        effects: Sequence[Effect],
        *,
        delta: float | Mapping[str, float],
        t_low: float,
        t_high: float,
        p_boundary: float = 0.5,
        m: int = 10,
        metric: str | Callable[[Episode], float] = "auto",
        initial: Mapping[str, float | Sequence[float]] | None = None,
    ) -> None:
        if isinstance(effects, Effect) or not isinstance(effects, Sequence) or not effects:
            raise TypeError(f"`effects` of ADR must be a non-empty list of effects. Received {effects!r}.")
        keys: list[str] = []
        for i, effect in enumerate(effects):
            if not isinstance(effect, Effect):
                raise TypeError(f"`effects[{i}]` of ADR must be a physics effect. Received {effect!r}.")
            dist = getattr(effect, "distribution", None)
            # One distribution over one model array (whose bounds a range replaces), or a joint Gaussian (whose
            # spread a range scales).
            if not isinstance(effect, Correlated) and (
                type(dist) not in (Uniform, LogUniform) or not isinstance(effect, ArrayEffect)
            ):
                raise ValueError(
                    f"`effects[{i}]` of ADR must draw from Uniform or LogUniform (ADR moves their bounds), or be a "
                    f"Correlated effect (ADR scales its covariance). Received {effect!r}."
                )
            if effect.schedule == "startup":
                raise ValueError(
                    f"`effects[{i}]` of ADR must be drawn every episode (schedule 'reset' or an Interval): its range "
                    f"moves between episodes. Received schedule='startup' in {effect!r}."
                )
            if effect.key in keys:
                raise ValueError(
                    f"`effects[{i}]` and `effects[{keys.index(effect.key)}]` of ADR share the key {effect.key!r}; "
                    "pass a distinct `name=` to one of them."
                )
            keys.append(effect.key)
        t_low, t_high = _real("t_low", t_low), _real("t_high", t_high)
        if t_low >= t_high:
            raise ValueError(f"`t_low` of ADR must be < `t_high`. Received t_low={t_low!r}, t_high={t_high!r}.")
        p = _real("p_boundary", p_boundary)
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"`p_boundary` of ADR must be in [0, 1]. Received {p_boundary!r}.")
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1:
            raise ValueError(f"`m` of ADR must be an int >= 1. Received {m!r}.")
        if not (metric in METRICS or callable(metric)):
            raise TypeError(f"`metric` of ADR must be one of {list(METRICS)} or a callable. Received {metric!r}.")
        self.effects: tuple[Effect, ...] = tuple(effects)
        self.keys: tuple[str, ...] = tuple(keys)
        self.t_low, self.t_high, self.p_boundary, self.m = t_low, t_high, p, int(m)
        self.metric = metric
        self._cov = np.array([isinstance(e, Correlated) for e in effects])
        self._log = np.array([type(getattr(e, "distribution", None)) is LogUniform for e in effects])
        # A Correlated dimension is the scale s of its standard deviations: range [0, s], hard limit s = 1.
        limits = [(0.0, 1.0) if c else e.distribution.support for c, e in zip(self._cov, effects, strict=True)]  # type: ignore[attr-defined]
        self.limit_low = np.array([lo for lo, _ in limits], dtype=np.float64)
        self.limit_high = np.array([hi for _, hi in limits], dtype=np.float64)
        self.delta = self._deltas(delta)
        self._initial = self._starts(initial)
        self.low = np.array([lo for lo, _ in self._initial])
        self.high = np.array([hi for _, hi in self._initial])
        self.buffers: dict[tuple[str, Side], list[float]] = {(k, s): [] for k in keys for s in _SIDES}
        self.frames = 0
        self.stale = 0
        self._history: list[tuple[int, tuple[float, ...], tuple[float, ...], float]] = []
        self._dists: list[Distribution] = []
        #: None on a controller; the results collected so far on a worker copy (:meth:`worker_copy`).
        self.collected: list[EpisodeResult] | None = None
        self._changed()

    # -- arguments -------------------------------------------------------------------------------
    def _deltas(self, delta: float | Mapping[str, float]) -> np.ndarray:
        if isinstance(delta, Mapping):
            unknown = sorted(set(delta) - set(self.keys))
            missing = [k for k in self.keys if k not in delta]
            if unknown or missing:
                raise ValueError(
                    f"`delta` of ADR must give one step per effect key {list(self.keys)}. "
                    f"Received unknown {unknown}, missing {missing}."
                )
            values = [_real(f"delta[{k!r}]", delta[k]) for k in self.keys]
        else:
            values = [_real("delta", delta)] * len(self.keys)
        for k, v in zip(self.keys, values, strict=True):
            if v <= 0:
                raise ValueError(f"`delta` of ADR must be > 0 (for {k!r}). Received {v!r}.")
        return np.array(values)

    def _starts(self, initial: Mapping[str, float | Sequence[float]] | None) -> list[tuple[float, float]]:
        initial = {} if initial is None else initial
        if not isinstance(initial, Mapping):
            raise TypeError(
                f"`initial` of ADR must be a mapping effect key -> point or (low, high). Received {initial!r}."
            )
        unknown = sorted(set(initial) - set(self.keys))
        if unknown:
            raise ValueError(f"`initial` of ADR names no ADR effect: {unknown}. Allowed keys: {list(self.keys)}.")
        out = []
        for i, (key, effect) in enumerate(zip(self.keys, self.effects, strict=True)):
            lim = (float(self.limit_low[i]), float(self.limit_high[i]))
            if key in initial:
                raw = initial[key]
                if isinstance(raw, Sequence) and not isinstance(raw, str):
                    if len(raw) != 2:
                        raise ValueError(
                            f"`initial[{key!r}]` of ADR must be a point or a range (low, high). Received {raw!r}."
                        )
                    lo, hi = _real(f"initial[{key!r}]", raw[0]), _real(f"initial[{key!r}]", raw[1])
                else:
                    lo = hi = _real(f"initial[{key!r}]", raw)
                if self._cov[i]:  # a scale s (or a pair) means the range [0, s]: its lower end never moves
                    lo = 0.0
            elif self._cov[i]:
                lo = hi = 0.0  # the fitted mean alone
            else:
                op = effect.operation  # type: ignore[attr-defined]
                if op == "set":
                    raise ValueError(
                        f"`initial` of ADR must give a start for {key!r}: a `set` effect has no nominal point "
                        "without the model. Received none."
                    )
                lo = hi = 1.0 if op == "scale" else 0.0
                if not lim[0] <= lo <= lim[1]:  # the user gave no start: say which default is outside
                    raise ValueError(
                        f"`initial` of ADR must give a start for {key!r} inside the effect's limits [{lim[0]}, "
                        f"{lim[1]}]: the default start, the nominal point ({op} {lo}), is outside them. Received none."
                    )
            if not lim[0] <= lo <= hi <= lim[1]:
                raise ValueError(
                    f"`initial[{key!r}]` of ADR must be a point or a range (low, high) with low <= high inside the "
                    f"effect's limits [{lim[0]}, {lim[1]}]. Received {initial.get(key, (lo, hi))!r}."
                )
            out.append((lo, hi))
        return out

    # -- the controller --------------------------------------------------------------------------
    @property
    def ranges(self) -> dict[str, tuple[float, float]]:
        """Effect key -> current ``(low, high)``."""
        return {k: (float(lo), float(hi)) for k, lo, hi in zip(self.keys, self.low, self.high, strict=True)}

    def entropy(self) -> float:
        """The paper's measure: the mean over dimensions of the differential entropy (nats) of each range.

        ``log(high - low)`` for a Uniform dimension; for a LogUniform one, the entropy of the log-uniform value; for a
        Correlated one, the entropy per component of its untruncated Gaussian. A dimension still at a point gives
        ``-inf`` (the start of every run that begins at the nominal point), and so does the mean.
        """
        return float(np.mean([self._entropy(i) for i in range(len(self.keys))]))

    def _entropy(self, i: int) -> float:
        lo, hi = float(self.low[i]), float(self.high[i])
        if not self._cov[i]:
            return _entropy(bool(self._log[i]), lo, hi)
        # Correlated: the untruncated Gaussian N(mean, s^2 cov) per component, 0.5 log(2 pi e) + log s + log det / 2P.
        cov = np.array(self.effects[i].distribution.cov)  # type: ignore[attr-defined]
        sign, logdet = np.linalg.slogdet(cov)
        if hi <= 0 or sign <= 0:
            return -math.inf
        return 0.5 * math.log(2 * math.pi * math.e) + math.log(hi) + 0.5 * float(logdet) / len(cov)

    def distribution(self, index: int) -> Distribution:
        """The distribution dimension ``index`` draws from in an unpinned episode (its current range; for a
        Correlated effect its Gaussian with the standard deviations scaled by the upper boundary)."""
        return self._dists[index]

    def effects_at_ranges(self) -> tuple[Effect, ...]:
        """The ADR effects drawing from their current ranges (what an unpinned episode draws from), as ordinary
        effects with the same keys: e.g. the final training distribution of a run, for an evaluation condition.

        Example:
            >>> from randomizers import Damping, dump_config
            >>> adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, m=1, t_low=0.2, t_high=0.8)
            >>> _ = adr.record(Pin("Damping[joints=*]", "high", 1.0), 1.0)
            >>> adr.effects_at_ranges()
            (Damping(scale=Uniform(low=1.0, high=1.5), joints='*'),)
        """
        out = []
        for i, effect in enumerate(self.effects):
            fields = effect._fields()
            fields["distribution" if self._cov[i] else effect.operation] = self._dists[i]  # type: ignore[attr-defined]
            out.append(type(effect)(**fields))
        return tuple(out)

    def parameter_ranges(self, model: Any) -> dict[str, tuple[float, float]]:
        """The current ranges in ``model``'s own units: parameter address -> ``(low, high)`` of the values an episode
        can write there (e.g. ``dof_damping[elbow]`` in N·m·s/rad, ``body_mass[hand]`` in kg), where :attr:`ranges`
        holds each effect's factor (``scale``) or offset (``add``). Addresses are those of the episode reports
        (``info["sim2real"]["params"]``). A Correlated dimension is left out: its range is a spread, not bounds.

        Args:
            model: the ``mujoco.MjModel`` the effects are applied to (read only; its nominal values).

        Raises:
            ValueError: an effect that selects nothing in ``model`` (the effect's own message).

        Example:
            >>> import mujoco
            >>> from randomizers import Damping
            >>> model = mujoco.MjModel.from_xml_string(
            ...     '<mujoco><worldbody><body><joint name="elbow" damping="1.5"/><geom size=".1"/></body>'
            ...     '</worldbody></mujoco>')
            >>> adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, m=1, t_low=0.2, t_high=0.8)
            >>> _ = adr.record(Pin("Damping[joints=*]", "high", 1.0), 1.0)
            >>> adr.ranges["Damping[joints=*]"], adr.parameter_ranges(model)
            ((1.0, 1.5), {'dof_damping[elbow]': (1.5, 2.25)})
        """
        import mujoco

        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"`model` of ADR.parameter_ranges must be a mujoco.MjModel. Received {model!r}.")
        out: dict[str, tuple[float, float]] = {}
        for i, effect in enumerate(self.effects):
            if self._cov[i]:
                continue
            binding = effect.bind(model)  # resolves and snapshots the targets; writes nothing
            ends = [binding.values(np.full(binding.size, bound[i])) for bound in (self.low, self.high)]
            for address, a, b in zip(binding.addresses, ends[0].tolist(), ends[1].tolist(), strict=True):
                out[str(address)] = (min(a, b), max(a, b))  # a scale of a negative nominal swaps the ends
        return out

    def pinned(self, index: int, value: float, rng: np.random.Generator, count: int) -> np.ndarray:
        """The draws of a pinned episode: ``value`` for every target; for a Correlated effect, one point at ``value``
        standard deviations on a random direction (``mean + value * A u``, ``A A^T = cov``, ``u`` uniform on the unit
        sphere, drawn from ``rng``), clipped to its box."""
        if not self._cov[index]:
            return np.full(count, value)
        dist: MultivariateNormal = self.effects[index].distribution  # type: ignore[attr-defined]
        vals, vecs = np.linalg.eigh(np.array(dist.cov))
        u = rng.standard_normal(dist.size)
        u /= np.linalg.norm(u) or 1.0
        point = np.array(dist.mean) + value * (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ u
        lo, hi = dist._box()
        return np.clip(point, lo, hi).reshape(1, dist.size)

    def choose(self, rng: np.random.Generator) -> Pin | None:
        """This episode's pin, from the episode's boundary stream ``rng`` (three draws, always)."""
        u, i, s = rng.random(), int(rng.integers(len(self.keys))), int(rng.integers(2))
        if u >= self.p_boundary:
            return None
        side = "high" if self._cov[i] else _SIDES[s]  # a Correlated range is [0, s]: only s moves
        return Pin(self.keys[i], side, float(self.low[i] if side == "low" else self.high[i]))

    def score(self, episode: Episode) -> float:
        """The metric of one episode (see ``metric``)."""
        if callable(self.metric):
            return float(self.metric(episode))
        if self.metric == "return" or (self.metric == "auto" and episode.success is None):
            return float(episode.episode_return)
        if episode.success is None:
            raise ValueError("`metric` of ADR is 'success' but the episode reports no success flag. Received None.")
        return float(episode.success)

    def record(self, pin: Pin | None, metric: float, frames: int = 0) -> bool:
        """Adds one finished episode: its ``frames`` always count; a pinned one's metric goes to its boundary buffer.

        A result whose pinned value is no longer that boundary (the boundary moved while the episode ran, on
        another environment's results) measured a different value and is dropped (counted in ``stale``).

        On a worker copy (:meth:`worker_copy`) the result is only collected, and nothing moves.

        Returns:
            Whether a boundary moved.
        """
        if self.collected is not None:
            self.collected.append(EpisodeResult(pin, float(metric), int(frames)))
            return False
        self.frames += int(frames)
        if pin is None:
            return False
        if pin.key not in self.keys or pin.side not in _SIDES:
            raise ValueError(f"`pin` of ADR.record must name one of {list(self.keys)} low/high. Received {pin!r}.")
        i = self.keys.index(pin.key)
        bound = self.low if pin.side == "low" else self.high
        if float(bound[i]) != pin.value:
            self.stale += 1
            return False
        buffer = self.buffers[(pin.key, pin.side)]
        buffer.append(float(metric))
        if len(buffer) < self.m:
            return False
        mean = float(np.mean(buffer))
        buffer.clear()
        if mean >= self.t_high:
            outward = True
        elif mean <= self.t_low:
            outward = False
        else:
            return False
        old = float(bound[i])
        bound[i] = self._moved(i, pin.side, outward)
        if float(bound[i]) == old:
            return False
        self._changed()
        return True

    def apply_results(self, results: Sequence[EpisodeResult]) -> int:
        """Records ``results`` in the order given (the order that makes a distributed run deterministic) and
        returns how many boundary moves they caused.

        Example:
            >>> from randomizers import Damping
            >>> adr = ADR([Damping(scale=Uniform(0.0, 2.0))], delta=0.5, m=1, t_low=0.2, t_high=0.8)
            >>> worker = adr.worker_copy()
            >>> worker.record(Pin("Damping[joints=*]", "high", 1.0), 1.0, frames=30)
            False
            >>> adr.apply_results(worker.collected), adr.ranges["Damping[joints=*]"], adr.frames
            (1, (1.0, 1.5), 30)
        """
        return sum(self.record(r.pin, r.metric, r.frames) for r in results)

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Episodes recorded inside the block move nothing and count no frames: they are not the policy's results
        (e.g. a training run's random-action warm-up that fits an observation normaliser, or a scripted teacher's
        demonstrations). Their episodes still draw pins, so every later draw is what it was.

        Example:
            >>> from randomizers import Damping
            >>> adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, m=1, t_low=0.2, t_high=0.8)
            >>> with adr.paused():
            ...     adr.record(Pin("Damping[joints=*]", "high", 1.0), 1.0, frames=200)
            False
            >>> adr.ranges["Damping[joints=*]"], adr.frames
            ((1.0, 1.0), 0)
        """
        saved = self.collected
        self.collected = []  # what a worker copy does with its results; discarded here
        try:
            yield
        finally:
            self.collected = saved

    def worker_copy(self) -> ADR:
        """A copy with the same ranges that collects results (``collected``) instead of applying them: what a
        worker of a distributed round runs with while the controller stays with the driver."""
        copy = ADR.from_state(self.state(), self.metric)
        copy.collected = []
        return copy

    def _moved(self, i: int, side: Side, outward: bool) -> float:
        step = float(self.delta[i]) * (1.0 if (side == "high") == outward else -1.0)
        value = float(self.low[i] if side == "low" else self.high[i])
        moved = math.exp(math.log(value) + step) if self._log[i] else value + step
        # Narrowing stops at the initial range, so the nominal start stays in every range.
        if side == "low":
            return max(float(self.limit_low[i]), moved) if outward else min(self._initial[i][0], moved)
        return min(float(self.limit_high[i]), moved) if outward else max(self._initial[i][1], moved)

    def _changed(self) -> None:
        self._dists = [self._range_distribution(i) for i in range(len(self.keys))]
        self._history.append((self.frames, tuple(self.low.tolist()), tuple(self.high.tolist()), self.entropy()))

    def _range_distribution(self, i: int) -> Distribution:
        lo, hi = float(self.low[i]), float(self.high[i])
        if self._cov[i]:
            d: MultivariateNormal = self.effects[i].distribution  # type: ignore[attr-defined]
            return MultivariateNormal(d.mean, tuple(tuple(hi * hi * c for c in row) for row in d.cov), d.low, d.high)
        return (LogUniform if self._log[i] else Uniform)(lo, hi)

    @property
    def history(self) -> ADRHistory:
        """The ranges and entropy after every change (and at the start), with the frame count of each."""
        rows = self._history
        return ADRHistory(
            keys=self.keys,
            frames=tuple(r[0] for r in rows),
            low=tuple(r[1] for r in rows),
            high=tuple(r[2] for r in rows),
            entropy=tuple(r[3] for r in rows),
        )

    # -- explicit state --------------------------------------------------------------------------
    def config(self) -> dict[str, Any]:
        """The construction arguments as plain data (a callable metric is not data: it is stored as None)."""
        return {
            "effects": [effect_to_config(e) for e in self.effects],
            "delta": dict(zip(self.keys, self.delta.tolist(), strict=True)),
            "t_low": self.t_low,
            "t_high": self.t_high,
            "p_boundary": self.p_boundary,
            "m": self.m,
            "metric": self.metric if isinstance(self.metric, str) else None,
            "initial": {k: list(v) for k, v in zip(self.keys, self._initial, strict=True)},
        }

    @classmethod
    def from_config(cls, config: Mapping[str, Any], metric: str | Callable[[Episode], float] | None = None) -> ADR:
        """An ADR at its start from :meth:`config` data (or a hand-written YAML mapping with the same keys)."""
        if not isinstance(config, Mapping) or "effects" not in config:
            raise ValueError(f"`config` of ADR must be a mapping with an `effects` list. Received {config!r}.")
        allowed = {"effects", "delta", "t_low", "t_high", "p_boundary", "m", "metric", "initial"}
        unknown = sorted(set(config) - allowed)
        if unknown:
            raise ValueError(f"`config` of ADR has unknown keys {unknown}. Allowed: {sorted(allowed)}.")
        missing = [k for k in ("delta", "t_low", "t_high") if k not in config]
        if missing:  # what the constructor requires, in the config's words (not a TypeError about __init__)
            raise ValueError(
                f"`config` of ADR must give {missing} (required: ['effects', 'delta', 't_low', 't_high']). "
                f"Received keys {sorted(map(str, config))}."
            )
        kwargs: dict[str, Any] = {k: _yaml_number(v) for k, v in config.items() if k not in ("effects", "metric")}
        if isinstance(kwargs.get("delta"), Mapping):
            kwargs["delta"] = {k: _yaml_number(v) for k, v in kwargs["delta"].items()}
        chosen = metric if metric is not None else (config.get("metric") or "auto")
        return cls(load_effects({"effects": config["effects"]}), metric=chosen, **kwargs)

    def state(self) -> dict[str, Any]:
        """Everything needed to resume: config, ranges, buffers, frame count, history (JSON-ready)."""
        return {
            "version": _STATE_VERSION,
            "config": self.config(),
            "low": self.low.tolist(),
            "high": self.high.tolist(),
            "buffers": {f"{k}|{s}": list(v) for (k, s), v in self.buffers.items()},
            "frames": self.frames,
            "stale": self.stale,
            "history": [[f, list(lo), list(hi), e] for f, lo, hi, e in self._history],
        }

    def to_json(self) -> str:
        """:meth:`state` as JSON text (an entropy of ``-inf`` is written as ``-Infinity``)."""
        return json.dumps(self.state())

    @classmethod
    def from_state(cls, state: Mapping[str, Any] | str, metric: str | Callable[[Episode], float] | None = None) -> ADR:
        """The controller :meth:`state` (or its JSON text) describes; pass ``metric`` again if it was a callable.

        Example:
            >>> from randomizers import Damping
            >>> a = ADR([Damping(scale=Uniform(0.5, 2.0))], delta=0.1, t_low=0.2, t_high=0.8, m=1)
            >>> _ = a.record(Pin("Damping[joints=*]", "high", 1.0), 1.0, frames=50)
            >>> b = ADR.from_state(a.to_json())
            >>> b.ranges == a.ranges and b.state() == a.state()
            True
        """
        data = json.loads(state) if isinstance(state, str) else state
        if not isinstance(data, Mapping) or data.get("version") != _STATE_VERSION:
            raise ValueError(
                f"`state` of ADR.from_state must be ADR.state() data of version {_STATE_VERSION}. "
                f"Received {str(data)[:80]!r}."
            )
        adr = cls.from_config(data["config"], metric)
        low, high = np.array(data["low"], dtype=np.float64), np.array(data["high"], dtype=np.float64)
        if low.shape != adr.low.shape or high.shape != adr.high.shape or (low > high).any():
            raise ValueError(
                f"`state` of ADR.from_state has ranges that do not fit its effects. Received {data['low']!r}, {data['high']!r}."
            )
        adr.low, adr.high = low, high
        adr.buffers = {(k, s): list(data["buffers"][f"{k}|{s}"]) for k in adr.keys for s in _SIDES}
        adr.frames, adr.stale = int(data["frames"]), int(data["stale"])
        adr._history = [(int(f), tuple(lo), tuple(hi), float(e)) for f, lo, hi, e in data["history"]]
        adr._dists = [adr._range_distribution(i) for i in range(len(adr.keys))]
        return adr

    def __repr__(self) -> str:
        ranges = ", ".join(f"{k}: [{lo:g}, {hi:g}]" for k, (lo, hi) in self.ranges.items())
        return f"ADR({ranges}; frames={self.frames}, entropy={self.entropy():.3g})"
