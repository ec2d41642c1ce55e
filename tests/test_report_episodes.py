"""The gap report with different episode counts per condition (more episodes on the target, issue 14), the episode
target it reports, sensor-noise units and what its Safety section says about sampling."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from sim2real.conditions import nominal, randomized, real, sweep
from sim2real.evaluation_results import Evaluation
from sim2real.metrics import Estimate
from sim2real.report import GapReport, GapStats
from sim2real.report.findings import gap_phrase
from sim2real.report.labels import axis_label, observation_unit
from sim2real.study.precision import extend, plan_target

POLICIES = ("nominal", "randomized", "calibrated")
MEANS = {"nominal": (800.0, 500.0), "randomized": (700.0, 600.0), "calibrated": (650.0, 640.0)}


def _evaluation(n_sim: int, n_real: int, seed: int = 0) -> Evaluation:
    """Returns on sim / randomized (``n_sim`` episodes), real (``n_real``; its first ``n_sim`` do not depend on
    ``n_real``) and a 3-point noise sweep, from a fixed generator."""
    returns: dict[str, dict[str, np.ndarray]] = {}
    for k, p in enumerate(POLICIES):
        rng = np.random.default_rng([seed, k])
        sim, twin = MEANS[p]
        real_values = rng.normal(twin, 150.0, 4096)[:n_real]
        returns[p] = {
            "sim": rng.normal(sim, 60.0, n_sim),
            "randomized": rng.normal(sim - 20, 80.0, n_sim),
            "real": real_values,
        }
        for std in (0.0, 0.02, 0.05):
            returns[p][f"ObservationNoise.processes.0.std={std:g}"] = rng.normal(sim * (1 - 4 * std), 50.0, n_sim)
    noise = {"type": "ObservationNoise", "processes": [{"type": "Gaussian", "std": 0.0}]}
    conditions = (
        nominal(),
        randomized([], name="randomized"),
        real(params={"body_mass[arm]": 1.2}),
        *sweep(noise, "processes.0.std", [0.0, 0.02, 0.05]),
    )
    return Evaluation(task="demo", seed=seed, episodes=n_sim, max_steps=None, policies=POLICIES,
                      conditions=conditions, returns=returns, successes={}, lengths={}, draws={})  # fmt: skip


def _report(ev: Evaluation, **kwargs: object) -> GapReport:
    return GapReport.build(ev, reference="sim", randomized="randomized", target="real", num_resamples=1000,
                           rng=0, **kwargs)  # type: ignore[arg-type]  # fmt: skip


def test_more_episodes_on_the_target_are_counted_paired_and_reported() -> None:
    report = _report(_evaluation(16, 64))
    assert {(s.condition, s.n) for s in report.stats if s.policy == "nominal"} == {
        ("sim", 16), ("randomized", 16), ("real", 64)}  # fmt: skip
    # policies on the target share its 64 episodes: paired differences over all of them
    d = report.difference("calibrated", "randomized")
    assert d.paired and d.n == 64
    # a gap between simulated conditions with different counts is paired over the 16 episodes they share
    g = report.gap("nominal", "sim", "real")
    assert (g.paired, g.n_reference, g.n_target) == (True, 16, 64)
    assert "(gap " in gap_phrase(g) and "paired over 16 runs)" in gap_phrase(g)
    ev = _evaluation(16, 64)
    assert g.absolute.value == pytest.approx(ev.returns["nominal"]["sim"].mean()
                                             - ev.returns["nominal"]["real"][:16].mean())  # fmt: skip
    # SRCC / Pearson across policies: each condition has one count, so agreement is computed, not skipped
    assert all(a.srcc is not None and a.note == "" for a in report.agreement)
    text = report.summary()
    assert "16 episode(s) per simulated condition (64 on real)" in text
    assert "per simulated condition (64 on real)" in report.to_markdown()
    assert "is paired over the episodes both ran (the first min of the two counts" in report.to_markdown()
    data = json.loads(report.to_json())
    assert data["evaluation"]["episodes"] == 16
    assert data["evaluation"]["episodes_by_condition"] == {"sim": [16], "randomized": [16], "real": [64]}
    assert "nan" not in json.dumps(data).lower()


def test_equal_counts_keep_the_json_as_before() -> None:
    data = json.loads(_report(_evaluation(16, 16)).to_json())
    assert "episodes_by_condition" not in data["evaluation"] and "episode_target" not in data
    assert "16 episode(s) per simulated condition (seed 0)" in data["summary"]


def test_plan_target_asks_for_the_episodes_the_pilot_sd_implies() -> None:
    ev = _evaluation(16, 16)
    t = plan_target(ev, fraction=0.05, cap=4000)
    diff = ev.returns["calibrated"]["real"] - ev.returns["randomized"]["real"]
    sd = float(diff.std(ddof=1))
    goal = 0.05 * float(ev.returns["nominal"]["sim"].mean())
    assert t.pilot_episodes == 16 and t.pilot_sd == pytest.approx(sd) and t.goal == pytest.approx(goal)
    assert t.needed == math.ceil((1.959963984540054 * sd / goal) ** 2)
    assert t.episodes == t.needed and not t.capped and math.isnan(t.half_width)
    capped = plan_target(ev, fraction=0.05, cap=100)
    assert (capped.episodes, capped.capped) == (100, True)
    loose = plan_target(ev, fraction=1.0, cap=100)
    assert loose.needed is not None and loose.needed < 16 and loose.episodes == 16  # never fewer than the pilot
    # whole batches (so a longer run continues this one), within the cap
    batched = plan_target(ev, fraction=0.05, cap=4000, batch=16)
    assert batched.needed == t.needed and batched.episodes == -(-t.needed // 16) * 16 >= t.needed
    assert plan_target(ev, fraction=0.05, cap=100, batch=64).episodes == 100
    assert plan_target(ev, fraction=1.0, cap=100, batch=16).episodes == 16
    with pytest.raises(ValueError, match=r"`batch` must be an int >= 1\. Received 0\."):
        plan_target(ev, fraction=0.05, cap=10, batch=0)
    with pytest.raises(ValueError, match=r"`fraction` must be a number in \(0, 1\]. Received 0."):
        plan_target(ev, fraction=0, cap=10)
    with pytest.raises(ValueError, match=r"`cap` must be an int >= 1\. Received 0\."):
        plan_target(ev, fraction=0.05, cap=0)
    with pytest.raises(ValueError, match="no returns of policy 'adr' on 'real'"):
        plan_target(ev, fraction=0.05, cap=10, x="adr")


def test_a_zero_reference_return_gives_no_goal() -> None:
    ev = _evaluation(16, 16)
    zero = {p: dict(ev.returns[p]) for p in POLICIES}
    zero["nominal"]["sim"] = np.zeros(16)
    t = plan_target(dataclasses.replace(ev, returns=zero), fraction=0.05, cap=64)
    assert t.needed is None and math.isnan(t.goal) and t.episodes == 16


def test_extend_replaces_the_target_and_refuses_what_is_not_a_continuation() -> None:
    pilot, longer = _evaluation(16, 16), _evaluation(16, 48)
    merged = extend(pilot, longer, "real")
    assert merged.returns["calibrated"]["real"].size == 48 and merged.returns["calibrated"]["sim"].size == 16
    np.testing.assert_array_equal(merged.returns["nominal"]["real"][:16], pilot.returns["nominal"]["real"])
    assert not merged.returns["nominal"]["real"].flags.writeable
    with pytest.raises(ValueError, match="`more` must continue the episodes of 'real': policy 'nominal' has 48"):
        extend(pilot, _shifted(longer), "real")
    with pytest.raises(ValueError, match="`more` must be a run of the same policies and seed"):
        extend(pilot, dataclasses.replace(longer, seed=1), "real")


def _shifted(ev: Evaluation) -> Evaluation:
    returns = {p: {c: (v + 1.0 if c == "real" else v) for c, v in ev.returns[p].items()} for p in ev.policies}
    return dataclasses.replace(ev, returns=returns)


def test_the_report_says_whether_the_precision_goal_was_met() -> None:
    ev = extend(_evaluation(16, 16), _evaluation(16, 64), "real")
    target = plan_target(_evaluation(16, 16), fraction=0.05, cap=64)
    report = _report(ev).with_episode_target(target)
    t = report.episode_target
    assert t is not None
    e = report.difference("calibrated", "randomized").difference
    assert t.half_width == pytest.approx((e.high - e.low) / 2.0)
    assert t.capped and t.met == (t.half_width <= t.goal)
    assert not t.met  # sd ~ 210 over 64 episodes: ~ +-51, goal 5% of ~800
    text = report.summary()
    assert "Episodes on real: 64, chosen so that the 95% interval of 'calibrated' - 'randomized' on real is at most" \
        in text  # fmt: skip
    assert "the budget caps it at 64" in text and "goal not met" in text
    # what would meet the goal is re-estimated from the achieved interval, not repeated from the pilot
    assert t.needed_now == max(65, math.ceil(64 * (t.half_width / t.goal) ** 2 - 1e-9))
    assert f"goal not met (about {t.needed_now} episodes would meet it)" in text
    assert any(w.startswith("Precision goal not met: 'calibrated' - 'randomized' on real") for w in
               json.loads(report.to_json())["budget_warnings"])  # fmt: skip
    data = json.loads(report.to_json())["episode_target"]
    assert data["episodes"] == 64 and data["met"] is False and data["capped"] is True
    assert data["half_width"] == pytest.approx(t.half_width) and data["goal_half_width"] == pytest.approx(t.goal)
    met = _report(ev).with_episode_target(dataclasses.replace(target, fraction=0.5, goal=400.0, needed=10))
    assert "goal met" in met.summary() and not any("Precision" in w for w in met.to_dict()["budget_warnings"])
    with pytest.raises(TypeError, match=r"`target` must be an EpisodeTarget\. Received dict\."):
        report.with_episode_target({})  # type: ignore[arg-type]


def test_a_gap_without_a_relative_interval_is_claimed_with_its_absolute_interval() -> None:
    g = GapStats("p", "sim", "real", Estimate(-10.5, -39.75, 8.25, 0.95, 4, "b"),
                 Estimate(-3.818, math.nan, math.nan, 0.95, 4, "b"), True, 4, 4, "mean")  # fmt: skip
    text = gap_phrase(g)
    assert text.startswith("gains 10.5 [-8.25, 39.75] from sim to real (absolute; 381.8% relative, without an interval")
    zero_end = dataclasses.replace(g, absolute=Estimate(-19.0, -57.0, 0.0, 0.95, 4, "b"))
    assert gap_phrase(zero_end).startswith("gains 19 [0, 57] from sim to real")  # no "-0" end
    assert "%" not in text.split("(")[0]  # the claim itself carries an interval, not a bare percentage


def test_sensor_noise_axis_in_physical_units() -> None:
    import sim2real

    env = sim2real.make("dmc/reacher-easy")
    try:
        unit = observation_unit(env)
    finally:
        env.close()
    assert unit == "rad (position), m (to_target), rad/s (velocity)"
    label = axis_label("ObservationNoise.processes.0.std", observation_unit=unit)
    assert label.text == "sensor noise std (rad (position), m (to_target), rad/s (velocity))"
    assert label.unit == "in each channel's unit"
    assert axis_label("ObservationNoise.processes.0.std", observation_unit="rad").unit == "rad"
    assert observation_unit(("position", "velocity"), angular=False) == "m (position), m/s (velocity)"
    assert observation_unit(("pixels",)) is None
    report = _report(_evaluation(16, 16), observation_unit=unit)
    md = report.to_markdown().replace("\\_", "_")  # Markdown escapes the underscore
    assert "sensor noise std (rad (position), m (to_target), rad/s (velocity))" in md
    assert "observation units" not in md
    assert json.loads(report.to_json())["observation_unit"] == unit
    with pytest.raises(ValueError, match=r"`observation_unit` must be a non-empty string or None\. Received ''\."):
        _report(_evaluation(4, 4), observation_unit="")


def test_safety_section_says_what_the_sampling_sees() -> None:
    import sim2real
    from sim2real.report.safety import safety_blocks
    from sim2real.safety import SafetyTable, load_limits, physics_substeps

    env = sim2real.make("dmc/reacher-easy")
    try:
        assert physics_substeps(env) == 1
    finally:
        env.close()
    q = {"joint_limit_hits": np.zeros(2), "effort_ratio": np.array([0.4, 1.0]), "contact_force": np.full(2, np.nan),
         "ee_speed": np.full(2, np.nan), "diverged": np.zeros(2)}  # fmt: skip
    ev = Evaluation(task="demo", seed=0, episodes=2, max_steps=None, policies=("p",), conditions=(nominal(),),
                    returns={"p": {"sim": np.zeros(2)}}, successes={}, lengths={}, draws={},
                    safety={"p": {"sim": q}})  # fmt: skip
    limits = load_limits({"max_effort_ratio": 1.0})
    texts = {k: safety_blocks(SafetyTable.build(ev, limits, substeps=k))[1]["text"] for k in (None, 1, 5)}
    assert "which is every physics step here (1 physics step per control step)" in texts[1]
    assert "every 5 physics steps: a peak inside the substeps is not seen" in texts[5]
    assert "a peak between two samples, inside the physics substeps, is not seen" in texts[None]
    assert SafetyTable.build(ev, limits, substeps=5).to_dict()["physics_steps_per_sample"] == 5
    assert "physics_steps_per_sample" not in SafetyTable.build(ev, limits).to_dict()
    with pytest.raises(ValueError, match=r"`substeps` must be None or an int >= 1\. Received 0\."):
        SafetyTable.build(ev, limits, substeps=0)


def test_replan_rounds_runs_again_while_the_longer_run_asks_for_more() -> None:
    from sim2real.report.results import EpisodeTarget
    from sim2real.study.precision import replan_rounds

    base = EpisodeTarget("real", "a", "b", "a", "sim", 900.0, 0.05, 45.0, 32, 150.0, 43, 128, 43, math.nan, 0.95)
    ran: list[int] = []
    notes: list[str] = []

    def run_to(n: int) -> int:
        ran.append(n)
        return n

    def replan(asks: dict[int, int]):  # type: ignore[no-untyped-def]
        return lambda n: dataclasses.replace(base, episodes=asks[n], pilot_episodes=n)

    # the pilot's 43 are run; their spread asks 60, then 60's asks 61, then 61's asks no more: three runs
    last, plan = replan_rounds(base, run_to, replan({43: 60, 60: 61, 61: 58}), note=notes.append)
    assert (ran, last, plan.episodes, plan.pilot_episodes) == ([43, 60, 61], 61, 61, 60)
    assert notes == ["the 43 episodes put the spread higher than the pilot did: 60 episodes (cap 128)",
                     "the 60 episodes put the spread higher than the pilot did: 61 episodes (cap 128)"]  # fmt: skip
    # at most `rounds` runs, and the plan reported is the one that ran last
    ran.clear()
    last, plan = replan_rounds(base, run_to, replan({43: 50, 50: 70, 70: 90}), rounds=2)
    assert (ran, last, plan.episodes) == ([43, 50], 50, 50)
    # a spread that asks for no more than ran: one run
    ran.clear()
    assert replan_rounds(base, run_to, replan({43: 43}))[0] == 43 and ran == [43]
    with pytest.raises(ValueError, match=r"`rounds` must be an int >= 1. Received 0."):
        replan_rounds(base, run_to, replan({}), rounds=0)
