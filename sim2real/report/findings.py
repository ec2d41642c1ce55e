"""What the data say, in sentences: the report's headline, read from paired intervals, never from the largest number.

Each sentence carries an interval from the same report:

- **the best policy on the target** against every other policy: the paired difference with its interval, and
  whether it is significant (the interval excludes 0) at the episodes run; when it is not, roughly how many
  episodes would resolve a difference of that size (the half-width shrinks as ``1 / sqrt(n)``);
- **does each simulator predict the target**: the largest end of any policy's relative-gap interval ("predicts the
  twin within 1.3% for all 4 policies"), or which policies it mispredicts (their gap interval excludes 0);
- **rank agreement**: Spearman (SRCC), Pearson and MMRV, named as what they are;
- **the budget**: too few episodes for the interval asked, with the minimum (:func:`sim2real.metrics.minimum_runs`).

Undefined numbers are said to be undefined and why ("relative gap undefined: the sim return is 0"), and an
interval of zero width says it has no spread, rather than printing ``nan%`` or ``0 [0, 0]`` silently.

Example:
    >>> from sim2real.metrics import Estimate
    >>> signed(Estimate(29.0, -10.0, 68.0, 0.95, 64, "percentile bootstrap"))
    '+29 [-10, +68]'
    >>> cell(Estimate(0.0, 0.0, 0.0, 0.95, 8, "percentile bootstrap"))
    '0 [0, 0] (no spread: the same in every bootstrap resample)'
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from sim2real.metrics import Estimate, minimum_runs
from sim2real.report.results import GapStats, Prediction

if TYPE_CHECKING:
    from sim2real.report.gap_report import GapReport

__all__ = [
    "budget_warnings",
    "cell",
    "episode_target_sentence",
    "episodes_text",
    "findings",
    "gap_phrase",
    "num",
    "pct",
    "prediction_sentence",
    "signed",
    "versus",
]


def num(value: float, digits: int = 4) -> str:
    """``value`` to ``digits`` significant digits, or ``n/a`` when not finite."""
    return f"{value:.{digits}g}" if math.isfinite(value) else "n/a"


def cell(e: Estimate | None, digits: int = 4) -> str:
    """``value [low, high]``; ``n/a`` for None; a zero-width interval says it has no spread."""
    if e is None:
        return "n/a"
    text = f"{num(e.value, digits)} [{num(e.low, digits)}, {num(e.high, digits)}]"
    if math.isfinite(e.value) and e.low == e.high == e.value:
        # Not "every run returned the same": a tail statistic (CVaR, worst) has no spread whenever the tail's runs
        # agree (e.g. 10% of the episodes return 0), however different the others are.
        text += " (no spread: the same in every bootstrap resample)"
    return text


def signed(e: Estimate, digits: int = 3) -> str:
    """A difference with explicit signs: ``+29 [-10, +68]``."""

    def one(v: float) -> str:
        if not math.isfinite(v):
            return "n/a"
        text = f"{v:+.{digits}g}"
        return "0" if float(text) == 0.0 else text  # no "-0" or "+0" for an end that rounds to zero

    return f"{one(e.value)} [{one(e.low)}, {one(e.high)}]"


def pct(value: float) -> str:
    """``value`` as a percentage with one decimal, or ``n/a``."""
    return f"{100.0 * value:.1f}%" if math.isfinite(value) else "n/a"


def _flipped(e: Estimate) -> Estimate:
    """``-e`` with its ends swapped (``+ 0.0`` so no end prints as ``-0``)."""
    return Estimate(-e.value + 0.0, -e.high + 0.0, -e.low + 0.0, e.confidence, e.n, e.method)


def gap_phrase(g: GapStats) -> str:
    """The gap of one policy between two named ends, worded by the sign of its point estimate:
    ``"loses 10.2% [9.6%, 10.9%] from sim to real (gap 10.12 [9.528, 10.76], paired)"`` or ``"gains ..."``."""
    where = f"from {g.reference} to {g.target}"
    pairing = (
        ("paired" if g.n_reference == g.n_target else f"paired over {min(g.n_reference, g.n_target)} runs")
        if g.paired
        else f"unpaired, {g.n_reference} vs {g.n_target} runs"
    )
    rel, ab = g.relative, g.absolute
    if not math.isfinite(rel.value):
        verb = "loses" if ab.value > 0 else "gains" if ab.value < 0 else "keeps"
        size = ab if ab.value >= 0 else _flipped(ab)
        return (
            f"{verb} {cell(size)} {where} (absolute; the relative gap is undefined: the {g.reference} "
            f"{g.statistic} return is 0; {pairing})"
        )
    if not math.isfinite(rel.low):  # the claim is the absolute gap, which has an interval; the % is a side note
        verb = "loses" if ab.value > 0 else "gains" if ab.value < 0 else "keeps"
        size = ab if ab.value >= 0 else _flipped(ab)
        return (
            f"{verb} {cell(size)} {where} (absolute; {pct(abs(rel.value))} relative, without an interval: the "
            f"{g.reference} {g.statistic} return is 0 in too many resamples; {pairing})"
        )
    if rel.value > 0:
        amount = f"loses {pct(rel.value)} [{pct(rel.low)}, {pct(rel.high)}]"
    elif rel.value < 0:
        amount = f"gains {pct(-rel.value)} [{pct(-rel.high)}, {pct(-rel.low)}]"
    else:
        amount = f"keeps its return (0.0% [{pct(rel.low)}, {pct(rel.high)}])"
    return f"{amount} {where} (gap {cell(ab)}, {pairing})"


def findings(report: GapReport) -> tuple[str, ...]:
    """The headline sentences of ``report`` (see the module docstring), each backed by one of its intervals."""
    out: list[str] = []
    target = report.target
    if target is not None and report.differences:
        scored = [s for s in report.stats if s.condition == target]
        best = max(scored, key=lambda s: s.statistic(report.statistic).value, default=None)
        if best is not None:
            out.append(
                f"On {target}, {best.policy!r} has the highest {report.statistic} return "
                f"({cell(best.statistic(report.statistic))})."
            )
            for other in scored:
                if other.policy == best.policy:
                    continue
                out.append(versus(report, best.policy, other.policy, target))
    out += [prediction_sentence(report, p) for p in report.predictions]
    for a in report.agreement:
        if a.srcc is not None:
            out.append(
                f"{a.reference} ranks the {len(a.policies)} policies like {a.target}: Spearman rank correlation (SRCC) "
                f"{cell(a.srcc)}, Pearson {cell(a.pearson)}, MMRV {cell(a.mmrv)} (0 = the same ranking)."
            )
    return tuple(out)


def prediction_sentence(report: GapReport, p: Prediction) -> str:
    """Whether simulator ``p.simulator`` predicts the target for every policy, with the interval bound."""
    conf = f"{report.confidence:.0%}"
    k = len(p.policies)
    policies = f"polic{'y' if k == 1 else 'ies'}"
    if not p.differ and math.isfinite(p.within):
        return (
            f"{p.simulator} predicts {p.target} within {pct(p.within)} for all {k} {policies} (the largest end of any "
            f"policy's {conf} interval of the relative gap)."
        )
    if not p.differ:
        return (
            f"{p.simulator} vs {p.target}: no policy differs significantly, but a relative gap is undefined (a "
            "return of 0), so no bound in % is given."
        )
    worst = next((g for g in report.gaps if g.policy == p.worst and g.reference == p.simulator), None)
    detail = f"; largest: {p.worst!r} {gap_phrase(worst)}" if worst is not None else ""
    return (
        f"{p.simulator} mispredicts {p.target} for {len(p.differ)} of {k} {policies} "
        f"({', '.join(map(repr, p.differ))}: their {conf} gap interval excludes 0){detail}."
    )


def versus(report: GapReport, x: str, y: str, where: str) -> str:
    """``stat(x) - stat(y)`` on the report's target (named ``where`` in the sentence), whether it is significant
    at the episodes run and, when not, about how many episodes would resolve a difference of that size.

    Raises:
        KeyError: the report has no difference between ``x`` and ``y``.
    """
    d = report.difference(x, y)
    e = d.difference
    head = f"{x!r} vs {y!r} on {where}: {signed(e)}"
    if d.significant:
        return f"{head}, significant at {d.n} episodes ({'paired' if d.paired else 'unpaired'})."
    text = f"{head}, not significant at {d.n} episodes (the {report.confidence:.0%} interval includes 0)"
    half = (e.high - e.low) / 2.0
    if math.isfinite(half) and abs(e.value) > 0 and half > 0:
        need = math.ceil(d.n * (half / abs(e.value)) ** 2)
        text += f"; about {need} episodes would resolve a difference of this size"
    return text + "."


def episodes_text(report: GapReport) -> str:
    """``"32 episode(s) per simulated condition"``, naming the conditions run with other counts:
    ``"32 episode(s) per simulated condition (160 on real)"``; a condition whose policies ran different counts
    gives the range (``"32-160 on real"``)."""
    others = []
    for condition, counts in report.episode_counts().items():
        if counts != (report.episodes,):
            n = str(counts[0]) if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
            others.append(f"{n} on {condition}")
    extra = f" ({', '.join(others)})" if others else ""
    return f"{report.episodes} episode(s) per simulated condition{extra}"


def episode_target_sentence(report: GapReport) -> str:
    """How the episodes on the target were chosen (:class:`~sim2real.report.results.EpisodeTarget`) and whether
    the interval's half-width reached the goal; ``""`` when the report has no episode target."""
    t = report.episode_target
    if t is None:
        return ""
    what = f"the {t.confidence:.0%} interval of {t.x!r} - {t.y!r} on {t.condition}"
    if t.needed is None or not math.isfinite(t.goal):
        return (
            f"Episodes on {t.condition}: {t.episodes}; no precision goal for {what}: the reference return of "
            f"{t.reference_policy!r} on {t.reference_condition!r} is {num(t.reference_return)}, so {t.fraction:.0%} "
            "of it is no width."
        )
    ask = (
        f"the pilot's {t.pilot_episodes} episodes put the standard deviation of the paired differences at "
        f"{num(t.pilot_sd, 3)}, asking for about {t.needed}"
    )
    if t.capped:
        ask += f"; the budget caps it at {t.cap}"
    verdict = "goal met" if t.met else f"goal not met (about {t.needed_now} episodes would meet it)"
    return (
        f"Episodes on {t.condition}: {t.episodes}, chosen so that {what} is at most +-{num(t.goal, 3)} "
        f"({t.fraction:.0%} of the mean return {num(t.reference_return)} of {t.reference_policy!r} on "
        f"{t.reference_condition!r}): "
        f"{ask}. Achieved +-{num(t.half_width, 3)}: {verdict}."
    )


