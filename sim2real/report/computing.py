"""The computations of the gap report: one keyed generator per interval, warnings collected, every statistic.

:class:`Builder` computes per-condition summaries, gaps, robustness curves (radii against each policy's training
sim), heatmaps, agreement, improvements and policy differences with :mod:`sim2real.metrics`; every interval draws
from its own generator, :func:`stream` ``(seed, *key)``, keyed by what it measures, so adding a policy or a sweep
moves no other interval. :func:`sim2real.report.statistics.report_fields` drives it.

Example:
    >>> a, b = stream(0, "gap", "ppo", "sim", "real"), stream(0, "gap", "ppo", "sim", "real")
    >>> bool(a.random() == b.random())
    True
"""

from __future__ import annotations

import hashlib
import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager

import numpy as np

from sim2real import metrics
from sim2real.evaluation import Evaluation
from sim2real.metrics import Estimate
from sim2real.report.results import (
    Agreement,
    ConditionStats,
    GapStats,
    GridMeans,
    Improvement,
    PolicyDifference,
    RobustnessCurve,
)

__all__ = ["MAIN_KINDS", "Builder", "stream"]

#: Condition kinds summarised one by one (sweep and grid points go to the robustness curves and heatmaps).
MAIN_KINDS: tuple[str, ...] = ("nominal", "randomized", "real", "measured")


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


# ------------------------------------------------------------------------------------------------ computation


class Builder:
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
                paired = self.ev.condition(ref).simulated and tcond.simulated
                counts = (int(a.size), int(b.size))
                if paired and a.size != b.size:
                    # Row e of every simulated condition is the same initial state, so two conditions that ran
                    # different numbers of episodes (more on the target) are paired over the first ones they share.
                    a, b = a[: min(a.size, b.size)], b[: min(a.size, b.size)]
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
                        n_reference=counts[0],
                        n_target=counts[1],
                        statistic=self.statistic,
                    )
                )
        return tuple(out)

    def curves(self, training: Mapping[str, str]) -> tuple[RobustnessCurve, ...]:
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
                # the threshold is a fraction of what the policy earns in the sim it was trained in
                trained_in = training.get(policy, "")
                reference = self.returns(policy, trained_in) if trained_in else None
                if trained_in and reference is None:
                    self.skip(
                        f"robustness of {policy!r}: no returns on its training sim {trained_in!r}; "
                        "its radii are measured against the sweep's nominal point."
                    )
                    trained_in = ""
                ref_value = self.point(reference) if reference is not None else math.nan
                radius, note = None, ""
                on_grid = np.flatnonzero(np.isclose(values, nominal, rtol=1e-9, atol=1e-12))
                if values.size < 2 or np.any(np.diff(values) <= 0):
                    note = "the sweep's values are not at least 2 strictly increasing points"
                elif on_grid.size != 1:
                    note = f"the nominal value {nominal:g} is not on the sweep's grid"
                elif reference is None and not points[int(on_grid[0])].value > 0:
                    note = f"the nominal {self.statistic} return {points[int(on_grid[0])].value:.4g} is not positive"
                elif reference is not None and not ref_value > 0:
                    note = f"the {self.statistic} return {ref_value:.4g} in its training sim {trained_in!r} is not positive"
                else:
                    with self.warnings.where(f"radius of {policy!r} on {name!r}"):
                        radius = metrics.robustness_radius(
                            values,
                            table,
                            nominal=nominal,
                            fraction=self.fraction,
                            statistic=self.statistic,
                            paired=all(c.simulated for c in conds),
                            reference=reference,
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
                        reference=trained_in,
                    )
                )
        return tuple(out)

    def differences(self, target: str | None) -> tuple[PolicyDifference, ...]:
        """``stat(x) - stat(y)`` on the target for each pair of policies (paired on a simulated target)."""
        if target is None:
            return ()
        out = []
        simulated = self.ev.condition(target).simulated
        policies = [p for p in self.ev.policies if self.returns(p, target) is not None]
        for i, x in enumerate(policies):
            for y in policies[i + 1 :]:
                a, b = self.returns(x, target), self.returns(y, target)
                assert a is not None and b is not None
                paired = simulated and a.size == b.size
                options = dict(
                    statistic=self.statistic,
                    rng=stream(self.seed, "difference", target, x, y),
                    confidence=self.confidence,
                    num_resamples=self.num_resamples,
                )
                with self.warnings.where(f"{x!r} - {y!r} on {target!r}"):
                    if paired:
                        g = metrics.gap(np.column_stack([a, b]), paired=True, **options)  # type: ignore[arg-type]
                    else:
                        g = metrics.unpaired_gap(a, b, **options)  # type: ignore[arg-type]
                out.append(PolicyDifference(target, x, y, g.absolute, paired, int(min(a.size, b.size)), self.statistic))
        return tuple(out)

    def point(self, x: np.ndarray) -> float:
        if self.statistic == "mean":
            return float(x.mean())
        return float(metrics.iqm_point(x[:, None])[0])

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
            srcc = mmrv = pearson = None
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
                        pearson = metrics.pearson(
                            sim,
                            real,
                            statistic=self.statistic,
                            rng=stream(self.seed, "pearson", ref, target),
                            confidence=self.confidence,
                            num_resamples=self.num_resamples,
                        )
                    except ValueError as err:
                        note = f"SRCC and Pearson undefined: {err}"
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
            out.append(Agreement(ref, target, policies, srcc, mmrv, note, pearson))
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
