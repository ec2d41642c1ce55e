"""Mass and BodyComOffset on massless bodies (mass 0 in the MJCF: only a site, or zero-density geoms)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from randomizers import BodyComOffset, Mass, PhysicsRandomizer, Uniform
from randomizers.parameters import ParameterSet

# A 2-link arm: "wrist" carries only a site (massless, its child has mass), "tip" only a zero-density geom
# (massless, welded to the hand), "marker" a site welded to the world.
XML = """
<mujoco>
  <worldbody>
    <body name="marker" pos="1 0 0"><site name="m"/></body>
    <body name="upper">
      <joint name="shoulder" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -.3" size=".03"/>
      <body name="wrist" pos="0 0 -.3">
        <joint name="elbow" axis="0 1 0"/>
        <site name="w"/>
        <body name="hand" pos="0 0 -.1">
          <geom type="box" size=".04 .04 .04"/>
          <body name="tip" pos="0 0 -.05"><geom type="sphere" size=".02" density="0"/></body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _model() -> mujoco.MjModel:
    model = mujoco.MjModel.from_xml_string(XML)
    assert [float(model.body(n).mass[0]) == 0 for n in ("marker", "wrist", "tip")] == [True, True, True]
    return model


def test_mass_set_on_a_massless_body_is_refused_naming_it_and_the_fix() -> None:
    model = _model()
    with pytest.raises(ValueError) as err:
        Mass(set=0.5, bodies="tip").bind(model)  # wrote body_mass 0.5 with inertia 0 before
    assert str(err.value) == (
        "`bodies` of Mass pattern 'tip' matches massless bodies only ('tip'): a body of mass 0 has no inertia for a "
        "new mass to go with, and a scaled 0 stays 0. Give them mass and inertia in the MJCF (an <inertial> element "
        "with mass and diaginertia, or geoms with a density) or leave them out of `bodies`. Received 'tip'."
    )
    for effect in (Mass(scale=2.0, bodies="wr*"), Mass(add=0.1, bodies=["hand", "marker"])):
        with pytest.raises(ValueError, match="matches massless bodies only"):
            effect.bind(model)
    assert float(model.body("tip").mass[0]) == 0.0  # nothing half-written


@pytest.mark.parametrize("effect", [Mass(set=Uniform(0.5, 1.0)), Mass(add=Uniform(0.1, 0.2)), Mass(scale=2.0)])
def test_a_pattern_leaves_massless_bodies_out_and_every_reported_mass_has_its_inertia(effect: Mass) -> None:
    model = _model()
    data = mujoco.MjData(model)
    randomizer = PhysicsRandomizer([effect], seed=0)
    randomizer.bind(model, data)
    randomizer.begin_episode()
    randomizer.apply()
    # Before: body_mass[marker/wrist/tip] were drawn and reported (set/add wrote a mass with no inertia).
    assert sorted(randomizer.current_params) == ["body_mass[hand]", "body_mass[upper]"]
    for name in ("marker", "wrist", "tip"):
        assert float(model.body(name).mass[0]) == 0.0 and not model.body(name).inertia.any()
    for name in ("upper", "hand"):
        assert float(model.body(name).mass[0]) == randomizer.current_params[f"body_mass[{name}]"]
        assert (model.body(name).inertia > 0).all()
    mujoco.mj_step(model, data)
    assert np.isfinite(data.qacc).all()


def test_com_offset_leaves_massless_bodies_out() -> None:
    model = _model()
    randomizer = PhysicsRandomizer([BodyComOffset(add=Uniform(-0.01, 0.01), axis="x")], seed=0)
    randomizer.bind(model, mujoco.MjData(model))
    randomizer.begin_episode()
    randomizer.apply()
    assert sorted(randomizer.current_params) == ["body_ipos[hand][0]", "body_ipos[upper][0]"]
    with pytest.raises(ValueError, match=r"pattern 'tip' matches massless bodies only \('tip'\): a body of mass 0 "):
        BodyComOffset(add=0.01, bodies="tip").bind(model)


def test_a_calibration_of_a_massless_bodys_mass_is_refused() -> None:
    model = _model()
    with pytest.raises(ValueError, match="matches massless bodies only"):
        ParameterSet(model, ["body_mass[tip]"])
    assert float(model.body("tip").mass[0]) == 0.0
