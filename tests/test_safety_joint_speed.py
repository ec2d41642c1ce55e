"""The safety envelope's per-joint speed limit (``max_joint_speed``): the measured ratio against ``|qvel| / limit``
read from MuJoCo, both forms of the key, the refusals, batched against single bitwise, the CLI's exit codes."""

from __future__ import annotations

import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import StandInBatch

from sim2real import cli
from sim2real.conditions import nominal, sweep
from sim2real.evaluation import episode_seed, evaluate
from sim2real.mjcf_env import MjcfEnv
from sim2real.safety import ConstantAction, LimitsError, SafetyLimits, SafetyTable, load_limits
from sim2real.safety_probe import SafetyMeter, speed_joints

# A ball-jointed bob first (4 qpos, 3 dofs: every later joint's qvel index differs from its id), then a carriage on a
# slide joint carrying a planar two-link arm (hinges about z; no gravity, no contacts: only the motors move it).
ARM = """
<mujoco model="speed_arm">
  <option timestep="0.002" gravity="0 0 0"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="bob" pos="0 0.6 0">
      <joint name="swivel" type="ball" damping="0.1"/>
      <geom type="sphere" size="0.05" mass="0.2"/>
    </body>
    <body name="carriage">
      <joint name="lift" type="slide" axis="1 0 0" range="-1 1" damping="5"/>
      <geom type="box" size="0.05 0.05 0.05" mass="1"/>
      <body name="upper">
        <joint name="shoulder" type="hinge" axis="0 0 1" damping="0.5"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="1"/>
        <body name="fore" pos="0.3 0 0">
          <joint name="elbow" type="hinge" axis="0 0 1" damping="0.5"/>
          <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.025" mass="0.5"/>
          <site name="grip" pos="0.25 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="lift" joint="lift" ctrlrange="-1 1" gear="10"/>
    <motor name="shoulder" joint="shoulder" ctrlrange="-1 1" gear="2"/>
    <motor name="elbow" joint="elbow" ctrlrange="-1 1" gear="3"/>
  </actuator>
</mujoco>
"""
ARM_JOINTS = ("lift", "shoulder", "elbow")  # the declared ones, in model order
PER_JOINT = {"lift": 0.5, "shoulder": 6.0, "elbow": 2.6}
ELBOW = [0.0, 0.0, 1.0]  # full torque on the elbow only
STEPS, EPISODES = 30, 3


@pytest.fixture(scope="module")
def arm_xml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("speed_arm") / "arm.xml"
    path.write_text(ARM)
    return path


def _by_hand(arm_xml: Path, action: list[float], limits: dict[str, float]) -> tuple[list[float], list[str]]:
    """Per episode: the peak over steps of max_j |qvel_j| / limit_j, read from MuJoCo's data after every step of the
    same env with the same seeds, and the joint at that peak."""
    env = MjcfEnv(arm_xml)
    ids = [mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_JOINT, name) for name in limits]
    dofs = env.model.jnt_dofadr[ids]
    bound = np.array(list(limits.values()))
    peaks, joints = [], []
    for e in range(EPISODES):
        env.reset(seed=episode_seed(0, e))
        ratios = []
        for _ in range(STEPS):
            env.step(np.array(action))
            ratios.append(np.abs(env.data.qvel[dofs]) / bound)
        table = np.array(ratios)  # (steps, joints)
        peaks.append(float(table.max()))
        joints.append(list(limits)[int(np.unravel_index(np.argmax(table), table.shape)[1])])
    return peaks, joints


def _run(
    arm_xml: Path, action: list[float], limits: SafetyLimits, engine: str = "auto", conditions: list | None = None
):
    return evaluate(
        {"push": ConstantAction(action)},
        f"model:{arm_xml}",
        conditions or [nominal()],
        episodes=EPISODES,
        seed=0,
        max_steps=STEPS,
        safety=limits,
        engine=engine,
    )


# ------------------------------------------------------------------------------------------------ the measurement


def test_ratio_is_the_peak_of_qvel_over_limit_read_from_mujoco(arm_xml: Path) -> None:
    limits = load_limits({"max_joint_speed": PER_JOINT})
    result = _run(arm_xml, ELBOW, limits)
    measured = result.safety["push"]["sim"]
    peaks, joints = _by_hand(arm_xml, ELBOW, PER_JOINT)
    assert measured["joint_speed_ratio"].tolist() == peaks  # exactly: the same divisions and maxima
    assert joints == ["elbow"] * EPISODES and min(peaks) > 1.0  # the elbow, driven, is over its 2.6 rad/s
    assert measured["joint_speed_joint"].tolist() == [2.0] * EPISODES  # elbow: third of lift, shoulder, elbow
    # The other quantities are untouched: no end-effector declared, so not measured.
    assert np.isnan(measured["ee_speed"]).all() and measured["diverged"].tolist() == [0.0] * EPISODES


