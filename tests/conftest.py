"""Shared fixtures: headless GL before mujoco loads, and a bitwise snapshot of a whole MjModel."""

from __future__ import annotations

import os
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np

import randomizers
import sim2real


def model_arrays(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Copies of every numeric array of ``model`` (and of ``model.opt``), for bitwise comparison."""
    out: dict[str, np.ndarray] = {}
    for owner, prefix in ((model, ""), (model.opt, "opt.")):
        for name in dir(owner):
            if name.startswith("_"):
                continue
            try:
                value = getattr(owner, name)
            except Exception:
                continue
            if isinstance(value, np.ndarray) and value.dtype.kind in "fiub":
                out[prefix + name] = value.copy()
    return out


def assert_same_model(before: dict[str, np.ndarray], model: mujoco.MjModel) -> None:
    """Every array of ``model`` equals the snapshot bitwise."""
    after = model_arrays(model)
    changed = [k for k in before if before[k].tobytes() != after[k].tobytes()]
    assert not changed, f"fields not restored bitwise: {changed}"


def assert_restored(before: dict[str, np.ndarray], model: mujoco.MjModel, twin: mujoco.MjModel) -> None:
    """``model`` equals ``before`` bitwise, except fields the env itself changed: those must equal
    the model of an unwrapped twin put through the same calls."""
    own = model_arrays(twin)
    expected = {k: (own[k] if own[k].tobytes() != v.tobytes() else v) for k, v in before.items()}
    assert_same_model(expected, model)


def reset_and_compare(batched: Any, singles: list[Any], seeds: list[int] | None) -> tuple[np.ndarray, dict[str, Any]]:
    """Resets batched worlds and their single envs with ``seeds`` and checks world ``i`` against env ``i``: the same
    first observation and bitwise the same reported draws. Returns the batched reset's (obs, params)."""
    obs, params = batched.reset(seed=seeds)
    for i, env in enumerate(singles):
        o, info = env.reset(seed=None if seeds is None else seeds[i])
        assert np.array_equal(o, obs[i])
        reported = info["sim2real"]["params"]
        assert sorted(reported) == sorted(params)
        for key, value in reported.items():
            assert params[key][i] == value, key  # bitwise, the same draw
    return obs, params


# A 3-joint arm with a slide joint, joint limits, a position servo next to motors, a free ball that it can hit
# and a touch sensor: nothing like the shipped tasks (tests/test_fused.py and tests/test_hot_path.py, whose digests
# were recorded with it: keep it byte for byte).
GENERATED_ARM = """
<mujoco model="generated">
  <option timestep="0.004" gravity="0 0 -9.81"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="base" pos="0 0 0.3">
      <joint name="lift" type="slide" axis="0 0 1" range="-0.2 0.2" damping="2"/>
      <geom name="base_geom" type="box" size="0.05 0.05 0.05" mass="1.5"/>
      <body name="upper" pos="0 0 0.05">
        <joint name="shoulder" type="hinge" axis="0 1 0" range="-1.5 1.5" damping="0.3"/>
        <geom name="upper_geom" type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="0.6"/>
        <body name="fore" pos="0.3 0 0">
          <joint name="elbow" type="hinge" axis="0 1 0" damping="0.2"/>
          <geom name="fore_geom" type="capsule" fromto="0 0 0 0.25 0 0" size="0.025" mass="0.4"/>
          <site name="tip" pos="0.25 0 0" size="0.02"/>
        </body>
      </body>
    </body>
    <body name="ball" pos="0.4 0 0.1">
      <freejoint/>
      <geom name="ball_geom" type="sphere" size="0.05" mass="0.2"/>
    </body>
  </worldbody>
  <actuator>
    <position name="lift_servo" joint="lift" kp="80" ctrlrange="-0.2 0.2"/>
    <motor name="shoulder_motor" joint="shoulder" gear="5" ctrlrange="-1 1" ctrllimited="true"/>
    <motor name="elbow_motor" joint="elbow" gear="3" ctrlrange="-1 1" ctrllimited="true"/>
  </actuator>
  <sensor>
    <touch name="tip_touch" site="tip"/>
    <framepos name="tip_pos" objtype="site" objname="tip"/>
  </sensor>
</mujoco>
"""

PHYSICS = (
    sim2real.Friction(scale=randomizers.Uniform(0.5, 1.5)),
    sim2real.Mass(scale=randomizers.Uniform(0.8, 1.2), bodies="*"),
    sim2real.Damping(scale=randomizers.Uniform(0.5, 2.0)),
    sim2real.ActuatorGain(scale=randomizers.Uniform(0.9, 1.1)),
)


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """``sim2real.cli.main(argv)`` in this process: its exit code, stdout and stderr."""
    import contextlib
    import io

    from sim2real.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


class StandInBatch:
    """A stand-in for ``mujoco.batch.Batch``: ``bind(name)`` gives an ``(N, ...)`` array that ``load`` fills from
    the worlds' ``MjData``."""

    def __init__(self, datas: list[mujoco.MjData]) -> None:
        self.datas, self.bound = datas, {}

    def bind(self, name: str) -> np.ndarray:
        self.bound[name] = np.array([np.asarray(getattr(d, name)) for d in self.datas])
        return self.bound[name]

    def load(self) -> None:
        for name, array in self.bound.items():
            for i, d in enumerate(self.datas):
                array[i] = getattr(d, name)
