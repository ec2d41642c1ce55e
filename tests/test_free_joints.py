"""Free and ball joints (a puck beside the arm, a ball-jointed wrist): every dof of them is named, addressed and
randomised, and a fit of a free body's parameter says it cannot be identified instead of crashing.

``model.jnt_type`` holds numpy ints, which never match mujoco's enum members as dict keys: three tables keyed by the
enum gave a free joint one dof (randomizers' dof effects, parameter addresses) and one qpos/qvel name (sysid's
channel names), so ``Damping`` reached one of a free joint's six dofs and a fit crashed with an IndexError.
"""

from __future__ import annotations

import mujoco
import numpy as np

import sim2real as s2r
import sysid
from randomizers.parameters import ParameterSet

MODEL = """<mujoco>
  <compiler angle="radian"/>
  <option timestep="0.005"/>
  <default><joint damping="0.1"/></default>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" axis="0 1 0" range="-1.5 1.5"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="1"/>
      <body name="hand" pos="0.2 0 0">
        <joint name="wrist" type="ball"/>
        <geom type="box" size="0.03 0.03 0.03" mass="0.3"/>
      </body>
    </body>
    <body name="puck" pos="0.5 0 0.1"><freejoint name="puck_free"/><geom size="0.03" mass="0.1"/></body>
  </worldbody>
  <actuator><position name="servo" joint="shoulder" kp="20" ctrlrange="-1.5 1.5"/></actuator>
</mujoco>
"""


def _model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(MODEL)


def test_channel_names_give_every_column_of_free_and_ball_joints_a_name() -> None:
    model = _model()
    names = sysid.channel_names(model)
    assert (len(names["qpos"]), len(names["qvel"])) == (model.nq, model.nv) == (12, 10)
    assert names["qpos"][1:6] == [f"qpos[wrist][{k}]" for k in range(4)] + ["qpos[puck_free][0]"]
    assert names["qvel"][-1] == "qvel[puck_free][5]"


def test_damping_reaches_every_dof_of_a_free_and_a_ball_joint_and_reports_each() -> None:
    model = _model()
    env = s2r.wrap(s2r.make("model:" + _write_model()), s2r.Damping(scale=2.0), seed=0)
    _, info = env.reset(seed=0)
    handle = s2r.find_physics(env)
    assert handle is not None
    held = handle.model
    np.testing.assert_array_equal(held.dof_damping, 2 * model.dof_damping)
    params = info["sim2real"]["params"]
    assert [k for k in params if "puck_free" in k] == [f"dof_damping[puck_free][{k}]" for k in range(6)]
    assert [k for k in params if "wrist" in k] == [f"dof_damping[wrist][{k}]" for k in range(3)]
    env.close()
    np.testing.assert_array_equal(held.dof_damping, model.dof_damping)
    space = ParameterSet(model, ["dof_damping[puck_free]"])
    assert list(space.addresses) == [f"dof_damping[puck_free][{k}]" for k in range(6)]


def _write_model() -> str:
    import tempfile
    from pathlib import Path

    path = Path(tempfile.mkdtemp()) / "free.xml"
    path.write_text(MODEL)
    return str(path)


def test_a_fit_of_a_free_bodys_parameter_reports_it_unidentifiable_instead_of_crashing() -> None:
    model = _model()
    ctrl = 0.3 * np.sin(0.2 * np.arange(40))[:, None]
    log = sysid.record_log(model, ctrl, n_substeps=4, noise_std=1e-3, rng=np.random.default_rng(0))
    fit = sysid.fit(log, model, ["body_mass[puck]", "dof_damping[shoulder]"], bounds=[(0.05, 0.5), (0.01, 1.0)],
                    progress=False, global_search=False)  # fmt: skip
    assert any(w.startswith("not identifiable") and "body_mass[puck]" in w for w in fit.warnings)
    assert len(fit.noise_std) == len(set(fit.noise_std))  # one distinct name per measured column
