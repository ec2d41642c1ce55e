"""The gap report: every number of a sim-to-real study, with honest intervals, as HTML, Markdown, JSON and PNG.

:meth:`GapReport.build` turns an :class:`~sim2real.evaluation.Evaluation` (plus, optionally, a sysid
:class:`~sysid.result.FitResult` and a contact sheet of the visual randomisation) into a frozen
:class:`GapReport` that holds every number the report shows: per policy and condition the mean and IQM
(stratified-bootstrap intervals), CVaR, worst case and success rate (Wilson); the absolute and relative gap from
the nominal sim and from the randomised sim to the "real" target (paired when both conditions are simulated,
since row ``e`` is the same initial state everywhere; unpaired for measured returns); robustness curves and
radii per sweep; grid means for heatmaps; sim-vs-real agreement across policies (SRCC, MMRV); the probability
that one policy beats another on the target. Warnings raised by :mod:`sim2real.metrics` (e.g. too few runs for
the interval asked) are collected into the report rather than lost.

Reproducible: every interval draws from its own generator, :func:`stream` ``(seed, *key)``, keyed by what it
measures, so :meth:`GapReport.to_json` is bitwise identical for the same evaluation and ``rng``, and adding a
policy or a sweep does not move any other interval. Figures are rendered with matplotlib's Agg canvas at a fixed
dpi and without version or time stamps, so they too are byte-identical for the same data.

Configurations of hidden conditions (a "real" twin with held-out parameters) and the sysid ground truth appear
only in the last section, "Appendix: the real target".

Example:
    >>> import numpy as np
    >>> from sim2real.evaluation import Evaluation, nominal, real
    >>> rng = np.random.default_rng(0)
    >>> sim = rng.normal(100.0, 5.0, 20)
    >>> evaluation = Evaluation(
    ...     task="demo", seed=0, episodes=20, max_steps=None, policies=("ppo",),
    ...     conditions=(nominal(), real(params={"body_mass[arm]": 1.2})),
    ...     returns={"ppo": {"sim": sim, "real": sim - rng.normal(10.0, 2.0, 20)}},
    ...     successes={}, lengths={}, draws={})
    >>> report = GapReport.build(evaluation, rng=0)
    >>> g = report.gap("ppo")
    >>> g.paired, g.absolute.low < g.absolute.value < g.absolute.high
    (True, True)
    >>> print(report.summary().splitlines()[1])
    'ppo' loses 10.2% [9.6%, 10.9%] from sim to real (gap 10.12 [9.528, 10.76], paired).
"""

from __future__ import annotations

import base64
import hashlib
import html
import io
import json
import math
import os
import re
import shutil
import tempfile
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from randomizers.files import atomic_write
from sim2real import metrics
from sim2real.evaluation import Condition, Evaluation
from sim2real.metrics import Estimate, RobustnessRadius

if TYPE_CHECKING:
    from sim2real.pixels import ContactSheet
    from sysid.result import FitResult

__all__ = [
    "APPENDIX",
    "Agreement",
    "ConditionInfo",
    "ConditionStats",
    "FitParameter",
    "GapReport",
    "GapStats",
    "GridMeans",
    "Improvement",
    "ParameterDraws",
    "ReportFiles",
    "RobustnessCurve",
    "html_page",
    "png_bytes",
    "stream",
]

#: Condition kinds summarised one by one (sweep and grid points go to the robustness curves and heatmaps).
MAIN_KINDS: tuple[str, ...] = ("nominal", "randomized", "real", "measured")
_DPI = 100
_PNG_METADATA = {"Software": None}  # no matplotlib version stamp: PNGs depend on the data only
_STYLE = (
    "body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;max-width:1100px;margin:2em auto;"
    "padding:0 1em;color:#222;line-height:1.45}"
    "h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}"
    "table{border-collapse:collapse;margin:.6em 0;font-size:.92em}"
    "th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}"
    "th:first-child,td:first-child{text-align:left}th{background:#f3f3f3}"
    "pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.85em}"
    "img{max-width:100%;height:auto}figure{margin:1em 0}figcaption{font-size:.85em;color:#555}"
    ".summary{background:#eef4fb;border-left:4px solid #3a78c2;padding:.6em 1em}"
    ".muted{color:#666;font-size:.9em}"
)


# ------------------------------------------------------------------------------------------------ result objects


@dataclass(frozen=True)
class ConditionStats:
    """Summary statistics of one policy on one (non-sweep) condition.

    Attributes:
        policy: policy name.
        condition: condition name.
        kind: the condition's kind (``nominal``, ``randomized``, ``real`` or ``measured``).
        n: episodes (runs).
        mean: mean return with a stratified-bootstrap interval.
        iqm: interquartile mean with a stratified-bootstrap interval.
        cvar: mean of the worst ``alpha`` fraction of returns, with an interval.
        worst: the lowest return.
        success: success rate with a Wilson interval, or None when the condition reported no successes.
    """

    policy: str
    condition: str
    kind: str
    n: int
    mean: Estimate
    iqm: Estimate
    cvar: Estimate
    worst: float
    success: Estimate | None

    def statistic(self, name: str) -> Estimate:
        """The ``mean`` or ``iqm`` estimate."""
        return self.mean if name == "mean" else self.iqm


@dataclass(frozen=True)
class GapStats:
    """The performance one policy loses from ``reference`` to ``target`` (:func:`sim2real.metrics.gap`).

    Attributes:
        policy: policy name.
        reference: the reference condition (e.g. ``"sim"`` or ``"randomized"``).
        target: the target condition (e.g. ``"real"``).
        absolute: ``stat(reference) - stat(target)``; positive when the target does worse.
        relative: ``absolute / |stat(reference)|`` (NaN when ``stat(reference)`` is 0).
        paired: True when both conditions are simulated (row ``e`` is the same initial state), so runs were
            resampled jointly; False for measured returns (resampled independently, counts may differ).
        n_reference: runs on the reference.
        n_target: runs on the target.
        statistic: ``"mean"`` or ``"iqm"``.
    """

    policy: str
    reference: str
    target: str
    absolute: Estimate
    relative: Estimate
    paired: bool
    n_reference: int
    n_target: int
    statistic: str


@dataclass(frozen=True)
class RobustnessCurve:
    """One policy's return along a one-parameter sweep, and its robustness radius.

    Attributes:
        policy: policy name.
        sweep: the sweep's name.
        axis: the swept parameter label, e.g. ``"Damping.scale"``.
        values: grid values, strictly increasing, shape ``(K,)``.
        conditions: the condition name at each grid value.
        nominal: the unperturbed grid value.
        points: the statistic at each grid value with its interval, shape ``(K,)``.
        radius: the largest distance from ``nominal`` keeping ``fraction`` of the nominal return, or None (see
            ``note``).
        fraction: the fraction of the nominal return to keep.
        note: why there is no radius ("" when there is one).
        statistic: ``"mean"`` or ``"iqm"``.
    """

    policy: str
    sweep: str
    axis: str
    values: tuple[float, ...]
    conditions: tuple[str, ...]
    nominal: float
    points: tuple[Estimate, ...]
    radius: RobustnessRadius | None
    fraction: float
    note: str
    statistic: str

    @property
    def threshold(self) -> float | None:
        """``fraction`` times the nominal return (the line the radius is measured against), or None."""
        return None if self.radius is None else self.fraction * self.radius.nominal_return


@dataclass(frozen=True)
class GridMeans:
    """One policy's statistic over a two-parameter grid (a heatmap).

    Attributes:
        policy: policy name.
        grid: the grid's name.
        axes: the two parameter labels (x, y).
        x: x values, increasing, shape ``(I,)``.
        y: y values, increasing, shape ``(J,)``.
        values: ``values[i][j]`` is the statistic at ``(x[i], y[j])`` (NaN where the grid has no point).
        nominal: the unperturbed ``(x, y)``.
        statistic: ``"mean"`` or ``"iqm"``.
    """

    policy: str
    grid: str
    axes: tuple[str, str]
    x: tuple[float, ...]
    y: tuple[float, ...]
    values: tuple[tuple[float, ...], ...]
    nominal: tuple[float, float]
    statistic: str


@dataclass(frozen=True)
class Agreement:
    """Whether a simulated condition ranks the policies as the target does (SIMPLER's SRCC and MMRV).

    Attributes:
        reference: the simulated condition compared (e.g. ``"sim"``).
        target: the target condition (e.g. ``"real"``).
        policies: the policies compared (those with returns on both).
        srcc: Pearson correlation of the per-policy statistic, or None when undefined (see ``note``).
        mmrv: mean maximum rank violation (0 = same ranking), in return units.
        note: why a value is missing ("" otherwise).
    """

    reference: str
    target: str
    policies: tuple[str, ...]
    srcc: Estimate | None
    mmrv: Estimate | None
    note: str


@dataclass(frozen=True)
class Improvement:
    """``P(x > y)``: the chance an episode of policy ``x`` beats one of policy ``y`` on ``condition``.

    Attributes:
        condition: the condition (the target).
        x: first policy.
        y: second policy.
        probability: the estimate with a bootstrap interval; 0.5 means neither is better.
    """

    condition: str
    x: str
    y: str
    probability: Estimate


