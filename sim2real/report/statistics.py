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

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.evaluation import Condition, Evaluation
from sim2real.report import labels
from sim2real.report.computing import MAIN_KINDS, Builder, stream
from sim2real.report.results import (
    ConditionInfo,
    FitParameter,
    GapStats,
    ParameterDraws,
    Prediction,
)

if TYPE_CHECKING:
    from sim2real.sheets import ContactSheet
    from sysid.result import FitResult

__all__ = ["MAIN_KINDS", "predictions", "report_fields", "stream"]


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
    training: Mapping[str, str] | None = None,
    control_timestep: float | None = None,
    substeps: int | None = None,
    linear: Sequence[str] = (),
    tendons: Mapping[str, str] | Iterable[tuple[str, str]] | None = None,
    policy_labels: Mapping[str, str] | None = None,
    condition_labels: Mapping[str, str] | None = None,
    lead: str = "",
    observation_unit: str | None = None,
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

    names = [c.name for c in evaluation.conditions]
    trained = _training(evaluation, training, ref)
    if control_timestep is not None and (
        isinstance(control_timestep, bool)
        or not isinstance(control_timestep, (int, float))
        or not math.isfinite(control_timestep)
        or control_timestep <= 0
    ):
        raise ValueError(f"`control_timestep` must be a number of seconds > 0 or None. Received {control_timestep!r}.")
    if substeps is not None and (isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1):
        raise ValueError(f"`substeps` must be an int >= 1 or None. Received {substeps!r}.")
    if isinstance(linear, str) or not all(isinstance(n, str) for n in linear):
        raise ValueError(f"`linear` must be a sequence of element names. Received {linear!r}.")
    try:
        tendon_units = dict(tendons or {})
    except (TypeError, ValueError):
        tendon_units = {"": ""}  # not pairs: refused below
    if isinstance(tendons, str) or not all(
        isinstance(n, str) and u in ("m", "rad", "mixed") for n, u in tendon_units.items()
    ):
        raise ValueError(
            "`tendons` must map tendon names to the unit of their length, 'm', 'rad' or 'mixed' "
            f"(sim2real.report.labels.tendon_units). Received {tendons!r}."
        )
    if observation_unit is not None and (not isinstance(observation_unit, str) or not observation_unit):
        raise ValueError(f"`observation_unit` must be a non-empty string or None. Received {observation_unit!r}.")
    if not isinstance(lead, str):
        raise TypeError(f"`lead` must be a string. Received {type(lead).__name__}.")
    plabels = _labels("policy_labels", policy_labels, evaluation.policies, labels.policy_label)
    clabels = _labels(
        "condition_labels",
        condition_labels,
        names,
        lambda n: labels.condition_label(n, evaluation.condition(n).kind, simulated=evaluation.condition(n).simulated),
    )
    # every simulator that is not the target: the named reference and randomised sims first
    simulators = [r for r in (ref, rand) if r is not None]
    simulators += [c.name for c in evaluation.of_kind("nominal", "randomized") if c.name not in simulators]
    simulators = [n for n in simulators if n != tgt]

    builder = Builder(evaluation, statistic, confidence, alpha, fraction, num_resamples, seed)
    stats = builder.stats()
    gaps = builder.gaps(simulators, tgt)
    curves = builder.curves(trained)
    grids = builder.grids()
    agreement = builder.agreement(simulators, tgt)
    improvements = builder.improvements(tgt)
    differences = builder.differences(tgt)
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
        differences=differences,
        predictions=predictions(gaps, simulators, tgt),
        training=tuple(trained.items()),
        control_timestep=None if control_timestep is None else float(control_timestep),
        substeps=substeps,
        linear=tuple(linear),
        tendons=tuple(tendon_units.items()),
        policy_labels=tuple(plabels.items()),
        condition_labels=tuple(clabels.items()),
        lead=lead,
        observation_unit=observation_unit,
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


def predictions(gaps: Sequence[GapStats], simulators: Sequence[str], target: str | None) -> tuple[Prediction, ...]:
    """Per simulated condition, how closely it predicts ``target`` across the policies (from the ``gaps``).

    Example:
        >>> from sim2real.metrics import Estimate
        >>> e = lambda v, lo, hi: Estimate(v, lo, hi, 0.95, 20, "percentile bootstrap")
        >>> g = GapStats("p", "sim", "real", e(1.0, -1.0, 3.0), e(0.01, -0.01, 0.03), True, 20, 20, "mean")
        >>> predictions([g], ["sim"], "real")[0].within, predictions([g], ["sim"], "real")[0].differ
        (0.03, ())
    """
    out = []
    for sim in simulators:
        rows = [g for g in gaps if g.reference == sim and g.target == target]
        if not rows:
            continue
        ends = [max(abs(g.relative.low), abs(g.relative.high)) for g in rows]
        within = max(ends) if all(math.isfinite(v) for v in ends) else math.nan
        differ = tuple(g.policy for g in rows if g.absolute.low > 0.0 or g.absolute.high < 0.0)
        # the worst of the mispredicted policies (of all, when none is)
        finite = [g for g in rows if math.isfinite(g.relative.value) and (g.policy in differ or not differ)]
        worst = max(finite, key=lambda g: abs(g.relative.value)).policy if finite else ""
        out.append(Prediction(sim, str(target), tuple(g.policy for g in rows), within, differ, worst))
    return tuple(out)


def _training(evaluation: Evaluation, training: Mapping[str, str] | None, reference: str | None) -> dict[str, str]:
    """Policy -> the simulated condition it was trained in (default: the reference sim), checked."""
    names = [c.name for c in evaluation.of_kind("nominal", "randomized")]
    given = dict(training or {})
    for policy, cond in given.items():
        if policy not in evaluation.policies:
            raise ValueError(
                f"`training` keys must be policies of the evaluation {list(evaluation.policies)}. Received {policy!r}."
            )
        if cond not in names:
            raise ValueError(
                f"`training` values must be simulated (nominal or randomized) conditions {names}. "
                f"Received {cond!r} for policy {policy!r}."
            )
    out: dict[str, str] = {}
    for policy in evaluation.policies:
        trained = given.get(policy, reference)
        if trained is not None:
            out[policy] = trained
    return out


def _labels(argument: str, given: Mapping[str, str] | None, names: Sequence[str], default: Any) -> dict[str, str]:
    given = dict(given or {})
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise ValueError(f"`{argument}` keys must be among {list(names)}. Received {unknown}.")
    out = {n: str(given.get(n, default(n))) for n in names}
    return out


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
    # A fit the CLI refused to export (exit 4) must not read as a clean one in the report: its not-ok reasons
    # come first, before the per-channel warnings.
    not_ok = tuple(f"the fit is NOT OK: {reason}" for reason in fit.quality.reasons)
    warnings = not_ok + tuple(fit.warnings)
    return parameters, warnings, tuple((str(k), float(v)) for k, v in fit.fit_percent.items())


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
