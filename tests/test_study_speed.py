"""The study's evaluation at the engine's speed (issues 14/15): what the cuts rely on, pinned bitwise.

* ``evaluate`` steps a job's batched conditions two at a time in lockstep, one policy call acting for both; the
  results are those of each condition run on its own (``_LOCKSTEP = 1``) and of the per-env engine, safety included.
* The twin's target run continues the pilot (``run_target(..., pilot=)``: only the new episodes run, in the batches of
  a run from episode 0) and equals the run from 0.
* ``SafetyMeter.observe_batch`` screens the end-effector speed in numpy; the screen's margin covers MuJoCo's own
  ``mj_objectVelocity`` on states far from rest.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

import sim2real.evaluation as evaluation
from sim2real.evaluation import evaluate, nominal, randomized, sweep
from sim2real.safety import load_limits

STUDY = Path(__file__).parents[1] / "sim2real/data/study/dmc-reacher-easy"
TASK = "dmc/reacher-easy"


def _limits():
    return load_limits(STUDY / "safety.yaml")


def _conditions():
    import sim2real as s2r

    noisy = randomized(
        [s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), s2r.ObservationNoise(s2r.Gaussian(std=0.005)),
         s2r.ActionLatency(steps=s2r.Choice([0, 1]))]
    )  # fmt: skip
    return [nominal(), noisy, *sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.75, 1.5])]


def test_lockstep_conditions_give_the_results_of_each_condition_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two SAC checkpoints (merged forwards) and the scripted baseline on four conditions, 4 episodes of 60 steps,
    with the study's safety envelope: lockstep (2 conditions a call), one condition at a time, and per env agree to
    the bit."""
    from sim2real.agents import baseline_for

    policies = {"nominal": str(STUDY / "checkpoints/nominal.pt"), "adr": str(STUDY / "checkpoints/adr.pt"),
                "scripted": baseline_for(TASK)}  # fmt: skip
    kwargs = {"episodes": 4, "seed": 3, "max_steps": 60, "safety": _limits()}
    lockstep = evaluate(policies, TASK, _conditions(), **kwargs)
    assert set(lockstep.engines.values()) == {"batched"}
    monkeypatch.setattr(evaluation, "_LOCKSTEP", 1)
    alone = evaluate(policies, TASK, _conditions(), **kwargs)
    per_env = evaluate(policies, TASK, _conditions(), engine="per-env", **kwargs)
    assert lockstep.to_json() == alone.to_json() == per_env.to_json()
    assert lockstep.safety["nominal"]["ActuatorGain.scale=1.5"]["ee_speed"].min() > 0


def test_a_policy_whose_rows_depend_on_the_batch_is_not_merged() -> None:
    """The probe catches a policy whose action for a row depends on the other rows (here: on the batch mean)."""

    def coupled(obs: np.ndarray) -> np.ndarray:
        return np.tile(obs.mean(axis=0)[:2], (len(obs), 1)).astype(np.float32)

    def rowwise(obs: np.ndarray) -> np.ndarray:
        return np.tanh(obs[:, :2]).astype(np.float32)

    assert not evaluation._rows_alike(coupled, 4, 2, 6)
    assert evaluation._rows_alike(rowwise, 4, 2, 6)


def test_target_run_continues_the_pilot_bitwise() -> None:
    """``run_target`` with the pilot runs only episodes 4..11 (a lone condition: two runs of 4 side by side) and
    equals the run of episodes 0..11 (runs 0-3 and 4-7 side by side, then 8-11 alone), safety and draws included;
    the pilot's episodes are kept."""
    from sim2real.spec import load_spec
    from sim2real.study.precision import extend, run_target

    spec = load_spec(
        {"task": TASK, "seed": 5, "episodes": 4, "batch": 4, "max_steps": 40,
         "policies": {"scripted": "baseline", "nominal": {"checkpoint": str(STUDY / "checkpoints/nominal.pt")}},
         "real": {"config": {"signals": [{"type": "ObservationNoise", "processes": [{"type": "Gaussian", "std": 0.01}]},
                                         {"type": "ActionLatency", "steps": 2}]},
                  "params": {"dof_damping[shoulder]": 0.03}}}
    )  # fmt: skip
    limits = _limits()
    pilot = spec.run(safety=limits)
    continued = run_target(spec, "real", 12, pilot=pilot, safety=limits)
    from_zero = run_target(spec, "real", 12, safety=limits)
    assert continued.episodes == from_zero.episodes == 12
    assert continued.to_json() == from_zero.to_json()
    assert continued.env_steps == from_zero.env_steps == 2 * 12 * 40
    merged = extend(pilot, continued, "real")
    assert np.array_equal(merged.returns["nominal"]["real"][:4], pilot.returns["nominal"]["real"])
    # a second round continues the first (the study's re-planned target stage): only episodes 12..19 run
    again = run_target(spec, "real", 20, pilot=continued, safety=limits)
    assert again.to_json() == run_target(spec, "real", 20, safety=limits).to_json()
    assert again.env_steps == 2 * 20 * 40
    assert np.array_equal(extend(pilot, again, "real").returns["scripted"]["real"][:12],
                          merged.returns["scripted"]["real"])  # fmt: skip


def test_start_must_be_an_int_at_least_0() -> None:
    with pytest.raises(ValueError, match=r"`start` must be an int >= 0\. Received -1\."):
        evaluate({"s": lambda o: o[:2]}, TASK, [nominal()], episodes=1, start=-1)


def test_speed_screen_margin_covers_mujoco_on_fast_states() -> None:
    """The screen's numpy transform of the body velocity to its centre of mass stays within the margin of
    ``mj_objectVelocity``'s speed on 2000 random states of reacher (velocities up to 50 rad/s)."""
    from dm_control import suite

    model = suite.load("reacher", "easy").physics.model.ptr
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "finger")
    root = int(model.body_rootid[body])
    out = np.zeros(6)
    worst = 0.0
    for _ in range(2000):
        data.qpos[:] = rng.uniform(-math.pi, math.pi, model.nq)
        data.qvel[:] = rng.uniform(-50, 50, model.nv)
        mujoco.mj_forward(model, data)
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, body, out, 0)
        exact = math.hypot(out[3], out[4], out[5])
        ang, lin = data.cvel[body, :3], data.cvel[body, 3:]
        dif = data.xipos[body] - data.subtree_com[root]
        screened = float(np.linalg.norm(lin - np.cross(dif, ang)))
        scale = np.abs(lin).sum() + np.abs(dif).sum() * np.abs(ang).sum()
        worst = max(worst, abs(screened - exact) / scale)
    assert worst < 1e-12