@dataclass(frozen=True)
class ParameterDraws:
    """The values one addressed parameter took over the episodes of one condition.

    Attributes:
        address: the parameter address, e.g. ``"dof_damping[elbow]"``.
        low: smallest value drawn.
        mean: mean value drawn.
        high: largest value drawn.
        n: episodes with a value.
    """

    address: str
    low: float
    mean: float
    high: float
    n: int


@dataclass(frozen=True)
class ConditionInfo:
    """What a condition is, for the report.

    Attributes:
        name: condition name.
        kind: condition kind.
        description: one line.
        simulated: False for measured returns.
        hidden: the configuration is revealed only in the appendix.
        config: the configuration as canonical JSON text (effects, params; measured returns left out).
        draws: the parameter values drawn per episode, summarised.
        sweep: the sweep or grid a point belongs to, else None.
        value: the point's coordinates on the sweep's axes (empty otherwise).
    """

    name: str
    kind: str
    description: str
    simulated: bool
    hidden: bool
    config: str
    draws: tuple[ParameterDraws, ...]
    sweep: str | None = None
    value: tuple[float, ...] = ()


@dataclass(frozen=True)
class FitParameter:
    """One parameter of a sysid fit.

    Attributes:
        address: parameter address.
        estimate: fitted value.
        stderr: standard error.
        low: lower end of the 95% interval.
        high: upper end of the 95% interval.
        truth: the true value from the log's metadata (a simulated twin), or None. Shown only in the appendix.
    """

    address: str
    estimate: float
    stderr: float
    low: float
    high: float
    truth: float | None


@dataclass(frozen=True)
class ReportFiles:
    """The files :meth:`GapReport.write` wrote.

    Attributes:
        directory: the output directory.
        html: ``report.html`` (self-contained).
        markdown: ``report.md`` (links to ``figures/``).
        json: ``report.json`` (written last: its presence marks a complete report).
        figures: ``figures/<name>.png``, in :meth:`GapReport.figure_names` order.
    """

    directory: Path
    html: Path
    markdown: Path
    json: Path
    figures: tuple[Path, ...]


# ------------------------------------------------------------------------------------------------ helpers

#: The heading of the last section, the only place hidden configurations and sysid ground truth appear.
APPENDIX = "Appendix: the real target"


@dataclass(frozen=True)
class _Block:
    """One piece of the document (plain text; escaped when rendered): a heading (``h1``-``h3``; ``style`` is its
    anchor), a paragraph ``p`` (lines; ``style`` is its CSS class), ``code``, a ``list`` of ``items``, a ``table``
    (``header``, ``rows``) or a ``figure`` (``items[0]`` its name, ``text`` its caption)."""

    kind: str
    text: str = ""
    header: tuple[str, ...] = ()
    rows: tuple[tuple[str, ...], ...] = ()
    items: tuple[str, ...] = ()
    style: str = ""


def stream(seed: int, *key: str) -> np.random.Generator:
    """The generator one interval of the report draws from: a child of ``seed`` keyed by ``key``.

    Keys name what is measured, e.g. ``("gap", policy, reference, target)``, ``("mean", policy, condition)``,
    ``("curve", policy, sweep)``, ``("radius", policy, sweep)``, ``("srcc", reference, target)``,
    ``("mmrv", reference, target)``, ``("improvement", condition, x, y)``; so one interval never depends on which
    other policies, conditions or sweeps are in the report, and any of them can be recomputed alone.

    Example:
        >>> a, b = stream(0, "gap", "ppo", "sim", "real"), stream(0, "gap", "ppo", "sim", "real")
        >>> bool(a.random() == b.random() != stream(0, "gap", "sac", "sim", "real").random())
        True
    """
    digest = hashlib.sha256("\x1f".join(key).encode("utf-8")).digest()
    spawn = tuple(int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4))
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=spawn))


def _root_seed(rng: np.random.Generator | int) -> int:
    if isinstance(rng, np.random.Generator):
        return int(rng.integers(0, 2**63))
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0:
        return int(rng)
    raise TypeError(f"`rng` must be a numpy.random.Generator or an int seed >= 0. Received {rng!r}.")


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _estimate_dict(e: Estimate | None) -> dict[str, Any] | None:
    if e is None:
        return None
    return {
        "value": _finite(e.value),
        "low": _finite(e.low),
        "high": _finite(e.high),
        "confidence": e.confidence,
        "n": e.n,
        "method": e.method,
    }


def _num(value: float, digits: int = 4) -> str:
    return f"{value:.{digits}g}" if math.isfinite(value) else "n/a"


def _cell(e: Estimate | None) -> str:
    if e is None:
        return "n/a"
    return f"{_num(e.value)} [{_num(e.low)}, {_num(e.high)}]"


def _pct(e: Estimate) -> str:
    return f"{_pct1(e.value)} [{_pct1(e.low)}, {_pct1(e.high)}]"


def _pct1(value: float) -> str:
    return f"{100.0 * value:.1f}%" if math.isfinite(value) else "n/a"


def _slug(name: str) -> str:
    slug = re.sub(r"[^A-Za-z0-9]+", "-", name).strip("-").lower()[:60].strip("-")
    return slug or "sweep"


def _tex(text: str) -> str:
    """A label matplotlib draws literally (a ``$`` would start mathtext)."""
    return text.replace("$", r"\$")


def _md(text: str) -> str:
    """Markdown-safe inline text: no raw HTML, no table breaks."""
    text = " ".join(str(text).split())
    return re.sub(r"([\\`*_\[\]<>|#])", r"\\\1", text)


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Mapping):
        return dict(value)
    if isinstance(value, (tuple, set, frozenset)):
        return list(value)
    return str(value)


def _config_text(cond: Condition) -> str:
    config = {k: v for k, v in cond.config().items() if k not in ("returns", "name", "kind", "hidden", "description")}
    return json.dumps(config, sort_keys=True, default=_json_default)


def _draws(evaluation: Evaluation, name: str) -> tuple[ParameterDraws, ...]:
    out = []
    for address, values in sorted(evaluation.draws.get(name, {}).items()):
        arr = np.asarray(values, dtype=np.float64)
        ok = arr[np.isfinite(arr)]
        if ok.size:
            out.append(ParameterDraws(address, float(ok.min()), float(ok.mean()), float(ok.max()), int(ok.size)))
    return tuple(out)


def _versions() -> tuple[tuple[str, str], ...]:
    from importlib.metadata import PackageNotFoundError, version

    out = []
    for package in ("sim2real", "numpy", "scipy", "matplotlib", "mujoco"):
        try:
            out.append((package, version(package)))
        except PackageNotFoundError:
            out.append((package, "not installed"))
    return tuple(out)


class _Warnings:
    """Collects warnings raised inside :meth:`where` blocks, grouped by message, with where they arose."""

    def __init__(self) -> None:
        self.by_message: dict[str, list[str]] = {}

    @contextmanager
    def where(self, context: str) -> Iterator[None]:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield
        for w in caught:
            self.by_message.setdefault(f"{w.category.__name__}: {w.message}", []).append(context)

    def lines(self) -> tuple[str, ...]:
        out = []
        for message, contexts in self.by_message.items():
            shown = "; ".join(contexts[:4]) + ("; ..." if len(contexts) > 4 else "")
            out.append(f"{message} ({len(contexts)}x: {shown})")
        return tuple(out)


def _resolve(
    evaluation: Evaluation, argument: str, name: str | None, default: str, kinds: tuple[str, ...]
) -> str | None:
    names = [c.name for c in evaluation.conditions]
    if name is not None:
        if not isinstance(name, str) or name not in names:
            import difflib

            close = difflib.get_close_matches(str(name), names, n=3)
            hint = f" Close matches: {close}." if close else ""
            raise ValueError(f"`{argument}` must be one of the conditions {names}. Received {name!r}.{hint}")
        return name
    if default in names and evaluation.condition(default).kind in kinds:
        return default
    for kind in kinds:  # in order of preference
        found = evaluation.of_kind(kind)
        if found:
            return found[0].name
    return None


def _check_unit(value: Any, argument: str, closed_high: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"`{argument}` must be a number in (0, 1{']' if closed_high else ')'}. Received {value!r}.")
    ok = 0.0 < float(value) <= 1.0 if closed_high else 0.0 < float(value) < 1.0
    if not ok:
        raise ValueError(f"`{argument}` must be in (0, 1{']' if closed_high else ')'}. Received {value!r}.")
    return float(value)


def _contact_image(contact_sheet: Any) -> np.ndarray | None:
    if contact_sheet is None:
        return None
    image = getattr(contact_sheet, "image", contact_sheet)
    arr = np.asarray(image) if isinstance(image, np.ndarray) else None
    if arr is None or arr.dtype != np.uint8 or arr.ndim != 3 or arr.shape[2] not in (3, 4) or 0 in arr.shape:
        described = f"an array of shape {arr.shape} and dtype {arr.dtype}" if arr is not None else type(image).__name__
        raise TypeError(
            "`contact_sheet` must be a ContactSheet (sim2real.contact_sheet) or an (H, W, 3) uint8 image. "
            f"Received {described}."
        )
    out = np.array(arr[..., :3], copy=True)
    out.setflags(write=False)
    return out


