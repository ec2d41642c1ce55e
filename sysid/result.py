"""`FitResult`: what :func:`sysid.fit` returns, with JSON, randomiser-config and figure exports.

Example:
    >>> import numpy as np
    >>> result = FitResult.from_estimates({"dof_damping[elbow]": (0.52, 0.01)})
    >>> result.ci95.round(3).tolist()
    [[0.5, 0.54]]
    >>> print(result.to_randomizers(width=2.0, min_relative_width=0.0).strip())
    effects:
    - type: Damping
      set:
        type: Uniform
        low: 0.5
        high: 0.54
      joints: elbow
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np

from noise_models.timing import ActionLatency, ObservationLatency, convert_time
from randomizers.config import dump_config
from randomizers.correlated import Correlated
from randomizers.distributions import MultivariateNormal, Uniform
from randomizers.effects import Effect
from randomizers.files import atomic_write
from randomizers.parameters import EFFECT_FIELDS, Address, effect_for
from sysid.quality import FitQuality, NotOkError

__all__ = ["FitResult"]

_ARRAYS = ("estimates", "stderr", "ci95", "crlb_sd", "covariance", "correlation", "bounds")
_TRACES = ("trace_time", "trace_measured", "trace_predicted")
_MAPPINGS = ("latency", "noise_std", "fit_percent", "whiteness_pvalue", "noise_dof")
_LATENCY_MODELS = {"action": ActionLatency, "obs": ObservationLatency}


def _num(value: float) -> float | str | None:
    """A JSON number; NaN is ``null`` and the infinities are the strings ``"inf"``/``"-inf"``."""
    value = float(value)
    if math.isnan(value):
        return None
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return value


def _from_num(value: Any) -> float:
    return math.nan if value is None else float(value)


def _nested(array: np.ndarray) -> Any:
    return [_nested(row) for row in array] if array.ndim > 1 else [_num(v) for v in array]


def _array(value: Any, ndim: int) -> np.ndarray:
    out = np.array(value if value is not None else [], dtype=object)
    shape = out.shape if out.size else (0,) * ndim
    return np.vectorize(_from_num, otypes=[np.float64])(out).reshape(shape) if out.size else np.zeros(shape)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def _round_sig(value: float, digits: int | None) -> float:
    if digits is None or value == 0 or not math.isfinite(value):
        return float(value)
    return float(f"{value:.{digits}g}")


def _readonly(array: np.ndarray) -> np.ndarray:
    out = np.array(array, dtype=np.float64)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class FitResult:
    """Estimates and their uncertainty from one :func:`sysid.fit` call.

    Shapes use P = number of fitted scalar parameters, C = number of measured channels, N = rows of the
    stored trace.

    Attributes:
        addresses: (P,) parameter addresses, e.g. ``"dof_damping[elbow]"``.
        estimates: (P,) fitted values.
        stderr: (P,) standard errors: ``sqrt(diag(s² (JᵀJ)⁻¹))`` of the 1/sigma-weighted Jacobian J (initial
            states profiled out), ``s²`` the reduced chi-square (≈ 1 when the model explains the data).
        ci95: (P, 2) 95% intervals ``estimate ± t(0.975, dof) · stderr``.
        crlb_sd: (P,) Cramér–Rao standard deviations ``sqrt(diag(F⁻¹))``, ``F = JᵀJ`` at the estimate with
            the estimated sensor noise (no chi-square scaling): the best any unbiased estimator can do.
        covariance: (P, P) covariance behind ``stderr``.
        correlation: (P, P) correlation matrix.
        bounds: (P, 2) the search bounds.
        latency: ``{"action": s, "obs": s}`` in **seconds** (``action`` may fall between control steps after
            sub-step refinement); only the latencies that were fitted or fixed. :attr:`latency_control_steps` and
            :attr:`latency_physics_steps` give them in steps.
        timestep: seconds per physics step of the fitted model (NaN when unknown).
        control_timestep: seconds per control step of the log (NaN when unknown).
        noise_std: ``{channel: sigma}`` estimated (or given) measurement noise, in the channel's units.
        noise_dof: ``{channel: dof}`` degrees of freedom of the residuals behind each ``noise_std`` (``σ̂² dof / σ²``
            is chi-square with ``dof`` when the model is right): ``inf`` for a given level, NaN for one not
            re-estimated from residuals; :meth:`noise_level` pools channels with them.
        fit_percent: ``{channel: percent}`` NRMSE fit ``100 (1 - ‖y-ŷ‖/‖y-ȳ‖)`` on held-out data.
        whiteness_pvalue: ``{channel: p}`` Ljung–Box p-value of the held-out residuals (small = not white).
        warnings: identifiability and validation warnings, each naming the parameters involved.
        condition_number: condition number of the relative (scale-free) Fisher information.
        cost: final ``½‖r‖²`` of the weighted residuals.
        n_residuals: length of the residual vector.
        dof: ``n_residuals`` minus every fitted scalar (parameters and initial states).
        iterations: Levenberg–Marquardt iterations of the final stage.
        converged: whether the final stage met its tolerances.
        wall_time: seconds spent in ``fit``.
        channels: (C,) channel names (``qpos[joint]``, ``qvel[joint]``, sensor names).
        trace_time: (N,) seconds of the stored trace (held-out rows, or fit rows without hold-out).
        trace_measured: (N, C) measured values (NaN where a channel has no sample on that row).
        trace_predicted: (N, C) simulated values with the estimates.
        trace_source: ``"validation"`` or ``"fit"``.
        true_params: ground truth from the log's meta, when it had any.
        quality: the :class:`~sysid.quality.FitQuality` verdict (fit percent, whiteness, bounds, shooting
            horizon, reasons); :attr:`ok` is its summary.
    """

    addresses: tuple[str, ...]  # Address objects (each is also its text)
    estimates: np.ndarray
    stderr: np.ndarray
    ci95: np.ndarray
    crlb_sd: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    bounds: np.ndarray
    latency: Mapping[str, float] = field(default_factory=dict)
    timestep: float = math.nan
    control_timestep: float = math.nan
    noise_std: Mapping[str, float] = field(default_factory=dict)
    noise_dof: Mapping[str, float] = field(default_factory=dict)
    fit_percent: Mapping[str, float] = field(default_factory=dict)
    whiteness_pvalue: Mapping[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    condition_number: float = math.nan
    cost: float = math.nan
    n_residuals: int = 0
    dof: int = 0
    iterations: int = 0
    converged: bool = True
    wall_time: float = 0.0
    channels: tuple[str, ...] = ()
    trace_time: np.ndarray = field(default_factory=lambda: np.zeros(0))
    trace_measured: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    trace_predicted: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    trace_source: str = "fit"
    true_params: Mapping[str, float] | None = None
    quality: FitQuality = field(default_factory=FitQuality)

    def __post_init__(self) -> None:
        if not isinstance(self.quality, FitQuality):
            raise TypeError(f"`quality` must be a FitQuality. Received {type(self.quality).__name__}.")
        for name in (*_ARRAYS, *_TRACES):
            object.__setattr__(self, name, _readonly(getattr(self, name)))
        for name in _MAPPINGS:
            object.__setattr__(self, name, {str(k): float(v) for k, v in getattr(self, name).items()})
        if self.true_params is not None:
            object.__setattr__(self, "true_params", {str(k): float(v) for k, v in self.true_params.items()})
        for name in ("timestep", "control_timestep", "condition_number", "cost", "wall_time"):
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("timestep", "control_timestep"):
            value = getattr(self, name)
            if not (math.isnan(value) or (math.isfinite(value) and value > 0)):
                raise ValueError(f"`{name}` must be a number of seconds > 0 (or NaN when unknown). Received {value!r}.")
        object.__setattr__(self, "addresses", tuple(Address.parse(a) for a in self.addresses))
        object.__setattr__(self, "warnings", tuple(self.warnings))
        object.__setattr__(self, "channels", tuple(self.channels))
        size = len(self.addresses)
        for name, shape in (
            ("estimates", (size,)),
            ("stderr", (size,)),
            ("crlb_sd", (size,)),
            ("ci95", (size, 2)),
            ("covariance", (size, size)),
            ("correlation", (size, size)),
            ("bounds", (size, 2)),
        ):
            if getattr(self, name).shape != shape:
                raise ValueError(f"`{name}` must have shape {shape}. Received {getattr(self, name).shape}.")

    def __eq__(self, other: object) -> bool:
        """Field by field, arrays compared with NaN equal to NaN (what a JSON round trip must preserve)."""
        if not isinstance(other, FitResult):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    __hash__ = None  # type: ignore[assignment]

    @classmethod
    def from_estimates(
        cls,
        estimates: Mapping[str, tuple[float, float]],
        bounds: Mapping[str, tuple[float, float]] | None = None,
    ) -> FitResult:
        """A result from ``{address: (estimate, stderr)}`` (no fit behind it): for configs and tests.

        ``bounds`` (``{address: (low, high)}``) default to unbounded; the covariance is diagonal.
        """
        addresses = tuple(estimates)
        est = np.array([float(v[0]) for v in estimates.values()])
        se = np.array([float(v[1]) for v in estimates.values()])
        z = 1.959963984540054
        given = bounds or {}
        box = np.array([given.get(a, (-math.inf, math.inf)) for a in addresses], dtype=np.float64).reshape(-1, 2)
        return cls(
            addresses=addresses,
            estimates=est,
            stderr=se,
            ci95=np.stack([est - z * se, est + z * se], axis=1),
            crlb_sd=se,
            covariance=np.diag(se**2),
            correlation=np.eye(len(addresses)),
            bounds=box,
        )

    @classmethod
    def from_json(cls, source: str | os.PathLike[str]) -> FitResult:
        """The result :meth:`to_json` wrote (a file path or the JSON text), every field included.

        Raises:
            ValueError: text that is not a fit result document.
        """
        text = str(source)
        if isinstance(source, os.PathLike) or not text.lstrip().startswith("{"):
            text = Path(source).read_text()
        try:
            return cls.from_dict(json.loads(text))
        except (ValueError, KeyError, TypeError) as err:
            raise ValueError(f"`source` is not a sysid fit result JSON document: {err}") from err

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FitResult:
        """The inverse of :meth:`to_dict`."""
        params = data["params"]
        addresses = tuple(params)
        kwargs: dict[str, Any] = {
            "addresses": addresses,
            "estimates": [_from_num(v["estimate"]) for v in params.values()],
            "stderr": [_from_num(v["stderr"]) for v in params.values()],
            "ci95": _array([v["ci95"] for v in params.values()], 2).reshape(-1, 2),
            "crlb_sd": [_from_num(v["crlb_sd"]) for v in params.values()],
            "bounds": _array([v.get("bounds", ["-inf", "inf"]) for v in params.values()], 2).reshape(-1, 2),
        }
        size = len(addresses)
        for name in ("covariance", "correlation"):
            kwargs[name] = _array(data[name], 2).reshape(size, size) if name in data else None
        if kwargs["covariance"] is None:  # a document written before the covariance was stored
            kwargs["covariance"] = np.diag(np.square(kwargs["stderr"]))
        if kwargs["correlation"] is None:
            kwargs["correlation"] = np.eye(size)
        for name in _MAPPINGS:
            kwargs[name] = {k: _from_num(v) for k, v in data.get(name, {}).items()}
        for name in ("timestep", "control_timestep", "condition_number", "cost", "wall_time"):
            kwargs[name] = _from_num(data.get(name))
        for name in ("n_residuals", "dof", "iterations"):
            kwargs[name] = int(data.get(name, 0))
        kwargs["converged"] = bool(data.get("converged", True))
        kwargs["warnings"] = tuple(data.get("warnings", ()))
        kwargs["channels"] = tuple(data.get("channels", ()))
        trace = data.get("trace", {})
        kwargs["trace_time"] = _array(trace.get("time"), 1)
        rows = (len(kwargs["trace_time"]), len(kwargs["channels"]))
        kwargs["trace_measured"] = _array(trace.get("measured"), 2).reshape(rows)
        kwargs["trace_predicted"] = _array(trace.get("predicted"), 2).reshape(rows)
        kwargs["trace_source"] = str(trace.get("source", "fit"))
        truth = data.get("true_params")
        kwargs["true_params"] = None if truth is None else {k: _from_num(v) for k, v in truth.items()}
        kwargs["quality"] = FitQuality.from_dict(data.get("quality", {}))
        return cls(**kwargs)

    @property
    def ok(self) -> bool:
        """Whether the fitted model reproduces the log (no :attr:`quality` reasons); exports refuse otherwise."""
        return self.quality.ok

    def _require_ok(self, force: bool) -> None:
        if not force and not self.quality.ok:
            raise NotOkError(
                "the fit is not ok, so it is not exported: " + "; ".join(self.quality.reasons) + ". Fix the model "
                "or the log, or pass `force=True` to export it anyway."
            )

    @property
    def params(self) -> dict[str, float]:
        """``{address: estimate}`` (what a calibrated environment is built from)."""
        return {a: float(v) for a, v in zip(self.addresses, self.estimates, strict=True)}

    def _latency_in(self, unit: str) -> dict[str, float]:
        if not math.isfinite(self.timestep) or not math.isfinite(self.control_timestep):
            return {k: math.nan for k in self.latency}
        substeps = max(1, round(self.control_timestep / self.timestep))
        return {
            k: convert_time(v, "seconds", unit, timestep=self.timestep, substeps=substeps)
            for k, v in self.latency.items()
        }

    @property
    def latency_control_steps(self) -> dict[str, float]:
        """:attr:`latency` in control steps of the log (NaN when the timesteps are unknown)."""
        return self._latency_in("control_steps")

    @property
    def latency_physics_steps(self) -> dict[str, float]:
        """:attr:`latency` in physics steps of the model (NaN when the timesteps are unknown)."""
        return self._latency_in("physics_steps")

    @property
    def latency_steps(self) -> dict[str, float]:
        """The former name of :attr:`latency_control_steps` (control steps)."""
        return self.latency_control_steps

    def to_dict(self) -> dict[str, Any]:
        """The JSON document as a dict (see :meth:`to_json`)."""
        params = {
            str(a): {
                "estimate": _num(self.estimates[i]),
                "stderr": _num(self.stderr[i]),
                "ci95": [_num(self.ci95[i, 0]), _num(self.ci95[i, 1])],
                "crlb_sd": _num(self.crlb_sd[i]),
                "bounds": [_num(self.bounds[i, 0]), _num(self.bounds[i, 1])],
            }
            for i, a in enumerate(self.addresses)
        }
        return {
            "params": params,
            "covariance": _nested(self.covariance),
            "correlation": _nested(self.correlation),
            "latency": {k: _num(v) for k, v in self.latency.items()},
            "latency_control_steps": {k: _num(v) for k, v in self.latency_control_steps.items()},
            "timestep": _num(self.timestep),
            "control_timestep": _num(self.control_timestep),
            **{name: {k: _num(v) for k, v in getattr(self, name).items()} for name in _MAPPINGS[1:]},
            "warnings": list(self.warnings),
            "condition_number": _num(self.condition_number),
            "cost": _num(self.cost),
            "n_residuals": self.n_residuals,
            "dof": self.dof,
            "iterations": self.iterations,
            "converged": self.converged,
            "wall_time": _num(self.wall_time),
            "channels": list(self.channels),
            "trace": {
                "source": self.trace_source,
                "time": _nested(self.trace_time),
                "measured": _nested(self.trace_measured),
                "predicted": _nested(self.trace_predicted),
            },
            "true_params": None if self.true_params is None else {k: _num(v) for k, v in self.true_params.items()},
            "quality": self.quality.to_dict(),
        }

    def to_json(self, path: str | os.PathLike[str] | None = None, indent: int = 2) -> str:
        """Every field as JSON (:meth:`from_json` reads back an equal result); written atomically to ``path``
        when given. ``params`` maps each address to ``estimate``, ``stderr``, ``ci95``, ``crlb_sd`` and
        ``bounds``; ``latency`` is in seconds (``latency_control_steps`` repeats it in control steps, for
        readers); NaN is ``null`` and the infinities are ``"inf"``/``"-inf"``."""
        text = json.dumps(self.to_dict(), indent=indent)
        if path is not None:
            atomic_write(path, text + "\n")
        return text

    def to_effects(
        self,
        width: float = 2.0,
        min_relative_width: float = 0.1,
        kind: Literal["uniform", "posterior"] = "uniform",
        *,
        digits: int | None = None,
        latency: bool = True,
        noise: bool = True,
        noise_select: Mapping[str, Any] | None = None,
        force: bool = False,
    ) -> list[Any]:
        """The randomised simulator this fit calls for: effects for the fitted parameters, then the fitted
        latencies and sensor noise (ready for ``sim2real.wrap``).

        The rule: each parameter is drawn around its estimate ``e`` with half-width
        ``h = max(min_relative_width * |e|, width * stderr)``, clipped to the fit bounds and, for quantities
        that must stay non-negative, at 0.

        * ``kind="uniform"``: one effect per parameter, ``set`` to ``Uniform(e - h, e + h)``; with ``digits``,
          ``e`` and ``h`` are first rounded to that many significant digits (configs that read well).
        * ``kind="posterior"``: one :class:`randomizers.Correlated` effect drawing all parameters jointly from the
          fit's Gaussian posterior (mean = estimates, covariance = :attr:`covariance`), truncated to the bounds
          (and at 0 where a quantity must stay non-negative); ``width`` and ``min_relative_width`` do not apply.

        Latencies become ``ActionLatency``/``ObservationLatency`` in **seconds**, rounded to whole physics steps
        of the model when its timestep is known. The sensor noise becomes Gaussian ``ObservationNoise``: without
        ``noise_select``, one level for the whole observation, the mean of the fitted channels' levels (one
        significant digit); with it (where each signal sits in the target env's observation, e.g.
        ``{"qpos": [0, 1, 2], "qvel": [3, 4, 5]}`` or ``{"qpos": "position", "qvel": "velocity"}``; for an env
        ``sim2real.calibration.noise_select(env)`` finds it), one ``Gaussian`` per entry, its ``std`` drawn per
        episode from ``Uniform`` over :meth:`noise_level` ``± max(min_relative_width * level, width * stderr)``
        (at least 0): position and velocity sensors keep their own levels.

        Example:
            >>> fit = FitResult.from_estimates({"dof_damping[shoulder]": (0.0299, 0.0001)})
            >>> fit.to_effects(digits=2)
            [Damping(set=Uniform(low=0.027, high=0.033), joints='shoulder')]

        Parameters without a single-element effect (multi-dof components, raw fields such as
        ``actuator_biasprm``) are left out of ``kind="uniform"``; :meth:`to_randomizers` lists them.

        A fit that is not :attr:`ok` (the model cannot reproduce the log) is refused unless ``force=True``.

        Raises:
            ValueError: a width that is not a finite number >= 0 (``width`` > 0), an unknown ``kind``, an empty
                ``noise_select`` or a ``noise_select`` signal no fitted channel belongs to.
            TypeError: a ``noise_select`` that is not a mapping (or None).
            NotOkError: (a ValueError) the fit is not ok and ``force`` is False; the message lists the reasons.
        """
        self._require_ok(force)
        for name, value, low in (("width", width, 0.0), ("min_relative_width", min_relative_width, 0.0)):
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not math.isfinite(value)
                or value < low
            ):
                raise ValueError(f"`{name}` must be a finite number >= 0. Received {value!r}.")
        if kind not in ("uniform", "posterior"):
            raise ValueError(f"`kind` must be 'uniform' or 'posterior'. Received {kind!r}.")
        if kind == "posterior":
            out: list[Any] = [self._posterior()] if self.addresses else []
        else:
            out = [
                e for e in (self._effect(i, width, min_relative_width, digits) for i in range(len(self.addresses))) if e
            ]
        if noise:
            out.extend(self._noise_models(noise_select, width, min_relative_width, digits))
        if latency:
            physics = self.latency_physics_steps
            for name, seconds in self.latency.items():
                if math.isfinite(physics.get(name, math.nan)):
                    seconds = convert_time(round(physics[name]), "physics_steps", "seconds", timestep=self.timestep)
                if seconds > 0:
                    out.append(_LATENCY_MODELS[name](seconds=seconds))
        return out

    def noise_level(self, signal: str) -> tuple[float, float]:
        """The fitted sensor noise of ``signal`` and its standard error, ``(sigma, stderr)``, in its units.

        Args:
            signal: a channel name (``"qpos[elbow]"``, a sensor) or what channel names start with before a ``[``:
                ``"qpos"``, ``"qvel"``, ``"qpos[puck_free]"``, a multi-dimensional sensor's name.

        Returns:
            ``sigma`` pools the channels' residual variances by their degrees of freedom,
            ``sqrt(sum(dof_c sigma_c²) / sum(dof_c))``; ``stderr = sigma / sqrt(2 sum(dof_c))`` (chi-square).
            Given levels have stderr 0; levels not estimated from residuals (no fit iterations, or a result saved
            before :attr:`noise_dof` existed) are pooled equally with stderr NaN.

        Raises:
            ValueError: no fitted channel belongs to ``signal`` (the channels are listed).

        Example:
            >>> fit = FitResult.from_estimates({})
            >>> fit = FitResult(**{**{f.name: getattr(fit, f.name) for f in fields(fit)},
            ...     "noise_std": {"qpos[a]": 0.001, "qpos[b]": 0.001, "qvel[a]": 0.005}, "noise_dof": {
            ...     "qpos[a]": 200.0, "qpos[b]": 200.0, "qvel[a]": 200.0}})
            >>> [round(v, 6) for v in fit.noise_level("qpos")], round(fit.noise_level("qvel")[0], 6)
            ([0.001, 3.5e-05], 0.005)
        """
        chosen = [c for c in self.noise_std if c == signal or c.startswith(signal + "[")]
        if not chosen:
            raise ValueError(
                f"`signal` must be a fitted channel or the start of some ('qpos', 'qvel', a sensor name): the fit has "
                f"{list(self.noise_std)}. Received {signal!r}."
            )
        levels = np.array([self.noise_std[c] for c in chosen])
        dofs = np.array([self.noise_dof.get(c, math.nan) for c in chosen])
        if np.isfinite(dofs).all():
            sigma = math.sqrt(float(np.sum(dofs * levels**2) / np.sum(dofs)))
            return sigma, sigma / math.sqrt(2.0 * float(np.sum(dofs)))
        sigma = math.sqrt(float(np.mean(levels**2)))
        return sigma, 0.0 if np.isposinf(dofs).all() else math.nan

    def _noise_models(
        self, noise_select: Mapping[str, Any] | None, width: float, min_relative: float, digits: int | None
    ) -> list[Any]:
        from noise_models import Gaussian, ObservationNoise

        if noise_select is None:  # the target's observation layout is unknown: one level for all of it
            levels = [float(v) for v in self.noise_std.values() if math.isfinite(v)]
            return [ObservationNoise(Gaussian(std=_round_sig(float(np.mean(levels)), 1)))] if levels else []
        if not isinstance(noise_select, Mapping):
            raise TypeError(
                "`noise_select` must be a mapping {signal: where in the observation} such as "
                f"{{'qpos': [0, 1], 'qvel': [2, 3]}}, or None. Received {noise_select!r}."
            )
        if not noise_select:  # no group named: exporting no sensor noise at all would be silent
            raise ValueError(
                "`noise_select` must map at least one signal ('qpos', 'qvel', a sensor) to where it sits in the "
                f"observation, or be None (one level for the whole observation). Received {dict(noise_select)!r}."
            )
        processes = []
        for signal, where in noise_select.items():
            sigma, se = self.noise_level(signal)
            if not math.isfinite(sigma):
                continue
            est = _round_sig(sigma, digits)
            half = _round_sig(max(min_relative * sigma, width * se if math.isfinite(se) else 0.0), digits)
            std: Any = est if half <= 0 else Uniform(round(max(est - half, 0.0), 12), round(est + half, 12))
            processes.append(Gaussian(std=std, select=where))
        return [ObservationNoise(*processes)] if processes else []

    def _nonnegative(self, i: int) -> bool:
        owner = EFFECT_FIELDS.get(Address.parse(self.addresses[i]).field)
        return owner.nonnegative if owner is not None else False

    def _range(self, i: int, width: float, min_relative: float, digits: int | None) -> tuple[float, float]:
        est, se = _round_sig(float(self.estimates[i]), digits), float(self.stderr[i])
        half = max(min_relative * abs(est), width * se if math.isfinite(se) else 0.0)
        half = _round_sig(max(half, 1e-12 * max(abs(est), 1.0)), digits)
        lo, hi = max(est - half, float(self.bounds[i, 0])), min(est + half, float(self.bounds[i, 1]))
        if self._nonnegative(i):
            lo = max(lo, 0.0)
        if not hi > lo:
            hi = lo + 1e-12 * max(abs(lo), 1.0)
        return round(lo, 12), round(hi, 12)

    def _effect(self, i: int, width: float, min_relative: float, digits: int | None) -> Effect | None:
        address = Address.parse(self.addresses[i])  # already an Address: no parsing happens
        owner = EFFECT_FIELDS.get(address.field)
        if owner is None or (owner.components is None and address.component is not None):
            return None
        if owner.components is not None and (
            address.component is None or address.component >= len(owner.components[1])
        ):
            return None
        return effect_for(address, "set", Uniform(*self._range(i, width, min_relative, digits)))

    def _posterior(self) -> Correlated:
        low = self.bounds[:, 0].copy()
        for i in range(len(self.addresses)):
            if self._nonnegative(i):
                low[i] = max(low[i], 0.0)
        cov = (self.covariance + self.covariance.T) / 2.0
        return Correlated(
            list(self.addresses),
            MultivariateNormal(
                tuple(self.estimates.tolist()),
                tuple(map(tuple, cov.tolist())),
                low=tuple(low),
                high=tuple(self.bounds[:, 1]),
            ),
        )

    def to_randomizers(
        self,
        width: float = 2.0,
        path: str | os.PathLike[str] | None = None,
        *,
        min_relative_width: float = 0.1,
        kind: Literal["uniform", "posterior"] = "uniform",
        noise_select: Mapping[str, Any] | None = None,
        force: bool = False,
    ) -> str:
        """A randomiser YAML config (``randomizers.load_config`` reads it) of :meth:`to_effects`.

        Args:
            width, min_relative_width, kind, noise_select, force: as for :meth:`to_effects` (a fit that is not ok is
                refused).
            path: when given, the YAML is also written there atomically.
        """
        effects = self.to_effects(width, min_relative_width, kind, noise_select=noise_select, force=force)
        text = dump_config(effects)
        covered = {a for e in effects if isinstance(e, Correlated) for a in e.addresses}
        notes = [
            f"# not expressible as an effect: {a} = {self.estimates[i]!r}"
            for i, a in enumerate(self.addresses)
            if a not in covered and self._effect(i, width, min_relative_width, None) is None
        ]
        if notes:
            text = "\n".join(notes) + "\n" + text
        if path is not None:
            atomic_write(path, text)
        return text

    def plot(self, path: str | os.PathLike[str] | None = None, max_channels: int = 6) -> Any:
        """Figure of measured vs simulated signals and their residuals (matplotlib, Agg backend).

        Args:
            path: when given, the figure is saved there (PNG/SVG/PDF by suffix).
            max_channels: at most this many channels are drawn, the worst-fitting first.

        Returns:
            The ``matplotlib.figure.Figure``.
        """
        from matplotlib.figure import Figure  # no pyplot: the caller's backend (e.g. Jupyter's) stays as it is

        count = len(self.channels)
        order = sorted(range(count), key=lambda c: self.fit_percent.get(self.channels[c], 0.0))[:max_channels]
        fig = Figure(figsize=(10, 2.2 * max(1, len(order))), layout="constrained")
        axes = fig.subplots(max(1, len(order)), 2, squeeze=False)
        t = self.trace_time
        for row, c in enumerate(order):
            name = self.channels[c]
            measured, predicted = self.trace_measured[:, c], self.trace_predicted[:, c]
            ok = np.isfinite(measured)
            ax = axes[row, 0]
            ax.plot(t[ok], measured[ok], ".", ms=2, color="0.4", label="measured")
            ax.plot(t[ok], predicted[ok], "-", lw=1, color="C0", label="simulated")
            fit = self.fit_percent.get(name, math.nan)
            ax.set_title(f"{name}  fit {fit:.1f}%", fontsize=9)
            ax.legend(fontsize=7, loc="upper right")
            ax2 = axes[row, 1]
            sigma = self.noise_std.get(name, math.nan)
            ax2.plot(t[ok], measured[ok] - predicted[ok], ".", ms=2, color="C3")
            if math.isfinite(sigma):
                for sign in (-2, 2):
                    ax2.axhline(sign * sigma, color="0.5", lw=0.8, ls="--")
            p = self.whiteness_pvalue.get(name, math.nan)
            ax2.set_title(f"residual  (±2σ dashed, Ljung–Box p={p:.2g})", fontsize=9)
        axes[-1, 0].set_xlabel(f"time [s] ({self.trace_source} data)")
        axes[-1, 1].set_xlabel("time [s]")
        if path is not None:
            fig.savefig(path, dpi=110)
        return fig

    def summary(self) -> str:
        """A plain-text table of estimates, intervals and warnings."""
        lines = [f"{'parameter':<36}{'estimate':>12}{'stderr':>11}{'crlb_sd':>11}   95% interval"]
        for i, a in enumerate(self.addresses):
            lo, hi = self.ci95[i]
            lines.append(
                f"{a:<36}{self.estimates[i]:>12.6g}{self.stderr[i]:>11.3g}{self.crlb_sd[i]:>11.3g}   [{lo:.6g}, {hi:.6g}]"
            )
        if self.latency:
            lines.append("latency (s): " + ", ".join(f"{k}={v:g}" for k, v in self.latency.items()))
        lines += [f"profile: {check.describe()}" for check in self.quality.profiles]
        lines += [f"warning: {w}" for w in self.warnings]
        lines += [f"NOT OK: {reason}" for reason in self.quality.reasons]
        return "\n".join(lines)

    def __repr__(self) -> str:
        body = ", ".join(
            f"{a}={v:.6g}±{s:.2g}" for a, v, s in zip(self.addresses, self.estimates, self.stderr, strict=True)
        )
        return f"FitResult({body}, latency={dict(self.latency)}, warnings={len(self.warnings)})"
