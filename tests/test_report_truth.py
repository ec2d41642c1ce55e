"""The report says what the data say (issue 14): signed gaps between named ends, a headline read from paired
intervals, per-simulator prediction of the target, Spearman named as Spearman, censored radii against each policy's
training sim, small-budget warnings, undefined numbers said to be undefined, figures in words and units."""

from __future__ import annotations

import io
import json
import math
import re
from pathlib import Path

import numpy as np
import PIL.Image
import pytest

import sim2real as s2r
from sim2real.evaluation import Evaluation, grid, nominal, randomized, real, sweep
from sim2real.report import GapReport
from sim2real.report.labels import axis_label
from sim2real.study.summary import DISPLAY_CONDITIONS, DISPLAY_POLICIES, TRAINING, study_summary

POLICIES = ("nominal", "randomized", "calibrated", "scripted")


def _study_like(episodes: int, seed: int = 0) -> Evaluation:
    """The study's shape without an env: the calibrated sim predicts the twin for every policy (the issue's
    finding), the nominal sim overrates every policy by ~10%, calibrated and randomised differ by less than the
    noise on the twin; sweeps over gain (censored for everyone) and latency (crossed)."""
    conditions = (
        nominal(),
        randomized([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))]),
        randomized([s2r.Damping(scale=s2r.Uniform(2.5, 3.5))], name="calibrated"),
        real(params={"dof_damping[shoulder]": 0.03}),
        *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 1.0, 1.25]),
        *sweep({"type": "ActionLatency", "steps": 0}, "steps", [0, 1, 2, 4]),
        *grid(
            {"effect": {"type": "Damping", "scale": 1.0}, "field": "scale", "values": [1.0, 2.0, 3.0]},
            {"effect": {"type": "ActuatorGain", "scale": 1.0}, "field": "scale", "values": [0.75, 1.0]},
        ),
    )
    rng = np.random.default_rng(seed)
    level = {"nominal": 530.0, "randomized": 690.0, "calibrated": 712.0, "scripted": 815.0}
    start = rng.normal(0.0, 60.0, episodes)  # the initial state's effect, shared by every condition (paired rows)
    returns: dict[str, dict[str, np.ndarray]] = {}
    for policy in POLICIES:
        mine = level[policy] + start
        out = {
            "sim": 1.1 * mine + rng.normal(0.0, 3.0, episodes),
            "randomized": mine + rng.normal(5.0, 3.0, episodes),
            "calibrated": mine + rng.normal(0.0, 3.0, episodes),
            "real": mine + rng.normal(0.0, 3.0, episodes),
        }
        for c in conditions:
            if c.sweep is None:
                continue
            if c.kind == "grid":
                out[c.name] = mine * (1.0 - 0.05 * abs(c.value[0] - 1.0))
            elif c.axes[0].startswith("ActuatorGain"):
                out[c.name] = mine * (1.0 - 0.1 * abs(c.value[0] - 1.0))  # never below 0.8: censored
            else:
                out[c.name] = mine * (1.0 - 0.15 * c.value[0])  # latency: crossed between 1 and 2 steps
        returns[policy] = out
    return Evaluation(
        task="dmc/reacher-easy", seed=seed, episodes=episodes, max_steps=None, policies=POLICIES,
        conditions=conditions, returns=returns, successes={}, lengths={}, draws={},
    )  # fmt: skip


def _build(evaluation: Evaluation, **kwargs: object) -> GapReport:
    report = GapReport.build(
        evaluation, num_resamples=1000, rng=0, control_timestep=0.02,
        training={p: c for p, c in TRAINING.items() if p in evaluation.policies},  # the study's table may name more
        policy_labels={p: n for p, n in DISPLAY_POLICIES.items() if p in evaluation.policies},
        condition_labels={c: n for c, n in DISPLAY_CONDITIONS.items() if c in {x.name for x in evaluation.conditions}},
        **kwargs,  # type: ignore[arg-type]
    )  # fmt: skip
    return report.with_lead(study_summary(report))


@pytest.fixture(scope="module")
def report() -> GapReport:
    return _build(_study_like(32))