def test_a_slide_joint_is_measured_in_metres_per_second(arm_xml: Path) -> None:
    limits = load_limits({"max_joint_speed": PER_JOINT})
    model = mujoco.MjModel.from_xml_path(str(arm_xml))
    assert [(j.name, j.dof, j.limit, j.unit) for j in speed_joints(model, limits)] == [
        ("lift", 3, 0.5, "m/s"),
        ("shoulder", 4, 6.0, "rad/s"),
        ("elbow", 5, 2.6, "rad/s"),
    ]
    result = _run(arm_xml, [1.0, 0.0, 0.0], limits)
    peaks, joints = _by_hand(arm_xml, [1.0, 0.0, 0.0], PER_JOINT)
    assert result.safety["push"]["sim"]["joint_speed_ratio"].tolist() == peaks
    assert joints == ["lift"] * EPISODES and min(peaks) > 1.0
    table = SafetyTable.build(result, limits, model=model)
    (violation,) = table.violations
    episode = int(np.argmax(peaks))
    speed = peaks[episode] * 0.5
    assert violation.message == (
        f"policy 'push' on 'sim': joint_speed_ratio worst {peaks[episode]:.4g} > limit 1 (episode {episode}: "
        f"lift {speed:.4g} m/s over 0.5; 3 of 3 episodes over 1, 95% interval of the rate 43.9%-100%)"
    )


def test_both_forms_of_the_key_measure_alike(arm_xml: Path) -> None:
    patterns = load_limits("max_joint_speed: {joints: [lift, '*o*'], limit: 2.6}")  # *o*: shoulder and elbow
    mapping = load_limits({"max_joint_speed": {"elbow": 2.6, "lift": 2.6, "shoulder": 2.6}})
    model = mujoco.MjModel.from_xml_path(str(arm_xml))
    assert speed_joints(model, patterns) == speed_joints(model, mapping)
    runs = [_run(arm_xml, ELBOW, limits) for limits in (patterns, mapping)]
    assert runs[0].to_json() == runs[1].to_json()
    assert (
        runs[0].safety["push"]["sim"]["joint_speed_ratio"].tolist()
        == _by_hand(arm_xml, ELBOW, dict.fromkeys(ARM_JOINTS, 2.6))[0]
    )
    # The file form round-trips, each in its own form.
    assert patterns.to_dict()["max_joint_speed"] == {"joints": ["lift", "*o*"], "limit": 2.6}
    assert mapping.to_dict()["max_joint_speed"] == {"elbow": 2.6, "lift": 2.6, "shoulder": 2.6}
    for limits in (patterns, mapping):
        assert load_limits(limits.to_dict()) == limits
    assert patterns.limit("joint_speed_ratio") == 1.0 and load_limits({}).limit("joint_speed_ratio") is None


def test_without_the_key_nothing_is_measured(arm_xml: Path) -> None:
    result = _run(arm_xml, ELBOW, load_limits({"joint_limit_hits": 0}))
    measured = result.safety["push"]["sim"]
    assert np.isnan(measured["joint_speed_ratio"]).all() and "joint_speed_joint" not in measured
    table = SafetyTable.build(result, load_limits({"joint_limit_hits": 0}))
    assert not any(r.quantity == "joint_speed_ratio" for r in table.rows)  # no row, as ee_speed without a site


