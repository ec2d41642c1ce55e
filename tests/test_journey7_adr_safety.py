"""User journey 7, "let ADR choose the ranges, train from scratch at full speed, and read the safety table before
touching hardware", on an arm nobody here designed, through the public API and the CLI only.

The arm is written here: four hinges under gravity with joint limits, position servos (``kp``, ``forcerange`` in
N·m), a ``home`` keyframe and 5 ms physics steps, run as ``--model robot.xml`` / ``sim2real.make("model:<path>")``
(50 Hz control: 4 physics steps per control step).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import io
import json
import re
import warnings
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import yaml

import sim2real as s2r
from randomizers import ADR

ARM = """
<mujoco model="journey7_arm">
  <compiler angle="radian"/>
  <option timestep="0.005" gravity="0 0 -9.81"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="base" pos="0 0 0.2">
      <joint name="turn" axis="0 0 1" range="-2 2" damping="0.8" armature="0.02"/>
      <geom type="cylinder" size="0.05 0.04" mass="2"/>
      <body name="link1" pos="0 0 0.06">
        <joint name="lift" axis="0 1 0" range="-1.2 1.2" damping="1.2" armature="0.02"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.03" mass="1.2"/>
        <body name="link2" pos="0.25 0 0">
          <joint name="bend" axis="0 1 0" range="-2.0 2.0" damping="0.6" armature="0.01"/>
          <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.025" mass="0.8"/>
          <body name="tool" pos="0.2 0 0">
            <joint name="twist" axis="1 0 0" range="-1.5 1.5" damping="0.2" armature="0.005"/>
            <geom type="box" size="0.03 0.02 0.02" mass="0.3"/>
            <site name="tip" pos="0.04 0 0"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="turn" joint="turn" kp="40" kv="2" ctrlrange="-2 2" forcerange="-20 20"/>
    <position name="lift" joint="lift" kp="80" kv="4" ctrlrange="-1.2 1.2" forcerange="-30 30"/>
    <position name="bend" joint="bend" kp="40" kv="2" ctrlrange="-2 2" forcerange="-15 15"/>
    <position name="twist" joint="twist" kp="8" kv="0.3" ctrlrange="-1.5 1.5" forcerange="-4 4"/>
  </actuator>
  <keyframe>
    <key name="home" qpos="0.3 -0.4 0.9 0"/>
  </keyframe>
