"""The study's one-paragraph summary: printed by ``sim2real study`` and the lead of its report (HTML, Markdown, JSON).

Every claim is read from the :class:`~sim2real.report.GapReport` it opens, with that report's intervals: each
policy's gap between two named ends, worded by the sign of its point estimate (the nominal policy from the nominal
sim, the randomised policy from its randomised sim, the calibrated policy from its calibrated sim); the paired
calibrated-vs-randomised difference on the twin and whether it is significant; whether each sim predicts the twin
for every policy; the scripted baseline.
"""

from __future__ import annotations

from typing import Any

from sim2real.report.findings import (
    cell,
    episode_target_sentence,
    episodes_text,
    gap_phrase,
    prediction_sentence,
    versus,
)

__all__ = ["DISPLAY_CONDITIONS", "DISPLAY_POLICIES", "TRAINING", "study_summary"]

#: The sim each study policy was trained in (the scripted baseline was tuned in the nominal sim).
TRAINING = {"nominal": "sim", "randomized": "randomized", "calibrated": "calibrated", "adr": "adr", "scripted": "sim"}
#: Display names of the study's policies, apart from its conditions (figures and tables).
DISPLAY_POLICIES = {
    "nominal": "trained: nominal",
    "randomized": "trained: randomised",
    "calibrated": "trained: calibrated",
    "adr": "trained: ADR",
    "scripted": "scripted baseline",
}
#: Display names of the study's non-sweep conditions.
DISPLAY_CONDITIONS = {
    "sim": "sim: nominal",
    "randomized": "sim: randomised",
    "calibrated": "sim: calibrated",
    "adr": "sim: ADR final ranges",
    "real": "real twin",
}


def study_summary(report: Any, evaluation: Any = None) -> str:
    """The study's paragraph (see the module docstring), from ``report`` alone; ``evaluation`` is not needed
    (kept for callers of the old signature). Falls back to ``report.summary()`` when a study role is missing."""
    del evaluation
    try:
        parts = []
        sim, real = report.stats_for("nominal", "sim").mean, report.stats_for("nominal", "real").mean
        parts.append(
            f"Before calibration, the nominal policy returns {cell(sim, 3)} in sim and {cell(real, 3)} on the real "
            f"twin: it {gap_phrase(report.gap('nominal', 'sim', 'real'))}."
        )
        parts.append(
            f"The policy trained under domain randomisation chosen without data returns "
            f"{cell(report.stats_for('randomized', 'real').mean, 3)} on the twin: it "
            f"{gap_phrase(report.gap('randomized', 'randomized', 'real'))}."
        )
        parts.append(
            f"After system identification, the policy trained on the calibrated, randomised sim returns "
            f"{cell(report.stats_for('calibrated', 'real').mean, 3)} on the twin and "
            f"{cell(report.stats_for('calibrated', 'calibrated').mean, 3)} in the calibrated sim it was trained on: "
            f"it {gap_phrase(report.gap('calibrated', 'calibrated', 'real'))}."
        )
        parts.append(versus(report, "calibrated", "randomized", "the twin"))
        if any(s.policy == "adr" for s in report.stats):
            parts.append(
                f"The policy trained under automatic domain randomisation from the nominal point returns "
                f"{cell(report.stats_for('adr', 'real').mean, 3)} on the twin and "
                f"{cell(report.stats_for('adr', 'adr').mean, 3)} in its final ranges: it "
                f"{gap_phrase(report.gap('adr', 'adr', 'real'))}."
            )
            parts.append(versus(report, "adr", "randomized", "the twin"))
        for p in report.predictions:
            parts.append(prediction_sentence(report, p))
        parts.append(f"The scripted baseline returns {cell(report.stats_for('scripted', 'real').mean, 3)} on the twin.")
        if report.episode_target is not None:
            parts.append(episode_target_sentence(report))
        parts.append(
            f"Intervals: {report.confidence:.0%} stratified bootstrap over {episodes_text(report)}; paired where "
            "the conditions share initial states (over the episodes both ran)."
        )
        return " ".join(parts)
    except KeyError:
        return str(report.summary())
