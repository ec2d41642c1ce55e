"""The safety envelope (issue 14): measured quantities against hand computations, the table, the CLI's exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import StandInBatch

from sim2real import cli
from sim2real.conditions import nominal, sweep
from sim2real.evaluation import Evaluation, evaluate
from sim2real.mjcf_env import MjcfEnv
from sim2real.safety import ConstantAction, LimitsError, SafetyLimits, SafetyTable, cvar_upper, load_limits
from sim2real.safety_probe import SafetyMeter, actuator_limits

# A planar two-link arm (hinges about z, so gravity does not move it) with limited joints, motors and a tip site.
ARM = """
<mujoco model="planar_arm">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" type="hinge" axis="0 0 1" range="-0.5 0.5" limited="true" damping="0.5"/>
      <geom name="upper_link" type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="1"/>
      <body name="fore" pos="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 0 1" range="-0.5 0.5" limited="true" damping="0.5"/>
        <geom name="finger_link" type="capsule" fromto="0 0 0 0.25 0 0" size="0.025" mass="0.5"/>
        <site name="grip" pos="0.25 0 0"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="shoulder" joint="shoulder" ctrlrange="-1 1" gear="5"/>
    <motor name="elbow" joint="elbow" ctrlrange="-1 1" gear="3"/>
  </actuator>