def test_every_simulator_gets_a_gap_to_the_target_worded_by_its_sign(report: GapReport) -> None:
    for policy in POLICIES:
        for sim in ("sim", "randomized", "calibrated"):
            report.gap(policy, sim, "real")  # a calibrated -> real row exists for every policy
    text = report.summary()
    # the nominal sim overrates (the policy loses on the twin); the randomised sim's +5 bias too
    assert re.search(r"'nominal' loses 9\.\d% \[[\d.]+%, [\d.]+%\] from sim to real \(gap [\d.]+ \[", text)
    assert "loses -" not in text and "gains -" not in text and "nan" not in text.lower()
    g = report.gap("scripted", "calibrated", "real")
    word = "loses" if g.absolute.value > 0 else "gains"
    assert f"{word} " in report.to_markdown().split("Sim-to-real gaps")[1].split("\n## ")[0]


def test_headline_is_read_from_paired_intervals(report: GapReport) -> None:
    d = report.difference("calibrated", "randomized")
    assert d.paired and d.n == 32 and d.difference.low < d.difference.value < d.difference.high
    flipped = report.difference("randomized", "calibrated")
    assert flipped.difference.value == -d.difference.value and flipped.difference.low == -d.difference.high
    sentence = next(s for s in report.summary().splitlines() if "'calibrated' vs 'randomized' on the twin" in s)
    verdict = "significant" if d.significant else "not significant"
    assert f"{d.difference.value:+.3g} [{d.difference.low:+.3g}, {d.difference.high:+.3g}], {verdict} at 32" in sentence
    # the study's paragraph is part of the report's files, not only printed
    assert report.summary().startswith("Before calibration, the nominal policy returns")
    data = json.loads(report.to_json())
    assert data["summary"] == report.summary() and data["lead"] == report.lead
    assert report.lead in report.to_html().replace("&#x27;", "'")
    assert any({f["x"], f["y"]} == {"calibrated", "randomized"} for f in data["differences"])


def test_the_calibrated_sim_predicts_the_twin_and_the_nominal_sim_does_not(report: GapReport) -> None:
    by = {p.simulator: p for p in report.predictions}
    calibrated, nominal_sim = by["calibrated"], by["sim"]
    assert calibrated.differ == () and 0 < calibrated.within < 0.05
    bound = max(
        max(abs(report.gap(p, "calibrated", "real").relative.low), abs(report.gap(p, "calibrated", "real").relative.high))
        for p in POLICIES
    )
    assert calibrated.within == bound
    assert f"calibrated predicts real within {100 * bound:.1f}% for all 4 policies" in report.summary()
    assert set(nominal_sim.differ) == set(POLICIES)  # 10% too optimistic for every policy
    assert "sim mispredicts real for 4 of 4 policies" in report.summary()


def test_agreement_names_spearman_and_pearson_and_keeps_points_inside(report: GapReport) -> None:
    for a in report.agreement:
        assert a.srcc is not None and a.pearson is not None and a.mmrv is not None
        for e in (a.srcc, a.pearson, a.mmrv):
            assert e.low <= e.value <= e.high
    md = report.to_markdown()
    assert "| SRCC (Spearman) | Pearson | MMRV |" in md and "SRCC: Spearman rank correlation" in md
    assert "Spearman rank correlation (SRCC)" in report.summary()


def test_radii_use_each_policys_training_sim_and_censored_ones_say_so(report: GapReport) -> None:
    for policy in POLICIES:
        c = report.curve(policy, next(c.sweep for c in report.robustness if c.axis.startswith("ActuatorGain")))
        assert c.reference == TRAINING[policy]
        assert c.radius is not None and c.radius.censored
        own = report.stats_for(policy, TRAINING[policy]).mean.value
        assert c.radius.nominal_return == pytest.approx(own)
    md, page = report.to_markdown(), report.to_html()
    # the gain sweep runs 0.5-1.25 around 1: the binding side ends 0.25 away
    assert "*\\>= 0.25 (sweep end; not crossed)*" in md  # greyed (italics) in Markdown
    assert "<td class='censored'>&gt;= 0.25 (sweep end; not crossed)</td>" in page
    assert "| 686 (sim: randomised) |" in md  # the randomised policy's reference is its own training sim
    assert "td.censored{" in page
    # latency in ms (0.02 s control steps): the nominal policy keeps 0.8 of its sim return (1.1 x the sweep's
    # level) while 1 - 0.15 steps >= 0.88, i.e. up to 0.8 steps = 16 ms
    latency = report.curve("nominal", next(c.sweep for c in report.robustness if c.axis.startswith("ActionLatency")))
    assert latency.radius is not None and not latency.radius.censored
    assert latency.radius.radius.value == pytest.approx(0.8, abs=0.03)  # stored in the sweep's own unit (steps)
    row = next(line for line in md.splitlines() if "trained: nominal | action latency (ms)" in line)
    assert re.search(r"\| 1[56]\.\d+ ms \|", row), row