# ------------------------------------------------------------------------------------------------ the report


@dataclass(frozen=True)
class GapReport:
    """Every number of a sim-to-real study (see the module docstring); build it with :meth:`build`.

    Tuples hold one entry per (policy, condition), (policy, reference, target), (policy, sweep) etc., in the
    evaluation's policy and condition order. Look entries up with :meth:`stats_for`, :meth:`gap` and :meth:`curve`.

    Attributes:
        title: report title.
        task: the evaluated task id.
        seed: the evaluation's root seed.
        episodes: episodes per (policy, simulated condition).
        max_steps: episode-length cap of the evaluation, or None.
        env_steps: environment steps the evaluation took.
        policies: policy names.
        conditions: every condition of the evaluation, with its configuration and draws.
        reference: the nominal-sim condition the gaps start from, or None.
        randomized: the randomised-sim condition, or None.
        target: the "real" condition (twin or measured), or None.
        statistic: ``"mean"`` or ``"iqm"``: the statistic of gaps, curves, radii, heatmaps and agreement.
        confidence: interval coverage.
        alpha: CVaR tail fraction.
        fraction: fraction of the nominal return a robustness radius keeps.
        num_resamples: bootstrap resamples.
        rng_seed: the root seed of :func:`stream` (an int ``rng`` itself; drawn once from a Generator).
        stats: per (policy, non-sweep condition) summaries.
        gaps: reference -> target and randomized -> target gaps per policy.
        robustness: per (policy, one-parameter sweep) curves and radii.
        grids: per (policy, two-parameter grid) heatmap values.
        agreement: sim-vs-target ranking agreement across policies (reference and randomized vs target).
        improvements: ``P(x > y)`` on the target for each pair of policies (x before y in policy order).
        fit_parameters: the sysid estimates, when a fit was given.
        fit_warnings: the fit's own warnings.
        fit_percent: ``(channel, NRMSE fit %)`` on held-out data.
        contact_sheet_shape: ``(H, W, 3)`` of the contact sheet image, or None.
        notes: the caller's notes.
        skipped: analyses left out and why (e.g. a non-positive nominal return for a radius).
        warnings: warnings raised while computing (e.g. :class:`~sim2real.metrics.FewSamplesWarning`), grouped.
        versions: ``(package, version)`` of the packages the numbers and figures depend on.
        fit: the FitResult (for its figure; not compared, not serialised beyond the fields above).
        contact_sheet: the contact sheet image (not compared, not serialised).
    """

    title: str
    task: str
    seed: int
    episodes: int
    max_steps: int | None
    env_steps: int
    policies: tuple[str, ...]
    conditions: tuple[ConditionInfo, ...]
    reference: str | None
    randomized: str | None
    target: str | None
    statistic: str
    confidence: float
    alpha: float
    fraction: float
    num_resamples: int
    rng_seed: int
    stats: tuple[ConditionStats, ...]
    gaps: tuple[GapStats, ...]
    robustness: tuple[RobustnessCurve, ...]
    grids: tuple[GridMeans, ...]
    agreement: tuple[Agreement, ...]
    improvements: tuple[Improvement, ...]
    fit_parameters: tuple[FitParameter, ...]
    fit_warnings: tuple[str, ...]
    fit_percent: tuple[tuple[str, float], ...]
    contact_sheet_shape: tuple[int, int, int] | None
    notes: tuple[str, ...]
    skipped: tuple[str, ...]
    warnings: tuple[str, ...]
    versions: tuple[tuple[str, str], ...]
    fit: FitResult | None = field(default=None, compare=False, repr=False)
    contact_sheet: np.ndarray | None = field(default=None, compare=False, repr=False)

    # -------------------------------------------------------------------------------------------- build

    @classmethod
    def build(
        cls,
        evaluation: Evaluation,
        *,
        fit: FitResult | None = None,
        contact_sheet: ContactSheet | np.ndarray | None = None,
        reference: str | None = None,
        randomized: str | None = None,
        target: str | None = None,
        statistic: str = "mean",
        confidence: float = 0.95,
        alpha: float = 0.1,
        fraction: float = 0.8,
        num_resamples: int = 2000,
        rng: np.random.Generator | int = 0,
        title: str | None = None,
        notes: Sequence[str] | str = (),
    ) -> GapReport:
        """Computes every number of the report from an evaluation.

        Args:
            evaluation: from :func:`sim2real.evaluation.evaluate`.
            fit: a :class:`sysid.result.FitResult` to report (estimates, intervals, the fit figure).
            contact_sheet: a :class:`sim2real.pixels.ContactSheet` or an ``(H, W, 3)`` uint8 image.
            reference: the nominal-sim condition; default ``"sim"`` if it is a nominal condition, else the first
                nominal condition (none: no reference gaps).
            randomized: the randomised-sim condition; default ``"randomized"`` if it is one, else the first
                randomized condition.
            target: the "real" condition; default ``"real"`` if it is a real or measured condition, else the first
                real condition, else the first measured one.
            statistic: ``"mean"`` or ``"iqm"`` for gaps, curves, radii, heatmaps and agreement.
            confidence: interval coverage in (0, 1).
            alpha: CVaR tail fraction in (0, 1).
            fraction: fraction of the nominal return a robustness radius keeps, in (0, 1].
            num_resamples: bootstrap resamples per interval.
            rng: int seed or Generator; every interval draws from :func:`stream` ``(seed, ...)``.
            title: report title (default ``"Sim-to-real gap report: <task>"``).
            notes: free-text notes shown in the report (a string is one note).

        Raises:
            TypeError: an argument of the wrong type.
            ValueError: a named condition that does not exist, reference/randomized equal to the target, or an
                argument out of range.
        """
        if not isinstance(evaluation, Evaluation):
            raise TypeError(
                f"`evaluation` must be a sim2real.evaluation.Evaluation. Received {type(evaluation).__name__}."
            )
        if statistic not in ("mean", "iqm"):
            raise ValueError(f"`statistic` must be one of 'mean', 'iqm'. Received {statistic!r}.")
        confidence = _check_unit(confidence, "confidence")
        alpha = _check_unit(alpha, "alpha")
        fraction = _check_unit(fraction, "fraction", closed_high=True)
        if isinstance(num_resamples, bool) or not isinstance(num_resamples, (int, np.integer)) or num_resamples < 1:
            raise ValueError(f"`num_resamples` must be an int >= 1. Received {num_resamples!r}.")
        num_resamples = int(num_resamples)
        seed = _root_seed(rng)
        if title is not None and not isinstance(title, str):
            raise TypeError(f"`title` must be a string or None. Received {type(title).__name__}.")
        notes = (notes,) if isinstance(notes, str) else tuple(notes)
        if not all(isinstance(n, str) for n in notes):
            raise TypeError(f"`notes` must be a sequence of strings. Received {notes!r}.")
        if fit is not None:
            from sysid.result import FitResult

            if not isinstance(fit, FitResult):
                raise TypeError(f"`fit` must be a sysid FitResult or None. Received {type(fit).__name__}.")
        image = _contact_image(contact_sheet)

        ref = _resolve(evaluation, "reference", reference, "sim", ("nominal",))
        rand = _resolve(evaluation, "randomized", randomized, "randomized", ("randomized",))
        tgt = _resolve(evaluation, "target", target, "real", ("real", "measured"))
        for argument, name in (("reference", ref), ("randomized", rand)):
            if name is not None and name == tgt:
                raise ValueError(f"`{argument}` must differ from `target`. Received {name!r} for both.")

        builder = _Builder(evaluation, statistic, confidence, alpha, fraction, num_resamples, seed)
        stats = builder.stats()
        gaps = builder.gaps([r for r in (ref, rand) if r is not None], tgt)
        curves = builder.curves()
        grids = builder.grids()
        agreement = builder.agreement([r for r in (ref, rand) if r is not None], tgt)
        improvements = builder.improvements(tgt)
        for role, name in (("reference", ref), ("randomized", rand), ("target", tgt)):
            if name is None:
                builder.skip(f"no {role} condition in the evaluation: the gaps that need it are left out.")

        fit_parameters: tuple[FitParameter, ...] = ()
        fit_warnings: tuple[str, ...] = ()
        fit_percent: tuple[tuple[str, float], ...] = ()
        if fit is not None:
            truths = dict(fit.true_params or {})
            fit_parameters = tuple(
                FitParameter(
                    address=a,
                    estimate=float(fit.estimates[i]),
                    stderr=float(fit.stderr[i]),
                    low=float(fit.ci95[i, 0]),
                    high=float(fit.ci95[i, 1]),
                    truth=float(truths[a]) if a in truths else None,
                )
                for i, a in enumerate(fit.addresses)
            )
            fit_warnings = tuple(fit.warnings)
            fit_percent = tuple((str(k), float(v)) for k, v in fit.fit_percent.items())

        infos = tuple(
            ConditionInfo(
                name=c.name,
                kind=c.kind,
                description=c.description,
                simulated=c.simulated,
                hidden=c.hidden,
                config=_config_text(c),
                draws=_draws(evaluation, c.name),
                sweep=c.sweep,
                value=tuple(float(v) for v in c.value),
            )
            for c in evaluation.conditions
        )
        return cls(
            title=title if title is not None else f"Sim-to-real gap report: {evaluation.task}",
            task=evaluation.task,
            seed=int(evaluation.seed),
            episodes=int(evaluation.episodes),
            max_steps=evaluation.max_steps,
            env_steps=int(evaluation.env_steps),
            policies=tuple(evaluation.policies),
            conditions=infos,
            reference=ref,
            randomized=rand,
            target=tgt,
            statistic=statistic,
            confidence=confidence,
            alpha=alpha,
            fraction=fraction,
            num_resamples=num_resamples,
            rng_seed=seed,
            stats=stats,
            gaps=gaps,
            robustness=curves,
            grids=grids,
            agreement=agreement,
            improvements=improvements,
            fit_parameters=fit_parameters,
            fit_warnings=fit_warnings,
            fit_percent=fit_percent,
            contact_sheet_shape=None if image is None else (int(image.shape[0]), int(image.shape[1]), 3),
            notes=notes,
            skipped=tuple(builder.skipped),
            warnings=builder.warnings.lines(),
            versions=_versions(),
            fit=fit,
            contact_sheet=image,
        )

    # -------------------------------------------------------------------------------------------- lookups

    def stats_for(self, policy: str, condition: str) -> ConditionStats:
        """The :class:`ConditionStats` of ``policy`` on ``condition``.

        Raises:
            KeyError: no such entry (naming what exists).
        """
        for s in self.stats:
            if s.policy == policy and s.condition == condition:
                return s
        raise KeyError(
            f"no statistics for policy {policy!r} on condition {condition!r}. "
            f"Available: {sorted({(s.policy, s.condition) for s in self.stats})}."
        )

    def gap(self, policy: str, reference: str | None = None, target: str | None = None) -> GapStats:
        """The :class:`GapStats` of ``policy`` from ``reference`` (default :attr:`reference`) to ``target``
        (default :attr:`target`).

        Raises:
            KeyError: no such gap (naming the gaps that exist).
        """
        reference = self.reference if reference is None else reference
        target = self.target if target is None else target
        for g in self.gaps:
            if g.policy == policy and g.reference == reference and g.target == target:
                return g
        raise KeyError(
            f"no gap for policy {policy!r} from {reference!r} to {target!r}. "
            f"Available: {[(g.policy, g.reference, g.target) for g in self.gaps]}."
        )

    def curve(self, policy: str, sweep: str) -> RobustnessCurve:
        """The :class:`RobustnessCurve` of ``policy`` on ``sweep``.

        Raises:
            KeyError: no such curve (naming the curves that exist).
        """
        for c in self.robustness:
            if c.policy == policy and c.sweep == sweep:
                return c
        raise KeyError(
            f"no robustness curve for policy {policy!r} on sweep {sweep!r}. "
            f"Available: {[(c.policy, c.sweep) for c in self.robustness]}."
        )

    # -------------------------------------------------------------------------------------------- text

    def summary(self) -> str:
        """The report's opening paragraph as plain text: the gap before and after randomisation per policy.

        The first line names the study; then one line per policy (at most 8), then agreement and warnings.
        """
        lines = [
            f"{len(self.policies)} polic{'y' if len(self.policies) == 1 else 'ies'} evaluated on {self.task} under "
            f"{len(self.conditions)} condition(s), {self.episodes} episode(s) per simulated condition (seed "
            f"{self.seed})."
        ]
        for policy in self.policies[:8]:
            parts = []
            for ref in (self.reference, self.randomized):
                if ref is None or self.target is None:
                    continue
                try:
                    g = self.gap(policy, ref, self.target)
                except KeyError:
                    continue
                parts.append(_gap_phrase(g))
            if parts:
                lines.append(f"{policy!r} " + "; ".join(parts) + ".")
        if len(self.policies) > 8:
            lines.append(f"... and {len(self.policies) - 8} more policies (see the gap table).")
        for a in self.agreement:
            if a.srcc is not None:
                lines.append(
                    f"{a.reference} ranks the {len(a.policies)} policies like {a.target} with correlation "
                    f"{_cell(a.srcc)} (MMRV {_cell(a.mmrv)})."
                )
        if self.target is None:
            lines.append("No target condition: no sim-to-real gap is reported.")
        if self.warnings:
            lines.append(f"{len(self.warnings)} kind(s) of warning were raised while computing (see Warnings).")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """Every number of the report as plain JSON-ready data (non-finite numbers become None).

        Hidden conditions' configurations and draws and the sysid ground truth are under ``"appendix"``.
        """

        def cond(info: ConditionInfo) -> dict[str, Any]:
            out: dict[str, Any] = {
                "name": info.name,
                "kind": info.kind,
                "description": info.description,
                "simulated": info.simulated,
                "hidden": info.hidden,
            }
            if not info.hidden:
                out["config"] = json.loads(info.config)
                out["draws"] = [_draw_dict(d) for d in info.draws]
            return out

        hidden = [c for c in self.conditions if c.hidden]
        return {
            "title": self.title,
            "summary": self.summary(),
            "evaluation": {
                "task": self.task,
                "seed": self.seed,
                "episodes": self.episodes,
                "max_steps": self.max_steps,
                "env_steps": self.env_steps,
                "policies": list(self.policies),
                "conditions": [cond(c) for c in self.conditions],
            },
            "roles": {"reference": self.reference, "randomized": self.randomized, "target": self.target},
            "settings": {
                "statistic": self.statistic,
                "confidence": self.confidence,
                "alpha": self.alpha,
                "fraction": self.fraction,
                "num_resamples": self.num_resamples,
                "rng_seed": self.rng_seed,
            },
            "stats": [
                {
                    "policy": s.policy,
                    "condition": s.condition,
                    "kind": s.kind,
                    "n": s.n,
                    "mean": _estimate_dict(s.mean),
                    "iqm": _estimate_dict(s.iqm),
                    "cvar": _estimate_dict(s.cvar),
                    "worst": _finite(s.worst),
                    "success": _estimate_dict(s.success),
                }
                for s in self.stats
            ],
            "gaps": [
                {
                    "policy": g.policy,
                    "reference": g.reference,
                    "target": g.target,
                    "absolute": _estimate_dict(g.absolute),
                    "relative": _estimate_dict(g.relative),
                    "paired": g.paired,
                    "n_reference": g.n_reference,
                    "n_target": g.n_target,
                    "statistic": g.statistic,
                }
                for g in self.gaps
            ],
            "robustness": [
                {
                    "policy": c.policy,
                    "sweep": c.sweep,
                    "axis": c.axis,
                    "values": list(c.values),
                    "conditions": list(c.conditions),
                    "nominal": c.nominal,
                    "points": [_estimate_dict(p) for p in c.points],
                    "fraction": c.fraction,
                    "statistic": c.statistic,
                    "note": c.note,
                    "radius": None
                    if c.radius is None
                    else {
                        "radius": _estimate_dict(c.radius.radius),
                        "nominal_return": _finite(c.radius.nominal_return),
                        "threshold": _finite(c.threshold if c.threshold is not None else math.nan),
                        "censored": c.radius.censored,
                    },
                }
                for c in self.robustness
            ],
            "grids": [
                {
                    "policy": g.policy,
                    "grid": g.grid,
                    "axes": list(g.axes),
                    "x": list(g.x),
                    "y": list(g.y),
                    "values": [[_finite(v) for v in row] for row in g.values],
                    "nominal": list(g.nominal),
                    "statistic": g.statistic,
                }
                for g in self.grids
            ],
            "agreement": [
                {
                    "reference": a.reference,
                    "target": a.target,
                    "policies": list(a.policies),
                    "srcc": _estimate_dict(a.srcc),
                    "mmrv": _estimate_dict(a.mmrv),
                    "note": a.note,
                }
                for a in self.agreement
            ],
            "improvements": [
                {"condition": i.condition, "x": i.x, "y": i.y, "probability": _estimate_dict(i.probability)}
                for i in self.improvements
            ],
            "fit": None
            if not self.fit_parameters and self.fit is None
            else {
                "params": {
                    p.address: {
                        "estimate": _finite(p.estimate),
                        "stderr": _finite(p.stderr),
                        "ci95": [_finite(p.low), _finite(p.high)],
                    }
                    for p in self.fit_parameters
                },
                "fit_percent": {k: _finite(v) for k, v in self.fit_percent},
                "warnings": list(self.fit_warnings),
            },
            "contact_sheet": None if self.contact_sheet_shape is None else {"shape": list(self.contact_sheet_shape)},
            "figures": self.figure_names(),
            "notes": list(self.notes),
            "skipped": list(self.skipped),
            "warnings": list(self.warnings),
            "versions": dict(self.versions),
            "appendix": {
                "conditions": [
                    {"name": c.name, "config": json.loads(c.config), "draws": [_draw_dict(d) for d in c.draws]}
                    for c in hidden
                ],
                "fit_truth": {p.address: _finite(p.truth) for p in self.fit_parameters if p.truth is not None},
            },
        }

    def to_json(self, path: str | os.PathLike[str] | None = None, indent: int | None = 1) -> str:
        """:meth:`to_dict` as JSON text (keys sorted: bitwise reproducible); written atomically to ``path`` when
        given."""
        text = json.dumps(self.to_dict(), indent=indent, sort_keys=True, allow_nan=False) + "\n"
        if path is not None:
            atomic_write(path, text)
        return text

    # -------------------------------------------------------------------------------------------- figures

    def _plan(self) -> list[tuple[str, str, str]]:
        """``(figure name, kind, key)`` in order; names are file-safe and unique."""
        plan: list[tuple[str, str, str]] = []
        if self.stats:
            plan.append(("returns", "returns", ""))
        used: set[str] = set()

        def unique(base: str) -> str:
            name, k = base, 2
            while name in used:
                name, k = f"{base}-{k}", k + 1
            used.add(name)
            return name

        for sweep in dict.fromkeys(c.sweep for c in self.robustness):
            plan.append((unique(f"robustness_{_slug(sweep)}"), "robustness", sweep))
        for grid in dict.fromkeys(g.grid for g in self.grids):
            plan.append((unique(f"heatmap_{_slug(grid)}"), "heatmap", grid))
        if self.fit is not None and len(self.fit.channels):  # a fit read back from JSON has no traces
            plan.append(("sysid_fit", "sysid_fit", ""))
        if self.contact_sheet is not None:
            plan.append(("contact_sheet", "contact_sheet", ""))
        return plan

    def figure_names(self) -> list[str]:
        """The names :meth:`figures` returns (and ``write`` saves as ``figures/<name>.png``), in order."""
        return [name for name, _, _ in self._plan()]

    def figures(self) -> dict[str, bytes]:
        """Every figure as PNG bytes, deterministic for the same data (Agg canvas, fixed dpi, no stamps).

        ``"returns"``: each policy's statistic on the non-sweep conditions with interval whiskers;
        ``"robustness_<sweep>"``: curves with interval bands, the nominal value and the ``fraction`` threshold;
        ``"heatmap_<grid>"``: grid values per policy; ``"sysid_fit"``: :meth:`FitResult.plot`;
        ``"contact_sheet"``: the contact sheet image.

        Rendered once per report (the report is immutable) and cached; each call returns a new dict.
        """
        return dict(self._rendered)

    @cached_property
    def _rendered(self) -> Mapping[str, bytes]:
        out: dict[str, bytes] = {}
        for name, kind, key in self._plan():
            if kind == "returns":
                out[name] = _png(self._returns_figure())
            elif kind == "robustness":
                out[name] = _png(self._robustness_figure(key))
            elif kind == "heatmap":
                out[name] = _png(self._heatmap_figure(key))
            elif kind == "sysid_fit":
                assert self.fit is not None
                out[name] = _png(self.fit.plot())
            else:
                assert self.contact_sheet is not None
                out[name] = _image_png(self.contact_sheet)
        return MappingProxyType(out)

    def _returns_figure(self) -> Any:
        from matplotlib.figure import Figure

        conditions = list(dict.fromkeys(s.condition for s in self.stats))
        policies = [p for p in self.policies if any(s.policy == p for s in self.stats)]
        fig = Figure(figsize=(max(5.0, 1.1 * len(policies) * max(1, len(conditions)) * 0.6 + 2.0), 3.8))
        fig.set_layout_engine("constrained")
        ax = fig.subplots()
        width = 0.8 / max(1, len(conditions))
        for k, condition in enumerate(conditions):
            xs, ys, lo, hi = [], [], [], []
            for i, policy in enumerate(policies):
                for s in self.stats:
                    if s.policy == policy and s.condition == condition:
                        e = s.statistic(self.statistic)
                        xs.append(i - 0.4 + width * (k + 0.5))
                        ys.append(e.value)
                        lo.append(max(0.0, e.value - e.low) if math.isfinite(e.low) else 0.0)
                        hi.append(max(0.0, e.high - e.value) if math.isfinite(e.high) else 0.0)
            ax.errorbar(xs, ys, yerr=[lo, hi], fmt="o", capsize=3, color=f"C{k % 10}", label=_tex(condition))
        ax.set_xticks(range(len(policies)), labels=[_tex(p) for p in policies], rotation=20 if len(policies) > 4 else 0)
        ax.set_ylabel(f"{self.statistic} return ({self.confidence:.0%} interval)")
        ax.set_title(_tex(f"{self.task}: return per condition"), fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=8)
        return fig

    def _robustness_figure(self, sweep: str) -> Any:
        from matplotlib.figure import Figure

        curves = [c for c in self.robustness if c.sweep == sweep]
        fig = Figure(figsize=(6.4, 4.0))
        fig.set_layout_engine("constrained")
        ax = fig.subplots()
        for k, c in enumerate(curves):
            color = f"C{k % 10}"
            values = np.array([p.value for p in c.points])
            low = np.array([p.low for p in c.points])
            high = np.array([p.high for p in c.points])
            ax.plot(c.values, values, "o-", color=color, ms=3, label=_tex(c.policy))
            ax.fill_between(c.values, low, high, color=color, alpha=0.2, linewidth=0)
            if c.threshold is not None:
                ax.axhline(c.threshold, color=color, ls=":", lw=1)
        ax.axvline(curves[0].nominal, color="0.4", ls="--", lw=1, label="nominal")
        ax.plot([], [], color="0.4", ls=":", lw=1, label=f"{self.fraction:g} x nominal return")
        ax.set_xlabel(_tex(curves[0].axis))
        ax.set_ylabel(f"{self.statistic} return ({self.confidence:.0%} band)")
        ax.set_title(_tex(f"robustness: {sweep}"), fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        return fig

    def _heatmap_figure(self, grid: str) -> Any:
        from matplotlib.figure import Figure
        from matplotlib.patches import Rectangle

        maps = [g for g in self.grids if g.grid == grid]
        cols = min(3, len(maps))
        rows = math.ceil(len(maps) / cols)
        fig = Figure(figsize=(4.2 * cols + 0.8, 3.6 * rows))
        fig.set_layout_engine("constrained")
        axes = fig.subplots(rows, cols, squeeze=False)
        every = np.concatenate([np.asarray(g.values, dtype=np.float64).ravel() for g in maps])
        every = every[np.isfinite(every)]
        vmin, vmax = (float(every.min()), float(every.max())) if every.size else (0.0, 1.0)
        image = None
        for ax, g in zip(axes.ravel(), maps, strict=False):
            m = np.asarray(g.values, dtype=np.float64)
            image = ax.imshow(m.T, origin="lower", aspect="auto", vmin=vmin, vmax=vmax, cmap="viridis")
            ax.set_xticks(range(len(g.x)), labels=[f"{v:g}" for v in g.x])
            ax.set_yticks(range(len(g.y)), labels=[f"{v:g}" for v in g.y])
            ax.set_xlabel(_tex(g.axes[0]))
            ax.set_ylabel(_tex(g.axes[1]))
            ax.set_title(_tex(g.policy), fontsize=10)
            if m.size <= 100:
                mid = (vmin + vmax) / 2.0
                for i in range(m.shape[0]):
                    for j in range(m.shape[1]):
                        if math.isfinite(m[i, j]):
                            color = "black" if m[i, j] > mid else "white"
                            ax.text(i, j, f"{m[i, j]:.3g}", ha="center", va="center", fontsize=7, color=color)
            xi = [i for i, v in enumerate(g.x) if math.isclose(v, g.nominal[0], abs_tol=1e-12)]
            yi = [j for j, v in enumerate(g.y) if math.isclose(v, g.nominal[1], abs_tol=1e-12)]
            if xi and yi:
                box = Rectangle((xi[0] - 0.5, yi[0] - 0.5), 1.0, 1.0, fill=False, edgecolor="red", linewidth=2.0)
                ax.add_patch(box)
        for ax in axes.ravel()[len(maps) :]:
            ax.set_axis_off()
        if image is not None:
            fig.colorbar(image, ax=axes.ravel().tolist(), label=f"{self.statistic} return")
        fig.suptitle(_tex(f"{grid} (nominal boxed)"), fontsize=10)
        return fig

    # -------------------------------------------------------------------------------------------- documents

    def _document(self) -> list[_Block]:
        """The report as format-neutral blocks (plain, unescaped text); :meth:`to_markdown` and :meth:`to_html`
        render the same blocks, so the two never drift apart."""
        plan = {(kind, key): name for name, kind, key in self._plan()}
        stat, conf = self.statistic, f"{self.confidence:.0%}"
        doc = [
            _Block("h1", self.title),
            _Block("p", self.summary(), style="summary"),
            _Block(
                "p",
                f"Task {self.task}, {self.episodes} episode(s) per simulated condition, seed {self.seed}, "
                f"{self.env_steps} environment steps. {conf} intervals from a stratified bootstrap "
                f"({self.num_resamples} resamples, rng seed {self.rng_seed}); success rates with Wilson intervals. "
                "Simulated conditions share initial states episode by episode, so gaps between them are paired.",
                style="muted",
            ),
        ]

        def figure(kind: str, key: str, caption: str) -> None:
            name = plan.get((kind, key))
            if name is not None:
                doc.append(_Block("figure", caption, items=(name,)))

        def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> None:
            doc.append(_Block("table", header=tuple(header), rows=tuple(tuple(r) for r in rows)))

        if self.stats:
            conditions = list(dict.fromkeys(s.condition for s in self.stats))
            doc += [_Block("h2", "Returns"), _Block("p", f"{stat} return [{conf} interval] per policy and condition.")]
            table(["policy", *conditions], [[p, *(self._cell_for(p, c) for c in conditions)] for p in self.policies])
            figure("returns", "", f"{stat} return per policy and condition, with {conf} interval whiskers")
            doc.append(_Block("h3", "Detail"))
            table(
                ["policy", "condition", "n", "mean", "IQM", f"CVaR {self.alpha:g}", "worst", "success"],
                [
                    [
                        s.policy,
                        s.condition,
                        str(s.n),
                        _cell(s.mean),
                        _cell(s.iqm),
                        _cell(s.cvar),
                        _num(s.worst),
                        _cell(s.success),
                    ]
                    for s in self.stats
                ],
            )
        if self.gaps:
            doc += [
                _Block("h2", "Sim-to-real gaps"),
                _Block(
                    "p",
                    f"absolute = {stat}(from) - {stat}(to), positive when the target does worse; relative = absolute / "
                    f"|{stat}(from)|. Paired: resampled jointly (same initial states); unpaired: independently.",
                ),
            ]
            table(
                ["policy", "from", "to", "absolute", "relative", "paired", "runs"],
                [
                    [
                        g.policy,
                        g.reference,
                        g.target,
                        _cell(g.absolute),
                        _pct(g.relative),
                        "yes" if g.paired else "no",
                        f"{g.n_reference} / {g.n_target}",
                    ]
                    for g in self.gaps
                ],
            )
        if self.robustness:
            doc += [
                _Block("h2", "Robustness"),
                _Block(
                    "p",
                    f"Radius: the largest distance from the nominal value that keeps {self.fraction:g} of the nominal "
                    f"{stat} return (censored: the sweep never crossed the threshold there, so the radius is a lower "
                    "bound).",
                ),
            ]
            table(
                ["policy", "sweep", "nominal", "nominal return", "radius", "censored"],
                [_radius_row(c) for c in self.robustness],
            )
            for sweep in dict.fromkeys(c.sweep for c in self.robustness):
                figure("robustness", sweep, f"robustness curves over {sweep} ({conf} bands)")
        if self.grids:
            doc.append(_Block("h2", "Parameter grids"))
            for grid in dict.fromkeys(g.grid for g in self.grids):
                figure("heatmap", grid, f"{stat} return over {grid}")
            for g in self.grids:
                doc.append(_Block("p", f"{g.policy} on {g.grid} ({stat}; rows {g.axes[0]}, columns {g.axes[1]}):"))
                table(
                    [f"{g.axes[0]} \\ {g.axes[1]}", *(f"{v:g}" for v in g.y)],
                    [[f"{x:g}", *(_num(v) for v in row)] for x, row in zip(g.x, g.values, strict=True)],
                )
        if self.agreement:
            doc += [
                _Block("h2", "Agreement across policies"),
                _Block(
                    "p",
                    "SRCC: Pearson correlation of the per-policy scores between a simulated condition and the target; "
                    "MMRV: mean maximum rank violation (0 = the same ranking), in return units.",
                ),
            ]
            table(
                ["sim", "target", "policies", "SRCC", "MMRV", "note"],
                [
                    [a.reference, a.target, str(len(a.policies)), _cell(a.srcc), _cell(a.mmrv), a.note]
                    for a in self.agreement
                ],
            )
        if self.improvements:
            doc.append(_Block("h2", f"Probability of improvement on {self.target}"))
            table(["x", "y", "P(x > y)"], [[i.x, i.y, _cell(i.probability)] for i in self.improvements])
        if self.fit is not None or self.fit_parameters:
            doc.append(_Block("h2", "System identification"))
            table(
                ["parameter", "estimate", "stderr", "95% interval"],
                [
                    [p.address, _num(p.estimate, 6), _num(p.stderr, 3), f"[{_num(p.low, 6)}, {_num(p.high, 6)}]"]
                    for p in self.fit_parameters
                ],
            )
            if self.fit_percent:
                doc.append(_Block("p", "held-out fit: " + ", ".join(f"{k} {v:.1f}%" for k, v in self.fit_percent)))
            if self.fit_warnings:
                doc.append(_Block("list", items=tuple(f"fit warning: {w}" for w in self.fit_warnings)))
            if self.fit is not None and len(self.fit.channels):
                figure("sysid_fit", "", "measured vs simulated signals and residuals")
        if self.contact_sheet is not None:
            doc.append(_Block("h2", "Visual randomisation"))
            figure("contact_sheet", "", "contact sheet of randomised first frames")
        doc.append(_Block("h2", "Conditions"))
        rows, drawn = [], []
        for group in self._condition_groups():
            c = group[0]
            if c.sweep is not None:
                rows.append([c.sweep, c.kind, f"{len(group)} points: {_points_text(group)}", f"e.g. {c.config}"])
            elif c.hidden:
                rows.append([c.name, c.kind, c.description, "(in the appendix)"])
            else:
                rows.append([c.name, c.kind, c.description, c.config])
                drawn += [[c.name, *_draw_row(d)] for d in c.draws]
        table(["condition", "kind", "description", "configuration"], rows)
        if drawn:
            doc.append(_Block("p", "Parameter values drawn per episode:"))
            table(["condition", "parameter", "low", "mean", "high", "episodes"], drawn)
        if self.notes or self.skipped:
            doc += [_Block("h2", "Notes"), _Block("list", items=(*self.notes, *self.skipped))]
        if self.warnings:
            doc += [_Block("h2", "Warnings"), _Block("list", items=self.warnings)]
        doc += [
            _Block("h2", "Settings"),
            _Block(
                "p",
                f"statistic {stat}, confidence {self.confidence:g}, CVaR alpha {self.alpha:g}, radius fraction "
                f"{self.fraction:g}, {self.num_resamples} resamples, rng seed {self.rng_seed}; "
                + ", ".join(f"{k} {v}" for k, v in self.versions),
            ),
        ]
        hidden = [c for c in self.conditions if c.hidden]
        truths = [p for p in self.fit_parameters if p.truth is not None]
        if hidden or truths:
            doc.append(_Block("h2", APPENDIX, style="appendix"))
            for c in hidden:
                doc += [_Block("h3", f"{c.name} ({c.kind})"), _Block("p", c.description), _Block("code", c.config)]
                if c.draws:
                    table(["parameter", "low", "mean", "high", "episodes"], [_draw_row(d) for d in c.draws])
            if truths:
                doc.append(_Block("h3", "sysid estimates against the true parameters"))
                table(
                    ["parameter", "estimate", "95% interval", "true", "inside"],
                    [
                        [
                            p.address,
                            _num(p.estimate, 6),
                            f"[{_num(p.low, 6)}, {_num(p.high, 6)}]",
                            _num(p.truth or 0.0, 6),
                            "yes" if p.low <= (p.truth or 0.0) <= p.high else "no",
                        ]
                        for p in truths
                    ],
                )
        return doc

    def _condition_groups(self) -> list[list[ConditionInfo]]:
        """Conditions in order, the points of each visible sweep or grid gathered into one group."""
        groups: list[list[ConditionInfo]] = []
        index: dict[str, list[ConditionInfo]] = {}
        for c in self.conditions:
            if c.sweep is None or c.hidden:
                groups.append([c])
            elif c.sweep in index:
                index[c.sweep].append(c)
            else:
                index[c.sweep] = [c]
                groups.append(index[c.sweep])
        return groups

    def _cell_for(self, policy: str, condition: str) -> str:
        for s in self.stats:
            if s.policy == policy and s.condition == condition:
                return _cell(s.statistic(self.statistic))
        return "n/a"

    def to_markdown(self, figure_dir: str | None = None) -> str:
        """The report as Markdown (the same sections and tables as :meth:`to_html`).

        With ``figure_dir`` (``write`` passes ``"figures"``) each figure is linked as ``<figure_dir>/<name>.png``;
        without it figures are left out. User strings are escaped (no raw HTML, no broken tables).
        """
        out: list[str] = []
        for block in self._document():
            if block.kind in ("h1", "h2", "h3"):
                out += [f"{'#' * int(block.kind[1])} {_md(block.text)}", ""]
            elif block.kind in ("p", "code"):
                out += ["  \n".join(_md(line) for line in block.text.splitlines()), ""]
            elif block.kind == "list":
                out += [*(f"- {_md(item)}" for item in block.items), ""]
            elif block.kind == "table":
                out += [*_md_table(block.header, block.rows), ""]
            elif block.kind == "figure" and figure_dir is not None:
                name = block.items[0]
                out += [f"![{_md(block.text)}]({figure_dir}/{name}.png)", ""]
        return "\n".join(out).rstrip("\n") + "\n"

    # -------------------------------------------------------------------------------------------- html

    def to_html(self) -> str:
        """One self-contained HTML page: figures embedded as base64 PNG, inline CSS, no scripts, no external
        resources; every user-supplied string escaped. Hidden configurations only in the final appendix."""
        return self._html(self.figures())

    def _html(self, figures: Mapping[str, bytes]) -> str:
        body: list[str] = []
        for block in self._document():
            style = f" class='{_e(block.style)}'" if block.style else ""
            if block.kind in ("h1", "h2", "h3"):
                anchor = f" id='{_e(block.style)}'" if block.style else ""
                body.append(f"<{block.kind}{anchor}>{_e(block.text)}</{block.kind}>")
            elif block.kind == "p":
                body.append(f"<p{style}>{'<br>'.join(_e(line) for line in block.text.splitlines())}</p>")
            elif block.kind == "code":
                body.append(f"<pre>{_e(block.text)}</pre>")
            elif block.kind == "list":
                body.append("<ul>" + "".join(f"<li>{_e(item)}</li>" for item in block.items) + "</ul>")
            elif block.kind == "table":
                body.append(_html_table(block.header, block.rows))
            elif block.kind == "figure" and block.items[0] in figures:
                name = block.items[0]
                data = base64.b64encode(figures[name]).decode("ascii")
                body.append(
                    f"<figure><img alt='{_e(name)}' src='data:image/png;base64,{data}'>"
                    f"<figcaption>{_e(block.text)}</figcaption></figure>"
                )
        return html_page(self.title, "\n".join(body))

    # -------------------------------------------------------------------------------------------- files

    def write(self, out_dir: str | os.PathLike[str]) -> ReportFiles:
        """Writes ``report.html``, ``report.md``, ``report.json`` and ``figures/<name>.png`` into ``out_dir``.

        Everything is rendered in memory, written into a temporary sibling directory and then moved into
        place (``report.json`` last, so its presence marks a complete report): an error or Ctrl-C leaves no
        half-written file and no temporary directory. A new ``out_dir`` appears in one rename; in an existing one
        the files are replaced one by one (the old ``report.json`` is removed first) and other files are left
        alone.

        Raises:
            NotADirectoryError: ``out_dir`` exists and is not a directory.
        """
        out = Path(out_dir)
        if out.exists() and not out.is_dir():
            raise NotADirectoryError(f"`out_dir` must be a directory. Received the file {str(out)!r}.")
        figures = self.figures()
        markdown = self.to_markdown(figure_dir="figures")
        page = self._html(figures)
        text = self.to_json()
        parent = out.parent if str(out.parent) else Path(".")
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))
        try:
            for name, png in figures.items():
                atomic_write(tmp / "figures" / f"{name}.png", png)
            atomic_write(tmp / "report.md", markdown)
            atomic_write(tmp / "report.html", page)
            atomic_write(tmp / "report.json", text)
            if not out.exists():
                mask = os.umask(0)
                os.umask(mask)
                os.chmod(tmp, 0o777 & ~mask)  # mkdtemp makes it private
                os.replace(tmp, out)
            else:
                (out / "report.json").unlink(missing_ok=True)
                (out / "figures").mkdir(exist_ok=True)
                for name in figures:
                    os.replace(tmp / "figures" / f"{name}.png", out / "figures" / f"{name}.png")
                for name in ("report.md", "report.html", "report.json"):
                    os.replace(tmp / name, out / name)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return ReportFiles(
            directory=out,
            html=out / "report.html",
            markdown=out / "report.md",
            json=out / "report.json",
            figures=tuple(out / "figures" / f"{name}.png" for name in figures),
        )