def test_violation_names_the_joint_and_the_table_carries_it(arm_xml: Path) -> None:
    limits = load_limits({"max_joint_speed": PER_JOINT})
    conditions = [nominal(), *sweep({"type": "Damping", "scale": 1.0}, "scale", [0.5, 4.0])]
    result = _run(arm_xml, ELBOW, limits, conditions=conditions)
    model = mujoco.MjModel.from_xml_path(str(arm_xml))
    table = SafetyTable.build(result, limits, model=model)
    ratios = result.safety["push"]["sim"]["joint_speed_ratio"]
    episode = int(np.argmax(ratios))
    sim = next(v for v in table.violations if v.condition == "sim")
    assert sim.peak == f"elbow {ratios[episode] * 2.6:.4g} rad/s over 2.6"
    assert f"(episode {episode}: elbow " in sim.message and " rad/s over 2.6; 3 of 3 episodes over 1" in sim.message
    row = next(r for r in table.rows if r.quantity == "joint_speed_ratio" and r.kind == "sweep")
    assert row.limit == 1.0 and row.violated and row.peak.startswith("elbow ") and row.where.startswith("Damping")
    as_json = table.to_dict()
    sweep_row = next(r for r in as_json["rows"] if r["quantity"] == "joint_speed_ratio" and r["kind"] == "sweep")
    assert sweep_row["unit"] == "" and sweep_row["peak"] == row.peak and sweep_row["limit"] == 1.0
    assert not any("peak" in r for r in as_json["rows"] if r["quantity"] != "joint_speed_ratio")
    # Without the model the ratio is still checked; the joint is not named.
    bare = SafetyTable.build(result, limits)
    assert [v.message.split(" (")[0] for v in bare.violations] == [v.message.split(" (")[0] for v in table.violations]
    assert all(v.peak == "" and "(episode " in v.message for v in bare.violations)
    from sim2real.report.safety import safety_blocks

    blocks = safety_blocks(table)
    assert "joint speed / limit" in blocks[2]["header"]
    assert "joint speed / limit <= 1" in blocks[1]["text"]
    cells = [cell for row in blocks[2]["rows"] for cell in row if "rad/s over 2.6" in cell]
    assert cells and all("VIOLATED (limit 1)" in cell for cell in cells)


# ------------------------------------------------------------------------------------------------ refusals


@pytest.mark.parametrize(
    ("key", "message"),
    [
        (
            {"joints": "elbow", "limit": 0},
            "<config>: `max_joint_speed.limit` must be a number > 0 (rad/s for a hinge joint, m/s for a slide "
            "joint). Received 0.",
        ),
        (
            {"joints": "elbow", "limit": float("inf")},
            "<config>: `max_joint_speed.limit` must be a number > 0 (rad/s for a hinge joint, m/s for a slide "
            "joint). Received inf.",
        ),
        (
            {"joints": "elbow"},
            "<config>: `max_joint_speed.limit` must be a number > 0 (rad/s for a hinge joint, m/s for a slide "
            "joint). Received None.",
        ),
        (
            {"elbow": -1.5},
            "<config>: `max_joint_speed.elbow` must be a number > 0 (rad/s for a hinge joint, m/s for a slide "
            "joint). Received -1.5.",
        ),
        (
            {"elbow": "fast"},
            "<config>: `max_joint_speed.elbow` must be a number > 0 (rad/s for a hinge joint, m/s for a slide "
            "joint). Received 'fast'.",
        ),
        (
            {"elbow": float("nan")},
            "<config>: `max_joint_speed.elbow` must be a number > 0 (rad/s for a hinge joint, m/s for a slide "
            "joint). Received nan.",
        ),
        (
            {"limit": 2.0},
            "<config>: `max_joint_speed.joints` must be a joint name pattern or a list of them. Received None.",
        ),
        (
            {"joints": [], "limit": 2.0},
            "<config>: `max_joint_speed.joints` must be a joint name pattern or a list of them. Received [].",
        ),
        (
            {"joints": "elbow", "limit": 2.0, "shoulder": 1.0},
            "<config>: `max_joint_speed` keys must be among ['joints', 'limit']. Received unknown ['shoulder'].",
        ),
        (
            [2.0],
            "<config>: `max_joint_speed` must be {joints: <pattern or list>, limit: <number>} or a mapping joint "
            "name -> limit (rad/s for a hinge joint, m/s for a slide joint). Received [2.0].",
        ),
    ],
)
def test_bad_values_are_refused_naming_the_argument(key: object, message: str) -> None:
    with pytest.raises(LimitsError) as err:
        load_limits({"max_joint_speed": key})
    assert str(err.value) == message