def test_small_budgets_warn_with_the_minimum_episodes() -> None:
    small = _build(_study_like(4))
    text = small.summary()
    assert "Warning: Small budget: 4 episode(s) per condition; a 95% bootstrap interval needs >= 10" in text
    assert any("Small budget" in w for w in json.loads(small.to_json())["budget_warnings"])
    assert "Small budget" in small.to_markdown().split("## Warnings")[1]
    big = _build(_study_like(32))
    assert "Small budget" not in big.summary()


def test_undefined_and_degenerate_numbers_are_explained() -> None:
    evaluation = _study_like(12)
    zero = {k: (np.zeros_like(v) if k in ("sim", "real") else v) for k, v in evaluation.returns["scripted"].items()}
    returns = {**evaluation.returns, "scripted": zero}
    import dataclasses

    report = _build(dataclasses.replace(evaluation, returns=returns))
    text = report.summary()
    assert "nan" not in text.lower()
    g = report.gap("scripted", "sim", "real")
    assert math.isnan(g.relative.value) and math.isnan(g.relative.low)
    assert "the relative gap is undefined: the sim mean return is 0" in text
    assert "0 \\[0, 0\\] (no spread: the same in every bootstrap resample)" in report.to_markdown()
    assert "undefined: the sim return is 0" in report.to_markdown()


def test_figures_speak_units_and_names(report: GapReport, tmp_path: Path) -> None:
    assert axis_label("ObservationNoise.processes.0.std").text == "sensor noise std (observation units)"
    assert axis_label("ActionLatency.steps", 0.02).factor == pytest.approx(20.0)
    md = report.to_markdown()
    assert "ActionLatency.steps" not in md.split("## Conditions")[0]  # axes in words, not internal paths
    # the grid tables are laid out like the heatmap: columns x, rows y with the largest on top
    table = md.split("trained: nominal, mean return over joint damping (× nominal) × actuator gain (× nominal)")[1]
    table = table.splitlines()
    assert table[2].startswith("| actuator gain (× nominal) \\\\ joint damping (× nominal) | 1 | 2 | 3 |")
    assert table[4].startswith("| 1 |") and table[5].startswith("| 0.75 |")
    # display names keep policies and conditions apart
    assert "| policy | sim: nominal | sim: randomised | sim: calibrated | real twin |" in md
    assert "| trained: calibrated |" in md
    files = report.write(tmp_path / "r")
    for png in files.figures:
        image = PIL.Image.open(io.BytesIO(png.read_bytes()))
        assert image.size[0] > 300
    assert json.loads(files.json.read_text())["labels"]["policies"]["scripted"] == "scripted baseline"


def test_report_json_is_bitwise_reproducible() -> None:
    a, b = _build(_study_like(8, seed=3)), _build(_study_like(8, seed=3))
    assert a.to_json() == b.to_json()
    assert a.figures() == b.figures()


def test_bad_training_and_labels_are_refused() -> None:
    evaluation = _study_like(4)
    with pytest.raises(ValueError, match=r"`training` values must be simulated \(nominal or randomized\) conditions "
                                         r"\['sim', 'randomized', 'calibrated'\]. Received 'real' for policy 'nominal'."):  # fmt: skip
        GapReport.build(evaluation, training={"nominal": "real"})
    with pytest.raises(ValueError, match=r"`training` keys must be policies of the evaluation .* Received 'ppo'."):
        GapReport.build(evaluation, training={"ppo": "sim"})
    with pytest.raises(ValueError, match=r"`policy_labels` keys must be among .* Received \['ppo'\]."):
        GapReport.build(evaluation, policy_labels={"ppo": "x"})
    with pytest.raises(ValueError, match=r"`control_timestep` must be a number of seconds > 0 or None. Received 0."):
        GapReport.build(evaluation, control_timestep=0)


def test_a_tail_statistic_without_spread_does_not_claim_every_run_agreed() -> None:
    """CVaR 0.1 of 32 runs of which 8 return 0 is 0 in every resample, while the runs differ (0 to 960)."""
    from sim2real.metrics import cvar
    from sim2real.report.findings import cell

    returns = np.concatenate([np.zeros(8), np.linspace(300.0, 960.0, 24)])[:, None]
    (tail,) = cvar(returns, alpha=0.1, rng=0, num_resamples=500)
    assert (tail.value, tail.low, tail.high) == (0.0, 0.0, 0.0)
    assert cell(tail) == "0 [0, 0] (no spread: the same in every bootstrap resample)"
