"""A gymnasium env around any MJCF file: the env ``sim2real ... --model robot.xml`` runs on.

:class:`MjcfEnv` needs nothing but the model. Actions are the actuator controls (``data.ctrl``, bounded by
``ctrlrange``; an unlimited actuator gets ``[-1, 1]``), observations are ``qpos`` and ``qvel`` concatenated, and
each episode starts at the home pose (the keyframe named ``home``, else the first keyframe, else ``qpos0``) with a small seeded
perturbation. The reward is a placeholder that makes training and evaluation meaningful on a bare arm: hold the
home pose, ``-sum((qpos - home)**2)`` over hinge and slide joints. For a real task bring an env factory
(``--env package.module:factory``) instead.

The control period is 50 Hz unless the model says otherwise: ``<custom><numeric name="sim2real_control_timestep"
data="0.005"/></custom>`` in the MJCF makes every command that takes ``--model`` (and ``sim2real.make("model:...")``,
and every process and checkpoint that names the file) step it at 200 Hz, a whole number of ``opt.timestep`` each;
``control_timestep=`` given in Python still wins.

Example:
    >>> xml = ('<mujoco><worldbody><body><joint name="j" range="-1 1"/><geom type="capsule" size=".05" fromto="0 0 0 0 0 -.3"/>'
    ...        '</body></worldbody><actuator><motor joint="j" ctrlrange="-1 1"/></actuator></mujoco>')
    >>> env = MjcfEnv(xml=xml, max_episode_steps=5)
    >>> obs, _ = env.reset(seed=0)
    >>> obs.shape, env.action_space.shape, env.n_substeps
    ((2,), (1,), 10)
    >>> _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
    >>> reward <= 0.0, terminated, truncated
    (True, False, False)
"""

from __future__ import annotations

import math
import os
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

__all__ = [
    "CONTROL_TIMESTEP_NUMERIC",
    "DEFAULT_CONTROL_TIMESTEP",
    "MjcfEnv",
    "declared_control_timestep",
    "home_key",
    "home_pose",
]

#: Control period (seconds) of an MJCF env unless ``control_timestep`` is given or the model declares one: 50 Hz, a
#: common driver rate.
DEFAULT_CONTROL_TIMESTEP = 0.02
#: The MJCF ``<custom><numeric>`` through which a model declares its control period in seconds.
CONTROL_TIMESTEP_NUMERIC = "sim2real_control_timestep"


def declared_control_timestep(model: mujoco.MjModel, where: str = "the model") -> float | None:
    """The control period ``model`` declares (``<numeric name="sim2real_control_timestep" data="SECONDS"/>``), or
    None when it declares none.

    Raises:
        ValueError: the numeric is not one number of seconds > 0.

    Example:
        >>> m = mujoco.MjModel.from_xml_string('<mujoco><custom><numeric name="sim2real_control_timestep" '
        ...                                    'data="0.005"/></custom></mujoco>')
        >>> declared_control_timestep(m)
        0.005
    """
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, CONTROL_TIMESTEP_NUMERIC)
    if i < 0:
        return None
    start, size = int(model.numeric_adr[i]), int(model.numeric_size[i])
    values = [float(v) for v in model.numeric_data[start : start + size]]
    if len(values) != 1 or not (math.isfinite(values[0]) and values[0] > 0):
        raise ValueError(
            f'<numeric name="{CONTROL_TIMESTEP_NUMERIC}"> in {where} must hold one number of seconds > 0 (the control '
            f"period). Received {values}."
        )
    return values[0]


def home_key(model: mujoco.MjModel) -> int | None:
    """The home keyframe's index: the keyframe named ``home``, else the first one; None without keyframes."""
    if model.nkey == 0:
        return None
    return max(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home"), 0)


def home_pose(model: mujoco.MjModel) -> np.ndarray:
    """The home keyframe's ``qpos`` (:func:`home_key`: named ``home``, else the first), else ``qpos0`` (a copy,
    shape ``(nq,)``).

    Example:
        >>> m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><body><joint/><geom size=".1"/></body>'
        ...     '</worldbody><keyframe><key qpos="0.5"/></keyframe></mujoco>')
        >>> home_pose(m).tolist()
        [0.5]
    """
    key = home_key(model)
    if key is not None:
        return np.array(model.key_qpos[key], dtype=np.float64)
    return np.array(model.qpos0, dtype=np.float64)


def _positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"`{name}` must be an int >= 1. Received {value!r}.")
    return int(value)


