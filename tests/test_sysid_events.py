"""Contact events (issue #17): rows where a contact touches what the parameters move are left out of the fit."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sysid import fit, record_log
from sysid.events import CONTACT_MARGIN_ROWS, contact_rows, split_ranges
from sysid.params import ModelPool, ParameterSpace

# A hinge arm swinging over a floor (its tip touches the floor past ~0.5 rad) and a ball resting on the floor
# beside it, on its own slide joint: the ball is always in contact, the arm only at the bottom of its swing.
XML = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 .1"/>
    <body name="arm" pos="0 0 0.35">
      <joint name="hinge" axis="0 1 0" damping="0.2"/>
      <geom name="link" type="capsule" size=".03" fromto="0 0 0 0.4 0 0" mass="1"/>
    </body>
    <body name="ball" pos="1 0 0.05">
      <joint name="slide" type="slide" axis="1 0 0"/>
      <geom name="ball" type="sphere" size=".05" mass=".2"/>
    </body>
  </worldbody>
  <actuator><motor name="m" joint="hinge" gear="1"/></actuator>
</mujoco>
"""


def _log(seed: int = 0) -> tuple[mujoco.MjModel, object, np.ndarray]:
    model = mujoco.MjModel.from_xml_string(XML)
    t = np.arange(200) * 0.02
    ctrl = (3.0 * np.sin(2 * np.pi * 0.7 * t) + 0.5 * np.sin(2 * np.pi * 2.3 * t))[:, None]
    log = record_log(
        model, ctrl, n_substeps=10, noise_std={"qpos": 1e-4, "qvel": 1e-3}, rng=np.random.default_rng(seed)
    )
    # Which rows have the arm on the floor, from the true (noise-free) simulation.
    data = mujoco.MjData(model)
    touching = np.zeros(200, dtype=bool)
    link = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "link")
    for row in range(200):
        data.qpos[:] = log.qpos[row]
        mujoco.mj_fwdPosition(model, data)
        touching[row] = any(link in (data.contact[i].geom1, data.contact[i].geom2) for i in range(data.ncon))
    return model, log, touching


def test_rows_with_the_arm_on_the_floor_are_flagged_and_the_ball_on_the_floor_is_not() -> None:
    model, log, touching = _log()
    assert 5 < touching.sum() < 100  # the excitation does swing the arm into the floor, part of the time
    space = ParameterSpace(model, ["dof_damping[hinge]"])
    flagged = contact_rows(log, model, space, ModelPool(model, space), space.nominal)
    # Every arm contact is flagged, with the margin around it, and nothing else: the ball touches the floor in
    # every row but its tree is not moved by the arm's damping.
    dilated = np.convolve(touching.astype(float), np.ones(2 * CONTACT_MARGIN_ROWS + 1), mode="same") > 0
    np.testing.assert_array_equal(flagged, dilated)
    # A parameter that acts through contacts (the floor's friction) needs the contact rows: nothing is cut.
    friction = ParameterSpace(model, ["dof_damping[hinge]", "geom_friction[ball][0]"])
    assert not contact_rows(log, model, friction, ModelPool(model, friction), friction.nominal).any()


def test_split_ranges_cuts_around_events_and_keeps_a_log_mostly_in_contact() -> None:
    flagged = np.zeros(100, dtype=bool)
    flagged[[30, 31, 32, 60]] = True
    assert split_ranges([(3, 80, 0, 100), (80, 100, 0, 100)], flagged) == [
        (3, 30, 0, 100),
        (33, 60, 0, 100),
        (61, 80, 0, 100),
        (80, 100, 0, 100),
    ]
    flagged[70:75] = True  # leaves 70..74 out; the 4-row piece 66..69 is too short to keep
    flagged[65] = True
    assert (61, 65, 0, 100) not in split_ranges([(3, 100, 0, 100)], flagged)
    assert split_ranges([(3, 100, 0, 100)], np.arange(100) % 3 == 0) == [(3, 100, 0, 100)]  # < half would remain


def test_fit_leaves_contact_rows_out_and_reports_them() -> None:
    _model, log, touching = _log(1)
    guess = mujoco.MjModel.from_xml_string(XML.replace('damping="0.2"', 'damping="0.3"'))
    cut = fit(log, guess, ["dof_damping[hinge]"], global_search=False, progress=False)
    assert cut.quality.contact_rows >= touching.sum()
    assert cut.quality.to_dict()["contact_rows"] == cut.quality.contact_rows
    kept = fit(log, guess, ["dof_damping[hinge]"], global_search=False, progress=False, contacts="keep")
    assert kept.quality.contact_rows == 0
    lo, hi = cut.ci95[0]
    assert lo <= 0.2 <= hi
    assert cut.n_residuals < kept.n_residuals
    with pytest.raises(ValueError, match=r"`contacts` must be 'cut' or 'keep'. Received 'drop'"):
        fit(log, guess, ["dof_damping[hinge]"], contacts="drop")  # type: ignore[arg-type]


def test_a_body_the_parameters_do_not_move_is_neither_measured_nor_fitted() -> None:
    _model, log, _ = _log(2)
    known = {"qpos[slide]": 1e-4, "qvel[slide]": 1e-3}  # the ball's noise may still be given
    cut = fit(log, XML, ["dof_damping[hinge]"], global_search=False, progress=False, noise_std=known)
    assert cut.channels == ("qpos[hinge]", "qvel[hinge]")
    lo, hi = cut.ci95[0]
    assert lo <= 0.2 <= hi
    kept = fit(log, XML, ["dof_damping[hinge]"], global_search=False, progress=False, contacts="keep")
    assert kept.channels == ("qpos[hinge]", "qpos[slide]", "qvel[hinge]", "qvel[slide]")
    with pytest.raises(ValueError, match=r"`noise_std` keys must be channel names \[.*\]. Received unknown \['x'\]"):
        fit(log, XML, ["dof_damping[hinge]"], noise_std={"x": 1.0}, progress=False)
