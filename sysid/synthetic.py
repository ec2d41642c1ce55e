"""Generated serial arms and realistic excitation logs: test beds that nobody tuned the fit on.

:func:`generate_arm` writes the MJCF of a 6- or 7-DoF serial arm (no meshes: capsules and boxes with realistic
masses of 0.5–4 kg, so inertias follow from the shapes), with gravity, joint limits, friction loss, reflected
rotor inertia (armature), a ``home`` keyframe and torque motors or position servos (``kp``, ``kv``).
:func:`excitation_log` runs the experiment an engineer would run on it: gravity-compensated multisine torques
around the home pose (a joint-space PD keeps the arm near home, computed from the *measured* state, as on a real
controller) or multisine servo set-points around home, a few seconds at 50 Hz, with a noisy logged initial state
and measurement noise (1e-3 rad, 1e-2 rad/s by default). The commands are logged as sent, so the log can be
replayed open loop by :func:`sysid.fit`.

Example:
    >>> import mujoco
    >>> from sysid.synthetic import generate_arm, excitation_log
    >>> xml = generate_arm(dof=7, seed=3)
    >>> model = mujoco.MjModel.from_xml_string(xml)
    >>> model.nq, model.nu, model.nkey
    (7, 7, 1)
    >>> bool(all(0.5 <= m <= 4.0 for m in model.body_mass[1:]))
    True
    >>> log = excitation_log(model, duration=2.0, seed=0)
    >>> log.qpos.shape, round(log.control_timestep, 3)
    ((100, 7), 0.02)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Literal

import mujoco
import numpy as np

from sysid.logs import TrajectoryLog, channel_names

__all__ = ["ACTUATORS", "excitation_log", "generate_arm", "gripper_arm", "home_pose"]

#: Actuator kinds :func:`generate_arm` can build.
ACTUATORS: tuple[str, ...] = ("motor", "position")

# Joint axes of a typical anthropomorphic arm: base yaw, shoulder pitch, elbow pitch, wrist roll/pitch/roll...
_AXES = {
    6: ("0 0 1", "0 1 0", "0 1 0", "1 0 0", "0 1 0", "1 0 0"),
    7: ("0 0 1", "0 1 0", "1 0 0", "0 1 0", "1 0 0", "0 1 0", "1 0 0"),
}
_NAMES = {
    6: ("base_yaw", "shoulder", "elbow", "wrist_roll", "wrist_pitch", "flange"),
    7: ("base_yaw", "shoulder", "upper_roll", "elbow", "forearm_roll", "wrist_pitch", "flange"),
}


def _check(name: str, value: object, ok: bool, allowed: str) -> None:
    if not ok:
        raise ValueError(f"`{name}` must be {allowed}. Received {value!r}.")


def generate_arm(
    dof: int = 7,
    seed: int = 0,
    actuators: Literal["motor", "position"] = "motor",
    gravity: bool = True,
    frictionloss: float | None = None,
    joint_limits: bool = True,
) -> str:
    """MJCF text of a random but realistic serial arm.

    Links get masses 0.5–4 kg (heavier near the base), lengths 0.08–0.4 m, capsule or box geometry (MuJoCo
    computes the inertias from the shapes), joint damping 0.3–3 N·m·s/rad, armature 0.02–0.3 kg·m² and torque
    limits sized to hold the arm against gravity with margin. The ``home`` keyframe bends the shoulder and elbow
    so gravity loads them. Every draw comes from ``numpy.random.default_rng(seed)``.

    Args:
        dof: 6 or 7 hinge joints.
        seed: the arm's seed (same seed, same text).
        actuators: ``"motor"`` (torque, ``gear`` 1, ``ctrlrange`` = torque limit) or ``"position"`` (servos with
            ``kp`` and ``kv``, ``ctrlrange`` = the joint range).
        gravity: ``False`` sets ``gravity="0 0 0"``.
        frictionloss: dry friction of every joint in N·m; ``None`` draws 0.05–0.5 per joint, 0 disables it.
        joint_limits: hinge ranges (limited) around home, or unlimited joints.

    Returns:
        The MJCF text (``mujoco.MjModel.from_xml_string`` loads it).

    Raises:
        ValueError: a bad argument (the message names it, the allowed values and what was received).

    Example:
        >>> import mujoco
        >>> m = mujoco.MjModel.from_xml_string(generate_arm(dof=6, seed=1, actuators="position"))
        >>> m.nv, int(m.actuator_biastype[0]) == int(mujoco.mjtBias.mjBIAS_AFFINE)
        (6, True)
        >>> generate_arm(dof=6, seed=1) == generate_arm(dof=6, seed=1)
        True
    """
    _check("dof", dof, isinstance(dof, int) and not isinstance(dof, bool) and dof in (6, 7), "6 or 7")
    _check("seed", seed, isinstance(seed, (int, np.integer)) and not isinstance(seed, bool), "an int")
    _check("actuators", actuators, actuators in ACTUATORS, f"one of {list(ACTUATORS)}")
    _check("gravity", gravity, isinstance(gravity, bool), "True or False")
    _check("joint_limits", joint_limits, isinstance(joint_limits, bool), "True or False")
    _check(
        "frictionloss",
        frictionloss,
        frictionloss is None
        or (isinstance(frictionloss, (int, float)) and not isinstance(frictionloss, bool) and 0 <= frictionloss < 50),
        "None or a number of N·m in [0, 50)",
    )
    rng = np.random.default_rng(int(seed))
    names, axes = _NAMES[dof], _AXES[dof]
    masses = np.sort(rng.uniform(0.5, 4.0, dof))[::-1]
    lengths = rng.uniform(0.08, 0.4, dof)
    lengths[1] = rng.uniform(0.3, 0.4)  # upper arm and forearm are the long links
    lengths[3 if dof == 7 else 2] = rng.uniform(0.25, 0.38)
    radii = rng.uniform(0.03, 0.06, dof)
    damping = rng.uniform(0.3, 3.0, dof)
    armature = np.sort(rng.uniform(0.02, 0.3, dof))[::-1]
    fric = rng.uniform(0.05, 0.5, dof) if frictionloss is None else np.full(dof, float(frictionloss))
    home = _home(dof, rng)
    # Torque limit: the static moment of everything downstream at full reach, times a margin.
    reach = np.cumsum(lengths[::-1])[::-1]
    limits = np.array([2.5 * 9.81 * float(np.sum(masses[i:])) * float(reach[i]) + 5.0 for i in range(dof)])
    limits = np.round(limits, 1)
    lines = [
        '<mujoco model="generated_arm">',
        '  <compiler angle="radian" autolimits="true"/>',
        f'  <option timestep="0.002" gravity="{"0 0 -9.81" if gravity else "0 0 0"}"/>',
        "  <worldbody>",
        '    <geom name="floor" type="plane" size="2 2 0.1" contype="0" conaffinity="0"/>',
    ]
    indent = "    "
    pos = "0 0 0.1"
    for i in range(dof):
        lo, hi = home[i] - rng.uniform(1.6, 2.6), home[i] + rng.uniform(1.6, 2.6)
        limit = f' range="{lo:.4f} {hi:.4f}"' if joint_limits else ' limited="false"'
        lines.append(f'{indent}<body name="link{i + 1}" pos="{pos}">')
        lines.append(
            f'{indent}  <joint name="{names[i]}" axis="{axes[i]}"{limit} damping="{damping[i]:.4f}" '
            f'armature="{armature[i]:.4f}" frictionloss="{fric[i]:.4f}"/>'
        )
        length = float(lengths[i])
        end = f"0 0 {length:.4f}"
        if i % 3 == 2:
            lines.append(
                f'{indent}  <geom type="box" pos="0 0 {length / 2:.4f}" size="{radii[i]:.4f} {radii[i]:.4f} '
                f'{length / 2:.4f}" mass="{masses[i]:.4f}" contype="0" conaffinity="0"/>'
            )
        else:
            lines.append(
                f'{indent}  <geom type="capsule" fromto="0 0 0 {end}" size="{radii[i]:.4f}" mass="{masses[i]:.4f}" '
                'contype="0" conaffinity="0"/>'
            )
        pos = f"0 0 {length:.4f}"
        indent += "  "
    for _ in range(dof):
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines += ["  </worldbody>", "  <actuator>"]
    for i in range(dof):
        if actuators == "motor":
            lines.append(
                f'    <motor name="{names[i]}" joint="{names[i]}" gear="1" ctrlrange="{-limits[i]} {limits[i]}"/>'
            )
        else:
            kp = round(float(limits[i]) * rng.uniform(4.0, 8.0), 1)
            kv = round(2.0 * 0.7 * math.sqrt(kp * (armature[i] + 0.5 * masses[i] * lengths[i] ** 2)), 2)
            ctrl = f' ctrlrange="{home[i] - 2.6:.4f} {home[i] + 2.6:.4f}"' if joint_limits else ""
            lines.append(f'    <position name="{names[i]}" joint="{names[i]}" kp="{kp}" kv="{kv}"{ctrl}/>')
    lines.append("  </actuator>")
    qpos = " ".join(f"{v:.4f}" for v in home)
    ctrl_home = " ".join(f"{v:.4f}" for v in (home if actuators == "position" else np.zeros(dof)))
    lines += ["  <keyframe>", f'    <key name="home" qpos="{qpos}" ctrl="{ctrl_home}"/>', "  </keyframe>", "</mujoco>"]
    return "\n".join(lines) + "\n"


def _home(dof: int, rng: np.random.Generator) -> np.ndarray:
    home = rng.uniform(-0.4, 0.4, dof)
    shoulder = 1
    elbow = 3 if dof == 7 else 2
    home[shoulder] = rng.uniform(0.5, 1.0)  # upper arm tilted forward: gravity loads shoulder and elbow
    home[elbow] = rng.uniform(0.8, 1.4)
    return home


def home_pose(model: mujoco.MjModel) -> np.ndarray:
    """The ``home`` keyframe's qpos (the first keyframe when none is called ``home``; ``qpos0`` without any).

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string(generate_arm(dof=6, seed=0))
        >>> bool(np.allclose(home_pose(model), model.key_qpos[0]))
        True
    """
    if model.nkey == 0:
        return model.qpos0.copy()
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    return model.key_qpos[max(key, 0)].copy()


def _multisine(rng: np.random.Generator, t: np.ndarray, channels: int, band: tuple[float, float]) -> np.ndarray:
    """Sum of 4 random sines per channel in ``band`` Hz, scaled to peak 1."""
    out = np.zeros((t.size, channels))
    for c in range(channels):
        freqs = rng.uniform(*band, 4)
        phases = rng.uniform(0, 2 * np.pi, 4)
        out[:, c] = np.sum(np.sin(2 * np.pi * freqs[None] * t[:, None] + phases[None]), axis=1) / 4.0
    return out


def excitation_log(
    model: mujoco.MjModel | str,
    *,
    duration: float = 8.0,
    control_timestep: float = 0.02,
    seed: int = 0,
    amplitude: float = 0.3,
    noise_std: Mapping[str, float] | None = None,
    initial_std: Sequence[float] = (0.02, 0.05),
    true_params: Mapping[str, float] | None = None,
) -> TrajectoryLog:
    """Runs a realistic identification experiment on ``model`` (the truth) and returns its log.

    Torque-driven arms (motors): ``u = g(q̃) + Kp (q_home - q̃) - Kd q̃̇ + a(t)`` where ``q̃`` is the measured
    (noisy) state, ``g`` MuJoCo's gravity torque, the PD gains are soft (a few Hz) and ``a(t)`` is a multisine
    (peak ``amplitude`` × half the torque limit, 0.2–3 Hz); position servos get set-points
    ``q_home + amplitude · multisine(t)`` (peak ``amplitude`` rad); an arm that mixes them drives each actuator as
    its kind. Commands are clipped to ``ctrlrange`` and logged as sent. The arm
    starts near home (true state drawn with ``initial_std`` = (rad, rad/s) around it); every logged row,
    the first included, carries Gaussian measurement noise.

    Args:
        model: the true model (``MjModel`` or MJCF text); not modified.
        duration: seconds of log (> 0).
        control_timestep: seconds per control step; a whole number of physics steps.
        seed: seed of the excitation, the initial state and the noise.
        amplitude: excitation size (see above; > 0).
        noise_std: ``{"qpos": rad, "qvel": rad/s}``; default 1e-3 and 1e-2.
        initial_std: SDs of the true initial position and velocity around home.
        true_params: stored in ``meta["true_params"]``.

    Returns:
        A validated :class:`~sysid.logs.TrajectoryLog` at the control rate.

    Raises:
        ValueError: a bad argument (named, with the allowed values and what was received).

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string(generate_arm(dof=6, seed=2, actuators="position"))
        >>> log = excitation_log(model, duration=1.0, seed=1)
        >>> bool(np.max(np.abs(log.qpos - home_pose(model))) < 1.0)
        True
    """
    if isinstance(model, str):
        model = mujoco.MjModel.from_xml_string(model)
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"`model` must be a mujoco.MjModel or MJCF text. Received {type(model).__name__}.")
    dt = float(model.opt.timestep)
    n_sub = round(control_timestep / dt) if control_timestep > 0 else 0
    _check(
        "control_timestep",
        control_timestep,
        n_sub >= 1 and abs(n_sub * dt - control_timestep) <= 1e-9 * max(1.0, control_timestep),
        f"a positive whole number of physics steps ({dt} s)",
    )
    _check(
        "duration",
        duration,
        isinstance(duration, (int, float)) and duration >= 2 * control_timestep,
        "a number of seconds >= 2 control steps",
    )
    _check("amplitude", amplitude, isinstance(amplitude, (int, float)) and amplitude > 0, "a number > 0")
    sigma = {"qpos": 1e-3, "qvel": 1e-2, **dict(noise_std or {})}
    rng = np.random.default_rng(int(seed))
    steps = round(duration / control_timestep)
    t = np.arange(steps) * control_timestep
    home = home_pose(model)
    nu = model.nu
    # Per actuator: a position servo takes a set-point, a motor a torque (an arm may mix them; each was once
    # driven as the kind all of them were, so a mixed arm's servos got gravity torques as set-points).
    servo = model.actuator_biastype[:nu] == mujoco.mjtBias.mjBIAS_AFFINE
    joint_of = model.actuator_trnid[:nu, 0]
    dof_of = model.jnt_dofadr[joint_of]
    qpos_of = model.jnt_qposadr[joint_of]
    lo, hi = model.actuator_ctrlrange[:nu].T
    limited = model.actuator_ctrllimited[:nu].astype(bool)
    wave = _multisine(rng, t, nu, (0.2, 3.0))
    setpoint = home[qpos_of][None] + amplitude * wave
    torque = np.where(limited, np.maximum(np.abs(lo), np.abs(hi)), 20.0)
    reference = np.where(servo[None], setpoint, 0.5 * amplitude * torque[None] * wave)
    # Soft PD on the motors (full torque at 1 rad error, about critically damped on the joint's own inertia).
    kp = torque
    kd = 2 * 0.7 * np.sqrt(kp * (model.dof_armature[dof_of] + 0.1))
    data = mujoco.MjData(model)
    probe = mujoco.MjData(model)
    data.qpos[:] = home + rng.normal(0.0, initial_std[0], model.nq)
    data.qvel[:] = rng.normal(0.0, initial_std[1], model.nv)
    mujoco.mj_forward(model, data)
    qpos = np.empty((steps, model.nq))
    qvel = np.empty((steps, model.nv))
    ctrl = np.empty((steps, nu))
    time = np.empty(steps)
    for k in range(steps):
        time[k] = data.time
        qpos[k] = data.qpos + rng.normal(0.0, sigma["qpos"], model.nq)
        qvel[k] = data.qvel + rng.normal(0.0, sigma["qvel"], model.nv)
        u = reference[k].copy()
        if not servo.all():
            probe.qpos[:] = qpos[k]
            probe.qvel[:] = 0.0
            mujoco.mj_forward(model, probe)
            gravity = probe.qfrc_bias[dof_of]
            pd = gravity + kp * (home[qpos_of] - qpos[k, qpos_of]) - kd * qvel[k, dof_of] + reference[k]
            u = np.where(servo, u, pd)
        u = np.where(limited, np.clip(u, lo, hi), u)
        ctrl[k] = u
        data.ctrl[:] = u
        for _ in range(n_sub):
            mujoco.mj_step(model, data)
    names = channel_names(model)
    meta = {
        "task": "generated_arm",
        "timestep": dt,
        "control_timestep": dt * n_sub,
        "joint_names": [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}" for j in range(model.njnt)],
        "actuator_names": [n[5:-1] for n in names["ctrl"]],
        "sensor_names": names["sensordata"],
        "true_latency_seconds": {"action": 0.0, "obs": 0.0},
        "noise_std": {"qpos": float(sigma["qpos"]), "qvel": float(sigma["qvel"]), "sensordata": 0.0},
    }
    if true_params is not None:
        meta["true_params"] = {str(k): float(v) for k, v in true_params.items()}
    return TrajectoryLog(time=time, qpos=qpos, qvel=qvel, ctrl=ctrl, meta=meta)


def gripper_arm() -> str:
    """The MJCF of a 7-DoF arm with stiff position servos and a two-finger gripper: slide fingers coupled by an
    equality and driven through a fixed tendon, wrist force/torque sensors, a ``home`` keyframe, its control rate
    declared (100 Hz). A start state a noise draw off the coupling is what the held-out check must survive
    (``sysid._problem.coupled_states``).

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string(gripper_arm())
        >>> model.nq, model.nu, model.neq, model.ntendon
        (9, 8, 1, 1)
    """
    return _GRIPPER_ARM


_GRIPPER_ARM = """<mujoco model="arm7_gripper">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.002" gravity="0 0 -9.81"/>
  <custom><numeric name="sim2real_control_timestep" data="0.01"/></custom>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="base" pos="0 0 0.1">
      <joint name="j1" axis="0 0 1" range="-2.8 2.8" damping="2.0" armature="0.1"/>
      <geom type="cylinder" size="0.06 0.05" mass="4"/>
      <body name="l2" pos="0 0 0.08">
        <joint name="j2" axis="0 1 0" range="-1.8 1.8" damping="3.0" armature="0.1"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.045" mass="3"/>
        <body name="l3" pos="0 0 0.3">
          <joint name="j3" axis="0 0 1" range="-2.8 2.8" damping="1.5" armature="0.05"/>
          <geom type="capsule" fromto="0 0 0 0 0 0.1" size="0.04" mass="1.5"/>
          <body name="l4" pos="0 0 0.1">
            <joint name="j4" axis="0 1 0" range="-2.5 0.2" damping="1.5" armature="0.05"/>
            <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.035" mass="1.5"/>
            <body name="l5" pos="0.25 0 0">
              <joint name="j5" axis="1 0 0" range="-2.8 2.8" damping="0.5" armature="0.02"/>
              <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.03" mass="0.8"/>
              <body name="l6" pos="0.1 0 0">
                <joint name="j6" axis="0 1 0" range="-1.6 1.6" damping="0.5" armature="0.02"/>
                <geom type="capsule" fromto="0 0 0 0.08 0 0" size="0.03" mass="0.6"/>
                <body name="l7" pos="0.08 0 0">
                  <joint name="j7" axis="1 0 0" range="-2.8 2.8" damping="0.2" armature="0.01"/>
                  <geom type="box" size="0.02 0.04 0.02" mass="0.3"/>
                  <site name="wrist" pos="0 0 0" size="0.01"/>
                  <body name="fl" pos="0.03 0.02 0">
                    <joint name="fl" type="slide" axis="0 1 0" range="0 0.04" damping="0.5" armature="0.01"/>
                    <geom type="box" size="0.02 0.005 0.01" mass="0.05"/>
                  </body>
                  <body name="fr" pos="0.03 -0.02 0">
                    <joint name="fr" type="slide" axis="0 -1 0" range="0 0.04" damping="0.5" armature="0.01"/>
                    <geom type="box" size="0.02 0.005 0.01" mass="0.05"/>
                  </body>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    <fixed name="grip" stiffness="5" damping="0.1"><joint joint="fl" coef="0.5"/><joint joint="fr" coef="0.5"/></fixed>
  </tendon>
  <equality><joint joint1="fl" joint2="fr"/></equality>
  <actuator>
    <general name="a1" joint="j1" gaintype="fixed" biastype="affine" gainprm="80" biasprm="0 -80 -6"
             ctrlrange="-2.8 2.8" forcerange="-60 60"/>
    <general name="a2" joint="j2" gaintype="fixed" biastype="affine" gainprm="150" biasprm="0 -150 -10"
             ctrlrange="-1.8 1.8" forcerange="-90 90"/>
    <general name="a3" joint="j3" gaintype="fixed" biastype="affine" gainprm="60" biasprm="0 -60 -4"
             ctrlrange="-2.8 2.8" forcerange="-40 40"/>
    <general name="a4" joint="j4" gaintype="fixed" biastype="affine" gainprm="60" biasprm="0 -60 -4"
             ctrlrange="-2.5 0.2" forcerange="-40 40"/>
    <general name="a5" joint="j5" gaintype="fixed" biastype="affine" gainprm="15" biasprm="0 -15 -1"
             ctrlrange="-2.8 2.8" forcerange="-10 10"/>
    <general name="a6" joint="j6" gaintype="fixed" biastype="affine" gainprm="15" biasprm="0 -15 -1"
             ctrlrange="-1.6 1.6" forcerange="-10 10"/>
    <general name="a7" joint="j7" gaintype="fixed" biastype="affine" gainprm="5" biasprm="0 -5 -0.3"
             ctrlrange="-2.8 2.8" forcerange="-3 3"/>
    <general name="grip" tendon="grip" gaintype="fixed" biastype="affine" gainprm="40" biasprm="0 -40 -2"
             ctrlrange="0 0.04" forcerange="-10 10"/>
  </actuator>
  <sensor>
    <jointpos name="q2" joint="j2"/>
    <jointvel name="dq4" joint="j4"/>
    <force name="wrist_f" site="wrist"/>
    <torque name="wrist_t" site="wrist"/>
    <tendonpos name="grip_pos" tendon="grip"/>
  </sensor>
  <keyframe>
    <key name="home" qpos="0 0.3 0 -1.2 0 0.5 0 0.02 0.02" ctrl="0 0.3 0 -1.2 0 0.5 0 0.02"/>
  </keyframe>
</mujoco>
"""
