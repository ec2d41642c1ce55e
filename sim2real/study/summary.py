"""The study's one-paragraph summary (printed, and at the top of the report)."""

from __future__ import annotations

import warnings
from typing import Any

__all__ = ["study_summary"]


def _fmt(e: Any, percent: bool = False) -> str:
    if percent:
        return f"{100 * e.value:.0f}% [{100 * e.low:.0f}%, {100 * e.high:.0f}%]"
    return f"{e.value:.0f} [{e.low:.0f}, {e.high:.0f}]"


def study_summary(report: Any, evaluation: Any = None) -> str:
    """The study's one-paragraph summary: the sim-to-real gap before calibration (the nominal and the randomised
    policy, from the nominal sim) and after it (the calibrated policy, whose own sim is the calibrated one; needs
    the ``evaluation``), with intervals."""
    try:
        parts = []
        conf = report.stats_for("nominal", "sim").mean.confidence
        nominal_sim, nominal_real = report.stats_for("nominal", "sim").mean, report.stats_for("nominal", "real").mean
        parts.append(
            f"Before calibration, the nominal policy returns {_fmt(nominal_sim)} in sim and {_fmt(nominal_real)} on the "
            f"real twin: it loses {_fmt(report.gap('nominal').relative, True)} of its sim return."
        )
        randomized_real = report.stats_for("randomized", "real").mean
        parts.append(
            f"Domain randomisation chosen without data gives {_fmt(randomized_real)} on the twin "
            f"(loss {_fmt(report.gap('randomized').relative, True)})."
        )
        calibrated_real = report.stats_for("calibrated", "real").mean
        text = (
            f"After system identification, the policy trained on the calibrated, randomised sim returns "
            f"{_fmt(calibrated_real)} on the twin"
        )
        if evaluation is not None:
            from sim2real import metrics

            with warnings.catch_warnings():  # the report lists the few-samples warnings already
                warnings.simplefilter("ignore", metrics.FewSamplesWarning)
                own = metrics.gap(
                    evaluation.table("calibrated", ["calibrated", "real"]),
                    paired=True,
                    rng=report.rng_seed,
                    num_resamples=report.num_resamples,
                )
            text += (
                f" and {_fmt(report.stats_for('calibrated', 'calibrated').mean)} in the calibrated sim it was trained "
                f"on, so it loses {_fmt(own.relative, True)} from its own sim to the twin"
            )
        parts.append(text + ".")
        scripted = report.stats_for("scripted", "real").mean
        parts.append(f"The scripted baseline returns {_fmt(scripted)} on the twin.")
        parts.append(f"Intervals: {100 * conf:.0f}% stratified bootstrap over {nominal_sim.n} episodes per condition.")
        return " ".join(parts)
    except KeyError:
        return report.summary()