# ------------------------------------------------------------------------------------------------ computation


class _Builder:
    """The computations behind :meth:`GapReport.build`, each with its own keyed generator and warning context."""

    def __init__(
        self,
        evaluation: Evaluation,
        statistic: str,
        confidence: float,
        alpha: float,
        fraction: float,
        num_resamples: int,
        seed: int,
    ) -> None:
        self.ev = evaluation
        self.statistic: metrics.Statistic = "iqm" if statistic == "iqm" else "mean"
        self.confidence = confidence
        self.alpha = alpha
        self.fraction = fraction
        self.num_resamples = num_resamples
        self.seed = seed
        self.warnings = _Warnings()
        self.skipped: list[str] = []

    def skip(self, note: str) -> None:
        if note not in self.skipped:
            self.skipped.append(note)

    def returns(self, policy: str, condition: str) -> np.ndarray | None:
        values = self.ev.returns.get(policy, {}).get(condition)
        return None if values is None or len(values) == 0 else np.asarray(values, dtype=np.float64)

    def per_point(self, table: np.ndarray, *key: str) -> tuple[Estimate, ...]:
        fn = metrics.mean if self.statistic == "mean" else metrics.iqm
        return fn(table, rng=stream(self.seed, *key), confidence=self.confidence, num_resamples=self.num_resamples)

    def stats(self) -> tuple[ConditionStats, ...]:
        out = []
        for policy in self.ev.policies:
            for cond in self.ev.of_kind(*MAIN_KINDS):
                x = self.returns(policy, cond.name)
                if x is None:
                    self.skip(f"policy {policy!r} has no returns on {cond.name!r}.")
                    continue
                col = x[:, None]
                with self.warnings.where(f"{policy!r} on {cond.name!r}"):
                    mean = metrics.mean(
                        col,
                        rng=stream(self.seed, "mean", policy, cond.name),
                        confidence=self.confidence,
                        num_resamples=self.num_resamples,
                    )[0]
                    iqm = metrics.iqm(
                        col,
                        rng=stream(self.seed, "iqm", policy, cond.name),
                        confidence=self.confidence,
                        num_resamples=self.num_resamples,
                    )[0]
                    cvar = metrics.cvar(
                        col,
                        alpha=self.alpha,
                        rng=stream(self.seed, "cvar", policy, cond.name),
                        confidence=self.confidence,
                        num_resamples=self.num_resamples,
                    )[0]
                    flags = self.ev.successes.get(policy, {}).get(cond.name)
                    success = (
                        metrics.success_rate(np.asarray(flags, dtype=np.float64)[:, None], confidence=self.confidence)[
                            0
                        ]
                        if flags is not None and len(flags)
                        else None
                    )
                out.append(
                    ConditionStats(
                        policy=policy,
                        condition=cond.name,
                        kind=cond.kind,
                        n=int(x.size),
                        mean=mean,
                        iqm=iqm,
                        cvar=cvar,
                        worst=float(x.min()),
                        success=success,
                    )
                )
        return tuple(out)

    def gaps(self, references: Sequence[str], target: str | None) -> tuple[GapStats, ...]:
        if target is None:
            return ()
        out = []
        tcond = self.ev.condition(target)
        for policy in self.ev.policies:
            for ref in references:
                a, b = self.returns(policy, ref), self.returns(policy, target)
                if a is None or b is None:
                    self.skip(f"no gap {ref!r} -> {target!r} for policy {policy!r}: returns missing.")
                    continue
                paired = self.ev.condition(ref).simulated and tcond.simulated and a.size == b.size
                rng = stream(self.seed, "gap", policy, ref, target)
                with self.warnings.where(f"gap of {policy!r} from {ref!r} to {target!r}"):
                    if paired:
                        g = metrics.gap(
                            np.column_stack([a, b]),
                            paired=True,
                            statistic=self.statistic,
                            rng=rng,
                            confidence=self.confidence,
                            num_resamples=self.num_resamples,
                        )
                    else:
                        g = metrics.unpaired_gap(
                            a,
                            b,
                            statistic=self.statistic,
                            rng=rng,
                            confidence=self.confidence,
                            num_resamples=self.num_resamples,
                        )
                out.append(
                    GapStats(
                        policy=policy,
                        reference=ref,
                        target=target,
                        absolute=g.absolute,
                        relative=g.relative,
                        paired=g.paired,
                        n_reference=int(a.size),
                        n_target=int(b.size),
                        statistic=self.statistic,
                    )
                )
        return tuple(out)

    def curves(self) -> tuple[RobustnessCurve, ...]:
        out = []
        for name, conds in self.ev.sweeps().items():
            if any(c.kind != "sweep" or len(c.value) != 1 for c in conds):
                continue
            conds = tuple(sorted(conds, key=lambda c: c.value[0]))
            values = np.array([c.value[0] for c in conds])
            nominal = float(conds[0].nominal[0]) if conds[0].nominal else math.nan
            names = [c.name for c in conds]
            for policy in self.ev.policies:
                found = [self.returns(policy, n) for n in names]
                columns = [c for c in found if c is not None]
                if len(columns) != len(found) or len({c.size for c in columns}) != 1:
                    self.skip(f"no robustness curve of {policy!r} on {name!r}: returns missing or uneven.")
                    continue
                table = np.column_stack(columns)
                with self.warnings.where(f"curve of {policy!r} on {name!r}"):
                    points = self.per_point(table, "curve", policy, name)
                radius, note = None, ""
                on_grid = np.flatnonzero(np.isclose(values, nominal, rtol=1e-9, atol=1e-12))
                if values.size < 2 or np.any(np.diff(values) <= 0):
                    note = "the sweep's values are not at least 2 strictly increasing points"
                elif on_grid.size != 1:
                    note = f"the nominal value {nominal:g} is not on the sweep's grid"
                elif not points[int(on_grid[0])].value > 0:
                    note = f"the nominal {self.statistic} return {points[int(on_grid[0])].value:.4g} is not positive"
                else:
                    with self.warnings.where(f"radius of {policy!r} on {name!r}"):
                        radius = metrics.robustness_radius(
                            values,
                            table,
                            nominal=nominal,
                            fraction=self.fraction,
                            statistic=self.statistic,
                            paired=all(c.simulated for c in conds),
                            rng=stream(self.seed, "radius", policy, name),
                            confidence=self.confidence,
                            num_resamples=self.num_resamples,
                        )
                if note:
                    hint = " (a fraction of it is meaningless: shift returns so 0 is the worst acceptable)"
                    self.skip(
                        f"no robustness radius of {policy!r} on {name!r}: {note}{hint if 'positive' in note else ''}."
                    )
                out.append(
                    RobustnessCurve(
                        policy=policy,
                        sweep=name,
                        axis=conds[0].axes[0] if conds[0].axes else name,
                        values=tuple(float(v) for v in values),
                        conditions=tuple(names),
                        nominal=nominal,
                        points=tuple(points),
                        radius=radius,
                        fraction=self.fraction,
                        note=note,
                        statistic=self.statistic,
                    )
                )
        return tuple(out)

    def point(self, x: np.ndarray) -> float:
        if self.statistic == "mean":
            return float(x.mean())
        cut = int(0.25 * x.size)  # as sim2real.metrics.iqm: floor(n / 4) runs cut from each end
        return float(np.sort(x)[cut : x.size - cut].mean())

    def grids(self) -> tuple[GridMeans, ...]:
        out = []
        for name, conds in self.ev.sweeps().items():
            if any(c.kind != "grid" or len(c.value) != 2 for c in conds):
                continue
            xs = sorted({c.value[0] for c in conds})
            ys = sorted({c.value[1] for c in conds})
            for policy in self.ev.policies:
                m = np.full((len(xs), len(ys)), math.nan)
                for c in conds:
                    x = self.returns(policy, c.name)
                    if x is not None:
                        m[xs.index(c.value[0]), ys.index(c.value[1])] = self.point(x)
                if not np.isfinite(m).any():
                    continue
                first = conds[0]
                out.append(
                    GridMeans(
                        policy=policy,
                        grid=name,
                        axes=(first.axes[0], first.axes[1]) if len(first.axes) == 2 else ("x", "y"),
                        x=tuple(float(v) for v in xs),
                        y=tuple(float(v) for v in ys),
                        values=tuple(tuple(float(v) for v in row) for row in m),
                        nominal=(float(first.nominal[0]), float(first.nominal[1]))
                        if len(first.nominal) == 2
                        else (math.nan, math.nan),
                        statistic=self.statistic,
                    )
                )
        return tuple(out)

    def agreement(self, references: Sequence[str], target: str | None) -> tuple[Agreement, ...]:
        if target is None or len(self.ev.policies) < 2:
            return ()
        out = []
        for ref in references:
            policies = tuple(
                p for p in self.ev.policies if self.returns(p, ref) is not None and self.returns(p, target) is not None
            )
            srcc = mmrv = None
            note = ""
            sims = [self.returns(p, ref) for p in policies]
            reals = [self.returns(p, target) for p in policies]
            if len(policies) < 3:
                note = f"SRCC and MMRV need >= 3 policies with returns on both; {len(policies)} have"
            elif len({s.size for s in sims if s is not None}) > 1 or len({r.size for r in reals if r is not None}) > 1:
                note = "SRCC and MMRV need the same number of runs for every policy on each condition"
            else:
                sim = np.column_stack([s for s in sims if s is not None])
                real = np.column_stack([r for r in reals if r is not None])
                context = f"agreement of {ref!r} with {target!r}"
                with self.warnings.where(context):
                    try:
                        srcc = metrics.srcc(
                            sim,
                            real,
                            statistic=self.statistic,
                            rng=stream(self.seed, "srcc", ref, target),
                            confidence=self.confidence,
                            num_resamples=self.num_resamples,
                        )
                    except ValueError as err:
                        note = f"SRCC undefined: {err}"
                    mmrv = metrics.mmrv(
                        sim,
                        real,
                        statistic=self.statistic,
                        rng=stream(self.seed, "mmrv", ref, target),
                        confidence=self.confidence,
                        num_resamples=self.num_resamples,
                    )
            if note:
                self.skip(f"agreement of {ref!r} with {target!r}: {note}.")
            out.append(Agreement(ref, target, policies, srcc, mmrv, note))
        return tuple(out)

    def improvements(self, target: str | None) -> tuple[Improvement, ...]:
        if target is None:
            return ()
        out = []
        policies = [p for p in self.ev.policies if self.returns(p, target) is not None]
        for i, x in enumerate(policies):
            for y in policies[i + 1 :]:
                a, b = self.returns(x, target), self.returns(y, target)
                assert a is not None and b is not None
                with self.warnings.where(f"P({x!r} > {y!r}) on {target!r}"):
                    p = metrics.probability_of_improvement(
                        a[:, None],
                        b[:, None],
                        rng=stream(self.seed, "improvement", target, x, y),
                        confidence=self.confidence,
                        num_resamples=self.num_resamples,
                    )
                out.append(Improvement(target, x, y, p))
        return tuple(out)