</mujoco>
"""
HOME = np.array([0.3, -0.4, 0.9, 0.0], np.float32)  # the servos' set points at the home keyframe
SLAM = [2.0, 1.2, 2.0, 1.5]  # every servo to its upper control limit: into the joint limits at full torque

# A tiny PPO from scratch: 2 batched worlds x 200 steps per batch, so every batch ends one episode per world (an MJCF
# episode is 200 control steps) and ADR sees results.
TINY_PPO = """algo: ppo
frames: 800
frames_per_batch: 400
num_envs: 2
minibatch_size: 100
epochs: 1
obs_norm_frames: 64
hidden_sizes: [16, 16]
"""


@pytest.fixture(scope="module")
def arm(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("journey7") / "robot.xml"
    path.write_text(ARM)
    return path


# -- ADR on the arm ------------------------------------------------------------------------------------------------
def test_adr_widens_only_where_the_held_arm_copes_and_reports_model_units(arm: Path) -> None:
    # Holding home under gravity: the return hardly depends on the joints' damping, but heavier links sag more.
    # ADR must open damping to its hard limits and stop the mass where the arm stops coping (a return of -0.2
    # over 25 steps; 1.5x the masses sits between the thresholds, so that boundary stays).
    adr = ADR(
        [s2r.Damping(scale=s2r.Uniform(0.2, 5.0)), s2r.Mass(scale=s2r.Uniform(0.5, 3.0))],
        delta={"Damping[joints=*]": 1.0, "Mass[bodies=*]": 0.25},
        t_low=-0.4,
        t_high=-0.2,
        m=1,
        p_boundary=1.0,
        metric="return",
    )
    env = s2r.wrap(s2r.make(f"model:{arm}", max_episode_steps=25), adr=adr, seed=0)
    nominal_mass = {name: float(m) for name, m in (("link1", 1.2), ("tool", 0.3))}
    pins: list[tuple[str, str, float]] = []
    for _ in range(40):
        env.reset()
        for _ in range(25):
            _, _, _, _, info = env.step(HOME)
        key, side, value = info["sim2real"]["adr"]["pin"]
        pins.append((key, side, value))
        params = info["sim2real"]["params"]
        if key == "Mass[bodies=*]":  # the pinned boundary is written into every target, reported in kg
            for body, kg in nominal_mass.items():
                assert params[f"body_mass[{body}]"] == kg * value
        else:  # in N·m·s/rad
            assert params["dof_damping[lift]"] == 1.2 * value
    env.close()
    assert adr.ranges == {"Damping[joints=*]": (0.2, 5.0), "Mass[bodies=*]": (0.5, 1.5)}
    assert ("Mass[bodies=*]", "high", 1.5) in pins[-10:]  # still tried at 1.5; 1.75 was never reached
    history = adr.history
    assert history.frames[0] == 0 and adr.frames == 40 * 25
    assert all(b >= a for a, b in zip(history.entropy[1:], history.entropy[2:], strict=False))  # only widened

    # The same ranges in the model's own units (what a datasheet says), addressed like the episode reports.
    model = mujoco.MjModel.from_xml_path(str(arm))
    ranges = adr.parameter_ranges(model)
    assert ranges["dof_damping[lift]"] == (1.2 * 0.2, 1.2 * 5.0)
    assert ranges["dof_damping[twist]"] == (0.2 * 0.2, 0.2 * 5.0)
    assert ranges["body_mass[tool]"] == (0.3 * 0.5, 0.3 * 1.5)
    assert set(ranges) == set(info["sim2real"]["params"])
    assert np.array_equal(model.dof_damping, [0.8, 1.2, 0.6, 0.2])  # read, never written


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        # The nominal start (scale 1) outside the limits: said so, not "Received (1.0, 1.0)" for nothing given.
        (
            {"effects": [s2r.Damping(scale=s2r.Uniform(2.0, 5.0))]},
            "`initial` of ADR must give a start for 'Damping[joints=*]' inside the effect's limits [2.0, 5.0]: the "
            "default start, the nominal point (scale 1.0), is outside them. Received none.",
        ),
        (
            {"initial": {"Damping[joints=*]": [0.5, 1.5, 2.0]}},
            "`initial['Damping[joints=*]']` of ADR must be a point or a range (low, high). Received [0.5, 1.5, 2.0].",
        ),
        (
            {"initial": {"Damping[joints=*]": 7.0}},
            "`initial['Damping[joints=*]']` of ADR must be a point or a range (low, high) with low <= high inside the "
            "effect's limits [0.2, 5.0]. Received 7.0.",
        ),
        (
            {"metric": "sucess"},
            "`metric` of ADR must be one of ['auto', 'return', 'success'] or a callable. Received 'sucess'.",
        ),
        ({"p_boundary": 1.5}, "`p_boundary` of ADR must be in [0, 1]. Received 1.5."),
        ({"m": 0}, "`m` of ADR must be an int >= 1. Received 0."),
        ({"t_low": 0.0, "t_high": -1.0}, "`t_low` of ADR must be < `t_high`. Received t_low=0.0, t_high=-1.0."),
        (
            {"delta": {"Damping": 0.1}},
            "`delta` of ADR must give one step per effect key ['Damping[joints=*]']. Received unknown ['Damping'], "
            "missing ['Damping[joints=*]'].",
        ),
    ],
)
def test_bad_adr_arguments_name_the_argument_the_allowed_values_and_what_was_received(
    kwargs: dict[str, Any], message: str
) -> None:
    args: dict[str, Any] = {
        "effects": [s2r.Damping(scale=s2r.Uniform(0.2, 5.0))],
        "delta": 0.2,
        "t_low": -30.0,
        "t_high": -2.0,
        **kwargs,
    }
    effects = args.pop("effects")
    with pytest.raises((TypeError, ValueError), match=f"^{re.escape(message)}$"):
        ADR(effects, **args)


def test_bad_adr_config_items_and_model_are_named(arm: Path) -> None:
    from sim2real.adr_rounds import run_adr_round

    # A config without thresholds: before, "ADR.__init__() missing 2 required keyword-only arguments" (a TypeError
    # about a function the user never called, and `train --adr` printed it as such).
    with pytest.raises(ValueError) as err:
        ADR.from_config({"effects": [{"type": "Damping", "scale": [0.2, 5.0]}], "delta": 0.1})
    assert str(err.value) == (
        "`config` of ADR must give ['t_low', 't_high'] (required: ['effects', 'delta', 't_low', 't_high']). "
        "Received keys ['delta', 'effects']."
    )
    adr = ADR([s2r.Damping(scale=s2r.Uniform(0.2, 5.0))], delta=0.1, t_low=0.0, t_high=1.0)
    with pytest.raises(TypeError) as err:  # before: "'int' object is not iterable"
        run_adr_round(len, adr, 5, backend="serial")
    assert str(err.value) == "`items` of run_adr_round must be a list (one item per task). Received 5."
    with pytest.raises(TypeError) as err:  # before: "'PosixPath' object has no attribute 'njnt'"
        adr.parameter_ranges(arm)
    assert str(err.value) == f"`model` of ADR.parameter_ranges must be a mujoco.MjModel. Received {arm!r}."


def test_bad_adr_file_is_one_line_and_exit_2_before_training(
    arm: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sim2real.cli import main

    adr = tmp_path / "adr.yaml"
    adr.write_text("effects: [{type: Damping, scale: [2.0, 5.0]}]\ndelta: 0.1\nt_low: -30\nt_high: -2\n")
    out = tmp_path / "never.pt"
    code = main(["train", "--model", str(arm), "--adr", str(adr), "--out", str(out), "--no-log", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and not out.exists()
    assert err.strip() == (
        "sim2real train: error: --adr: `initial` of ADR must give a start for 'Damping[joints=*]' inside the "
        "effect's limits [2.0, 5.0]: the default start, the nominal point (scale 1.0), is outside them. Received none."
    )
    # --adr-export: only with --adr, never onto the checkpoint or an input.
    ranges = tmp_path / "ranges.yaml"
    adr.write_text("effects: [{type: Damping, scale: [0.2, 5.0]}]\ndelta: 0.1\nt_low: -30\nt_high: -2\n")
    for extra, message in (
        (["--adr-export", str(ranges)], f"--adr-export needs --adr (the ranges it writes are ADR's). Received "
                                        f"--adr-export {str(ranges)!r} alone."),
        (["--adr", str(adr), "--adr-export", str(out)], f"--adr-export must differ from --out. Received {str(out)!r} "
                                                        "for both."),
        (["--adr", str(adr), "--adr-export", str(adr)], f"--adr-export must not be the input --adr, which it would "
                                                        f"overwrite. Received {str(adr)!r} for both."),
    ):  # fmt: skip
        code = main(["train", "--model", str(arm), *extra, "--out", str(out), "--no-log", "--quiet"])
        assert (code, capsys.readouterr().err.strip()) == (2, f"sim2real train: error: {message}")
    assert not out.exists() and not ranges.exists()


def test_a_success_metric_on_an_arm_without_success_is_refused_before_training(
    arm: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The bare MJCF arm reports no success flag. Before, a run long enough to end an episode died in a traceback
    # from inside the collector ("the episode reports no success flag", exit 1) after collecting for nothing; a
    # shorter one exited 0 without the metric ever being checked.
    from sim2real.agents import PPOConfig, SACConfig, train
    from sim2real.cli import main

    adr_text = "effects: [{type: Damping, scale: [0.2, 5.0]}]\ndelta: 0.1\nt_low: 0.2\nt_high: 0.8\nmetric: success\n"
    adr = tmp_path / "adr.yaml"
    adr.write_text(adr_text)
    out = tmp_path / "never.pt"
    for algo in ("ppo", "sac"):
        argv = ["train", "--model", str(arm), "--algo", algo, "--adr", str(adr), "--frames", "400", "--out", str(out)]
        assert main([*argv, "--no-log", "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and not out.exists()
        assert err.strip() == (
            "sim2real train: error: the effects of --adr do not fit 'robot.xml': `metric` of ADR must be 'return' or "
            f"'auto' (its return, here) on 'model:{arm}': its episodes report no success flag. Received 'success'."
        )
    # The batched engine refuses it too, whoever builds the worlds.
    from sim2real.batched import make_batched

    controller = ADR.from_config(yaml.safe_load(adr_text))
    with pytest.raises(ValueError, match=re.escape("on this task: its episodes report no success flag.")):
        make_batched(f"model:{arm}", 2, controller, seed=0)
    for config in (PPOConfig(frames=400, adr=adr_text), SACConfig(frames=400, adr=adr_text)):
        with pytest.raises(ValueError, match=re.escape(f"on 'model:{arm}': its episodes report no success flag")):
            train(f"model:{arm}", config)


# -- train from scratch, export, train again, evaluate -------------------------------------------------------------
def test_train_adr_on_the_arm_is_batched_and_its_ranges_export_into_train_config(arm: Path, tmp_path: Path) -> None:
    from sim2real.agents import load_checkpoint
    from sim2real.agents.cli import cli_train
    from sim2real.evaluation import evaluate, nominal, randomized

    agent = tmp_path / "ppo.yaml"
    agent.write_text(TINY_PPO)
    adr_file = tmp_path / "adr.yaml"  # thresholds every return clears: each pinned boundary widens
    adr_file.write_text(
        "effects:\n  - {type: Damping, scale: [0.2, 5.0]}\n"
        "  - {type: Mass, scale: {type: LogUniform, low: 0.5, high: 2.0}, bodies: '*'}\n"
        "delta: 0.2\nt_low: -5000\nt_high: -4000\np_boundary: 1.0\nm: 1\nmetric: return\n"
    )
    ckpt = tmp_path / "adr.pt"
    exported = tmp_path / "adr_ranges.yaml"  # the ranges ADR chose, as an effects file for `train --config`
    base = ["--model", str(arm), "--algo", "ppo", "--agent-config", str(agent), "--no-log", "--quiet"]
    out = io.StringIO()
    argv = [*base, "--adr", str(adr_file), "--adr-export", str(exported), "--out", str(ckpt)]
    assert cli_train(argv, out=out) == 0
    summary = out.getvalue()
    assert "collection: batched engine, 2 worlds x 200 steps per batch" in summary  # the engine it used, said
    assert "seed 0, 0 effect(s) + ADR over 2\n" in summary  # before: "0 effect(s)", ADR's two left out
    checkpoint = load_checkpoint(ckpt)
    adr = ADR.from_state(checkpoint.adr)
    assert adr.frames == 800  # four 200-step episodes, two per batch ending on the same step
    # Each was pinned and widened its boundary, unless the other world's result of that step had moved it (stale).
    assert len(adr.history.frames) == 1 + 4 - adr.stale
    assert adr.ranges["Damping[joints=*]"][1] > 1.0 and adr.ranges["Mass[bodies=*]"][0] < 1.0  # widened
    ranges = ", ".join(f"{key} [{lo:g}, {hi:g}]" for key, (lo, hi) in adr.ranges.items())
    assert f"adr: entropy {adr.entropy():.3f} nats/dim; {ranges}" in summary
    # ... and what they mean on this arm, in its units (N·m·s/rad, kg), one range per joint and body.
    in_units = adr.parameter_ranges(mujoco.MjModel.from_xml_path(str(arm)))
    low, high = in_units["dof_damping[lift]"]
    assert (low, high) == (1.2 * adr.ranges["Damping[joints=*]"][0], 1.2 * adr.ranges["Damping[joints=*]"][1])
    line = ", ".join(f"{address} [{lo:.4g}, {hi:.4g}]" for address, (lo, hi) in in_units.items())
    assert f"adr ranges in the model's units: {line}\n" in summary and "body_mass[tool] [" in line

    # The exported ranges are the checkpoint's final ones, exactly, and train the next run (what it trains under).
    assert f"adr ranges (effects for --config): {exported}\n" in summary
    assert exported.read_text() == s2r.dump_config(list(adr.effects_at_ranges()))
    assert list(s2r.load_config(exported)) == list(adr.effects_at_ranges())
    ckpt2 = tmp_path / "ranges.pt"
    out = io.StringIO()
    assert cli_train([*base, "--config", str(exported), "--out", str(ckpt2)], out=out) == 0
    assert "collection: batched engine, 2 worlds x 200 steps per batch" in out.getvalue()
    second = load_checkpoint(ckpt2)
    assert list(s2r.load_config(second.effects)) == list(adr.effects_at_ranges())

    # Both checkpoints load and evaluate on the arm, batched (no fallback), under the chosen ranges too.
    result = evaluate(
        {"adr": str(ckpt), "ranges": str(ckpt2)},
        f"model:{arm}",
        [nominal(), randomized(list(adr.effects_at_ranges()))],
        episodes=2,
        seed=0,
        max_steps=20,
    )
    assert not result.fallbacks
    for policy in ("adr", "ranges"):
        for condition in ("sim", "randomized"):
            returns = result.returns[policy][condition]
            assert returns.shape == (2,) and np.isfinite(returns).all() and (returns < 0).all()


def test_a_budget_that_ends_no_episode_says_adr_saw_nothing(arm: Path, tmp_path: Path) -> None:
    # 20 batched worlds x 20 steps: no 200-step episode of the arm ends, so ADR gets no result. Before, the summary
    # printed the unmoved ranges as if ADR had judged them.
    from sim2real.agents.cli import cli_train

    adr = tmp_path / "adr.yaml"
    adr.write_text("effects: [{type: Damping, scale: [0.2, 5.0]}]\ndelta: 0.1\nt_low: -1e9\nt_high: -1e8\n")
    out = io.StringIO()
    argv = ["--model", str(arm), "--adr", str(adr), "--frames", "400", "--no-log", "--quiet"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert cli_train([*argv, "--out", str(tmp_path / "p.pt")], out=out) == 0
    summary = out.getvalue()
    # --frames 400 ran PPO's one whole batch of 1000: said once, in sim2real's words (before: only TorchRL's
    # "total_frames (400) is not exactly divisible" warning, and "1000 frames" in the summary).
    assert not [w for w in caught if "not exactly divisible" in str(w.message)]
    assert (
        "note: PPO collects whole batches of 1000 frames: 1000 frames for 400 asked (frames_per_batch in "
        "--agent-config sets the batch)\n"
    ) in summary
    assert "collection: batched engine, 20 worlds x 50 steps per batch" in summary  # PPO's whole first batch
    assert (
        "note: no episode ended in each of its 20 worlds within 1000 frames, so ADR had no results and its ranges "
        "stayed where they started; give more --frames (or fewer num_envs in --agent-config)\n"
    ) in summary


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_adr_learns_only_from_the_policy_not_from_the_normaliser_warm_up(arm: Path, algo: str) -> None:
    # Both algorithms fit their observation normaliser on obs_norm_frames uniform-random steps of the training env
    # (ADR's env) first. Before, the episodes of that warm-up were reported to ADR as if the policy had run them:
    # SAC's default 2000 warm-up steps were 10 of the arm's 200-step episodes, ADR counted 2400 frames for a
    # 450-frame run and moved its ranges on random actions' returns before training began.
    from sim2real.agents import PPOConfig, SACConfig, train

    adr_text = (
        "effects: [{type: Damping, scale: [0.2, 5.0]}]\ndelta: 0.2\nt_low: -5000\nt_high: -4000\n"
        "p_boundary: 1.0\nm: 1\n"
    )
    if algo == "sac":
        config: Any = SACConfig(frames=450, obs_norm_frames=2000, hidden_sizes=(16, 16), adr=adr_text)
    else:  # 2 worlds x 200 warm-up steps: one whole episode each before the first batch
        config = PPOConfig(frames=800, frames_per_batch=400, num_envs=2, minibatch_size=100, epochs=1,
                           obs_norm_frames=400, hidden_sizes=(16, 16), adr=adr_text)  # fmt: skip
    result = train(f"model:{arm}", config, seed=0)
    adr = ADR.from_state(result.adr)
    episodes = 2 if algo == "sac" else 4  # 200-step episodes the training itself ended
    assert adr.frames == 200 * episodes and adr.history.frames[-1] <= result.frames


def test_sac_from_scratch_on_the_arm_says_its_engine_and_evaluates(arm: Path, tmp_path: Path) -> None:
    from sim2real.agents import load_checkpoint
    from sim2real.agents.cli import cli_train
    from sim2real.evaluation import evaluate, nominal

    ckpt = tmp_path / "sac.pt"
    out = io.StringIO()
    argv = ["--model", str(arm), "--algo", "sac", "--frames", "300", "--no-log", "--quiet", "--out", str(ckpt)]
    assert cli_train(argv, out=out) == 0
    # SAC steps the arm's gymnasium env itself (before: "one TorchRL env", which it is not).
    assert "collection: per-env (one gymnasium env): SAC steps one env" in out.getvalue()
    assert load_checkpoint(ckpt).config.algo == "sac"
    result = evaluate({"sac": str(ckpt)}, f"model:{arm}", [nominal()], episodes=2, seed=0, max_steps=10)
    assert np.isfinite(result.returns["sac"]["sim"]).all()


# -- the safety table before the hardware ---------------------------------------------------------------------------
LIMITS = """joint_limit_hits: 0
max_effort_ratio: 0.95
max_ee_speed: {site: tip, m_per_s: 2.0}
divergences: 0
"""


def _spec(folder: Path, arm: Path, policies: str) -> Path:
    spec = folder / "spec.yaml"
    spec.write_text(f"model: {arm}\nepisodes: 4\nmax_steps: 60\nbatch: 4\npolicies: {policies}\n")
    (folder / "limits.yaml").write_text(LIMITS)
    return spec


def test_slamming_into_the_limits_exits_3_with_intervals_and_the_report_written(
    arm: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sim2real.cli import main

    policies = f"{{hold: {{constant: {HOME.tolist()}}}, slam: {{constant: {SLAM}}}}}"
    spec = _spec(tmp_path, arm, policies)
    out = tmp_path / "report"
    argv = ["evaluate", "--config", str(spec), "--safety", str(tmp_path / "limits.yaml"), "--out", str(out)]
    code = main([*argv, "--backend", "serial", "--quiet"])
    captured = capsys.readouterr()
    assert code == 3
    lines = captured.err.strip().splitlines()
    assert all(line.startswith("sim2real evaluate: safety: policy 'slam' on 'sim': ") for line in lines)
    # Every slam episode drives the arm into its limits: 4 of 4, and the interval says what 4 episodes can say.
    hits = next(line for line in lines if "joint_limit_hits" in line)
    assert hits.endswith("; 4 of 4 episodes over 0, 95% interval of the rate 51%-100%)")
    safety = json.loads((out / "report.json").read_text())["safety"]
    rows = {(r["policy"], r["quantity"]): r for r in safety["rows"]}
    assert rows[("slam", "joint_limit_hits")]["violated"] and rows[("slam", "joint_limit_hits")]["worst"] > 0
    held = rows[("hold", "joint_limit_hits")]
    assert (held["violated"], held["worst"], held["episodes_over_limit"]) == (False, 0.0, 0)
    assert held["verdict"] == "within: 0 of 4 episodes over 0, 95% interval of the rate 0%-49%"
    low, high = held["over_limit_rate"]["low"], held["over_limit_rate"]["high"]
    assert (low, round(high, 4), held["over_limit_rate"]["confidence"]) == (0.0, 0.4899, 0.95)
    # Units are the model's: the tip speed in m/s, the effort against the servo's forcerange in N·m (a clamped
    # servo reaches exactly 1), the sampling every 4 physics steps (50 Hz control over 5 ms steps).
    assert rows[("hold", "ee_speed")]["unit"] == "m/s" and rows[("slam", "effort_ratio")]["worst"] == 1.0
    assert safety["physics_steps_per_sample"] == 4
    assert "## Safety" in (out / "report.md").read_text()


def test_holding_home_passes_with_exit_0_and_the_effort_is_the_servo_torque_over_its_limit(
    arm: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sim2real.cli import main
    from sim2real.evaluation import episode_seed

    spec = _spec(tmp_path, arm, f"{{hold: {{constant: {HOME.tolist()}}}}}")
    out = tmp_path / "report"
    argv = ["evaluate", "--config", str(spec), "--safety", str(tmp_path / "limits.yaml"), "--out", str(out)]
    code = main([*argv, "--backend", "serial", "--quiet"])
    captured = capsys.readouterr()
    assert code == 0 and captured.err == ""
    assert f"safety: every policy within {tmp_path / 'limits.yaml'} on every condition" in captured.out
    rows = {r["quantity"]: r for r in json.loads((out / "report.json").read_text())["safety"]["rows"]}
    # The effort ratio is the peak |actuator_force| (N·m) over the servo's forcerange, stepping the env by hand.
    env = s2r.make(f"model:{arm}", max_episode_steps=60)
    model = mujoco.MjModel.from_xml_path(str(arm))
    limit = np.abs(model.actuator_forcerange).max(axis=1)
    data = env.unwrapped.data
    peaks = []
    for episode in range(4):
        env.reset(seed=episode_seed(0, episode))
        peak = 0.0
        for _ in range(60):
            env.step(HOME)
            peak = max(peak, float((np.abs(data.actuator_force) / limit).max()))
        peaks.append(peak)
    env.close()
    assert rows["effort_ratio"]["worst"] == pytest.approx(max(peaks), rel=1e-12)
    assert 0.0 < rows["effort_ratio"]["worst"] < 0.95 and rows["effort_ratio"]["verdict"].startswith("within: 0 of 4")


def test_a_site_the_arm_does_not_have_is_exit_2_before_any_episode(
    arm: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sim2real.cli import main

    spec = _spec(tmp_path, arm, f"{{hold: {{constant: {HOME.tolist()}}}}}")
    (tmp_path / "limits.yaml").write_text("max_ee_speed: {site: tipp, m_per_s: 2.0}\n")
    out = tmp_path / "report"
    argv = ["evaluate", "--config", str(spec), "--safety", str(tmp_path / "limits.yaml"), "--out", str(out)]
    code = main([*argv, "--backend", "serial", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "tipp" in err and "'tip'" in err
    assert not out.exists()
    assert yaml.safe_load((tmp_path / "limits.yaml").read_text())["max_ee_speed"]["site"] == "tipp"  # untouched


def test_an_effort_limit_on_servos_without_a_force_limit_is_exit_2_not_a_pass(
    arm: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The same arm with its servos' forceranges left out: no actuator declares a limit to divide by. Before, the
    # effort was not measured, its row left out, and `max_effort_ratio: 0.9` "passed": exit 0 and "every policy
    # within limits.yaml" for a policy slamming every servo to its stop.
    bare = tmp_path / "bare.xml"
    bare.write_text(re.sub(r' forcerange="[^"]*"', "", ARM))
    spec = _spec(tmp_path, bare, f"{{slam: {{constant: {SLAM}}}}}")
    limits = tmp_path / "limits.yaml"
    limits.write_text("max_effort_ratio: 0.9\n")
    out = tmp_path / "report"
    code = main_evaluate(["--config", str(spec), "--safety", str(limits), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and not out.exists()
    assert err.strip() == (
        f"sim2real evaluate: error: --safety: {limits}: `max_effort_ratio` needs an actuator with a declared force "
        "limit (forcelimited with a forcerange, or a motor with a limited ctrlrange); none of the model's actuators "
        "['turn', 'lift', 'bend', 'twist'] has one. Received max_effort_ratio=0.9."
    )
    from sim2real.safety import LimitsError, load_limits

    with pytest.raises(LimitsError, match=re.escape("none of the model's actuators")):
        load_limits({"max_effort_ratio": 0.9}).meter(mujoco.MjModel.from_xml_path(str(bare)), 1)
    load_limits({"joint_limit_hits": 0}).meter(mujoco.MjModel.from_xml_path(str(bare)), 1)  # no effort limit: fine


@pytest.mark.parametrize(
    ("limits", "message"),
    [
        # Every geom of the arm has contype=0 conaffinity=0: its contact force is 0 at every step, whatever happens.
        (
            "max_contact_force: {geoms: '*', newtons: 50}",
            "`max_contact_force.geoms` must select a geom that can touch something; ['base', 'link1', 'link2', "
            "'tool'] cannot (their contype/conaffinity bits match no geom's and no <pair> names them), so the force "
            "would be 0 at every step. Received geoms ['base', 'link1', 'link2', 'tool'].",
        ),
        (
            "joint_limit_hits: 0",
            '`joint_limit_hits` needs a limited joint (a `range` with limited="true" or autolimits); none of the '
            "model's joints ['turn', 'lift', 'bend', 'twist'] has one, so no step could count. Received "
            "joint_limit_hits=0.",
        ),
    ],
)
def test_a_limit_that_can_never_fail_on_the_arm_is_exit_2_not_a_pass(
    arm: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], limits: str, message: str
) -> None:
    # Before, both "passed": exit 0 and "every policy within" with contacts that cannot happen, or with joints that
    # have no range to hit (here the arm's ranges are left out for the second case).
    xml = ARM.replace('<geom type="', '<geom name="{}" type="')
    for name in ("base", "link1", "link2", "tool"):
        xml = xml.replace('name="{}"', f'name="{name}"', 1)
    if "joint_limit_hits" in limits:
        xml = re.sub(r' range="[^"]*"', "", xml)
    model = tmp_path / "arm.xml"
    model.write_text(xml)
    spec = _spec(tmp_path, model, f"{{slam: {{constant: {SLAM}}}}}")
    path = tmp_path / "limits.yaml"
    path.write_text(limits + "\n")
    out = tmp_path / "report"
    code = main_evaluate(["--config", str(spec), "--safety", str(path), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and not out.exists()
    assert err.strip() == f"sim2real evaluate: error: --safety: {path}: {message}"


def main_evaluate(argv: list[str]) -> int:
    from sim2real.cli import main

    return main(["evaluate", *argv, "--backend", "serial", "--quiet"])