def test_joints_the_model_cannot_limit_are_refused(arm_xml: Path) -> None:
    model = mujoco.MjModel.from_xml_path(str(arm_xml))
    cases = [
        (
            {"joints": "*", "limit": 2.0},  # every joint: the ball one too
            "<config>: `max_joint_speed.joints` must select hinge (rad/s) or slide (m/s) joints; 'swivel' is a ball "
            "joint, whose velocity has 3 components and no one speed to limit. Received '*'.",
        ),
        (
            {"elbw": 2.0},
            "<config>: `max_joint_speed` pattern 'elbw' matches no joint in the model. Close matches: 'elbow'. Known "
            "joints: 'swivel', 'lift', 'shoulder', 'elbow'.",
        ),
        (
            {"joints": ["elbow", "wrist*"], "limit": 2.0},
            "<config>: `max_joint_speed.joints` pattern 'wrist*' matches no joint in the model. Known joints: "
            "'swivel', 'lift', 'shoulder', 'elbow'.",
        ),
        (
            {"elb*": 2.0, "elbow": 3.0},
            "<config>: `max_joint_speed` gives joint 'elbow' two limits ('elb*': 2.0, 'elbow': 3.0); each joint takes "
            "one. Received {'elb*': 2.0, 'elbow': 3.0}.",
        ),
    ]
    for key, message in cases:
        with pytest.raises(LimitsError) as err:
            load_limits({"max_joint_speed": key}).meter(model, 1)
        assert str(err.value) == message
    free = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="box"><freejoint name="float"/><geom size=".1"/></body></worldbody></mujoco>'
    )
    with pytest.raises(LimitsError, match=r"'float' is a free joint, whose velocity has 6 components and no one"):
        load_limits({"max_joint_speed": {"float": 1.0}}).meter(free, 1)
    # The Python form is checked as the file is.
    with pytest.raises(LimitsError, match=r"`max_joint_speed.joints` must name the joints the limit is on."):
        SafetyLimits(max_joint_speed=2.0)
    with pytest.raises(LimitsError, match=r"takes \{joints: ..., limit: ...\} or a mapping joint -> limit, not both"):
        SafetyLimits(speed_joints=("elbow",), max_joint_speed=2.0, joint_speeds=(("lift", 1.0),))


# ------------------------------------------------------------------------------------------------ batched == single


def test_observe_batch_is_observe_world_by_world(monkeypatch: pytest.MonkeyPatch) -> None:
    """Random joint speeds, some tied between joints relative to their limits and some NaN (a diverging world),
    random subsets of worlds observed (the others faster: they must not count), blocks of 4 steps, a reset and
    episodes read inside a block: ``observe_batch`` gives ``observe``'s ratios and joints bitwise."""
    import sim2real.safety_probe as probe

    monkeypatch.setattr(probe, "_BLOCK", 4)
    model = mujoco.MjModel.from_xml_string(ARM)
    n = 5
    datas = [mujoco.MjData(model) for _ in range(n)]
    dofs = [3, 4, 5]
    for limits in (
        SafetyLimits(joint_speeds=tuple(PER_JOINT.items())),
        SafetyLimits(speed_joints=("lift", "*o*"), max_joint_speed=2.0, ee_site="grip"),
    ):
        scale = np.array([j.limit for j in speed_joints(model, limits)])
        batched, single, batch = SafetyMeter(model, limits, n), SafetyMeter(model, limits, n), StandInBatch(datas)
        batched.bind_batch(batch)
        rng = np.random.default_rng(1)
        for step in range(31):
            if step == 10:
                batched.reset()
                single.reset()
            if step == 21:  # read inside a block
                assert np.array_equal(batched.episodes(np.zeros(n))["joint_speed_ratio"],
                                      single.episodes(np.zeros(n))["joint_speed_ratio"])  # fmt: skip
            worlds = np.flatnonzero(rng.random(n) < 0.6)
            for i, d in enumerate(datas):
                unseen = i not in worlds
                d.qpos[:] = 0.0
                d.qvel[:] = rng.normal(0.0, 3.0 if unseen else 1.0, model.nv)
                d.qvel[dofs] *= scale  # each joint as likely as the others to be the fastest against its limit
                if rng.random() < 0.3:  # every joint at the same ratio (exactly: a power of 2): the first is named
                    d.qvel[dofs] = scale * 2.0 ** int(rng.integers(-1, 3))
                mujoco.mj_forward(model, d)
                if step == 17 and i == 2:  # a diverged world: NaN sets no peak, on either path
                    d.qvel[dofs[0]] = np.nan
            batch.load()
            for i in worlds.tolist():
                single.observe(i, model, datas[i])
            batched.observe_batch(None if len(worlds) == n else worlds, [model] * n, lambda i: datas[i])
        got, want = batched.episodes(np.zeros(n, bool)), single.episodes(np.zeros(n, bool))
        assert set(got) == set(want) and "joint_speed_joint" in want
        for quantity in want:
            assert np.array_equal(got[quantity], want[quantity], equal_nan=True), quantity
        assert (want["joint_speed_ratio"] > 0).all() and len(set(want["joint_speed_joint"].tolist())) > 1