def budget_warnings(report: GapReport) -> tuple[str, ...]:
    """Warnings about the budget: too few episodes (or resamples) for the interval asked, with the minimum, and a
    precision goal on the target's episodes that was not met."""
    need = minimum_runs(report.confidence)
    out = []
    t = report.episode_target
    if t is not None and math.isfinite(t.goal) and not t.met:
        out.append(
            f"Precision goal not met: {t.x!r} - {t.y!r} on {t.condition} has a {t.confidence:.0%} half-width of "
            f"{num(t.half_width, 3)} at {t.episodes} episodes, above the goal {num(t.goal, 3)} ({t.fraction:.0%} of "
            f"the mean return of {t.reference_policy!r} on {t.reference_condition!r})"
            + (f"; about {t.needed_now} episodes would meet it." if t.needed_now is not None else ".")
        )
    counts = sorted({s.n for s in report.stats})
    if counts and counts[0] < need:
        out.append(
            f"Small budget: {counts[0]} episode(s) per condition; a {report.confidence:.0%} bootstrap interval needs "
            f">= {need} per condition (the intervals here are likely too narrow and the headline may not hold)."
        )
    tail = report.num_resamples * (1.0 - report.confidence) / 2.0
    if tail < 25 - 1e-9:
        out.append(
            f"Few resamples: {report.num_resamples} leave {tail:g} in each tail of a {report.confidence:.0%} interval; "
            f"use >= {math.ceil(round(50.0 / (1.0 - report.confidence), 9))} for stable interval ends."
        )
    return tuple(out)
