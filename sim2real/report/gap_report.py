"""The :class:`GapReport` result object: every number of a sim-to-real study, frozen, with its documents.

The numbers are computed in :mod:`sim2real.report.statistics`, drawn in :mod:`sim2real.report.figures`, laid out in
:mod:`sim2real.report.rendering` and written by :mod:`sim2real.report.files`; this module ties them to one object.
See :mod:`sim2real.report` for an example.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from randomizers.files import atomic_write
from sim2real.evaluation import Evaluation
from sim2real.report import figures as _figures
from sim2real.report import files as _files
from sim2real.report import rendering
from sim2real.report.results import (
    Agreement,
    ConditionInfo,
    ConditionStats,
    EpisodeTarget,
    FitParameter,
    GapStats,
    GridMeans,
    Improvement,
    PolicyDifference,
    Prediction,
    ReportFiles,
    RobustnessCurve,
)
from sim2real.report.statistics import report_fields

if TYPE_CHECKING:
    from sim2real.safety import SafetyTable
    from sim2real.sheets import ContactSheet
    from sysid.result import FitResult

__all__ = ["GapReport"]


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
        differences: ``stat(x) - stat(y)`` on the target for each pair of policies, with intervals (the headline is
            read from these: a difference is claimed only when its interval excludes 0).
        predictions: per simulated condition, how closely it predicts the target across the policies.
        training: ``(policy, condition)``: the sim each policy was trained in; its robustness radii keep a fraction
            of the policy's return there.
        control_timestep: seconds per control step (latencies are shown in ms), or None.
        substeps: physics steps per control step (a timing model's ``steps`` count them), or None (one).
        linear: names of slide joints (and actuators along them), whose units are lengths.
        tendons: ``(tendon, unit of its length)``: ``"m"``, ``"rad"`` or ``"mixed"``
            (:func:`sim2real.report.labels.tendon_units`), which gives each tendon parameter its unit.
        policy_labels: ``(policy, label)`` shown in tables and figures (``"policy: <name>"`` by default).
        condition_labels: ``(condition, label)`` shown in tables and figures (``"sim: nominal"``, ``"real twin"``).
        lead: the caller's opening paragraph (e.g. the study's), shown first in the summary; see :meth:`with_lead`.
        fit: the FitResult (for its figure; not compared, not serialised beyond the fields above).
        contact_sheet: the contact sheet image (not compared, not serialised).
        safety: a :class:`sim2real.safety.SafetyTable` (``evaluate --safety``): the Safety section and the
            ``"safety"`` entry of the JSON; None leaves both out.
        episode_target: how the episodes on the target were chosen (:class:`EpisodeTarget`, set by the study with
            :meth:`with_episode_target`), or None.
        observation_unit: the unit of the observation channels a sensor-noise sweep perturbs (e.g. ``"rad
            (position), m (to_target), rad/s (velocity)"``, :func:`sim2real.report.labels.observation_unit`), or
            None (shown as "observation units").
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
    differences: tuple[PolicyDifference, ...] = ()
    predictions: tuple[Prediction, ...] = ()
    training: tuple[tuple[str, str], ...] = ()
    control_timestep: float | None = None
    substeps: int | None = None
    linear: tuple[str, ...] = ()
    tendons: tuple[tuple[str, str], ...] = ()
    policy_labels: tuple[tuple[str, str], ...] = ()
    condition_labels: tuple[tuple[str, str], ...] = ()
    lead: str = ""
    fit: FitResult | None = field(default=None, compare=False, repr=False)
    contact_sheet: np.ndarray | None = field(default=None, compare=False, repr=False)
    safety: SafetyTable | None = None  # the Safety section (sim2real.report.safety); set with dataclasses.replace
    episode_target: EpisodeTarget | None = None
    observation_unit: str | None = None

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
        training: Mapping[str, str] | None = None,
        control_timestep: float | None = None,
        substeps: int | None = None,
        linear: Sequence[str] = (),
        tendons: Mapping[str, str] | Iterable[tuple[str, str]] | None = None,
        policy_labels: Mapping[str, str] | None = None,
        condition_labels: Mapping[str, str] | None = None,
        lead: str = "",
        observation_unit: str | None = None,
    ) -> GapReport:
        """Computes every number of the report from an evaluation.

        Args:
            evaluation: from :func:`sim2real.evaluation.evaluate`.
            fit: a :class:`sysid.result.FitResult` to report (estimates, intervals, the fit figure).
            contact_sheet: a :class:`sim2real.sheets.ContactSheet` or an ``(H, W, 3)`` uint8 image.
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
            training: policy -> the simulated condition it was trained in (default: ``reference`` for every
                policy); a robustness radius keeps ``fraction`` of the policy's return there.
            control_timestep: seconds per control step, to show latencies in ms (None: a timing model's ``steps``
                in physics steps).
            substeps: physics steps per control step, which a timing model's ``steps`` count on a MuJoCo env
                (None: one, as on a suite task).
            linear: names of slide joints and of actuators that push along them: their parameters and channels are
                shown in N·s/m, m, m/s (default: every joint a hinge, as on the suite tasks).
            tendons: tendon -> the unit of its length (``"m"``, ``"rad"`` or ``"mixed"``; a mapping or pairs), read
                from the model by :func:`sim2real.report.labels.tendon_units`: a fitted ``tendon_damping[grip]`` is then shown in
                N·s/m or N·m·s/rad (default: none known, shown without a unit).
            policy_labels: policy -> display name (default ``"policy: <name>"``).
            condition_labels: condition -> display name (default by kind: ``"sim: nominal"``, ``"real twin"``).
            lead: an opening paragraph for the summary (e.g. the study's).
            observation_unit: the unit of the observation channels, for a sensor-noise sweep's axis (e.g. ``"rad"``
                or ``"rad (position), rad/s (velocity)"``; :func:`sim2real.report.labels.observation_unit` reads it
                from an env); None shows "observation units".

        Raises:
            TypeError: an argument of the wrong type.
            ValueError: a named condition that does not exist, reference/randomized equal to the target, or an
                argument out of range.
        """
        return cls(
            **report_fields(
                evaluation,
                fit=fit,
                contact_sheet=contact_sheet,
                reference=reference,
                randomized=randomized,
                target=target,
                statistic=statistic,
                confidence=confidence,
                alpha=alpha,
                fraction=fraction,
                num_resamples=num_resamples,
                rng=rng,
                title=title,
                notes=notes,
                training=training,
                control_timestep=control_timestep,
                substeps=substeps,
                linear=linear,
                tendons=tendons,
                policy_labels=policy_labels,
                condition_labels=condition_labels,
                lead=lead,
                observation_unit=observation_unit,
            )
        )

    def with_lead(self, lead: str) -> GapReport:
        """A copy of this report whose summary opens with ``lead`` (a paragraph computed from this report, e.g.
        :func:`sim2real.study.study_summary`), so the paragraph is part of the HTML, Markdown and JSON."""
        if not isinstance(lead, str):
            raise TypeError(f"`lead` must be a string. Received {type(lead).__name__}.")
        return dataclasses.replace(self, lead=lead)

    def with_episode_target(self, target: EpisodeTarget) -> GapReport:
        """A copy of this report that says how its target's episodes were chosen, with ``target.half_width`` read
        from this report's own interval of ``stat(target.x) - stat(target.y)`` on ``target.condition``.

        Raises:
            KeyError: the report has no difference between ``target.x`` and ``target.y``.
        """
        if not isinstance(target, EpisodeTarget):
            raise TypeError(f"`target` must be an EpisodeTarget. Received {type(target).__name__}.")
        e = self.difference(target.x, target.y).difference
        half = (e.high - e.low) / 2.0
        return dataclasses.replace(self, episode_target=dataclasses.replace(target, half_width=float(half)))

    def episode_counts(self) -> dict[str, tuple[int, ...]]:
        """Condition -> the distinct episode counts of its policies (non-sweep conditions; sweep and grid points
        run :attr:`episodes` each)."""
        out: dict[str, set[int]] = {}
        for s in self.stats:
            out.setdefault(s.condition, set()).add(s.n)
        return {c: tuple(sorted(n)) for c, n in out.items()}

    def axis_label(self, axis: str) -> Any:
        """:func:`sim2real.report.labels.axis_label` of a sweep axis with this report's control timestep (latencies
        in ms) and observation unit (sensor noise)."""
        from sim2real.report.labels import axis_label

        return axis_label(axis, self.control_timestep, observation_unit=self.observation_unit, substeps=self.substeps)

    def label(self, name: str, role: str = "policy") -> str:
        """The display name of a policy (``role="policy"``) or a condition (``role="condition"``)."""
        table = dict(self.policy_labels if role == "policy" else self.condition_labels)
        return table.get(name, name)

    def difference(self, x: str, y: str) -> PolicyDifference:
        """The :class:`PolicyDifference` ``stat(x) - stat(y)`` on the target (the sign flipped when the report
        holds ``y - x``).

        Raises:
            KeyError: no such pair (naming the pairs that exist).
        """
        for d in self.differences:
            if (d.x, d.y) == (x, y):
                return d
            if (d.x, d.y) == (y, x):
                e = d.difference
                flipped = dataclasses.replace(e, value=-e.value, low=-e.high, high=-e.low)
                return dataclasses.replace(d, x=x, y=y, difference=flipped)
        raise KeyError(f"no difference {x!r} - {y!r}. Available: {[(d.x, d.y) for d in self.differences]}.")

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
        return rendering.summary(self)

    def to_dict(self) -> dict[str, Any]:
        """Every number of the report as plain JSON-ready data (non-finite numbers become None).

        Hidden conditions' configurations and draws and the sysid ground truth are under ``"appendix"``.
        """
        return rendering.to_dict(self)

    def to_json(self, path: str | os.PathLike[str] | None = None, indent: int | None = 1) -> str:
        """:meth:`to_dict` as JSON text (keys sorted: bitwise reproducible); written atomically to ``path`` when
        given."""
        text = rendering.json_text(self, indent)
        if path is not None:
            atomic_write(path, text)
        return text

    # -------------------------------------------------------------------------------------------- figures

    def figure_names(self) -> list[str]:
        """The names :meth:`figures` returns (and ``write`` saves as ``figures/<name>.png``), in order."""
        return [name for name, _, _ in _figures.plan(self)]

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
        return _figures.render(self)

    # -------------------------------------------------------------------------------------------- documents

    def to_markdown(self, figure_dir: str | None = None) -> str:
        """The report as Markdown (the same sections and tables as :meth:`to_html`).

        With ``figure_dir`` (``write`` passes ``"figures"``) each figure is linked as ``<figure_dir>/<name>.png``;
        without it figures are left out. User strings are escaped (no raw HTML, no broken tables).
        """
        return rendering.to_markdown(self, figure_dir)

    def to_html(self) -> str:
        """One self-contained HTML page: figures embedded as base64 PNG, inline CSS, no scripts, no external
        resources; every user-supplied string escaped. Hidden configurations only in the final appendix."""
        return rendering.to_html(self, self.figures())

    # -------------------------------------------------------------------------------------------- files

    def write(self, out_dir: str | os.PathLike[str]) -> ReportFiles:
        """Writes ``report.html``, ``report.md``, ``report.json`` and ``figures/<name>.png`` into ``out_dir``.

        Everything is rendered in memory, written into a temporary sibling directory and then moved into
        place (``report.json`` last, so its presence marks a complete report): an error or Ctrl-C leaves no
        half-written file and no temporary directory. A new ``out_dir`` appears in one rename; in an existing one
        the report's files are replaced all or nothing (the old ones are moved aside first and put back if a
        rename fails; Ctrl-C waits for the renames) and other files are left alone.

        Raises:
            NotADirectoryError: ``out_dir`` exists and is not a directory.
            OSError: in an existing ``out_dir``, a report file is a folder or ``figures`` a file (nothing changed).
        """
        return _files.write(self, out_dir)