# ------------------------------------------------------------------------------------------------ rendering


def _gap_phrase(g: GapStats) -> str:
    where = f"from {g.reference} to {g.target}"
    pairing = "paired" if g.paired else f"unpaired, {g.n_reference} vs {g.n_target} runs"
    rel = g.relative
    if math.isfinite(rel.value):
        if rel.value >= 0:
            amount = f"loses {_pct(rel)}"
        else:
            amount = f"gains {_pct1(-rel.value)} [{_pct1(-rel.high)}, {_pct1(-rel.low)}]"
        return f"{amount} {where} (gap {_cell(g.absolute)}, {pairing})"
    return f"has a gap of {_cell(g.absolute)} {where} ({pairing})"


def _radius_row(c: RobustnessCurve) -> list[str]:
    if c.radius is None:
        return [c.policy, c.sweep, f"{c.nominal:g}", "n/a", f"n/a ({c.note})", ""]
    r = c.radius
    return [
        c.policy,
        c.sweep,
        f"{c.nominal:g}",
        _num(r.nominal_return),
        _cell(r.radius),
        "yes (lower bound)" if r.censored else "no",
    ]


def _points_text(group: Sequence[ConditionInfo]) -> str:
    return ", ".join(
        f"{c.value[0]:g}" if len(c.value) == 1 else "(" + ", ".join(f"{v:g}" for v in c.value) + ")" for c in group
    )