</mujoco>
"""

SPEC = """
model: arm.xml
seed: 0
episodes: 3
max_steps: 40
policies:
{policies}
"""

LIMITS = """
joint_limit_hits: 0
max_effort_ratio: 1.0
max_ee_speed: {site: grip, m_per_s: 20.0}
divergences: 0
"""


def _run(tmp_path: Path, policies: str, limits: str = LIMITS, out: str = "report") -> int:
    (tmp_path / "arm.xml").write_text(ARM)
    (tmp_path / "spec.yaml").write_text(SPEC.format(policies=policies))
    (tmp_path / "limits.yaml").write_text(limits)
    return cli.main(
        [
            "evaluate",
            "--config",
            str(tmp_path / "spec.yaml"),
            "--safety",
            str(tmp_path / "limits.yaml"),
            "--out",
            str(tmp_path / out),
            "--backend",
            "serial",
            "--quiet",
        ]
    )


# ------------------------------------------------------------------------------------------------ hand computations


def test_joint_limit_and_effort_against_hand_values() -> None:
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint name="s" type="slide" range="-0.1 0.1"/><geom size=".05" mass="1"/>'
        '</body></worldbody><actuator><motor joint="s" ctrlrange="-1 1" gear="2"/>'
        '<motor joint="s" ctrlrange="-1 1" forcerange="-0.4 0.4"/></actuator></mujoco>'
    )
    assert actuator_limits(model).tolist() == [1.0, 0.4]  # max|ctrlrange| * gain, then forcerange
    data = mujoco.MjData(model)
    meter = SafetyMeter(model, SafetyLimits(), num_envs=2)
    data.qpos[0], data.ctrl[:] = 0.05, [0.5, 1.0]  # inside the range; the second motor is clamped at 0.4
    mujoco.mj_forward(model, data)
    meter.observe(0, model, data)
    data.qpos[0] = 0.12  # beyond the upper limit: a hit
    mujoco.mj_forward(model, data)
    meter.observe(0, model, data)
    meter.observe(1, model, data)
    first, second = meter.episode(0, diverged=False), meter.episode(1, diverged=True)
    assert first["joint_limit_hits"] == 1.0 and second["joint_limit_hits"] == 1.0
    assert first["effort_ratio"] == pytest.approx(1.0)  # 0.4 / 0.4 (the clamped one), above 0.5 / 1
    assert np.isnan(first["contact_force"]) and np.isnan(first["ee_speed"])  # not declared: not measured
    assert (first["diverged"], second["diverged"]) == (0.0, 1.0)


def test_contact_force_of_a_resting_box_is_its_weight() -> None:
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom name="floor" type="plane" size="1 1 .1"/>'
        '<body name="box" pos="0 0 .1"><freejoint/><geom name="box_geom" type="box" size=".05 .05 .05" mass="2"/>'
        "</body></worldbody></mujoco>"
    )
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, 1500)  # settled: four corner contacts carry m g between them
    meter = SafetyMeter(model, SafetyLimits(contact_geoms=("box*",), max_contact_force=100.0), 1)
    meter.observe(0, model, data)
    assert data.ncon == 4
    assert meter.episode(0, diverged=False)["contact_force"] == pytest.approx(2.0 * 9.81, rel=1e-3)
    floor = SafetyMeter(model, SafetyLimits(contact_geoms=("floor",)), 1)  # the reaction on the other side
    floor.observe(0, model, data)
    assert floor.episode(0, diverged=False)["contact_force"] == pytest.approx(2.0 * 9.81, rel=1e-3)


def test_end_effector_speed_is_radius_times_rate() -> None:
    model = mujoco.MjModel.from_xml_string(ARM)
    data = mujoco.MjData(model)
    data.qvel[:] = [2.0, 0.0]  # the whole arm turns at 2 rad/s about the base: the tip (0.55 m out) moves 1.1 m/s
    mujoco.mj_forward(model, data)
    meter = SafetyMeter(model, SafetyLimits(ee_site="grip"), 1)
    meter.observe(0, model, data)
    assert meter.episode(0, diverged=False)["ee_speed"] == pytest.approx(1.1, rel=1e-9)
    body = SafetyMeter(model, SafetyLimits(ee_body="fore"), 1)  # a body's speed at its centre of mass: 0.425 m out
    body.observe(0, model, data)
    assert body.episode(0, diverged=False)["ee_speed"] == pytest.approx(0.85, rel=1e-9)


def test_observe_batch_is_observe_world_by_world(monkeypatch: pytest.MonkeyPatch) -> None:
    """``observe_batch`` on a stand-in batch against ``observe`` world by world, bitwise: random states within and
    beyond the joint ranges (a margin makes MuJoCo's limit constraint active inside the range too, so the
    constraint rows are looked through), random subsets of the worlds observed at each step while the others'
    states keep changing (they must not count), blocks of 4 steps, a reset and episodes read inside a block."""
    import sim2real.safety_probe as probe

    monkeypatch.setattr(probe, "_BLOCK", 4)
    model = mujoco.MjModel.from_xml_string(ARM)
    model.jnt_margin[:] = 0.1
    n = 5
    datas = [mujoco.MjData(model) for _ in range(n)]
    speeds = (("shoulder", 2.0), ("elbow", 3.0))  # the joint speed ratio too (tests/test_safety_joint_speed.py)
    for limits in (SafetyLimits(ee_site="grip", joint_speeds=speeds), SafetyLimits(ee_body="fore")):
        batched, single, batch = SafetyMeter(model, limits, n), SafetyMeter(model, limits, n), StandInBatch(datas)
        batched.bind_batch(batch)
        rng = np.random.default_rng(0)
        for step in range(31):
            if step == 10:  # a new episode: what was observed since the last fold does not count
                batched.reset()
                single.reset()
            worlds = np.flatnonzero(rng.random(n) < 0.6)
            for i, d in enumerate(datas):
                unseen = i not in worlds  # beyond both limits, faster, pushing harder: it would show if counted
                d.qpos[:] = rng.uniform(-0.7, 0.7, model.nq) * (1.5 if unseen else 1.0)
                d.qvel[:] = rng.normal(0.0, 10.0 if unseen else 3.0, model.nv)
                d.ctrl[:] = rng.uniform(-1.0, 1.0, model.nu) * (3.0 if unseen else 1.0)
                mujoco.mj_forward(model, d)
            batch.load()
            for i in worlds.tolist():
                single.observe(i, model, datas[i])
            batched.observe_batch(None if len(worlds) == n else worlds, [model] * n, lambda i: datas[i])
        got, want = batched.episodes(np.zeros(n, bool)), single.episodes(np.zeros(n, bool))
        for quantity in want:
            assert np.array_equal(got[quantity], want[quantity], equal_nan=True), quantity
        assert (want["joint_limit_hits"] > 0).all() and (want["ee_speed"] > 0).all()


def test_episode_counts_match_stepping_the_env_by_hand(tmp_path: Path) -> None:
    (tmp_path / "arm.xml").write_text(ARM)
    slam = ConstantAction([1.0, 1.0])
    conditions = [nominal(), *sweep({"type": "Damping", "scale": 1.0}, "scale", [0.5, 4.0])]
    limits = load_limits({"joint_limit_hits": 0, "max_ee_speed": {"site": "grip"}})
    result = evaluate(
        {"slam": slam}, f"model:{tmp_path / 'arm.xml'}", conditions, episodes=2, seed=0, max_steps=40, safety=limits
    )
    measured = result.safety["slam"]["sim"]
    # By hand: the same env, reset with the same seed, stepped 40 times; count the steps over the range.
    from sim2real.evaluation import episode_seed

    env = MjcfEnv(tmp_path / "arm.xml")
    hits, peak = [], []
    for e in range(2):
        env.reset(seed=episode_seed(0, e))
        count, fastest = 0, 0.0
        for _ in range(40):
            env.step(np.array([1.0, 1.0]))
            q = env.data.qpos
            count += int(
                np.any(np.abs(q) > 0.5) or np.any(env.data.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT)
            )
            velocity = np.zeros(6)
            mujoco.mj_objectVelocity(env.model, env.data, mujoco.mjtObj.mjOBJ_SITE, 0, velocity, 0)
            fastest = max(fastest, float(np.linalg.norm(velocity[3:])))
        hits.append(count)
        peak.append(fastest)
    assert measured["joint_limit_hits"].tolist() == hits and min(hits) > 10  # slammed into its limits
    assert measured["ee_speed"].tolist() == pytest.approx(peak, rel=1e-12)
    assert measured["effort_ratio"].tolist() == [1.0, 1.0]  # full command: both motors at their limit
    assert measured["diverged"].tolist() == [0.0, 0.0]
    table = SafetyTable.build(result, limits)
    rows = {(r.condition, r.quantity): r for r in table.rows}
    sweep_row = rows[("Damping.scale", "joint_limit_hits")]
    assert sweep_row.kind == "sweep" and sweep_row.episodes == 6
    # An MJCF env reports info["diverged"] = False on every step; the wrapped (swept) env must not end there.
    assert result.lengths["slam"]["Damping.scale=4"].tolist() == [40, 40]
    points = [result.safety["slam"][f"Damping.scale={x}"]["joint_limit_hits"] for x in ("0.5", "1", "4")]
    assert sweep_row.worst == max(float(p.max()) for p in points)
    assert {v.condition for v in table.violations} == {"sim", "Damping.scale=0.5", "Damping.scale=1", "Damping.scale=4"}
    assert rows[("sim", "ee_speed")].limit is None and not rows[("sim", "ee_speed")].violated  # measured, not gated


def test_cvar_is_the_mean_of_the_worst_tail() -> None:
    values = np.array([0.0, 1.0, 2.0, 3.0, 10.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 20.0])
    assert cvar_upper(values, 0.1) == pytest.approx(15.0)  # ceil(1.2) = 2 worst: 20 and 10
    assert cvar_upper(values, 1.0) == pytest.approx(values.mean())


def test_batched_engine_measures_the_same_as_per_env() -> None:
    speeds = {"joints": "*", "limit": 2.0}  # every joint's speed ratio too
    limits = load_limits(
        {"max_ee_speed": {"site": "ee", "m_per_s": 1.0}, "max_effort_ratio": 0.5, "max_joint_speed": speeds}
    )
    from sim2real.agents import ReachController

    conditions = [nominal(), *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [1.0, 2.0])]
    runs = [
        evaluate(
            {"reach": ReachController(kp=5.0)},
            "sim2real/arm-reach",
            conditions,
            episodes=2,
            seed=3,
            max_steps=25,
            safety=limits,
            engine=engine,
        )
        for engine in ("auto", "per-env")
    ]
    assert set(runs[0].engines.values()) == {"batched"} and set(runs[1].engines.values()) == {"per-env"}
    for cond in ("sim", "ActuatorGain.scale=2"):
        for quantity, values in runs[0].safety["reach"][cond].items():
            assert np.array_equal(values, runs[1].safety["reach"][cond][quantity], equal_nan=True), (cond, quantity)
    assert runs[0].to_json() == runs[1].to_json()
    plain = evaluate(
        {"reach": ReachController(kp=5.0)}, "sim2real/arm-reach", conditions, episodes=2, seed=3, max_steps=25
    )
    assert not plain.safety and "safety" not in plain.to_dict()  # without limits nothing is measured
    assert plain.returns["reach"]["sim"].tolist() == runs[0].returns["reach"]["sim"].tolist()


def test_batched_meter_reads_the_batch_like_the_single_env_on_the_study_arm() -> None:
    """The study's envelope on reacher: an end-effector *body* (``xipos``), the wrist's limit constraint (the
    ``efc_type`` look-up copies a world out of the batch) and the effort ratio, batched and per env bitwise."""
    from sim2real.agents import ReacherPD

    limits = load_limits(Path(__file__).parents[1] / "sim2real/data/study/dmc-reacher-easy/safety.yaml")
    conditions = [nominal(), *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [1.0, 1.5])]
    runs = [
        evaluate(
            {"pd": ReacherPD()},
            "dmc/reacher-easy",
            conditions,
            episodes=3,
            seed=1,
            max_steps=300,
            safety=limits,
            engine=engine,
        )
        for engine in ("auto", "per-env")
    ]
    assert set(runs[0].engines.values()) == {"batched"} and set(runs[1].engines.values()) == {"per-env"}
    assert runs[0].to_json() == runs[1].to_json()
    measured = runs[0].safety["pd"]["ActuatorGain.scale=1.5"]
    assert measured["joint_limit_hits"].max() > 0 and (measured["ee_speed"] > 0).all()
    assert measured["effort_ratio"].max() == pytest.approx(1.5)


def test_batched_meter_folds_blocks_of_steps_as_step_by_step(monkeypatch: pytest.MonkeyPatch) -> None:
    """``observe_batch`` folds its steps into the peaks and counts a block at a time: with blocks of 3 steps,
    episodes that end inside a block and worlds observed on only some steps of a block (the ones still running),
    the end-effector site's speed, the effort ratio and the reacher's wrist-limit hits are bitwise what the single
    envs give step by step."""
    import sim2real.safety_probe as probe
    from sim2real.agents import ReachController, ReacherPD

    monkeypatch.setattr(probe, "_BLOCK", 3)
    speeds = {"base_yaw": 3.0, "elbow_pitch": 2.0, "wrist_roll": 4.0}  # the joint speed ratio and its joint too
    limits = load_limits(
        {"max_ee_speed": {"site": "ee", "m_per_s": 1.0}, "max_effort_ratio": 0.5, "max_joint_speed": speeds}
    )
    conditions = [nominal(), *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [1.0, 2.0])]
    runs = [
        evaluate({"reach": ReachController(kp=20.0)}, "sim2real/arm-reach", conditions, episodes=6, seed=3,
                 max_steps=200, safety=limits, engine=engine)
        for engine in ("auto", "per-env")
    ]  # fmt: skip
    lengths = runs[0].lengths["reach"]["sim"]
    assert len(set((lengths % 3).tolist())) > 1 and lengths.min() < lengths.max()  # ends inside blocks, apart
    assert runs[0].to_json() == runs[1].to_json()
    study = load_limits(Path(__file__).parents[1] / "sim2real/data/study/dmc-reacher-easy/safety.yaml")
    conditions = [nominal(), *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [1.0, 1.5])]
    runs = [
        evaluate({"pd": ReacherPD()}, "dmc/reacher-easy", conditions, episodes=3, seed=1, max_steps=100,
                 safety=study, engine=engine)
        for engine in ("auto", "per-env")
    ]  # fmt: skip
    assert runs[0].safety["pd"]["ActuatorGain.scale=1.5"]["joint_limit_hits"].max() > 0
    assert runs[0].to_json() == runs[1].to_json()


# ------------------------------------------------------------------------------------------------ the command line


def test_a_policy_slamming_into_a_limit_exits_3(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = _run(tmp_path, "  gentle: {constant: [0.0, 0.0]}\n  slam: {constant: [1.0, 1.0]}")
    captured = capsys.readouterr()
    assert code == 3, captured.err
    lines = captured.err.strip().splitlines()
    assert lines and all(line.startswith("sim2real evaluate: safety: policy 'slam' on 'sim': ") for line in lines)
    assert any("joint_limit_hits worst" in line and "> limit 0 (episode" in line for line in lines)
    assert "Traceback" not in captured.err
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    safety = report["safety"]
    assert safety["passed"] is False and len(safety["violations"]) == len(lines)
    hits = {r["policy"]: r for r in safety["rows"] if r["quantity"] == "joint_limit_hits"}
    assert hits["gentle"]["worst"] == 0 and not hits["gentle"]["violated"]
    assert hits["slam"]["worst"] > 10 and hits["slam"]["violated"] and hits["slam"]["limit"] == 0
    markdown = (tmp_path / "report" / "report.md").read_text()
    assert "## Safety" in markdown and "VIOLATED (limit 0)" in markdown
    # the arm steps 10 physics steps per control step (its timestep 0.002 s, control period 0.02 s)
    assert "Sampled once per control step, every 10 physics steps: a peak inside the substeps is not seen." in markdown
    assert "<h2 id='safety'>Safety</h2>" in (tmp_path / "report" / "report.html").read_text()


def test_a_gentle_policy_passes_with_exit_0(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = _run(tmp_path, "  gentle: {constant: [0.0, 0.0]}")
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert f"safety: every policy within {tmp_path / 'limits.yaml'} on every condition" in captured.out
    # ... and how weak a pass on few episodes is (the line said nothing of it before).
    assert "(at 95%, up to " in captured.out and "% of episodes may still cross a limit: " in captured.out
    safety = json.loads((tmp_path / "report" / "report.json").read_text())["safety"]
    assert safety["passed"] is True and safety["violations"] == []
    assert "Every policy stays within the declared envelope" in (tmp_path / "report" / "report.md").read_text()


@pytest.mark.parametrize(
    ("limits", "message"),
    [
        ("joint_limit_hits: -1\n", "`joint_limit_hits` must be an int >= 0. Received -1."),
        (
            "max_contact_force: {geoms: 'finger*', newtons: 0}\n",
            "`max_contact_force.newtons` must be a number > 0. Received 0.",
        ),
        (
            "max_ee_sped: 1\n",
            "keys must be among ['joint_limit_hits', 'max_effort_ratio', 'max_contact_force', "
            "'max_ee_speed', 'max_joint_speed', 'divergences', 'statistic', 'alpha']. Received unknown "
            "['max_ee_sped'].",
        ),
        ("max_ee_speed: {site: grip, body: fore}\n", "`max_ee_speed` must name exactly one `site` or `body` (a name)."),
        ("statistic: mean\n", "`statistic` must be one of ['worst', 'cvar']. Received 'mean'."),
        (
            "max_ee_speed: {site: gripper, m_per_s: 1}\n",
            "`max_ee_speed.site` pattern 'gripper' matches no site in the model. Close matches: 'grip'.",
        ),
        (
            "max_contact_force: {geoms: 'fingr*', newtons: 5}\n",
            "`max_contact_force.geoms` pattern 'fingr*' matches no geom in the model.",
        ),
    ],
)
def test_bad_limits_exit_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], limits: str, message: str
) -> None:
    assert _run(tmp_path, "  gentle: {constant: [0.0, 0.0]}", limits=limits) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(f"sim2real evaluate: error: --safety: {tmp_path / 'limits.yaml'}: ")
    assert message in err
    assert not (tmp_path / "report").exists()  # nothing was written


def test_a_missing_limits_file_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "arm.xml").write_text(ARM)
    (tmp_path / "spec.yaml").write_text(SPEC.format(policies="  gentle: {constant: [0.0, 0.0]}"))
    code = cli.main(
        [
            "evaluate",
            "--config",
            str(tmp_path / "spec.yaml"),
            "--safety",
            str(tmp_path / "nope.yaml"),
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert code == 2
    assert (
        capsys.readouterr().err
        == f"sim2real evaluate: error: --safety: file {str(tmp_path / 'nope.yaml')!r} does not exist.\n"
    )


def test_limits_object_errors_name_the_argument() -> None:
    with pytest.raises(LimitsError, match=r"`max_contact_force.geoms` must name the geoms the limit is on."):
        SafetyLimits(max_contact_force=5.0)
    with pytest.raises(LimitsError, match=r"`alpha` must be a number in \(0, 1\]. Received 0."):
        load_limits({"alpha": 0})
    with pytest.raises(ValueError, match=r"`action` must be a finite number or a non-empty list of them."):
        ConstantAction([])


def test_composer_task_contacts_measured_alike_on_both_engines() -> None:
    """dm-control's manipulator recompiles its physics every episode: both engines read the live MjData."""
    limits = load_limits(
        {
            "max_contact_force": {"geoms": ["finger*", "thumb*"], "newtons": 5.0},
            "joint_limit_hits": 0,
            "max_ee_speed": {"site": "grasp"},
        }
    )
    push = ConstantAction([1.0] * 5)
    runs = [
        evaluate(
            {"push": push},
            "dmc/manipulator-bring_ball",
            [nominal()],
            episodes=2,
            seed=0,
            max_steps=40,
            safety=limits,
            engine=engine,
        )
        for engine in ("auto", "per-env")
    ]
    assert runs[0].engines == {"sim": "batched"} and runs[1].engines == {"sim": "per-env"}
    assert runs[0].to_json() == runs[1].to_json()
    measured = runs[0].safety["push"]["sim"]
    assert (measured["contact_force"] > 5.0).all() and (measured["joint_limit_hits"] > 0).all()  # it slams
    table = SafetyTable.build(runs[0], limits)
    assert {v.quantity for v in table.violations} == {"contact_force", "joint_limit_hits"}


