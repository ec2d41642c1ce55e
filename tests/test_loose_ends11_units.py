"""Tendon parameters carry their unit in the gap report (loose end 1 of session 11).

Before: ``parameter_unit("tendon_damping[...]")`` was ``""`` whatever the tendon, so the report's System identification
table showed a fitted tendon parameter without a unit. Now the unit follows the tendon's length, read from the model
(:func:`sim2real.report.labels.tendon_units`): rad for a fixed tendon over hinges, m over slides and for a spatial
tendon, "mixed" said so for a fixed tendon over both.
"""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from sim2real.evaluation import Evaluation, nominal, real
from sim2real.report import GapReport
from sim2real.report.labels import axis_label, parameter_unit, tendon_units
from sysid.result import FitResult

# a hinge arm with a slide gripper: a fixed tendon over the two hinges, one over the two slides, one over both
# (named and unnamed), and a spatial cable through two sites
MJCF = """
<mujoco>
  <worldbody>
    <site name="anchor" pos="0 0 0.3"/>
    <body name="upper">
      <joint name="shoulder" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
      <body name="lower" pos="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
        <site name="tip" pos="0.3 0 0"/>
        <body name="left" pos="0.3 0.02 0">
          <joint name="left" type="slide" axis="0 1 0"/>
          <geom type="box" size="0.01 0.005 0.01"/>
        </body>
        <body name="right" pos="0.3 -0.02 0">
          <joint name="right" type="slide" axis="0 -1 0"/>
          <geom type="box" size="0.01 0.005 0.01"/>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    <fixed name="coupling" stiffness="2" damping="0.3"><joint joint="shoulder" coef="1"/><joint joint="elbow" coef="-1"/></fixed>
    <fixed name="grip" damping="0.5"><joint joint="left" coef="0.5"/><joint joint="right" coef="0.5"/></fixed>
    <spatial name="cable" stiffness="50"><site site="anchor"/><site site="tip"/></spatial>
    <fixed name="wrist_grip"><joint joint="elbow" coef="0.01"/><joint joint="left" coef="1"/></fixed>
    <fixed><joint joint="right" coef="1"/></fixed>
  </tendon>
</mujoco>
"""

FIELDS = ("tendon_stiffness", "tendon_damping", "tendon_frictionloss", "tendon_lengthspring", "tendon_armature")
MIXED = "mixed units (tendon over hinge and slide joints)"


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(MJCF)


def test_tendon_units_read_from_the_model(model: mujoco.MjModel) -> None:
    assert tendon_units(model) == (
        ("coupling", "rad"),
        ("grip", "m"),
        ("cable", "m"),
        ("wrist_grip", "mixed"),
        ("#4", "m"),  # unnamed: named as addresses name it
    )


def test_every_tendon_field_has_its_unit(model: mujoco.MjModel) -> None:
    units = tendon_units(model)
    got = {(f, t): parameter_unit(f"{f}[{t}]", tendons=units) for f in FIELDS for t in dict(units)}
    angular = ("N·m/rad", "N·m·s/rad", "N·m", "rad", "kg·m²")
    linear = ("N/m", "N·s/m", "N", "m", "kg")
    for field, rad, m in zip(FIELDS, angular, linear, strict=True):
        assert got[field, "coupling"] == rad
        assert got[field, "grip"] == got[field, "cable"] == got[field, "#4"] == m
        assert got[field, "wrist_grip"] == MIXED
    # a component of a raw field keeps its tendon's unit; a tendon the model does not have has none
    assert parameter_unit("tendon_lengthspring[cable][1]", tendons=units) == "m"
    assert parameter_unit("tendon_damping[nope]", tendons=units) == ""
    # without the model's tendons nothing is guessed (as before); a joint named like a tendon keeps its own unit
    assert parameter_unit("tendon_damping[grip]") == ""
    assert parameter_unit("dof_damping[grip]", tendons=units) == "N·m·s/rad"
    assert axis_label("TendonDamping.scale").text == "tendon damping (× nominal)"


def _fit(addresses: list[str]) -> FitResult:
    p = len(addresses)
    est = np.arange(1.0, p + 1.0)
    return FitResult(
        addresses=tuple(addresses),
        estimates=est,
        stderr=0.1 * est,
        ci95=np.stack([0.8 * est, 1.2 * est], axis=1),
        crlb_sd=0.1 * est,
        covariance=np.eye(p),
        correlation=np.eye(p),
        bounds=np.stack([0.0 * est, 10.0 * est], axis=1),
    )


def test_report_shows_tendon_units(model: mujoco.MjModel) -> None:
    sim = np.arange(20.0)
    evaluation = Evaluation(
        task="tendons",
        seed=0,
        episodes=20,
        max_steps=None,
        policies=("p",),
        conditions=(nominal(), real()),
        returns={"p": {"sim": sim, "real": sim - 1.0}},
        successes={},
        lengths={},
        draws={},
    )
    fit = _fit(
        ["tendon_damping[coupling]", "tendon_stiffness[cable]", "tendon_damping[grip]", "tendon_damping[wrist_grip]"]
    )
    report = GapReport.build(evaluation, fit=fit, rng=0, num_resamples=50, tendons=tendon_units(model))
    md = report.to_markdown()
    assert "| tendon\\_damping\\[coupling\\] | N·m·s/rad |" in md, md
    assert "| tendon\\_stiffness\\[cable\\] | N/m |" in md
    assert "| tendon\\_damping\\[grip\\] | N·s/m |" in md
    assert f"| tendon\\_damping\\[wrist\\_grip\\] | {MIXED} |" in md
    params = json.loads(report.to_json())["fit"]["params"]
    assert {a: v["unit"] for a, v in params.items()} == {
        "tendon_damping[coupling]": "N·m·s/rad",
        "tendon_stiffness[cable]": "N/m",
        "tendon_damping[grip]": "N·s/m",
        "tendon_damping[wrist_grip]": MIXED,
    }
    assert report.tendons == tendon_units(model)
    with pytest.raises(ValueError) as err:
        GapReport.build(evaluation, rng=0, num_resamples=50, tendons={"grip": "mm"})
    assert str(err.value) == (
        "`tendons` must map tendon names to the unit of their length, 'm', 'rad' or 'mixed' "
        "(sim2real.report.labels.tendon_units). Received {'grip': 'mm'}."
    )
