"""Recording logs, `sim2real record` / `sim2real sysid fit`, and calibrated envs."""

from __future__ import annotations

import json

import numpy as np
import pytest

import sim2real as s2r
import sysid
from sim2real.cli import main
from sim2real.recording import RecordTrajectory, parse_set, record


@pytest.mark.parametrize(
    ("text", "op", "value"),
    [
        ("dof_damping[*]=*1.3", "scale", 1.3),
        ("dof_damping[*]=+0.1", "add", 0.1),
        ("dof_damping[elbow]=0.5", "set", 0.5),
    ],
)
def test_parse_set_forms(text: str, op: str, value: float) -> None:
    effect = parse_set(text)
    assert type(effect).__name__ == "Damping" and effect.operation == op and effect.distribution.value == value


def test_parse_set_rejects_unknown_field() -> None:
    with pytest.raises(ValueError, match=r"`--set` field must be one of .*Received 'dof_dampin'"):
        parse_set("dof_dampin[*]=*2")


def test_record_then_fit_recovers_truth_and_latency() -> None:
    log = record(
        "sim2real/arm-reach",
        sets=["dof_damping[*_pitch]=*1.5"],
        policy="prbs",
        episodes=2,
        steps=120,
        seed=3,
        latency=2,
    )
    handle = s2r.find_physics(s2r.make("sim2real/arm-reach"))
    assert log.meta["true_latency_seconds"]["action"] == pytest.approx(2 * handle.substeps * handle.model.opt.timestep)
    model = s2r.find_physics(s2r.make("sim2real/arm-reach")).model
    result = sysid.fit(log, model, ["dof_damping[*_pitch]"], latency=True, progress=False)
    truth = log.meta["true_params"]
    for address, estimate in result.params.items():
        assert estimate == pytest.approx(truth[address], rel=1e-4)
    assert result.latency_control_steps["action"] == 2
    assert result.latency["action"] == pytest.approx(2 * result.control_timestep)


def test_calibrated_make_writes_the_estimates() -> None:
    env = s2r.make("dmc/reacher-easy", params={"dof_damping[shoulder]": 0.123})
    assert s2r.find_physics(env).model.dof_damping[0] == 0.123
    # Randomisation on top is relative to the calibrated nominal.
    wrapped = s2r.wrap(env, s2r.Damping(scale=2.0, joints="shoulder"), seed=0)
    _, info = wrapped.reset(seed=0)
    assert info["sim2real"]["params"]["dof_damping[shoulder]"] == pytest.approx(0.246)


def test_record_trajectory_wrapper_logs_commands_under_latency() -> None:
    env = RecordTrajectory(s2r.wrap(s2r.make("dmc/reacher-easy"), s2r.ActionLatency(steps=3), seed=0))
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (10, 2)).astype(np.float32)
    for a in actions:
        env.step(a)
    log = env.to_log()
    assert np.allclose(log.ctrl, actions)  # what was commanded, not what latency applied
    assert log.qpos.shape == (10, 2) and np.all(np.diff(log.time) > 0)
    env.close()


def test_cli_record_and_fit(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "log.npz"
    code = main(
        [
            "record",
            "--task",
            "dmc/reacher-easy",
            "--set",
            "dof_damping[*]=*2",
            "--episodes",
            "2",
            "--steps",
            "100",
            "--policy",
            "multisine",
            "--obs-noise",
            "1e-3",
            "--out",
            str(out),
        ]
    )
    assert code == 0 and out.exists()
    result = tmp_path / "result.json"
    report = tmp_path / "result.html"
    code = main(
        [
            "sysid",
            "fit",
            str(out),
            "--task",
            "dmc/reacher-easy",
            "--params",
            "dof_damping[*]",
            "--out",
            str(result),
            "--report",
            str(report),
            "--quiet",
        ]
    )
    assert code == 0
    doc = json.loads(result.read_text())
    assert {"params", "covariance", "correlation", "latency", "latency_control_steps", "noise_std"} <= set(doc)
    assert doc["params"]["dof_damping[shoulder]"]["estimate"] == pytest.approx(0.02, rel=1e-4)
    assert "data:image/png;base64," in report.read_text()


def test_cli_fit_bad_log_exits_2(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    code = main(["sysid", "fit", str(bad), "--task", "dmc/reacher-easy", "--params", "dof_damping[*]"])
    assert code == 2
    assert capsys.readouterr().err.startswith("sim2real sysid: error: ")


def test_cli_fit_that_is_not_ok_exits_4_and_is_not_exported(tmp_path, capsys, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    quality = pytest.importorskip("sysid.quality")  # FitResult.ok comes with issue 17 part A's quality checks
    import dataclasses

    import sysid

    log = tmp_path / "log.npz"
    assert main(["record", "--task", "dmc/reacher-easy", "--episodes", "1", "--steps", "50", "--out", str(log)]) == 0
    reason = "held-out error is 86x the in-fit error (> 1.5)"
    refused = dataclasses.replace(
        sysid.FitResult.from_estimates({"dof_damping[shoulder]": (0.02, 0.001)}),
        quality=quality.FitQuality(reasons=(reason,)),
    )
    monkeypatch.setattr(sysid, "fit", lambda *args, **kwargs: refused)  # what the CLI does with a fit that is not ok
    fit = ["sysid", "fit", str(log), "--task", "dmc/reacher-easy", "--params", "dof_damping[*]", "--quiet"]
    out, effects = tmp_path / "fit.json", tmp_path / "effects.yaml"
    capsys.readouterr()
    assert main([*fit, "--out", str(out), "--export", str(effects)]) == 4  # not 3: that is evaluate --safety's
    assert capsys.readouterr().err == (
        f"sim2real sysid fit: the fit is not ok: {reason}; {effects} was not written (pass --force to export it "
        "anyway)\n"
    )
    assert sysid.FitResult.from_json(out) == refused and not effects.exists()  # the fit is kept, not exported
    assert main([*fit, "--out", str(out), "--export", str(effects), "--force"]) == 0
    assert capsys.readouterr().err.endswith(f"{reason} (exported anyway: --force)\n")
    assert "type: Damping" in effects.read_text()