def test_process_backend_gives_the_same_measurements(tmp_path: Path) -> None:
    (tmp_path / "arm.xml").write_text(ARM)
    limits = load_limits({"joint_limit_hits": 0, "max_ee_speed": {"site": "grip"}})
    runs = [
        evaluate(
            {"slam": ConstantAction([1.0, -1.0])},
            f"model:{tmp_path / 'arm.xml'}",
            [nominal()],
            episodes=3,
            batch=2,
            seed=1,
            max_steps=20,
            safety=limits,
            backend=backend,
            workers=2,
        )
        for backend in ("serial", "local")
    ]
    assert runs[0].to_json() == runs[1].to_json() and "safety" in runs[0].to_dict()


def _evaluation_with(values: dict[str, np.ndarray]) -> Evaluation:
    conditions = (nominal(), *sweep({"type": "Damping", "scale": 1.0}, "scale", [0.5, 2.0]))
    n = len(next(iter(values.values())))
    nan = np.full(n, np.nan)

    def quantities(hits: np.ndarray) -> dict[str, np.ndarray]:
        return {"joint_limit_hits": hits, "effort_ratio": nan, "contact_force": nan, "ee_speed": nan,
                "diverged": np.zeros(n)}  # fmt: skip

    return Evaluation(
        task="demo",
        seed=0,
        episodes=n,
        max_steps=None,
        policies=("p",),
        conditions=conditions,
        returns={"p": {c.name: np.zeros(n) for c in conditions}},
        successes={},
        lengths={},
        draws={},
        safety={"p": {name: quantities(v) for name, v in values.items()}},
    )


