"""The numbers of the gap report: argument checks, keyed generators and every statistic, from an evaluation.

:func:`report_fields` does the work behind :meth:`sim2real.report.GapReport.build`: it checks the arguments,
resolves the reference, randomised and target conditions, and computes every per-condition summary, gap,
robustness curve, heatmap, agreement and improvement with :mod:`sim2real.metrics`. Every interval draws from its
own generator, :func:`stream` ``(seed, *key)``, keyed by what it measures, so adding a policy or a sweep moves no
other interval; warnings raised while computing are collected (grouped, with where they arose), not lost.

Example:
    >>> import numpy as np
    >>> from sim2real.evaluation import Evaluation, nominal, real
    >>> sim = np.arange(20.0)
    >>> evaluation = Evaluation(
    ...     task="demo", seed=0, episodes=20, max_steps=None, policies=("p",),
    ...     conditions=(nominal(), real()), returns={"p": {"sim": sim, "real": sim - 1.0}},
    ...     successes={}, lengths={}, draws={})
    >>> fields = report_fields(evaluation, rng=0)
    >>> fields["target"], fields["gaps"][0].absolute.value
    ('real', 1.0)
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real import metrics
from sim2real.evaluation import Condition, Evaluation
from sim2real.metrics import Estimate
from sim2real.report.results import (
    Agreement,
    ConditionInfo,
    ConditionStats,
    FitParameter,
    GapStats,
    GridMeans,
    Improvement,
    ParameterDraws,
    RobustnessCurve,
)

if TYPE_CHECKING:
    from sim2real.sheets import ContactSheet
    from sysid.result import FitResult

__all__ = ["MAIN_KINDS", "report_fields", "stream"]

#: Condition kinds summarised one by one (sweep and grid points go to the robustness curves and heatmaps).
MAIN_KINDS: tuple[str, ...] = ("nominal", "randomized", "real", "measured")


def report_fields(
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
) -> dict[str, Any]:
    """Every field of a :class:`~sim2real.report.GapReport`, by name; the arguments are those of
    :meth:`GapReport.build <sim2real.report.GapReport.build>` (see there).

    Raises:
        TypeError: an argument of the wrong type.
        ValueError: a named condition that does not exist, reference/randomized equal to the target, or an
            argument out of range.
    """
    if not isinstance(evaluation, Evaluation):
        raise TypeError(f"`evaluation` must be a sim2real.evaluation.Evaluation. Received {type(evaluation).__name__}.")
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
    fit_parameters, fit_warnings, fit_percent = _fit_fields(fit)
    return dict(
        title=title if title is not None else f"Sim-to-real gap report: {evaluation.task}",
        task=evaluation.task,
        seed=int(evaluation.seed),
        episodes=int(evaluation.episodes),
        max_steps=evaluation.max_steps,
        env_steps=int(evaluation.env_steps),
        policies=tuple(evaluation.policies),
        conditions=condition_infos(evaluation),
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


def condition_infos(evaluation: Evaluation) -> tuple[ConditionInfo, ...]:
    """What each condition of ``evaluation`` is (configuration as canonical JSON text, draws summarised)."""
    return tuple(
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


def _fit_fields(
    fit: FitResult | None,
) -> tuple[tuple[FitParameter, ...], tuple[str, ...], tuple[tuple[str, float], ...]]:
    """The fit's parameters (with the true values, when known), warnings and held-out fit percentages."""
    if fit is None:
        return (), (), ()
    truths = dict(fit.true_params or {})
    parameters = tuple(
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
    return parameters, tuple(fit.warnings), tuple((str(k), float(v)) for k, v in fit.fit_percent.items())


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
