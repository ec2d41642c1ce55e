"""Journey 2 through the command line: a 7-DoF arm with a tendon gripper, a foreign driver CSV, a user's own
gymnasium MujocoEnv. Each test pins what a user saw before a fix and sees now."""

from __future__ import annotations

import contextlib
import io
import logging
from pathlib import Path
from typing import Any

import pytest

import sysid
from sim2real.cli import main

ARM = """<mujoco model="two_link">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <custom><numeric name="sim2real_control_timestep" data="0.01"/></custom>
  <worldbody>
    <body name="upper" pos="0 0 0.5">
      <joint name="shoulder" axis="0 1 0" range="-1.5 1.5" damping="0.5" armature="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="1"/>
      <body name="fore" pos="0.2 0 0">
        <joint name="elbow" axis="0 1 0" range="-2 2" damping="0.2" armature="0.01"/>
        <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.02" mass="0.5"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="servo_shoulder" joint="shoulder" kp="30" kv="1" ctrlrange="-1.5 1.5"/>
    <position name="servo_elbow" joint="elbow" kp="10" kv="0.5" ctrlrange="-2 2"/>
  </actuator>
  <keyframe><key name="home" qpos="0.3 -0.5"/></keyframe>
</mujoco>
"""


def _run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture
def arm(tmp_path: Path) -> Path:
    path = tmp_path / "arm.xml"
    path.write_text(ARM)
    return path


def test_mujoco_instability_warnings_during_a_fit_are_counted_not_printed(
    tmp_path: Path, arm: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Before: every diverging rollout of the search printed "WARNING:absl:Nan, Inf or huge value in QACC ... The
    # simulation is unstable" (about 1900 lines for one fit of a 7-DoF arm's CSV in the wrong units) around the
    # one line that mattered. Now one note counts them.
    log = tmp_path / "log.npz"
    code, _, err = _run(
        ["record", "--model", str(arm), "--episodes", "1", "--steps", "40", "--quiet", "--out", str(log)]
    )
    assert code == 0, err
    real_fit = sysid.fit

    def fit(*args: Any, **kwargs: Any) -> Any:
        for _ in range(3):
            logging.getLogger("absl").warning("Nan, Inf or huge value in QACC at DOF 0. The simulation is unstable.")
        logging.getLogger("absl").warning("something else")
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(sysid, "fit", fit)
    seen: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: seen.append(record.getMessage())  # type: ignore[method-assign]
    logging.getLogger().addHandler(handler)
    try:
        code, _, err = _run(
            ["sysid", "fit", str(log), "--model", str(arm), "--params", "dof_damping[*]", "--quiet",
             "--out", str(tmp_path / "fit.json")]
        )  # fmt: skip
    finally:
        logging.getLogger().removeHandler(handler)
    assert code == 0, err
    assert "MuJoCo reported an unstable simulation 3 time(s) during the search" in err
    assert seen == ["something else"]  # other warnings still pass
