"""Fields ``mj_setConst`` writes: restored bitwise, and run-time edits the effects do not own survive.

Also the zero-mass validation of :class:`randomizers.Mass` (zero mass is singular)."""

from __future__ import annotations

import copy
import pickle
import re
import threading
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real as s2r
from randomizers import Armature, Interval, Mass, PhysicsRandomizer, Uniform, setconst
from randomizers.setconst import DERIVED_FROM, OUTPUTS

# A two-link arm whose hand is welded to a mocap target; the weld's relative pose is computed by
# mj_setConst (eq_data[11] == 1), as for an MJCF weld without `relpose`.
ARM_XML = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <light name="lamp" mode="targetbodycom" target="upper" pos="0 0 2"/>
    <camera name="follow" mode="trackcom" pos="0 -1 1"/>
    <body name="target" mocap="true" pos="0.3 0 0.2"/>
    <body name="upper" pos="0 0 0.2">
      <joint name="shoulder" axis="0 1 0" armature="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.02"/>
      <body name="hand" pos="0.15 0 0">
        <joint name="elbow" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.02"/>
      </body>
    </body>
  </worldbody>
  <equality><weld name="grip" body1="target" body2="hand"/></equality>
  <tendon><fixed name="t"><joint joint="elbow" coef="1"/></fixed></tendon>
  <actuator><motor joint="shoulder"/><motor tendon="t"/></actuator>