def test_cvar_gate_and_sweep_rows_name_the_worst_point() -> None:
    ten = np.zeros(10)
    spiky = ten.copy()
    spiky[7] = 5.0  # one bad episode of ten: worst 5, CVaR 0.1 = 5, CVaR 0.3 = 5/3
    evaluation = _evaluation_with(
        {"sim": ten, "Damping.scale=0.5": ten, "Damping.scale=1": ten, "Damping.scale=2": spiky}
    )
    worst = SafetyTable.build(evaluation, load_limits({"joint_limit_hits": 2}))
    assert [v.message for v in worst.violations] == [
        "policy 'p' on 'Damping.scale=2': joint_limit_hits worst 5 > limit 2 (episode 7; 1 of 10 episodes over 2, "
        "95% interval of the rate 1.79%-40.4%)"
    ]
    row = next(r for r in worst.rows if r.kind == "sweep")
    assert (row.condition, row.worst, row.episodes, row.where) == (
        "Damping.scale",
        5.0,
        30,
        "Damping.scale=2 episode 7",
    )
    assert row.cvar == pytest.approx(5.0 / 3.0) and row.violated  # the worst 3 of 30 pooled episodes
    assert row.point == "Damping.scale=2"
    # The verdict carries the rate of episodes over the limit with its Wilson interval (1 of 30 pooled).
    assert (row.over, round(row.over_rate.low, 4), round(row.over_rate.high, 4)) == (1, 0.0059, 0.1667)
    assert row.verdict == "VIOLATED: 1 of 30 episodes over 2, 95% interval of the rate 0.591%-16.7%"
    from sim2real.report.safety import safety_blocks

    table_rows = safety_blocks(worst)[2]["rows"]
    # The table cell carries the same evidence (it showed only the worst / CVaR and the VIOLATED mark before).
    cell = "5 / 1.667 at Damping.scale=2 VIOLATED (limit 2); 1 of 30 episodes over, 95% 0.591%-16.7%"
    assert ("p", "Damping.scale (sweep)", cell, "0 / 30") in table_rows
    within = dict(((r[0], r[1]), r[2]) for r in table_rows)[("p", "sim")]
    assert within == "0 / 0; 0 of 10 episodes over, 95% 0%-27.8%"
    lenient = SafetyTable.build(evaluation, load_limits({"joint_limit_hits": 2, "statistic": "cvar", "alpha": 0.3}))
    assert lenient.passed  # CVaR 0.3 of the point: 5/3 <= 2
    strict = SafetyTable.build(evaluation, load_limits({"joint_limit_hits": 1, "statistic": "cvar", "alpha": 0.3}))
    assert [v.message for v in strict.violations] == [
        "policy 'p' on 'Damping.scale=2': joint_limit_hits CVaR 0.3 1.667 > limit 1 (episode 7; 1 of 10 episodes "
        "over 1, 95% interval of the rate 1.79%-40.4%)"
    ]
    assert not any(r.quantity == "effort_ratio" for r in worst.rows)  # not measured: no row