def _draw_dict(d: ParameterDraws) -> dict[str, Any]:
    return {"address": d.address, "low": _finite(d.low), "mean": _finite(d.mean), "high": _finite(d.high), "n": d.n}


def _draw_row(d: ParameterDraws) -> list[str]:
    return [d.address, _num(d.low, 6), _num(d.mean, 6), _num(d.high, 6), str(d.n)]


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(_md(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_md(c) for c in row) + " |" for row in rows]
    return lines


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def html_page(title: str, body: str) -> str:
    """A self-contained HTML page (inline CSS, no scripts, no external resources) around ``body`` (already
    escaped HTML); ``title`` is escaped here. The house look of every HTML report (gap report, sysid fit).

    Example:
        >>> html_page("a <b>", "<p>hi</p>").count("&lt;b&gt;")
        1
    """
    return (
        "<!doctype html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{_e(title)}</title><style>{_STYLE}</style></head>\n<body>\n{body}\n</body></html>\n"
    )


def png_bytes(figure: Any) -> bytes:
    """A matplotlib ``Figure`` as PNG bytes at a fixed dpi, without version or time stamps (deterministic for the
    same data); the figure is cleared afterwards to free its artists."""
    return _png(figure)


def _png(figure: Any) -> bytes:
    buffer = io.BytesIO()
    try:
        figure.savefig(buffer, format="png", dpi=_DPI, metadata=_PNG_METADATA)
    finally:
        figure.clear()
    return buffer.getvalue()


def _image_png(image: np.ndarray) -> bytes:
    from matplotlib import image as mimage

    buffer = io.BytesIO()
    # matplotlib drops None-valued keys (the version stamp); its annotation allows only str values
    mimage.imsave(buffer, image, format="png", metadata=_PNG_METADATA)  # type: ignore[arg-type]
    return buffer.getvalue()
