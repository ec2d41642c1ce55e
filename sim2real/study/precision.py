"""Enough episodes to decide: the study's episodes on the twin, chosen for the precision of its headline.

The headline is the paired difference ``calibrated - randomized`` on the real twin. The main evaluation is the
pilot: its ``budget.episodes`` episodes estimate the standard deviation ``sd`` of the per-episode differences, and
with the normal approximation a ``confidence`` interval over ``n`` episodes has half-width ``z * sd / sqrt(n)``.
The goal is a half-width of at most ``budget.precision`` of the nominal return (the nominal policy's mean in the
nominal sim), so ``needed = ceil((z * sd / goal) ** 2)``; the twin then runs ``max(needed, pilot)`` episodes of every
policy, rounded up to whole batches and at most the cap (:attr:`Budget.max_target_episodes` keeps the study within
its wall-time budget). While the longer run's spread asks for more, the episodes are planned again from it
(:func:`replan_rounds`, the study's target stage). The report reads the half-width reached from its own interval
(:meth:`sim2real.report.GapReport.with_episode_target`) and says whether the goal was met.

The longer twin run continues the pilot (or the previous round): episodes ``pilot``, ``pilot + 1``, ... with the same
episode seeds and in the same batches as a run from episode 0 (:func:`run_target` with ``pilot=``; the pilot's
episodes are not run again), so its first ``pilot`` episodes are the pilot's own (bitwise) and its rows keep sharing
initial states with every other condition's.

Example:
    >>> import numpy as np
    >>> from sim2real.conditions import nominal, real
    >>> from sim2real.evaluation_results import Evaluation
    >>> rng = np.random.default_rng(0)
    >>> returns = {p: {"sim": rng.normal(800, 50, 32), "real": rng.normal(600, 300, 32)}
    ...            for p in ("nominal", "randomized", "calibrated")}
    >>> ev = Evaluation(task="demo", seed=0, episodes=32, max_steps=None, policies=tuple(returns),
    ...     conditions=(nominal(), real(params={"body_mass[arm]": 1.2})), returns=returns, successes={}, lengths={},
    ...     draws={})
    >>> t = plan_target(ev, fraction=0.05, cap=256)
    >>> bool(t.goal == 0.05 * abs(returns["nominal"]["sim"].mean())), t.needed > t.episodes == t.cap == 256
    (True, True)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from statistics import NormalDist
from typing import Any

import numpy as np

from sim2real.report.results import EpisodeTarget

__all__ = ["extend", "plan_target", "replan_rounds", "run_target"]


def plan_target(
    evaluation: Any,
    *,
    fraction: float,
    cap: int,
    batch: int = 1,
    x: str = "calibrated",
    y: str = "randomized",
    condition: str = "real",
    reference: tuple[str, str] = ("nominal", "sim"),
    confidence: float = 0.95,
) -> EpisodeTarget:
    """The episodes ``condition`` needs so that the ``confidence`` interval of ``mean(x) - mean(y)`` there has a
    half-width of at most ``fraction`` of ``reference``'s mean return (see the module docstring); the evaluation's
    episodes are the pilot. With ``batch`` > 1 the episodes are rounded up to whole batches (within ``cap``), so a
    longer run can continue this one (:func:`run_target`) instead of starting again after the pilot. ``half_width``
    is NaN until the report fills it in.

    Raises:
        ValueError: ``fraction`` not in (0, 1], ``cap`` or ``batch`` not an int >= 1, or returns missing for ``x``
            or ``y`` on ``condition`` or for the reference (the names and what the evaluation has are given).
    """
    if isinstance(fraction, bool) or not isinstance(fraction, (int, float)) or not 0 < fraction <= 1:
        raise ValueError(f"`fraction` must be a number in (0, 1]. Received {fraction!r}.")
    if isinstance(cap, bool) or not isinstance(cap, int) or cap < 1:
        raise ValueError(f"`cap` must be an int >= 1. Received {cap!r}.")
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise ValueError(f"`batch` must be an int >= 1. Received {batch!r}.")
    returns = evaluation.returns

    def get(policy: str, cond: str) -> np.ndarray:
        values = returns.get(policy, {}).get(cond)
        if values is None or len(values) == 0:
            have = {p: sorted(c) for p, c in returns.items()}
            raise ValueError(f"no returns of policy {policy!r} on {cond!r}; the evaluation has {have}.")
        return np.asarray(values, dtype=np.float64)

    a, b = get(x, condition), get(y, condition)
    pilot = int(min(a.size, b.size))
    diff = a[:pilot] - b[:pilot]
    sd = float(diff.std(ddof=1)) if pilot > 1 else math.nan
    ref = float(get(*reference).mean())
    goal = fraction * abs(ref)
    z = NormalDist().inv_cdf(0.5 + confidence / 2.0)
    needed: int | None
    if not goal > 0 or not math.isfinite(sd):
        needed, goal = None, (goal if goal > 0 else math.nan)
    else:
        needed = max(2, math.ceil((z * sd / goal) ** 2 - 1e-9))
    episodes = pilot if needed is None else min(-(-max(needed, pilot) // batch) * batch, max(cap, pilot))
    return EpisodeTarget(
        condition=condition,
        x=x,
        y=y,
        reference_policy=reference[0],
        reference_condition=reference[1],
        reference_return=ref,
        fraction=float(fraction),
        goal=float(goal),
        pilot_episodes=pilot,
        pilot_sd=sd,
        needed=needed,
        cap=int(cap),
        episodes=int(episodes),
        half_width=math.nan,
        confidence=float(confidence),
    )


def replan_rounds(
    plan: EpisodeTarget,
    run_to: Callable[[int], Any],
    replan: Callable[[Any], EpisodeTarget],
    *,
    rounds: int = 4,
    note: Callable[[str], None] | None = None,
) -> tuple[Any, EpisodeTarget]:
    """Runs ``run_to(plan.episodes)`` (the evaluation with that many episodes on the target), plans again from it
    with ``replan`` and, while the new plan asks for more episodes, runs that, at most ``rounds`` runs in all: a
    pilot's spread is off when returns are bimodal (one stall moves a paired difference by ~1000), so the longer
    run's spread plans the next. Returns the last evaluation and the plan that ran (the report's target).

    Example:
        >>> import dataclasses
        >>> base = EpisodeTarget("real", "a", "b", "a", "sim", 900.0, 0.05, 45.0, 32, 150.0, 43, 128, 43, 0.0, 0.95)
        >>> asks = {43: 60, 60: 61, 61: 61}  # episodes run -> what their spread asks for
        >>> ran, plan = replan_rounds(base, lambda n: n, lambda n: dataclasses.replace(base, episodes=asks[n]))
        >>> ran, plan.episodes
        (61, 61)
    """
    if isinstance(rounds, bool) or not isinstance(rounds, int) or rounds < 1:
        raise ValueError(f"`rounds` must be an int >= 1. Received {rounds!r}.")
    current: Any = None
    for round_ in range(rounds):
        current = run_to(plan.episodes)
        again = replan(current)
        if round_ == rounds - 1 or again.episodes <= plan.episodes:
            break
        if note is not None:
            note(f"the {plan.episodes} episodes put the spread higher than the pilot did: {again.episodes} episodes "
                 f"(cap {again.cap})")  # fmt: skip
        plan = again
    return current, plan


def run_target(spec: Any, condition: str, episodes: int, *, pilot: Any = None, **run: Any) -> Any:
    """``spec`` (an :class:`sim2real.spec.EvaluationSpec`) run on ``condition`` alone for ``episodes`` episodes of
    every policy; ``run`` goes to ``spec.run`` (backend, workers, progress, safety).

    With ``pilot`` (an evaluation of ``spec`` that has ``condition``, e.g. the study's main one), its episodes are
    not run again when they fill whole batches of ``spec.batch``: only episodes ``pilot.episodes``, ... run (in the
    batches a run from 0 has) and the pilot's rows are put in front, so the result is bitwise the run from 0 (its
    ``seconds`` are the new episodes' alone)."""
    chosen = tuple(c for c in spec.conditions if c.name == condition)
    if not chosen:
        raise ValueError(f"`condition` must be one of {[c.name for c in spec.conditions]}. Received {condition!r}.")
    start = 0 if pilot is None else int(pilot.episodes)
    if pilot is not None and (start % spec.batch or start >= episodes or pilot.policies != tuple(spec.policies)):
        start = 0  # not whole batches of a run from 0 (or nothing to add): run every episode
    target = dataclasses.replace(spec, conditions=chosen, episodes=int(episodes) - start)
    more = target.run(start=start, **run)
    return more if start == 0 else _stitch(pilot, more, condition, int(episodes))


def _stitch(pilot: Any, more: Any, condition: str, episodes: int) -> Any:
    """``more`` (episodes ``pilot.episodes``, ... of ``condition``) with the pilot's rows of ``condition`` in front."""
    from sim2real.evaluation import _safety_view
    from sim2real.evaluation_results import _nested

    def joined(before: Any, after: Any, dtype: Any) -> Any:
        out = {p: {c: np.concatenate([before[p][c], x]) if c == condition else x for c, x in v.items()}
               for p, v in after.items()}  # fmt: skip
        return _nested(out, dtype)

    draws = {}
    if condition in more.draws:
        old = pilot.draws.get(condition, {})
        nan = np.full(pilot.episodes, math.nan)
        draws[condition] = {k: np.concatenate([old.get(k, nan), v]) for k, v in more.draws[condition].items()}
    safety = {p: {condition: {q: np.concatenate([pilot.safety[p][condition][q], v]) for q, v in d[condition].items()}}
              for p, d in more.safety.items() if condition in d}  # fmt: skip
    steps = sum(int(pilot.lengths[p][condition].sum()) for p in pilot.policies if condition in pilot.lengths.get(p, {}))
    return dataclasses.replace(
        more,
        episodes=episodes,
        returns=joined(pilot.returns, more.returns, np.float64),
        lengths=joined(pilot.lengths, more.lengths, np.int64),
        successes=joined(pilot.successes, more.successes, bool),
        draws=_nested(draws, np.float64),
        safety=_safety_view(safety),
        env_steps=more.env_steps + steps,
    )


def extend(evaluation: Any, more: Any, condition: str) -> Any:
    """``evaluation`` with ``condition``'s returns, lengths, successes, draws and safety measurements replaced by
    ``more``'s (a longer run of the same policies and seed on that condition, :func:`run_target`).

    Raises:
        ValueError: ``more`` has other policies, another seed, or fewer episodes on ``condition``, or its first
            episodes differ from ``evaluation``'s (it is not a continuation of the same episodes).
    """
    from sim2real.evaluation import _safety_view
    from sim2real.evaluation_results import _nested

    if more.policies != evaluation.policies or more.seed != evaluation.seed:
        raise ValueError(
            f"`more` must be a run of the same policies and seed: {list(evaluation.policies)} seed "
            f"{evaluation.seed}. Received {list(more.policies)} seed {more.seed}."
        )
    for p in evaluation.policies:
        old, new = evaluation.returns[p][condition], more.returns[p][condition]
        if new.size < old.size or not np.array_equal(new[: old.size], old):
            raise ValueError(
                f"`more` must continue the episodes of {condition!r}: policy {p!r} has {new.size} episodes there "
                f"whose first {old.size} differ from the evaluation's."
            )

    def swap(data: Any, extra: Any) -> dict[str, dict[str, np.ndarray]]:
        out = {k: dict(v) for k, v in data.items()}
        for k, v in extra.items():
            if condition in v:
                out.setdefault(k, {})[condition] = v[condition]
        return out

    draws = {k: dict(v) for k, v in evaluation.draws.items()}
    if condition in more.draws:
        draws[condition] = dict(more.draws[condition])
    safety = {p: {c: dict(q) for c, q in d.items()} for p, d in evaluation.safety.items()}
    for p, d in more.safety.items():
        if condition in d:
            safety.setdefault(p, {})[condition] = dict(d[condition])
    old_steps = sum(int(evaluation.lengths[p][condition].sum()) for p in evaluation.policies
                    if condition in evaluation.lengths.get(p, {}))  # fmt: skip
    return dataclasses.replace(
        evaluation,
        returns=_nested(swap(evaluation.returns, more.returns), np.float64),
        lengths=_nested(swap(evaluation.lengths, more.lengths), np.int64),
        successes=_nested(swap(evaluation.successes, more.successes), bool),
        draws=_nested(draws, np.float64),
        safety=_safety_view(safety),
        env_steps=evaluation.env_steps - old_steps + more.env_steps,
        seconds=evaluation.seconds + more.seconds,
    )
