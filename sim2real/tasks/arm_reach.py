"""Five-joint arm reaching task in MuJoCo, driven by end-effector delta commands.

The arm is described by an MJCF string embedded in this module, so the task needs no
asset files and no downloads. The policy commands small Cartesian displacements of the
end-effector; a damped-least-squares inverse-kinematics step turns them into targets
for the joint position actuators, which is how many real arms are commanded too.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

__all__ = ["ARM_REACH_XML", "JOINT_NAMES", "ArmReachEnv"]

#: Hinge joints from base to hand; each has a position actuator of the same name.
JOINT_NAMES: tuple[str, ...] = ("base_yaw", "shoulder_pitch", "elbow_pitch", "wrist_pitch", "wrist_roll")

# Links carry ``gravcomp="1"`` because industrial and research arms compensate gravity
# in their low-level controller; without it a position servo sags below its target, and
# since every step re-plans from the measured pose, the sag would accumulate into drift.
# Arm geoms use contype=1/conaffinity=0 and the floor contype=0/conaffinity=1, so the arm
# collides with the floor but never with itself, which keeps contact detection cheap.
ARM_REACH_XML = """
<mujoco model="arm_reach">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.002" integrator="implicitfast"/>

  <visual>
    <global offwidth="640" offheight="640"/>
    <quality shadowsize="2048"/>
  </visual>

  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.55 0.7 0.85" rgb2="0.1 0.12 0.15"
             width="256" height="256"/>
    <texture name="grid" type="2d" builtin="checker" width="256" height="256"
             rgb1="0.82 0.84 0.86" rgb2="0.62 0.65 0.68"/>
    <material name="grid" texture="grid" texrepeat="8 8" reflectance="0.05"/>
    <material name="link" rgba="0.85 0.55 0.15 1"/>
    <material name="joint" rgba="0.25 0.25 0.28 1"/>
  </asset>

  <default>
    <joint type="hinge" limited="true"/>
    <geom contype="1" conaffinity="0" friction="0.8 0.02 0.001" material="link"/>
    <site group="3"/>
  </default>

  <worldbody>
    <light name="key" pos="0.6 -0.6 2.5" dir="-0.2 0.2 -1" directional="true" castshadow="true"/>
    <light name="fill" pos="-1 1 2" dir="0.4 -0.4 -1" directional="true" castshadow="false"
           diffuse="0.3 0.3 0.3"/>
    <geom name="floor" type="plane" size="2 2 0.05" material="grid" contype="0" conaffinity="1"/>
    <camera name="overview" pos="1.1 -1.0 0.9" xyaxes="0.707 0.707 0 -0.276 0.276 0.921"/>
    <site name="target" type="sphere" size="0.03" pos="0.4 0 0.3" rgba="0.9 0.15 0.15 0.8" group="0"/>

    <body name="base" pos="0 0 0">
      <geom name="base_link" type="cylinder" size="0.08 0.05" pos="0 0 0.05" material="joint" mass="4"/>
      <body name="shoulder" pos="0 0 0.1" gravcomp="1">
        <joint name="base_yaw" axis="0 0 1" range="-3.1416 3.1416" damping="1.0" armature="0.1"/>
        <geom name="shoulder_link" type="capsule" fromto="0 0 0 0 0 0.1" size="0.045" material="joint"/>
        <body name="upper_arm" pos="0 0 0.12" gravcomp="1">
          <joint name="shoulder_pitch" axis="0 1 0" range="-2.0 2.0" damping="1.0" armature="0.1"/>
          <geom name="upper_arm_link" type="capsule" fromto="0 0 0 0 0 0.3" size="0.035"/>
          <body name="forearm" pos="0 0 0.3" gravcomp="1">
            <joint name="elbow_pitch" axis="0 1 0" range="-2.5 2.5" damping="0.8" armature="0.06"/>
            <geom name="elbow_link" type="cylinder" fromto="0 -0.04 0 0 0.04 0" size="0.04"
                  material="joint"/>
            <geom name="forearm_link" type="capsule" fromto="0 0 0 0 0 0.25" size="0.03"/>
            <body name="wrist" pos="0 0 0.25" gravcomp="1">
              <joint name="wrist_pitch" axis="0 1 0" range="-2.0 2.0" damping="0.3" armature="0.02"/>
              <geom name="wrist_link" type="capsule" fromto="0 0 0 0 0 0.06" size="0.025"
                    material="joint"/>
              <body name="hand" pos="0 0 0.07" gravcomp="1">
                <joint name="wrist_roll" axis="0 0 1" range="-3.0 3.0" damping="0.1" armature="0.01"/>
                <geom name="palm" type="capsule" fromto="0 -0.03 0.01 0 0.03 0.01" size="0.018"/>
                <geom name="finger_left" type="capsule" fromto="0 0.025 0.02 0 0.015 0.075" size="0.008"
                      material="joint"/>
                <geom name="finger_right" type="capsule" fromto="0 -0.025 0.02 0 -0.015 0.075"
                      size="0.008" material="joint"/>
                <site name="ee" type="sphere" size="0.01" pos="0 0 0.08"/>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>

  <actuator>
    <position name="base_yaw" joint="base_yaw" kp="200" kv="14" inheritrange="1" forcerange="-60 60"/>
    <position name="shoulder_pitch" joint="shoulder_pitch" kp="200" kv="14" inheritrange="1"
              forcerange="-60 60"/>
    <position name="elbow_pitch" joint="elbow_pitch" kp="150" kv="8" inheritrange="1" forcerange="-40 40"/>
    <position name="wrist_pitch" joint="wrist_pitch" kp="60" kv="2" inheritrange="1" forcerange="-15 15"/>
    <position name="wrist_roll" joint="wrist_roll" kp="50" kv="1" inheritrange="1" forcerange="-10 10"/>
  </actuator>