def test_batched_engine_measures_the_same_as_per_env(arm_xml: Path) -> None:
    limits = load_limits({"max_joint_speed": PER_JOINT, "max_ee_speed": {"site": "grip"}})
    conditions = [nominal(), *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 2.0])]
    runs = [_run(arm_xml, [0.3, -1.0, 1.0], limits, engine, conditions) for engine in ("auto", "per-env")]
    assert set(runs[0].engines.values()) == {"batched"} and set(runs[1].engines.values()) == {"per-env"}
    assert runs[0].to_json() == runs[1].to_json()
    for cond, measured in runs[0].safety["push"].items():
        for quantity, values in measured.items():
            assert np.array_equal(values, runs[1].safety["push"][cond][quantity], equal_nan=True), (cond, quantity)
    assert (runs[0].safety["push"]["ActuatorGain.scale=2"]["joint_speed_ratio"] > 1.0).all()


# ------------------------------------------------------------------------------------------------ the command line

SPEC = f"""
model: arm.xml
seed: 0
episodes: {EPISODES}
max_steps: {STEPS}
policies:
{{policies}}
"""


def _cli(tmp_path: Path, policies: str, limits: str) -> int:
    (tmp_path / "arm.xml").write_text(ARM)
    (tmp_path / "spec.yaml").write_text(SPEC.format(policies=policies))
    (tmp_path / "limits.yaml").write_text(limits)
    args = ["evaluate", "--config", str(tmp_path / "spec.yaml"), "--safety", str(tmp_path / "limits.yaml")]
    return cli.main([*args, "--out", str(tmp_path / "report"), "--backend", "serial", "--quiet"])


def test_a_joint_over_its_speed_limit_exits_3(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = _cli(tmp_path, f"  still: {{constant: [0, 0, 0]}}\n  push: {{constant: {ELBOW}}}",
                "max_joint_speed: {lift: 0.5, shoulder: 6.0, elbow: 2.6}\n")  # fmt: skip
    captured = capsys.readouterr()
    assert code == 3, captured.err
    (line,) = captured.err.strip().splitlines()
    peaks, _ = _by_hand(tmp_path / "arm.xml", ELBOW, PER_JOINT)
    episode = int(np.argmax(peaks))
    assert line == (
        f"sim2real evaluate: safety: policy 'push' on 'sim': joint_speed_ratio worst {peaks[episode]:.4g} > limit 1 "
        f"(episode {episode}: elbow {peaks[episode] * 2.6:.4g} rad/s over 2.6; 3 of 3 episodes over 1, 95% interval "
        "of the rate 43.9%-100%)"
    )
    safety = json.loads((tmp_path / "report" / "report.json").read_text())["safety"]
    assert safety["limits"]["max_joint_speed"] == PER_JOINT and safety["passed"] is False
    rows = {r["policy"]: r for r in safety["rows"] if r["quantity"] == "joint_speed_ratio"}
    assert rows["push"]["worst"] == max(peaks) and rows["push"]["violated"] and rows["push"]["limit"] == 1.0
    assert rows["still"]["worst"] == 0.0 and not rows["still"]["violated"] and "peak" not in rows["still"]
    markdown = (tmp_path / "report" / "report.md").read_text()
    assert "joint speed / limit" in markdown and re.search(r"elbow [0-9.]+ rad/s over 2\.6", markdown)


@pytest.mark.parametrize(
    ("limits", "message"),
    [
        (
            "max_joint_speed: {joints: '*', limit: 2}\n",
            "`max_joint_speed.joints` must select hinge (rad/s) or slide (m/s) joints; 'swivel' is a ball joint",
        ),
        ("max_joint_speed: {elbw: 2}\n", "`max_joint_speed` pattern 'elbw' matches no joint in the model."),
        ("max_joint_speed: {elbow: 0}\n", "`max_joint_speed.elbow` must be a number > 0 (rad/s for a hinge joint"),
    ],
)
def test_bad_joint_speed_limits_exit_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], limits: str, message: str
) -> None:
    assert _cli(tmp_path, "  still: {constant: [0, 0, 0]}", limits) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(f"sim2real evaluate: error: --safety: {tmp_path / 'limits.yaml'}: ")
    assert message in err
    assert not (tmp_path / "report").exists()  # refused before any episode: nothing written
