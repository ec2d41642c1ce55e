"""Excitation signals for system identification: multisine, chirp, PRBS and random steps within actuator limits.

Every policy maps time (seconds) to a control vector ``(nu,)`` that stays inside the actuator limits: it is a
unit signal in ``[-1, 1]`` per actuator, scaled by ``amplitude`` (a fraction of the half-range available around
the actuator's centre) and shifted to the centre. Torque motors are centred on the middle of ``ctrlrange``;
position servos (whose control is a set point) on the middle of their range unless ``center`` says otherwise, so
they swing around a pose instead of slamming into a joint limit.

All randomness (Schroeder time shifts, PRBS register states, random steps) comes from the ``seed`` argument (an
int, a sequence of ints or an explicit ``numpy.random.Generator``), never from the global ``np.random``: the same
seed gives bitwise-identical signals.

A recorder uses a policy either per step (``policy(t) -> ctrl``) or as a block (``policy.signal(n_steps, dt)``);
the CLI picks one by name from :data:`EXCITATIONS` (``--policy {random,multisine,chirp,prbs}``), see
:func:`make_excitation`. The limits themselves (:class:`ActuatorLimits`, :func:`as_limits`) live in
:mod:`sysid.actuator_limits` and are re-exported here.

Example:
    >>> import mujoco
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body><joint name="hinge"/><geom size=".1"/></body></worldbody>'
    ...     '<actuator><motor name="motor" joint="hinge" ctrlrange="-2 2"/></actuator></mujoco>')
    >>> policy = Multisine(model, amplitude=0.5, band=(0.5, 4.0), period=2.0, seed=0)
    >>> u = policy.signal(1000, 0.002)
    >>> u.shape, bool(abs(u).max() <= 1.0)
    ((1000, 1), True)
    >>> policy.frequencies[0][:3]
    array([0.5, 1. , 1.5])
    >>> float(policy(0.25)[0]) == float(Multisine(model, amplitude=0.5, band=(0.5, 4.0), period=2.0, seed=0)(0.25)[0])
    True
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any, ClassVar, Literal

import numpy as np

from randomizers.seeding import normalize_seed
from sysid.actuator_limits import ActuatorLimits, _as_vector, as_limits

__all__ = [
    "EXCITATIONS",
    "PRBS",
    "ActuatorLimits",
    "Chirp",
    "ExcitationPolicy",
    "Multisine",
    "RandomSteps",
    "SeedOrGenerator",
    "as_limits",
    "lfsr_sequence",
    "make_excitation",
]

SeedOrGenerator = int | Sequence[int] | np.random.Generator | None

# Fibonacci taps of maximal-length LFSRs (period 2**order - 1), from the standard tables (Xilinx XAPP 052).
# tests/test_sysid_excitation.py checks every entry really has the maximal period.
_LFSR_TAPS: dict[int, tuple[int, ...]] = {
    3: (3, 2),
    4: (4, 3),
    5: (5, 3),
    6: (6, 5),
    7: (7, 6),
    8: (8, 6, 5, 4),
    9: (9, 5),
    10: (10, 7),
    11: (11, 9),
    12: (12, 6, 4, 1),
    13: (13, 4, 3, 1),
    14: (14, 5, 3, 1),
    15: (15, 14),
    16: (16, 15, 13, 4),
    17: (17, 14),
    18: (18, 11),
}
# The power spectrum of a PRBS clocked every Tc falls as sinc^2(f Tc): it is 3 dB down at f = 0.443 / Tc.
_PRBS_3DB = 0.443


def _generator(seed: SeedOrGenerator) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    try:
        root = normalize_seed(seed)
    except ValueError:
        raise ValueError(
            "`seed` must be None, a non-negative int, a sequence of them or a numpy.random.Generator. "
            f"Received {seed!r}."
        ) from None
    return np.random.default_rng(None if root is None else np.random.SeedSequence(list(root)))


def _positive(value: object, name: str, owner: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"`{name}` of {owner} must be a finite number > 0. Received {value!r}.")
    out = float(value)
    if not (math.isfinite(out) and out > 0):
        raise ValueError(f"`{name}` of {owner} must be a finite number > 0. Received {value!r}.")
    return out


class ExcitationPolicy(ABC):
    """An open-loop control signal ``t -> ctrl`` inside actuator limits.

    Subclasses implement :meth:`unit`, the signal in ``[-1, 1]`` per actuator; this base scales it by
    ``amplitude * half_range`` around the centre and clips to the bounds (a guard against rounding only: the
    unit signals are normalised so the clip never changes a value by more than a few ulps).

    Attributes:
        limits: the actuator bounds and centres.
        amplitude: fraction of each actuator's half-range used, shape ``(nu,)``, each in ``(0, 1]``.
    """

    name: ClassVar[str]

    def __init__(self, limits: object, amplitude: float | Sequence[float], center: Any = None) -> None:
        self.limits = as_limits(limits, center)
        amp = _as_vector(amplitude, self.limits.nu, "amplitude")
        if not np.all((amp > 0) & (amp <= 1)):
            shown = amplitude if np.ndim(amplitude) == 0 else list(amplitude)  # type: ignore[arg-type]
            raise ValueError(f"`amplitude` must be in (0, 1]. Received {shown}.")
        amp.setflags(write=False)
        self.amplitude = amp
        self._scale = self.amplitude * self.limits.half_range

    @property
    def nu(self) -> int:
        """Number of actuators driven."""
        return self.limits.nu

    @abstractmethod
    def unit(self, t: np.ndarray) -> np.ndarray:
        """The normalised signal at times ``t`` (shape ``(T,)``), shape ``(T, nu)``, values in ``[-1, 1]``."""

    def __call__(self, t: float) -> np.ndarray:
        """The control vector at time ``t`` (seconds), shape ``(nu,)``."""
        return self._controls(np.array([float(t)]))[0]

    def signal(self, n_steps: int, dt: float, t0: float = 0.0) -> np.ndarray:
        """Controls sampled at ``t0 + k * dt`` for ``k = 0 .. n_steps - 1``, shape ``(n_steps, nu)``.

        Example:
            >>> policy = PRBS(([-1.0], [1.0]), switch_period=0.1, seed=0)
            >>> policy.signal(0, 0.01)
            Traceback (most recent call last):
            ...
            ValueError: `n_steps` must be an int >= 1. Received 0.
        """
        if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)) or n_steps < 1:
            raise ValueError(f"`n_steps` must be an int >= 1. Received {n_steps!r}.")
        dt = _positive(dt, "dt", "signal")
        return self._controls(float(t0) + dt * np.arange(int(n_steps)))

    def _controls(self, t: np.ndarray) -> np.ndarray:
        u = self.limits.center + self._scale * self.unit(t)
        return np.clip(u, self.limits.low, self.limits.high)

    def _repr_fields(self) -> dict[str, Any]:
        return {}

    def __repr__(self) -> str:
        amp = float(self.amplitude[0]) if np.all(self.amplitude == self.amplitude[0]) else self.amplitude.tolist()
        fields = {"nu": self.nu, "amplitude": amp, **self._repr_fields()}
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in fields.items())})"


def _band(band: object, owner: str) -> tuple[float, float]:
    ok = isinstance(band, (tuple, list)) and len(band) == 2
    if ok:
        try:
            lo, hi = float(band[0]), float(band[1])  # type: ignore[index]
        except (TypeError, ValueError):
            ok = False
        else:
            ok = math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi
    if not ok:
        raise ValueError(f"`band` of {owner} must be (f_low, f_high) in Hz with 0 < f_low < f_high. Received {band!r}.")
    return lo, hi


class Multisine(ExcitationPolicy):
    """A periodic sum of sines on a harmonic grid inside ``band``, with Schroeder phases (low crest factor).

    The period ``T`` fixes the frequency resolution ``1/T``; the excited frequencies are the harmonics
    ``k / T`` inside ``band`` (thinned to ``n_freqs`` if given). With several actuators and ``interleave`` the
    harmonics are dealt out round-robin (in a seeded order), so each actuator owns disjoint frequencies and the
    inputs are orthogonal over a period — the MIMO design that keeps every actuator's effect separable.
    The seed also draws a circular time shift per actuator, which changes the waveform but not its crest factor.

    Args:
        limits: a ``mujoco.MjModel`` (reads ``actuator_ctrlrange``), an :class:`ActuatorLimits` or ``(low, high)``.
        amplitude: fraction of the half-range around the centre, in ``(0, 1]`` (scalar or one per actuator).
        band: ``(f_low, f_high)`` in Hz.
        period: signal period in seconds (default ``1 / f_low``); must be at least ``1 / f_low``.
        n_freqs: at most this many frequencies per actuator (default: every harmonic in the band).
        spacing: ``"linear"`` or ``"log"`` thinning when ``n_freqs`` is given.
        phases: ``"schroeder"`` (deterministic low crest factor) or ``"random"`` (uniform, from the seed).
        interleave: give each actuator its own harmonics when there are at least ``nu`` of them.
        center: override the centre of each actuator's swing (e.g. a home pose for position servos).
        seed: int, sequence of ints or ``numpy.random.Generator``.

    Attributes:
        frequencies: per actuator, the excited frequencies in Hz.
        period: the signal period in seconds.

    Example:
        >>> ms = Multisine(([-1.0, -1.0], [1.0, 1.0]), band=(1.0, 4.0), period=1.0, seed=3)
        >>> [f.tolist() for f in ms.frequencies]
        [[2.0, 4.0], [1.0, 3.0]]
        >>> Multisine(([-1.0], [1.0]), band=(2.0, 1.0))
        Traceback (most recent call last):
        ...
        ValueError: `band` of Multisine must be (f_low, f_high) in Hz with 0 < f_low < f_high. Received (2.0, 1.0).
    """

    name = "multisine"

    def __init__(
        self,
        limits: object,
        *,
        amplitude: float | Sequence[float] = 0.5,
        band: tuple[float, float] = (0.1, 2.0),
        period: float | None = None,
        n_freqs: int | None = None,
        spacing: Literal["linear", "log"] = "linear",
        phases: Literal["schroeder", "random"] = "schroeder",
        interleave: bool = True,
        center: Any = None,
        seed: SeedOrGenerator = None,
    ) -> None:
        super().__init__(limits, amplitude, center)
        lo, hi = _band(band, "Multisine")
        period = 1.0 / lo if period is None else _positive(period, "period", "Multisine")
        if period * lo < 1.0 - 1e-9:
            raise ValueError(
                f"`period` of Multisine must be >= 1 / band[0] = {1.0 / lo!r} s so the lowest frequency fits. "
                f"Received {period!r}."
            )
        if n_freqs is not None and (isinstance(n_freqs, bool) or not isinstance(n_freqs, int) or n_freqs < 1):
            raise ValueError(f"`n_freqs` of Multisine must be None or an int >= 1. Received {n_freqs!r}.")
        if spacing not in ("linear", "log"):
            raise ValueError(f"`spacing` of Multisine must be 'linear' or 'log'. Received {spacing!r}.")
        if phases not in ("schroeder", "random"):
            raise ValueError(f"`phases` of Multisine must be 'schroeder' or 'random'. Received {phases!r}.")
        harmonics = np.arange(math.ceil(lo * period - 1e-9), math.floor(hi * period + 1e-9) + 1)
        harmonics = harmonics[harmonics >= 1]
        if harmonics.size == 0:
            raise ValueError(
                f"`band` of Multisine holds no harmonic of 1 / period = {1.0 / period!r} Hz. Received band={band!r}."
            )
        gen = _generator(seed)
        nu = self.nu
        share = bool(interleave) and nu > 1 and harmonics.size >= nu
        wanted = None if n_freqs is None else n_freqs * (nu if share else 1)
        if wanted is not None and wanted < harmonics.size:
            if spacing == "log":
                grid = np.geomspace(harmonics[0], harmonics[-1], wanted)
                idx = np.unique(np.searchsorted(harmonics, grid).clip(0, harmonics.size - 1))
            else:
                idx = np.unique(np.round(np.linspace(0, harmonics.size - 1, wanted)).astype(int))
            harmonics = harmonics[idx]
        if share:
            order = gen.permutation(nu)
            sets = [harmonics[order[j] :: nu] for j in range(nu)]
        else:
            sets = [harmonics] * nu
        self.period = float(period)
        self.phases = phases
        self.band = (lo, hi)
        self._k = [np.asarray(s, dtype=np.float64) for s in sets]
        self._phi = []
        for k in self._k:
            count = k.size
            if phases == "schroeder":
                idx1 = np.arange(1, count + 1)
                phi = -np.pi * idx1 * (idx1 - 1) / count
                shift = gen.uniform(0.0, 1.0)  # fraction of a period; circular shifts keep the crest factor
                phi = phi + 2 * np.pi * k * shift
            else:
                phi = gen.uniform(0.0, 2 * np.pi, size=count)
            self._phi.append(phi)
        # Normalise by the peak over one period on a grid 32x finer than the highest harmonic.
        grid = np.arange(max(4096, 32 * int(harmonics.max()))) / max(4096, 32 * int(harmonics.max())) * period
        self._norm = np.array([np.abs(self._raw(j, grid)).max() for j in range(nu)])
        self.frequencies: tuple[np.ndarray, ...] = tuple(k / period for k in self._k)

    def _raw(self, j: int, t: np.ndarray) -> np.ndarray:
        arg = 2 * np.pi * np.outer(t / self.period, self._k[j]) + self._phi[j]
        return np.cos(arg).sum(axis=1)

    def unit(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        out = np.empty((t.shape[0], self.nu))
        for j in range(self.nu):
            out[:, j] = self._raw(j, t) / self._norm[j]
        return np.clip(out, -1.0, 1.0)

    @property
    def crest_factor(self) -> np.ndarray:
        """Peak over RMS per actuator, shape ``(nu,)`` (a single sine has sqrt(2) ≈ 1.41)."""
        rms = np.sqrt(np.array([k.size / 2.0 for k in self._k]))
        return self._norm / rms

    def _repr_fields(self) -> dict[str, Any]:
        return {"band": self.band, "period": self.period, "phases": self.phases}


class Chirp(ExcitationPolicy):
    """A swept sine from ``f0`` to ``f1`` Hz over ``duration`` seconds, repeating; linear or logarithmic sweep.

    The instantaneous frequency is ``f0 + (f1 - f0) * s`` (linear) or ``f0 * (f1 / f0) ** s`` (log), with
    ``s = (t mod duration) / duration``. The seed draws each actuator's starting phase.

    Args:
        limits: a ``mujoco.MjModel``, an :class:`ActuatorLimits` or ``(low, high)``.
        amplitude: fraction of the half-range around the centre, in ``(0, 1]``.
        f0: start frequency in Hz (> 0).
        f1: end frequency in Hz (> 0, may be below ``f0`` for a downward sweep).
        duration: sweep length in seconds.
        method: ``"linear"`` or ``"log"``.
        center: override the centre of each actuator's swing.
        seed: int, sequence of ints or ``numpy.random.Generator``.

    Example:
        >>> chirp = Chirp(([-1.0], [1.0]), f0=0.5, f1=5.0, duration=4.0, method="log", seed=0)
        >>> chirp.instantaneous_frequency(np.array([0.0, 2.0])).round(3).tolist()
        [0.5, 1.581]
        >>> Chirp(([-1.0], [1.0]), method="cubic")
        Traceback (most recent call last):
        ...
        ValueError: `method` of Chirp must be 'linear' or 'log'. Received 'cubic'.
    """

    name = "chirp"

    def __init__(
        self,
        limits: object,
        *,
        amplitude: float | Sequence[float] = 0.5,
        f0: float = 0.1,
        f1: float = 2.0,
        duration: float = 20.0,
        method: Literal["linear", "log"] = "linear",
        center: Any = None,
        seed: SeedOrGenerator = None,
    ) -> None:
        super().__init__(limits, amplitude, center)
        self.f0 = _positive(f0, "f0", "Chirp")
        self.f1 = _positive(f1, "f1", "Chirp")
        self.duration = _positive(duration, "duration", "Chirp")
        if method not in ("linear", "log"):
            raise ValueError(f"`method` of Chirp must be 'linear' or 'log'. Received {method!r}.")
        if method == "log" and self.f0 == self.f1:
            method = "linear"  # a log sweep between equal frequencies is a pure sine; avoid log(1) = 0 below
        self.method = method
        self._phase0 = _generator(seed).uniform(0.0, 2 * np.pi, size=self.nu)

    def instantaneous_frequency(self, t: np.ndarray) -> np.ndarray:
        """Frequency in Hz at times ``t`` (same shape as ``t``)."""
        s = np.mod(np.asarray(t, dtype=np.float64), self.duration) / self.duration
        if self.method == "linear":
            return self.f0 + (self.f1 - self.f0) * s
        return self.f0 * (self.f1 / self.f0) ** s

    def _phase(self, t: np.ndarray) -> np.ndarray:
        tau = np.mod(t, self.duration)
        if self.method == "linear":
            return 2 * np.pi * (self.f0 * tau + 0.5 * (self.f1 - self.f0) * tau**2 / self.duration)
        ratio = math.log(self.f1 / self.f0)
        return 2 * np.pi * self.f0 * self.duration / ratio * (np.exp(ratio * tau / self.duration) - 1.0)

    def unit(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        return np.sin(self._phase(t)[:, None] + self._phase0)

    def _repr_fields(self) -> dict[str, Any]:
        return {"f0": self.f0, "f1": self.f1, "duration": self.duration, "method": self.method}


def lfsr_sequence(order: int, state: int) -> np.ndarray:
    """One period (``2**order - 1`` bits, values 0/1) of the maximal-length LFSR of ``order`` from ``state``.

    Example:
        >>> lfsr_sequence(3, 1).tolist()
        [1, 0, 0, 1, 0, 1, 1]
    """
    if isinstance(order, bool) or order not in _LFSR_TAPS:
        raise ValueError(f"`order` must be an int in [3, 18]. Received {order!r}.")
    n = (1 << order) - 1
    if isinstance(state, bool) or not (isinstance(state, (int, np.integer)) and 1 <= state <= n):
        raise ValueError(f"`state` must be an int in [1, {n}]. Received {state!r}.")
    return _lfsr(int(order), int(state)).copy()


@functools.lru_cache(maxsize=32)
def _lfsr(order: int, state: int) -> np.ndarray:
    n = (1 << order) - 1
    taps = _LFSR_TAPS[order]
    reg = int(state)
    out = np.empty(n, dtype=np.int8)
    for i in range(n):
        out[i] = reg & 1
        bit = 0
        for tap in taps:
            bit ^= (reg >> (order - tap)) & 1
        reg = (reg >> 1) | (bit << (order - 1))
    return out


class PRBS(ExcitationPolicy):
    """A pseudo-random binary sequence: ``±amplitude`` around the centre, switching only on a clock of
    ``switch_period`` seconds, from a maximal-length shift register (period ``2**order - 1`` clocks).

    Its power is flat up to about ``0.443 / switch_period`` Hz (3 dB down there), so ``f_max`` picks the clock
    for a band. Each actuator starts the register at a seeded state: shifted copies of one m-sequence are nearly
    uncorrelated (cross-correlation ``-1 / (2**order - 1)``), so several actuators are excited independently.

    Args:
        limits: a ``mujoco.MjModel``, an :class:`ActuatorLimits` or ``(low, high)``.
        amplitude: fraction of the half-range around the centre, in ``(0, 1]``.
        switch_period: clock period in seconds (default 0.05 when neither it nor ``f_max`` is given).
        f_max: the highest frequency to excite with at most 3 dB loss (sets ``switch_period = 0.443 / f_max``).
        order: shift-register length, 3..18 (default 10: 1023 clocks per period).
        center: override the centre of each actuator's swing.
        seed: int, sequence of ints or ``numpy.random.Generator``.

    Example:
        >>> prbs = PRBS(([-2.0], [2.0]), amplitude=0.5, switch_period=0.05, order=5, seed=1)
        >>> sorted(set(prbs.signal(200, 0.01)[:, 0].tolist()))
        [-1.0, 1.0]
        >>> PRBS(([-1.0], [1.0]), switch_period=0.1, f_max=2.0)
        Traceback (most recent call last):
        ...
        ValueError: PRBS needs exactly one of `switch_period` (s) or `f_max` (Hz). Received switch_period=0.1, f_max=2.0.
    """

    name = "prbs"

    def __init__(
        self,
        limits: object,
        *,
        amplitude: float | Sequence[float] = 0.5,
        switch_period: float | None = None,
        f_max: float | None = None,
        order: int = 10,
        center: Any = None,
        seed: SeedOrGenerator = None,
    ) -> None:
        super().__init__(limits, amplitude, center)
        if switch_period is None and f_max is None:
            switch_period = 0.05
        elif (switch_period is None) == (f_max is None):
            raise ValueError(
                "PRBS needs exactly one of `switch_period` (s) or `f_max` (Hz). "
                f"Received switch_period={switch_period!r}, f_max={f_max!r}."
            )
        if f_max is not None:
            switch_period = _PRBS_3DB / _positive(f_max, "f_max", "PRBS")
        self.switch_period = _positive(switch_period, "switch_period", "PRBS")
        if isinstance(order, bool) or order not in _LFSR_TAPS:
            raise ValueError(f"`order` of PRBS must be an int in [3, 18]. Received {order!r}.")
        self.order = int(order)
        n = (1 << self.order) - 1
        gen = _generator(seed)
        starts = gen.integers(0, n, size=self.nu)
        base = 2.0 * _lfsr(self.order, 1).astype(np.float64) - 1.0
        self._bits = np.stack([np.roll(base, -int(s)) for s in starts], axis=1)  # (n, nu) of ±1

    @property
    def f_max(self) -> float:
        """The 3 dB band edge in Hz."""
        return _PRBS_3DB / self.switch_period

    def unit(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        # A tiny relative guard keeps t = m * switch_period (as produced by m * dt sums) on clock m.
        clock = np.floor(t / self.switch_period * (1 + 1e-12) + 1e-9).astype(np.int64)
        return self._bits[np.mod(clock, self._bits.shape[0])]

    def _repr_fields(self) -> dict[str, Any]:
        return {"switch_period": self.switch_period, "order": self.order}


class RandomSteps(ExcitationPolicy):
    """Independent uniform values in ``[-1, 1]`` (scaled into the limits), held for ``hold`` seconds each.

    Values are drawn from the seed in clock order and cached, so ``policy(t)`` is the same whatever order the
    times are queried in.

    Args:
        limits: a ``mujoco.MjModel``, an :class:`ActuatorLimits` or ``(low, high)``.
        amplitude: fraction of the half-range around the centre, in ``(0, 1]``.
        hold: seconds each value is held (> 0).
        center: override the centre of each actuator's swing.
        seed: int, sequence of ints or ``numpy.random.Generator``.

    Example:
        >>> steps = RandomSteps(([-1.0], [1.0]), amplitude=1.0, hold=0.1, seed=0)
        >>> bool(steps(0.05)[0] == steps(0.0)[0] != steps(0.1)[0])
        True
    """

    name = "random"

    def __init__(
        self,
        limits: object,
        *,
        amplitude: float | Sequence[float] = 1.0,
        hold: float = 0.05,
        center: Any = None,
        seed: SeedOrGenerator = None,
    ) -> None:
        super().__init__(limits, amplitude, center)
        self.hold = _positive(hold, "hold", "RandomSteps")
        # A private child stream: values are drawn lazily, so sharing the caller's generator would make them depend
        # on what else drew from it in between.
        self._gen = np.random.default_rng(_generator(seed).integers(0, 2**63, size=4))
        self._table = np.empty((0, self.nu))

    def unit(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        if np.any(t < 0):
            raise ValueError(f"`t` of RandomSteps must be >= 0. Received min t = {float(t.min())!r}.")
        clock = np.floor(t / self.hold * (1 + 1e-12) + 1e-9).astype(np.int64)
        need = int(clock.max(initial=-1)) + 1
        if need > self._table.shape[0]:
            extra = self._gen.uniform(-1.0, 1.0, size=(max(need - self._table.shape[0], 256), self.nu))
            self._table = np.concatenate([self._table, extra])
        return self._table[clock]

    def _repr_fields(self) -> dict[str, Any]:
        return {"hold": self.hold}


EXCITATIONS: dict[str, type[ExcitationPolicy]] = {cls.name: cls for cls in (RandomSteps, Multisine, Chirp, PRBS)}


def make_excitation(name: str, limits: object, **kwargs: Any) -> ExcitationPolicy:
    """Builds the excitation registered as ``name`` in :data:`EXCITATIONS` (what ``--policy`` selects).

    Example:
        >>> make_excitation("chirp", ([-1.0], [1.0]), f0=1.0, f1=2.0, seed=0)
        Chirp(nu=1, amplitude=0.5, f0=1.0, f1=2.0, duration=20.0, method='linear')
        >>> make_excitation("sine", ([-1.0], [1.0]))
        Traceback (most recent call last):
        ...
        ValueError: `policy` must be one of ['chirp', 'multisine', 'prbs', 'random']. Received 'sine'.
    """
    if name not in EXCITATIONS:
        raise ValueError(f"`policy` must be one of {sorted(EXCITATIONS)}. Received {name!r}.")
    return EXCITATIONS[name](limits, **kwargs)