</mujoco>
"""
# What a mocap-driven env writes into the weld at run time: a grasp offset and a rotated grasp.
GRASP = np.array([0.02, -0.01, 0.03, 0.9238795325112867, 0.0, 0.3826834323650898, 0.0])


def _outputs(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    out = {f: getattr(model, f).copy() for f in OUTPUTS}
    for scalar in ("ngravcomp", "npolygonmax", "nmeshdegmax", "flg_gravcomp", "flg_surfacevel", "flg_adhesion"):
        out[scalar] = np.array(getattr(model, scalar))
    return out


def _assert_bitwise(got: dict[str, np.ndarray], want: dict[str, np.ndarray]) -> None:
    changed = sorted(f for f in want if got[f].tobytes() != want[f].tobytes())
    assert changed == []


def test_outputs_are_those_the_installed_mujoco_declares() -> None:
    header = Path(mujoco.__file__).parent / "include" / "mujoco" / "mjxmacro.h"
    if not header.exists():
        pytest.skip("this MuJoCo wheel ships no headers")
    table = header.read_text().split("#define MJSETCONST_ARRAYS", 1)[1].split("\n\n", 1)[0]
    rows = re.findall(r"X\(\s*(\w+),([^)]*)\)", table)
    written = {name for name, groups in rows if "OUT" in groups}
    assert written == set(OUTPUTS)
    assert set(DERIVED_FROM["body_mass"]) <= written


@pytest.mark.parametrize(
    "effect",
    [Mass(scale=Uniform(0.5, 2.0)), Armature(add=Uniform(0.0, 0.1))],
    ids=["mass", "armature"],
)
def test_a_draw_keeps_a_weld_pose_written_at_run_time(effect: Any) -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    data = mujoco.MjData(model)
    assert model.eq_data[0, 11] == 1.0  # mj_setConst recomputes this weld's relative pose
    r = PhysicsRandomizer([effect], seed=0)
    r.bind(model, data)
    model.eq_data[0, 3:10] = GRASP  # the env's reset, after bind
    runtime = model.eq_data.copy()
    r.begin_episode()
    r.apply()
    assert model.eq_data.tobytes() == runtime.tobytes()  # before: relpose back to the qpos0 pose
    r.restore_nominal()
    assert model.eq_data.tobytes() == runtime.tobytes()


def test_every_field_mj_setconst_writes_is_restored_bitwise() -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    model.eq_data[0, 3:10] = GRASP  # written by the env before the randomiser sees the model
    nominal = _outputs(model)
    r = PhysicsRandomizer([Mass(scale=Uniform(0.5, 2.0))], seed=3)
    r.bind(model, mujoco.MjData(model))
    r.begin_episode()
    r.apply()
    during = _outputs(model)
    moved = {f for f in nominal if during[f].tobytes() != nominal[f].tobytes()}
    assert moved == {
        "body_subtreemass",
        "body_invweight0",
        "dof_invweight0",
        "dof_M0",
        "tendon_invweight0",
        "actuator_acc0",
        "cam_poscom0",
        "light_poscom0",
    }
    # What the draw leaves is what mj_setConst computes from the drawn masses.
    twin = mujoco.MjModel.from_xml_string(ARM_XML)
    twin.body_mass[:] = model.body_mass
    twin.body_inertia[:] = model.body_inertia
    mujoco.mj_setConst(twin, mujoco.MjData(twin))
    for f in moved:
        np.testing.assert_array_equal(getattr(model, f), getattr(twin, f))
    r.begin_episode()
    r.apply()
    r.restore_nominal()
    _assert_bitwise(_outputs(model), nominal)


class WeldedArmEnv(gym.Env):
    """A mocap-driven arm as manipulation suites write it: the env writes the weld's grasp pose into
    ``eq_data`` (in every ``reset``, or once when built) and ``step`` moves the mocap target."""

    frame_skip = 5

    def __init__(self, write_at_reset: bool = True) -> None:
        self.model = mujoco.MjModel.from_xml_string(ARM_XML)
        self.data = mujoco.MjData(self.model)
        self.write_at_reset = write_at_reset
        if not write_at_reset:
            self.model.eq_data[0, 3:10] = GRASP
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (4,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float64)

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.data.qpos, self.data.qvel])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        if self.write_at_reset:
            self.model.eq_data[0, 3:10] = GRASP
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.data.mocap_pos[0] = np.array([0.3, 0.0, 0.2]) + 0.1 * np.asarray(action)
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        return self._obs(), 0.0, False, False, {}


def _rollout(env: gym.Env, actions: np.ndarray) -> np.ndarray:
    first, _ = env.reset(seed=0)
    return np.array([first] + [env.step(a)[0] for a in actions])


@pytest.mark.parametrize(
    ("write_at_reset", "schedule"),
    [(True, "reset"), (True, Interval(steps=7)), (False, "reset")],
    ids=["reset-writes-weld", "resampled-mid-episode", "built-with-weld"],
)
def test_mass_scale_one_on_a_welded_arm_is_bitwise_the_bare_env(write_at_reset: bool, schedule: Any) -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, (40, 3))
    bare = _rollout(WeldedArmEnv(write_at_reset), actions)
    env = s2r.wrap(WeldedArmEnv(write_at_reset), s2r.Mass(scale=1.0, schedule=schedule), seed=0)
    wrapped = _rollout(env, actions)
    assert wrapped.tobytes() == bare.tobytes()  # before: mj_setConst recomputed the grasp pose away
    assert _rollout(env, actions).tobytes() == bare.tobytes()  # and again on the next episode
    env.close()


# -- zero mass is singular -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"scale": 0.0},
            "`scale` of Mass must be > 0 over its whole support (body_mass of 0 is singular). "
            "Received Constant(value=0.0) with support [0.0, 0.0].",
        ),
        (
            {"scale": Uniform(0.0, 2.0)},
            "`scale` of Mass must be > 0 over its whole support (body_mass of 0 is singular). "
            "Received Uniform(low=0.0, high=2.0) with support [0.0, 2.0].",
        ),
        (
            {"set": Uniform(-1.0, 1.0)},
            "`set` of Mass must be > 0 over its whole support (body_mass of 0 is singular). "
            "Received Uniform(low=-1.0, high=1.0) with support [-1.0, 1.0].",
        ),
    ],
)
def test_mass_that_can_reach_zero_is_refused_at_construction(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError) as err:
        Mass(**kwargs)
    assert str(err.value) == message


def test_mass_add_that_can_reach_zero_is_refused_when_bound() -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    hand = float(model.body_mass[model.body("hand").id])
    effect = Mass(add=Uniform(-hand, 0.0), bodies="hand")
    with pytest.raises(ValueError) as err:
        effect.bind(model)
    assert str(err.value) == (
        f"`add` of Mass would make body_mass[hand] zero or negative (body_mass of 0 is singular): "
        f"nominal {hand!r} + lowest draw {-hand!r} <= 0. Received Uniform(low={-hand!r}, high=0.0)."
    )


def test_massless_bodies_and_zero_armature_stay_allowed() -> None:
    model = mujoco.MjModel.from_xml_string(ARM_XML)
    Mass(add=Uniform(0.0, 0.1)).bind(model)  # the mocap target has no mass: 0 + 0 is its nominal
    Armature(scale=0.0).bind(model)  # armature 0 is MuJoCo's default, not singular


# -- the scratch MjData shared by models of one layout ---------------------------------------------------

# ARM_XML without its mocap target and weld: a model whose scratch is shared (tendon, camera, light kept).
FREE_ARM_XML = ARM_XML.replace('<body name="target" mocap="true" pos="0.3 0 0.2"/>', "").replace(
    '<equality><weld name="grip" body1="target" body2="hand"/></equality>', ""
)


def _copies(k: int) -> list[mujoco.MjModel]:
    reacher = s2r.find_physics(s2r.make("dmc/reacher-easy", textures=False)).model  # type: ignore[union-attr]
    arm = mujoco.MjModel.from_xml_string(FREE_ARM_XML)
    reach = s2r.find_physics(s2r.make("sim2real/arm-reach")).model  # type: ignore[union-attr]
    return [copy.deepcopy(m) for m in (reacher, arm, reach) for _ in range(k)]


def _runs(models: list[mujoco.MjModel]) -> list[dict[str, np.ndarray]]:
    """Each model's outputs after SetConst runs on drawn masses and armatures, the models interleaved."""
    rng = np.random.default_rng(7)
    consts = [setconst.SetConst(m, {"body_mass", "dof_armature"}) for m in models]
    nominal = [(m.body_mass.copy(), m.dof_armature.copy()) for m in models]
    out = []
    for _ in range(2):
        for m, sc, (mass, armature) in zip(models, consts, nominal, strict=True):
            m.body_mass[:] = mass * rng.uniform(0.5, 2.0, mass.shape)
            m.dof_armature[:] = armature + rng.uniform(0.0, 0.1, armature.shape)
            sc.run()
            out.append(_outputs(m))
    for sc in consts:
        sc.restore()
    return out