</mujoco>
"""

_RENDER_MODES: tuple[str | None, ...] = (None, "rgb_array")


def _check_positive_int(name: str, value: Any) -> None:
    # bool is a subclass of int, but ``width=True`` is always a mistake.
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise ValueError(f"`{name}` must be a positive int. Received {value!r}.")


class ArmReachEnv(gym.Env[np.ndarray, np.ndarray]):
    """Reach a random target with the end-effector of a five-joint arm.

    Actions are end-effector displacements ``(dx, dy, dz)`` in metres, clipped to
    ``[-0.05, 0.05]`` per axis. Each step converts the displacement into joint targets
    with one damped-least-squares inverse-kinematics step,
    ``dq = J^T (J J^T + lambda^2 I)^-1 dx`` with ``lambda = 0.05``, sends them to the
    joint position actuators and advances the physics by ``n_substeps`` steps of 0.002 s
    (a 0.02 s, 50 Hz control period).

    Observation layout (float32, shape ``(16,)``):

    ========  =====================================================================
    Indices   Content
    ========  =====================================================================
    0:3       end-effector (site ``ee``) position in the world frame, metres
    3:6       target position in the world frame, metres
    6:11      joint positions in :data:`JOINT_NAMES` order, radians
    11:16     joint velocities in :data:`JOINT_NAMES` order, rad/s
    ========  =====================================================================

    The reward is the negative end-effector-to-target distance. An episode terminates
    with success when that distance drops below ``success_threshold`` and is truncated
    after ``max_episode_steps`` steps. ``info`` carries ``"distance"`` and
    ``"is_success"``.

    ``reset`` accepts ``options={"target_pos": (x, y, z)}`` to place the target by hand
    instead of sampling it.

    Args:
        render_mode: ``None`` or ``"rgb_array"``.
        width: Width in pixels of rendered frames.
        height: Height in pixels of rendered frames.
        max_episode_steps: Number of steps after which an episode is truncated.
        success_threshold: Distance in metres below which the target counts as reached.
        textures: False builds the env headless (no textures; it cannot render, the physics is bitwise the
            same). The model is compiled once per process either way; each env owns its copy.

    Raises:
        ValueError: If an argument is outside its allowed values.

    Attributes:
        model: The compiled ``mujoco.MjModel``; other code finds the physics through
            ``env.unwrapped.model``.
        data: The ``mujoco.MjData`` that is stepped.
        n_substeps: Physics steps per environment step.
        control_timestep: Seconds of simulated time per environment step.

    Example:
        >>> import numpy as np
        >>> env = ArmReachEnv()
        >>> obs, info = env.reset(seed=0)
        >>> obs.shape, obs.dtype
        ((16,), dtype('float32'))
        >>> obs, reward, terminated, truncated, info = env.step(np.zeros(3, dtype=np.float32))
        >>> obs.shape, sorted(info)
        ((16,), ['distance', 'is_success'])
        >>> bool(np.isclose(reward, -info["distance"]))
        True
        >>> env.close()
    """

    # gym.Env declares `metadata` as an instance attribute, so a ClassVar annotation would clash.
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 50}  # noqa: RUF012

    #: Home joint configuration: the hand held forward and down above the floor.
    HOME_QPOS: ClassVar[tuple[float, ...]] = (0.0, 0.4, 1.2, 0.9, 0.0)
    #: Half-width in radians of the uniform noise added to the home pose at reset.
    HOME_NOISE: ClassVar[float] = 0.02
    #: Damping of the least-squares inverse kinematics, metres.
    IK_DAMPING: ClassVar[float] = 0.05
    #: Largest end-effector displacement per step, metres.
    MAX_DELTA: ClassVar[float] = 0.05
    #: Lowest allowed target height, metres.
    MIN_TARGET_HEIGHT: ClassVar[float] = 0.05
    #: Smallest allowed distance between the target and the initial end-effector, metres.
    MIN_TARGET_DISTANCE: ClassVar[float] = 0.10

    def __init__(
        self,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
        max_episode_steps: int = 200,
        success_threshold: float = 0.05,
        textures: bool = True,
    ) -> None:
        from sim2real.tasks.models import check_textures, compiled_model

        if render_mode not in _RENDER_MODES:
            raise ValueError(f"`render_mode` must be one of {list(_RENDER_MODES)}. Received {render_mode!r}.")
        check_textures(textures, render_mode)
        _check_positive_int("width", width)
        _check_positive_int("height", height)
        _check_positive_int("max_episode_steps", max_episode_steps)
        if (
            isinstance(success_threshold, bool)
            or not isinstance(success_threshold, (int, float, np.integer, np.floating))
            or not math.isfinite(success_threshold)
            or success_threshold <= 0
        ):
            raise ValueError(f"`success_threshold` must be > 0. Received {success_threshold!r}.")

        self.render_mode = render_mode
        self.width = int(width)
        self.height = int(height)
        self.max_episode_steps = int(max_episode_steps)
        self.success_threshold = float(success_threshold)

        self.model = compiled_model(ARM_REACH_XML, textures=textures)
        # The offscreen framebuffer bounds the renderer, so grow it to the requested size
        # instead of rejecting large frames.
        self.model.vis.global_.offwidth = max(self.model.vis.global_.offwidth, self.width)
        self.model.vis.global_.offheight = max(self.model.vis.global_.offheight, self.height)
        self.data = mujoco.MjData(self.model)
        # Target sampling runs forward kinematics here so that it never disturbs `data`.
        self._scratch = mujoco.MjData(self.model)

        self.n_substeps = 10
        self.control_timestep = self.n_substeps * float(self.model.opt.timestep)

        self._ee_site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "ee")
        self._target_site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "target")
        self._joint_ids = np.array(
            [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, name) for name in JOINT_NAMES]
        )
        # The arm is a single chain of hinges, so qpos and qvel both use one slot per
        # joint; the lookup still goes through the model so that edits to the MJCF that
        # reorder joints cannot silently scramble observations.
        self._qpos_idx = self.model.jnt_qposadr[self._joint_ids].copy()
        self._dof_idx = self.model.jnt_dofadr[self._joint_ids].copy()
        self._jnt_range = self.model.jnt_range[self._joint_ids].copy()
        self._ctrl_low = self.model.actuator_ctrlrange[:, 0].copy()
        self._ctrl_high = self.model.actuator_ctrlrange[:, 1].copy()
        self._home_qpos = np.array(self.HOME_QPOS, dtype=np.float64)

        nv = self.model.nv
        self._jacp = np.zeros((3, nv))
        self._damping_eye = (self.IK_DAMPING**2) * np.eye(3)
        self._target_pos = self.model.site_pos[self._target_site].copy()
        self._elapsed_steps = 0
        self._renderer: mujoco.Renderer | None = None

        self.action_space = spaces.Box(-self.MAX_DELTA, self.MAX_DELTA, shape=(3,), dtype=np.float32)
        obs_dim = 3 + 3 + 2 * len(JOINT_NAMES)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float32)

    # ------------------------------------------------------------------ gym API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Put the arm in its home pose and draw a new target.

        Args:
            seed: Seed for ``self.np_random``; ``None`` keeps the current generator.
            options: Optional ``{"target_pos": (x, y, z)}`` to place the target instead of
                sampling it.

        Returns:
            The first observation and an info dict with ``"distance"`` and ``"is_success"``.

        Raises:
            ValueError: If ``options`` has unknown keys or a malformed ``target_pos``.
        """
        super().reset(seed=seed)
        options = {} if options is None else dict(options)
        unknown = sorted(set(options) - {"target_pos"})
        if unknown:
            raise ValueError(f"`options` keys must be among ['target_pos']. Received {unknown}.")

        mujoco.mj_resetData(self.model, self.data)
        noise = self.np_random.uniform(-self.HOME_NOISE, self.HOME_NOISE, size=len(JOINT_NAMES))
        qpos = np.clip(self._home_qpos + noise, self._jnt_range[:, 0], self._jnt_range[:, 1])
        self.data.qpos[self._qpos_idx] = qpos
        # Servo targets equal to the start pose, so the arm holds still until commanded.
        self.data.ctrl[:] = np.clip(qpos, self._ctrl_low, self._ctrl_high)
        mujoco.mj_forward(self.model, self.data)

        start_ee = self.data.site_xpos[self._ee_site].copy()
        if "target_pos" in options:
            target = np.asarray(options["target_pos"], dtype=np.float64)
            if target.shape != (3,) or not np.all(np.isfinite(target)):
                raise ValueError(
                    f"`options['target_pos']` must be 3 finite numbers. Received {options['target_pos']!r}."
                )
        else:
            target = self._sample_target(start_ee)
        self._target_pos = target.copy()
        self.model.site_pos[self._target_site] = target
        # Refresh site_xpos so renders and readers of `data` see the new target at once.
        mujoco.mj_kinematics(self.model, self.data)

        self._elapsed_steps = 0
        distance = _distance(start_ee, target)
        return self._get_obs(), {"distance": distance, "is_success": distance < self.success_threshold}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Move the end-effector by ``action`` metres and advance one control period.

        Args:
            action: End-effector displacement ``(dx, dy, dz)``; clipped to the action space.

        Returns:
            ``(observation, reward, terminated, truncated, info)``.
        """
        dx = np.clip(np.asarray(action, dtype=np.float64), -self.MAX_DELTA, self.MAX_DELTA)
        model, data = self.model, self.data

        # One IK iteration suffices: displacements are at most a few centimetres, where the
        # linearisation is accurate, and the next step re-linearises from the measured pose,
        # so any residual is corrected in closed loop at a fraction of the cost.
        mujoco.mj_jacSite(model, data, self._jacp, None, self._ee_site)
        jac = self._jacp[:, self._dof_idx]
        dq = jac.T @ np.linalg.solve(jac @ jac.T + self._damping_eye, dx)
        q_target = data.qpos[self._qpos_idx] + dq
        np.clip(q_target, self._ctrl_low, self._ctrl_high, out=data.ctrl)

        self._simulate(self.n_substeps)
        # mj_step leaves positions one substep ahead of the derived kinematics; recompute
        # them so the observation, reward and next Jacobian all describe the same state.
        mujoco.mj_forward(model, data)
        self._elapsed_steps += 1

        distance = _distance(data.site_xpos[self._ee_site], self._target_pos)
        terminated = distance < self.success_threshold
        truncated = self._elapsed_steps >= self.max_episode_steps
        info = {"distance": distance, "is_success": terminated}
        return self._get_obs(), -distance, terminated, truncated, info

    def _simulate(self, nstep: int) -> None:
        # The one place physics advances: sim2real's latency and jitter models intercept it here.
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def render(self) -> np.ndarray | None:
        """Render the ``overview`` camera.

        Returns:
            An ``(height, width, 3)`` uint8 RGB frame in ``"rgb_array"`` mode, else ``None``.
        """
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, height=self.height, width=self.width)
        self._renderer.update_scene(self.data, camera="overview")
        return self._renderer.render()

    def close(self) -> None:
        """Release the renderer, if one was created."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()

    # ------------------------------------------------------------------ helpers

    @property
    def target_pos(self) -> np.ndarray:
        """Copy of the current target position in the world frame, metres."""
        return self._target_pos.copy()

    @property
    def ee_pos(self) -> np.ndarray:
        """Copy of the current end-effector position in the world frame, metres."""
        return self.data.site_xpos[self._ee_site].copy()

    def _get_obs(self) -> np.ndarray:
        return np.concatenate(
            (
                self.data.site_xpos[self._ee_site],
                self._target_pos,
                self.data.qpos[self._qpos_idx],
                self.data.qvel[self._dof_idx],
            )
        ).astype(np.float32)

    def _sample_target(self, start_ee: np.ndarray, max_tries: int = 1000) -> np.ndarray:
        # Sampling joint space and running forward kinematics guarantees the target is
        # kinematically reachable, which sampling a Cartesian box would not.
        scratch = self._scratch
        low, high = self._jnt_range[:, 0], self._jnt_range[:, 1]
        for _ in range(max_tries):
            scratch.qpos[self._qpos_idx] = self.np_random.uniform(low, high)
            mujoco.mj_kinematics(self.model, scratch)
            candidate = scratch.site_xpos[self._ee_site]
            if candidate[2] >= self.MIN_TARGET_HEIGHT and _distance(candidate, start_ee) >= self.MIN_TARGET_DISTANCE:
                return candidate.copy()
        raise RuntimeError(f"No valid target found in {max_tries} samples; the workspace limits are too tight.")


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """The distance of two 3-vectors as ``sqrt(dx*dx + dy*dy + dz*dz)``, summed in that order: the same float on
    every machine (``np.linalg.norm`` goes through BLAS, whose kernel, and with it the last bit, depends on the CPU)
    and what the batched engine computes for all worlds at once (``sim2real.batched.kernels.ArmReachKernel``)."""
    dx, dy, dz = float(a[0] - b[0]), float(a[1] - b[1]), float(a[2] - b[2])
    return math.sqrt(dx * dx + dy * dy + dz * dz)