class MjcfEnv(gym.Env[np.ndarray, np.ndarray]):
    """Any MJCF model as a gymnasium env (see the module docstring for spaces and reward).

    Args:
        path: an MJCF file (give ``path`` or ``xml``).
        xml: MJCF text.
        control_timestep: seconds per control step, a whole multiple of ``opt.timestep`` (rounded to the
            nearest, at least one physics step); default: what the model declares (:func:`declared_control_timestep`),
            else :data:`DEFAULT_CONTROL_TIMESTEP`.
        max_episode_steps: control steps per episode before ``truncated``.
        reset_noise: half-width (rad or m) of the uniform perturbation of the home pose at reset.
        render_mode: None or ``"rgb_array"``.
        width: rendered frame width in pixels.
        height: rendered frame height in pixels.

    Raises:
        ValueError: the file does not compile (MuJoCo's message is quoted), a bad argument.
        FileNotFoundError: ``path`` does not exist.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}  # noqa: RUF012 - gymnasium API

    def __init__(
        self,
        path: str | os.PathLike[str] | None = None,
        *,
        xml: str | None = None,
        control_timestep: float | None = None,
        max_episode_steps: int = 200,
        reset_noise: float = 0.01,
        render_mode: str | None = None,
        width: int = 240,
        height: int = 240,
    ) -> None:
        if (path is None) == (xml is None):
            raise ValueError(
                f"give exactly one of `path` and `xml`. Received path={path!r} and xml of "
                f"{'no' if xml is None else len(xml)} characters."
            )
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"`render_mode` must be one of [None, 'rgb_array']. Received {render_mode!r}.")
        self.max_episode_steps = _positive_int("max_episode_steps", max_episode_steps)
        self.width = _positive_int("width", width)
        self.height = _positive_int("height", height)
        if not (isinstance(reset_noise, (int, float)) and math.isfinite(reset_noise) and reset_noise >= 0):
            raise ValueError(f"`reset_noise` must be a finite number >= 0. Received {reset_noise!r}.")
        self.reset_noise = float(reset_noise)
        self.path = None if path is None else os.fspath(path)
        if self.path is not None and not os.path.isfile(self.path):
            raise FileNotFoundError(f"`path` {self.path!r} does not exist.")
        try:
            model = (
                mujoco.MjModel.from_xml_path(self.path)
                if self.path is not None
                else mujoco.MjModel.from_xml_string(xml or "")
            )
        except ValueError as err:
            where = repr(self.path) if self.path is not None else "`xml`"
            raise ValueError(f"{where} is not a valid MJCF model: {' '.join(str(err).split())}") from err
        self.model = model
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        self.data = mujoco.MjData(model)
        timestep = float(model.opt.timestep)
        if control_timestep is None:
            declared = declared_control_timestep(model, repr(self.path) if self.path is not None else "`xml`")
            wanted: Any = DEFAULT_CONTROL_TIMESTEP if declared is None else declared
        else:
            wanted = control_timestep
        if not (isinstance(wanted, (int, float)) and math.isfinite(wanted) and wanted > 0):
            raise ValueError(f"`control_timestep` must be a number of seconds > 0. Received {control_timestep!r}.")
        self.n_substeps = max(1, round(float(wanted) / timestep))
        self.control_timestep = self.n_substeps * timestep
        self.render_mode = render_mode
        self.home = home_pose(model)
        limited = model.actuator_ctrllimited.astype(bool)
        low = np.where(limited, model.actuator_ctrlrange[:, 0], -1.0)
        high = np.where(limited, model.actuator_ctrlrange[:, 1], 1.0)
        self.action_space = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(model.nq + model.nv,), dtype=np.float32)
        scalar = np.isin(model.jnt_type, (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE))
        self._scored = model.jnt_qposadr[scalar].copy()
        self._low, self._high = low, high
        self._elapsed = 0
        self._renderer: mujoco.Renderer | None = None

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.data.qpos, self.data.qvel]).astype(np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        model, data = self.model, self.data
        mujoco.mj_resetData(model, data)
        key = home_key(model)
        if key is not None:
            mujoco.mj_resetDataKeyframe(model, data, key)
        noise = self.np_random.uniform(-self.reset_noise, self.reset_noise, size=self._scored.shape[0])
        data.qpos[self._scored] += noise
        mujoco.mj_forward(model, data)
        self._elapsed = 0
        return self._obs(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        # sim2real.batched.kernels.MjcfKernel repeats this arithmetic for all batched worlds at once: change both
        # (tests/test_journey5_batched.py holds them bitwise equal).
        data = self.data
        data.ctrl[:] = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), self._low, self._high)
        self._simulate(self.n_substeps)
        mujoco.mj_forward(self.model, data)
        self._elapsed += 1
        error = data.qpos[self._scored] - self.home[self._scored]
        reward = -float(error @ error)
        diverged = bool(data.warning.number[mujoco.mjtWarning.mjWARN_BADQACC])
        truncated = self._elapsed >= self.max_episode_steps or diverged
        return self._obs(), reward, False, truncated, {"diverged": diverged}

    def _simulate(self, nstep: int) -> None:
        # The one place physics advances: sim2real's latency and jitter models intercept it here.
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def render(self) -> np.ndarray | None:
        """An ``(height, width, 3)`` uint8 frame of the first camera (the free camera when there is none)."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, height=self.height, width=self.width)
        self._renderer.update_scene(self.data, camera=0 if self.model.ncam > 0 else -1)
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()