def test_an_env_without_mujoco_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "spec.yaml").write_text(
        "env: gymnasium.envs.classic_control.cartpole:CartPoleEnv\nepisodes: 2\npolicies: {hold: {constant: [0]}}\n"
    )
    (tmp_path / "limits.yaml").write_text(LIMITS)
    code = cli.main(
        [
            "evaluate",
            "--config",
            str(tmp_path / "spec.yaml"),
            "--safety",
            str(tmp_path / "limits.yaml"),
            "--out",
            str(tmp_path / "o"),
            "--backend",
            "serial",
            "--quiet",
        ]
    )
    assert code == 2
    assert capsys.readouterr().err == (
        f"sim2real evaluate: error: --safety: {tmp_path / 'limits.yaml'}: the limits need a MuJoCo model inside the "
        "env; found none in CartPoleEnv.\n"
    )
    assert not (tmp_path / "o").exists()


def test_contact_forces_are_solved_for_the_state_not_read_from_a_stale_solve() -> None:
    """After dm-control's legacy step (mj_step2, then mj_step1) the contacts are the new state's while efc_force is
    the previous solve's; a row that did not exist then held whatever the arena had (1.4e146 N once in CI). The
    meter solves the forces of the state it is given, in a copy, and leaves the env's data alone."""
    from sim2real.safety import SafetyLimits
    from sim2real.safety_probe import SafetyMeter

    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom name="floor" type="plane" size="1 1 .1"/>'
        '<body name="box" pos="0 0 .2"><freejoint/><geom name="box" type="box" size=".05 .05 .05" mass="2"/></body>'
        "</worldbody></mujoco>"
    )
    data = mujoco.MjData(model)
    for _ in range(400):  # falls and comes to rest on the floor: weight 2 kg x 9.81
        mujoco.mj_step(model, data)
    assert data.ncon > 0
    limits = SafetyLimits(contact_geoms=("box",), max_contact_force=100.0)
    honest = SafetyMeter(model, limits, num_envs=1)
    honest.observe(0, model, data)
    weight = honest.episode(0, diverged=False)["contact_force"]
    assert weight == pytest.approx(2 * 9.81, rel=0.02)
    data.efc_force[:] = 1.4e146  # a stale or garbage solve
    before = data.efc_force.copy()
    poisoned = SafetyMeter(model, limits, num_envs=1)
    poisoned.observe(0, model, data)
    assert poisoned.episode(0, diverged=False)["contact_force"] == weight
    assert np.array_equal(data.efc_force, before)  # the env's own data untouched
