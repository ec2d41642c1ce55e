"""`FitResult`: what :func:`sysid.fit` returns, with JSON, randomiser-config and figure exports.

Example:
    >>> import numpy as np
    >>> result = FitResult.from_estimates({"dof_damping[elbow]": (0.52, 0.01)})
    >>> result.ci95.round(3).tolist()
    [[0.5, 0.54]]
    >>> print(result.to_randomizers(width=2.0).strip())
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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from randomizers.addressing import Address
from randomizers.config import dump_effects
from randomizers.distributions import Uniform
from randomizers.effects import (
    ActuatorGain,
    Armature,
    Damping,
    Effect,
    Friction,
    FrictionLoss,
    Gravity,
    Mass,
    Stiffness,
)
from randomizers.files import atomic_write

__all__ = ["FitResult"]

_FRICTION_AXES = ("sliding", "torsional", "rolling")
_SINGLE_ELEMENT = {
    "dof_damping": (Damping, "joints"),
    "dof_armature": (Armature, "joints"),
    "dof_frictionloss": (FrictionLoss, "joints"),
    "jnt_stiffness": (Stiffness, "joints"),
    "body_mass": (Mass, "bodies"),
    "actuator_gain": (ActuatorGain, "actuators"),
}


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
        latency_steps: ``{"action": k, "obs": k}`` in control steps (``action`` may be fractional after
            sub-step refinement); only the latencies that were fitted or fixed.
        noise_std: ``{channel: sigma}`` estimated (or given) measurement noise, in the channel's units.
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
    """

    addresses: tuple[str, ...]
    estimates: np.ndarray
    stderr: np.ndarray
    ci95: np.ndarray
    crlb_sd: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    bounds: np.ndarray
    latency_steps: Mapping[str, float] = field(default_factory=dict)
    noise_std: Mapping[str, float] = field(default_factory=dict)
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

    def __post_init__(self) -> None:
        for name in ("estimates", "stderr", "ci95", "crlb_sd", "covariance", "correlation", "bounds"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))
        for name in ("trace_time", "trace_measured", "trace_predicted"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))
        object.__setattr__(self, "addresses", tuple(self.addresses))
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

    @classmethod
    def from_estimates(cls, estimates: Mapping[str, tuple[float, float]]) -> FitResult:
        """A result from ``{address: (estimate, stderr)}`` (no fit behind it): for configs and tests."""
        addresses = tuple(estimates)
        est = np.array([float(v[0]) for v in estimates.values()])
        se = np.array([float(v[1]) for v in estimates.values()])
        z = 1.959963984540054
        return cls(
            addresses=addresses,
            estimates=est,
            stderr=se,
            ci95=np.stack([est - z * se, est + z * se], axis=1),
            crlb_sd=se,
            covariance=np.diag(se**2),
            correlation=np.eye(len(addresses)),
            bounds=np.stack([np.full(est.shape, -np.inf), np.full(est.shape, np.inf)], axis=1),
        )

    @classmethod
    def from_json(cls, source: str | os.PathLike[str]) -> FitResult:
        """A result read back from :meth:`to_json` (a file path or the JSON text): estimates, intervals,
        latency, noise, fit percentages and warnings. The traces are not part of the JSON, so :meth:`plot` of
        the result is empty.

        Raises:
            ValueError: text that is not a fit result document.
        """
        text = str(source)
        if isinstance(source, os.PathLike) or not text.lstrip().startswith("{"):
            text = Path(source).read_text()
        try:
            data = json.loads(text)
            params = data["params"]
            base = cls.from_estimates({a: (v["estimate"], v["stderr"]) for a, v in params.items()})
        except (ValueError, KeyError, TypeError) as err:
            raise ValueError(f"`source` is not a sysid fit result JSON document: {err}") from err

        def num(value: Any) -> float:
            return math.nan if value is None else float(value)

        return replace(
            base,
            ci95=np.array([[num(v["ci95"][0]), num(v["ci95"][1])] for v in params.values()]).reshape(-1, 2),
            crlb_sd=np.array([num(v["crlb_sd"]) for v in params.values()]),
            latency_steps={k: float(v) for k, v in data.get("latency_steps", {}).items()},
            noise_std={k: num(v) for k, v in data.get("noise_std", {}).items()},
            fit_percent={k: num(v) for k, v in data.get("fit_percent", {}).items()},
            warnings=tuple(data.get("warnings", ())),
        )

    @property
    def params(self) -> dict[str, float]:
        """``{address: estimate}`` (what a calibrated environment is built from)."""
        return {a: float(v) for a, v in zip(self.addresses, self.estimates, strict=True)}

    def to_dict(self) -> dict[str, Any]:
        """The CLI's JSON document as a dict (see :meth:`to_json`)."""

        def num(value: float) -> float | None:
            return float(value) if math.isfinite(value) else None

        params = {
            a: {
                "estimate": num(self.estimates[i]),
                "stderr": num(self.stderr[i]),
                "ci95": [num(self.ci95[i, 0]), num(self.ci95[i, 1])],
                "crlb_sd": num(self.crlb_sd[i]),
            }
            for i, a in enumerate(self.addresses)
        }
        return {
            "params": params,
            "latency_steps": {k: float(v) for k, v in self.latency_steps.items()},
            "noise_std": {k: num(v) for k, v in self.noise_std.items()},
            "fit_percent": {k: num(v) for k, v in self.fit_percent.items()},
            "warnings": list(self.warnings),
        }

    def to_json(self, path: str | os.PathLike[str] | None = None, indent: int = 2) -> str:
        """``{"params": {address: {"estimate", "stderr", "ci95": [lo, hi], "crlb_sd"}}, "latency_steps",
        "noise_std", "fit_percent", "warnings"}``; written atomically to ``path`` when given. Non-finite
        numbers become ``null``."""
        text = json.dumps(self.to_dict(), indent=indent)
        if path is not None:
            atomic_write(path, text + "\n")
        return text

    def to_effects(self, width: float = 2.0) -> list[Effect]:
        """Randomiser effects ``set`` to ``Uniform(estimate ± width · stderr)`` per parameter.

        The range is clipped to the fit bounds and, for quantities that must stay non-negative, at 0.
        Parameters without a single-element effect (multi-dof components, raw fields such as
        ``actuator_biasprm``) are left out; :meth:`to_randomizers` lists them in a comment.

        Raises:
            ValueError: ``width`` is not a positive finite number.
        """
        if isinstance(width, bool) or not isinstance(width, (int, float)) or not math.isfinite(width) or width <= 0:
            raise ValueError(f"`width` must be a finite number > 0 (standard errors each side). Received {width!r}.")
        effects: list[Effect] = []
        for effect in (self._effect(i, float(width)) for i in range(len(self.addresses))):
            if effect is not None:
                effects.append(effect)
        return effects

    def _range(self, i: int, width: float, nonnegative: bool) -> tuple[float, float]:
        est, se = float(self.estimates[i]), float(self.stderr[i])
        lo_b, hi_b = float(self.bounds[i, 0]), float(self.bounds[i, 1])
        if not math.isfinite(se):
            lo, hi = lo_b, hi_b
        else:
            half = max(width * se, 1e-12 * max(abs(est), 1.0))
            lo, hi = max(est - half, lo_b), min(est + half, hi_b)
        if nonnegative:
            lo = max(lo, 0.0)
        if not hi > lo:
            hi = lo + 1e-12 * max(abs(lo), 1.0)
        return round(lo, 12), round(hi, 12)

    def _effect(self, i: int, width: float) -> Effect | None:
        address = Address.parse(self.addresses[i])
        if address.field in _SINGLE_ELEMENT and address.index is None:
            cls, selector = _SINGLE_ELEMENT[address.field]
            return cls(set=Uniform(*self._range(i, width, True)), **{selector: address.element})  # type: ignore[arg-type]
        if address.field == "geom_friction" and address.index is not None and address.index < 3:
            return Friction(
                set=Uniform(*self._range(i, width, True)), geoms=address.element, axis=_FRICTION_AXES[address.index]
            )
        if address.field == "gravity" and address.element in ("x", "y", "z"):
            return Gravity(set=Uniform(*self._range(i, width, False)), axes=address.element)
        return None

    def to_randomizers(self, width: float = 2.0, path: str | os.PathLike[str] | None = None) -> str:
        """A randomiser YAML config (``randomizers.load_effects`` reads it) centred on the estimates.

        Args:
            width: half-width of each uniform range in standard errors (2 ≈ the 95% interval).
            path: when given, the YAML is also written there atomically.
        """
        effects = self.to_effects(width)
        text = dump_effects(effects)
        kept = {i for i in range(len(self.addresses)) if self._effect(i, float(width)) is not None}
        notes = [
            f"# not expressible as an effect: {self.addresses[i]} = {self.estimates[i]!r}"
            for i in range(len(self.addresses))
            if i not in kept
        ]
        notes += [f"# fitted {name}_latency: {value!r} control steps" for name, value in self.latency_steps.items()]
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
        if self.latency_steps:
            lines.append("latency (control steps): " + ", ".join(f"{k}={v:g}" for k, v in self.latency_steps.items()))
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def __repr__(self) -> str:
        body = ", ".join(
            f"{a}={v:.6g}±{s:.2g}" for a, v, s in zip(self.addresses, self.estimates, self.stderr, strict=True)
        )
        return f"FitResult({body}, latency_steps={dict(self.latency_steps)}, warnings={len(self.warnings)})"