def test_a_shared_scratch_gives_bitwise_what_a_scratch_of_its_own_gives(monkeypatch: pytest.MonkeyPatch) -> None:
    shared = _runs(_copies(3))
    monkeypatch.setattr(setconst, "_scratch_key", lambda model: None)  # every SetConst makes its own, as before
    own = _runs(_copies(3))
    assert len(shared) == len(own) == 18
    for got, want in zip(shared, own, strict=True):
        _assert_bitwise(got, want)


def test_the_scratch_is_shared_by_one_layout_per_thread_and_never_with_mocap() -> None:
    a, b, _ = _copies(1)
    a2 = copy.deepcopy(a)
    key = setconst._scratch_key(a)
    assert key is not None and key == setconst._scratch_key(a2) != setconst._scratch_key(b)
    assert setconst._shared_scratch(a, key) is setconst._shared_scratch(a2, key)
    others: list[Any] = []
    worker = threading.Thread(target=lambda: others.append(setconst._shared_scratch(a, key)))
    worker.start()
    worker.join()
    assert others[0] is not setconst._shared_scratch(a, key)  # mj_setConst runs without the GIL
    welded = mujoco.MjModel.from_xml_string(ARM_XML)  # a mocap body starts at its body_pos: its own scratch
    assert setconst._scratch_key(welded) is None
    assert isinstance(setconst.SetConst(welded, {"body_mass"})._scratch, mujoco.MjData)


@pytest.mark.parametrize("xml", [ARM_XML, FREE_ARM_XML], ids=["own-scratch", "shared-scratch"])
def test_a_copied_randomizer_keeps_what_its_own_model_holds(xml: str) -> None:
    # A pickled or deep-copied randomiser runs mj_setConst on its own copy of the model, and the outputs it keeps
    # are those of that copy (here a run-time edit of the camera pose, which mj_setConst would recompute).
    model = mujoco.MjModel.from_xml_string(xml)
    r = PhysicsRandomizer([Mass(scale=Uniform(0.5, 2.0))], seed=0)
    r.bind(model, mujoco.MjData(model))
    for twin in (pickle.loads(pickle.dumps(r)), copy.deepcopy(r)):
        own = twin.model
        assert own is not None and own is not model
        own.cam_pos0[0] += 0.25
        edited = own.cam_pos0.copy()
        twin.begin_episode()
        twin.apply()
        assert own.cam_pos0.tobytes() == edited.tobytes()
        twin.restore_nominal()
