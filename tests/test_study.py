"""``sim2real study``: the whole loop on the quick budget, reproducibility, and nothing half-written on Ctrl-C."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

from sim2real import cli
from sim2real.study import BUDGETS, calibrated_effects, load_profile, run_study, study_tasks


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("study") / "first"
    err = io.StringIO()
    with contextlib.redirect_stderr(err):  # the stage lines (not --quiet), kept beside the study for a test below
        assert cli.main(["study", "--budget", "quick", "--backend", "serial", "--out", str(out)]) == 0
    (out.parent / "stderr.txt").write_text(err.getvalue())
    return out


def test_quick_study_says_which_engine_ran_its_evaluation(quick: Path) -> None:
    # Before, nothing said whether the batched engine ran the conditions (or why not), only the Python API did.
    lines = (quick.parent / "stderr.txt").read_text().splitlines()
    (engines,) = [line.strip() for line in lines if line.strip().startswith("engines: ")]
    assert engines.startswith("engines: batched for sim, randomized"), engines


def test_quick_study_writes_the_report(quick: Path) -> None:
    assert sorted(p.name for p in quick.iterdir()) == ["checkpoints", "figures", "report.html", "report.json",
                                                       "report.md", "sysid"] or sorted(
        p.name for p in quick.iterdir()) == ["figures", "report.html", "report.json", "report.md", "sysid"]  # fmt: skip
    report = json.loads((quick / "report.json").read_text())
    html = (quick / "report.html").read_text()
    for role in ("nominal", "randomized", "calibrated", "adr", "scripted"):
        assert role in report["evaluation"]["policies"]
        assert f"{role}" in html
    assert {"returns.png", "sysid_fit.png"} <= {p.name for p in (quick / "figures").iterdir()}
    assert any(p.name.startswith("robustness_") for p in (quick / "figures").iterdir())
    assert any(p.name.startswith("heatmap_") for p in (quick / "figures").iterdir())
    assert (quick / "sysid" / "fit.json").is_file() and (quick / "sysid" / "calibrated.yaml").is_file()
    # The twin's configuration (its params, as JSON) appears only in the appendix; a "0.03" elsewhere (a radius, a
    # fitted estimate) is no leak.
    head, _, appendix = html.partition("Appendix")
    twin_param = "dof_damping[shoulder]&quot;: 0.03"
    assert twin_param not in head and twin_param in appendix


def test_quick_study_decides_its_twin_episodes_and_reports_safety_and_units(quick: Path) -> None:
    import re

    report = json.loads((quick / "report.json").read_text())
    # Enough episodes to decide: the main evaluation is the pilot, the twin runs what the precision goal asks for,
    # capped by the budget (quick: 4 episodes, at most 8 on the twin).
    t = report["episode_target"]
    assert (t["condition"], t["x"], t["y"], t["pilot_episodes"], t["cap"]) == ("real", "calibrated", "randomized", 4, 8)
    # whole batches of 4 (the quick budget's batch), so a longer run continues the last one
    assert t["episodes"] == (4 if t["needed"] is None else min(-(-max(t["needed"], 4) // 4) * 4, 8))
    assert report["evaluation"]["episodes"] == 4
    if t["episodes"] != 4:
        assert report["evaluation"]["episodes_by_condition"]["real"] == [t["episodes"]]
    assert all(s["n"] == (t["episodes"] if s["condition"] == "real" else 4) for s in report["stats"])
    assert "Episodes on real:" in report["lead"]
    # The arm's envelope (sim2real/data/study/dmc-reacher-easy/safety.yaml), every physics step of reacher seen.
    safety = report["safety"]
    assert safety["physics_steps_per_sample"] == 1 and safety["limits"]["max_ee_speed"]["body"] == "finger"
    assert {r["quantity"] for r in safety["rows"]} >= {"joint_limit_hits", "effort_ratio", "ee_speed", "diverged"}
    # The sensor-noise sweep in the observation's physical units, not "observation units".
    assert report["observation_unit"] == "rad (position), m (to_target), rad/s (velocity)"
    md = (quick / "report.md").read_text()
    assert "observation units" not in md and "## Safety" in md
    # No nan, and a zero-width interval always says why.
    assert not re.search(r"\bnan\b", md, re.IGNORECASE) and not re.search(r"\bnan\b", report["summary"], re.I)
    for match in re.finditer(r"0 \\?\[0, 0\\?\]", md):
        assert md[match.end() : match.end() + 12] == " (no spread:", md[match.start() - 80 : match.end() + 40]


def test_same_seed_reproduces_the_report_json_bitwise(quick: Path, tmp_path: Path) -> None:
    again = run_study(out=tmp_path / "again", budget="quick", backend="serial", seed=0, progress=False, log=None)
    assert (again.out / "report.json").read_bytes() == (quick / "report.json").read_bytes()
    assert again.summary.startswith("Before calibration, the nominal policy returns")
    assert "on the real twin" in again.summary and "calibrated sim it was trained on" in again.summary
    # The checkpoints the package ships were trained under exactly this study's configurations.
    roles = ("nominal", "randomized", "calibrated", "adr")
    assert all(again.policies[r].startswith("shipped checkpoint") for r in roles)


def test_interrupt_leaves_nothing_half_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import sim2real.evaluation as evaluation

    out = tmp_path / "study"
    out.mkdir()  # an existing empty folder is used in place (a folder that holds anything is refused up front)

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluation, "evaluate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_study(out=out, budget="quick", backend="serial", progress=False, log=None)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study"]  # no staging folder left
    assert list(out.iterdir()) == []  # the staging folder inside it is gone too


def test_profile_and_errors() -> None:
    assert "dmc/reacher-easy" in study_tasks()
    profile = load_profile()
    from noise_models import ActionLatency
    from sim2real.twin import sensor_noise_std

    # The twin is one Condition: the evaluation scores it and the recorder records through its env.
    assert profile.twin.kind == "real" and profile.twin.hidden
    assert sensor_noise_std(profile.twin) == 0.005
    assert ActionLatency(steps=2) in profile.twin.effects
    # The shipped checkpoints match the profile as it is (a new agent option must not orphan them).
    from sim2real.study.policies import effects_yaml, shipped

    assert shipped(profile, "nominal", None) is not None
    assert shipped(profile, "randomized", effects_yaml(profile.randomized)) is not None
    assert shipped(profile, "adr", effects_yaml(profile.adr_signals)) is not None  # ADR from the nominal point
    with pytest.raises(
        ValueError,
        match=r"`task` must be one of \[.*'dmc/reacher-easy'.*\] \(tasks with a bundled study\). Received 'dmc/cheetah-run'.",
    ):
        load_profile("dmc/cheetah-run")
    with pytest.raises(ValueError, match=r"`budget` must be one of \['quick', 'standard', 'full'\]. Received 'huge'."):
        run_study(budget="huge")
    assert BUDGETS["quick"].episodes < BUDGETS["standard"].episodes < BUDGETS["full"].episodes


def test_calibrated_effects_round_and_widen() -> None:
    from sysid import FitResult

    fit = FitResult.from_estimates({"dof_damping[shoulder]": (0.02987, 0.0001), "actuator_gain[wrist]": (0.7926, 0.1)})
    from randomizers.config import effect_to_config

    damping, gain = (effect_to_config(e)["set"] for e in calibrated_effects(fit))
    assert (damping["low"], damping["high"]) == (0.027, 0.033)  # 0.030 +- 10%
    assert (gain["low"], gain["high"]) == (0.59, 0.99)  # 0.79 +- 2 stderr (0.2) dominates the 10% floor


def test_calibrated_effects_keep_one_noise_level_over_the_whole_observation() -> None:
    """The twin corrupts every observation entry alike, so the study's calibrated sim does too (no per-group export:
    see calibrated_effects), and its config stays the one the shipped calibrated checkpoint was trained under."""
    from dataclasses import replace

    from sysid import FitResult

    fit = replace(
        FitResult.from_estimates({"dof_damping[shoulder]": (0.03, 0.0001)}),
        noise_std={"qpos[shoulder]": 0.001, "qpos[wrist]": 0.001, "qvel[shoulder]": 0.005, "qvel[wrist]": 0.005},
        noise_dof={"qpos[shoulder]": 400.0, "qpos[wrist]": 400.0, "qvel[shoulder]": 400.0, "qvel[wrist]": 400.0},
    )
    (noise,) = [e for e in calibrated_effects(fit) if type(e).__name__ == "ObservationNoise"]
    (gaussian,) = noise.processes
    assert gaussian.std == 0.003 and gaussian.select is None  # the mean level, on every entry
