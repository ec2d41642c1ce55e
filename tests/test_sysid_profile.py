"""Profile-likelihood check of barely informed parameters (issue #17): a log that does not excite one joint."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from sysid import FitResult, fit, record_log
from sysid.profile import CHI2_95, ProfileCheck

# Two independent pendulums with a motor each; the log drives `a` hard and `b` with `amp` (0: not at all).
XML = """
<mujoco><option timestep="0.005"/><worldbody>
  <body name="A" pos="0 0 1"><joint name="a" axis="0 1 0" damping="0.3"/>
    <geom type="capsule" size=".04" fromto="0 0 0 0 0 -.3" mass="1"/></body>
  <body name="B" pos="1 0 1"><joint name="b" axis="0 1 0" damping="0.3"/>
    <geom type="capsule" size=".04" fromto="0 0 0 0 0 -.3" mass="1"/></body>
</worldbody><actuator><motor name="ma" joint="a"/><motor name="mb" joint="b"/></actuator></mujoco>"""
PARAMS = ["dof_damping[a]", "dof_damping[b]"]


def _fit(amp: float, **kwargs: object) -> FitResult:
    truth = mujoco.MjModel.from_xml_string(XML)
    t = np.arange(300) * 0.01
    ctrl = np.stack(
        [0.5 * np.sin(2 * np.pi * 0.8 * t) + 0.3 * np.sin(2 * np.pi * 2.1 * t), amp * np.sin(2 * np.pi * 1.3 * t)], 1
    )
    log = record_log(truth, ctrl, n_substeps=2, noise_std={"qpos": 1e-3, "qvel": 1e-2}, rng=np.random.default_rng(0))
    return fit(log, XML, PARAMS, progress=False, **kwargs)  # type: ignore[arg-type]


def test_a_joint_the_log_never_moves_has_an_open_profile_and_a_warning() -> None:
    result = _fit(0.0)
    (check,) = result.quality.profiles  # only b: a's curvature is sharp (SE 0.03% of the estimate)
    assert check.address == "dof_damping[b]"
    assert check.open_high and check.high == pytest.approx(3.0)  # the default search bound, nominal x 10
    assert check.describe().endswith(f"(Wald [{check.wald_low:.6g}, {check.wald_high:.6g}])")
    assert any(
        w.startswith("the data barely inform dof_damping[b]: dof_damping[b]: profile-likelihood 95% interval [")
        and w.endswith("3 (the search bound: not bounded by the data)] (Wald " + w.split("(Wald ")[1])
        for w in result.warnings
    )
    assert "profile: dof_damping[b]: profile-likelihood 95% interval" in result.summary()


def test_a_barely_excited_joint_gets_an_asymmetric_profile_interval_that_covers_the_truth(tmp_path: Path) -> None:
    result = _fit(3e-4)
    (check,) = result.quality.profiles
    assert not check.open
    assert check.low < 0.3 < check.high  # the truth
    # The cost is far from quadratic: a high damping barely changes the tiny response, so the profile reaches
    # well past the curvature (Wald) interval on that side.
    assert check.high > 2 * check.wald_high
    assert check.low > check.wald_low
    assert not any("barely inform" in w for w in result.warnings)
    result.to_json(tmp_path / "fit.json")
    assert FitResult.from_json(tmp_path / "fit.json").quality.profiles == (check,)
    assert not _fit(3e-4, profile=False).quality.profiles


def test_profile_check_round_trip_and_threshold() -> None:
    check = ProfileCheck("dof_damping[b]", 0.2, 0.1, 1.4, False, False, 0.02, 0.36)
    assert ProfileCheck.from_dict(check.to_dict()) == check and not check.open
    assert pytest.approx(3.841458820694124) == CHI2_95
