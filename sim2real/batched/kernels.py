"""Per-task kernels of the batched engine: what a task computes around its physics, for all worlds at once.

A kernel says how a control step advances one world (the C calls, in the task's order: :attr:`Kernel.scheme`),
which per-world MjData arrays it reads (:attr:`Kernel.fields`; the engine copies them into preallocated
``(N, ...)`` buffers after every step), how actions become controls (:meth:`Kernel.controls`) and how the
buffers become observations, rewards and terminations (:meth:`Kernel.outputs`), each one numpy operation over
all worlds. Every kernel repeats its task's arithmetic operation for operation (same operands, same order,
float64 until the float32 observation cast), so each world's values are bitwise those of the single env;
``tests/test_batched.py`` checks it episode by episode. What goes through BLAS in the task (small products and dots,
whose last bit depends on the CPU's BLAS kernel) is called per world with the single env's expression; everything
else is elementwise numpy over all worlds, the same float on every machine.

Example:
    >>> from sim2real.batched.kernels import KERNELS, kernel_for
    >>> sorted(KERNELS)[:3]
    ['dmc/manipulator-bring_ball', 'dmc/manipulator-bring_peg', 'dmc/manipulator-insert_ball']
    >>> kernel_for("sim2real/arm-reach").obs_dim
    16
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import mujoco
import numpy as np

__all__ = [
    "KERNELS",
    "MODEL_KERNEL",
    "ArmReachKernel",
    "Kernel",
    "ManipulatorKernel",
    "MjcfKernel",
    "ReacherKernel",
    "kernel_factory",
    "kernel_for",
]

Outputs = tuple[np.ndarray, np.ndarray, np.ndarray]


class Kernel:
    """What the engine needs from a task.

    Attributes:
        obs_dim: length of the flat float32 observation.
        fields: MjData attribute names gathered per world after every step (``(N, *shape)`` buffers).
        scheme: ``"dm_control"`` (dm-control's legacy step: ``mj_step2``, further substeps, ``mj_step1``) or
            ``"forward"`` (``mj_step`` over the substeps, then ``mj_forward``).
        jacobian_site: a site whose translational Jacobian is computed per world after every step and reset
            (``gathered["jacobian"]``, ``(N, 3, nv)``), or None.
        diverged_reward: the reward of a step whose physics diverged: ``"zero"`` (dm-control adapter) or
            ``"computed"`` (gymnasium envs: the env's own reward of the state MuJoCo fell back to).
        reports_success: whether the single env reports ``info["is_success"]`` (then equal to ``terminated``).
        options: the :func:`sim2real.make` options a batched world may take (others change what is computed).
        bare_warnings: MuJoCo warnings (``mjtWarning`` values) on which the task env itself, without sim2real's
            wrappers, ends an episode (``truncated``, its own observation and reward; MjcfEnv: bad accelerations).
    """

    options: tuple[str, ...] = ()
    obs_dim: int = 0
    fields: tuple[str, ...] = ()
    scheme: str = "dm_control"
    jacobian_site: str | None = None
    diverged_reward: str = "zero"
    reports_success: bool = False
    bare_warnings: tuple[int, ...] = ()

    def configure(self, env: Any) -> None:
        """Reads what the kernel's shapes depend on from world 0's single env ``env`` (once, before any reset)."""

    def bind(self, models: Sequence[mujoco.MjModel], envs: Sequence[Any]) -> None:
        """Reads what stays fixed over an episode (called after every reset of any world)."""

    def observe(self, env: Any) -> np.ndarray:
        """The single env ``env``'s own (clean) observation of its current state, as its ``step`` would return it."""
        return np.asarray(env.unwrapped._get_obs())

    def substeps(self, env: Any) -> int:
        """Physics steps per control step of the single env ``env``."""
        return int(env.unwrapped.dm_env._n_sub_steps)

    def step_limit(self, env: Any) -> float:
        """Control steps after which the single env truncates its episode."""
        return float(env.unwrapped.dm_env._step_limit)

    def controls(self, actions: np.ndarray, qpos: np.ndarray, gathered: dict[str, np.ndarray]) -> np.ndarray:
        """``(N, nu)`` float64 controls written to ``data.ctrl`` from ``(N, action_dim)`` float64 actions."""
        return actions

    def outputs(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> Outputs:
        """``(obs, reward, terminated)``: ``(N, obs_dim)`` float32, ``(N,)`` float64, ``(N,)`` bool, fresh arrays (a
        lockstep step hands them to the caller as they are)."""
        raise NotImplementedError


class ReacherKernel(Kernel):
    """dm-control ``reacher``: observation ``[position, to_target, velocity]`` and the sparse reward
    ``1.0 if |finger - target| <= r_target + r_finger else 0.0``; never terminates.

    ``to_target`` is ``geom_xpos[target, :2] - geom_xpos[finger, :2]``; the radii sum is re-read at every
    reset (the task writes the target's size in its ``initialize_episode``).
    """

    options = ("time_limit", "textures")
    obs_dim = 6
    fields = ("geom_xpos",)

    def __init__(self) -> None:
        self._target = self._finger = -1
        self._radii = np.zeros(0)

    def bind(self, models: Sequence[mujoco.MjModel], envs: Sequence[Any]) -> None:
        m0 = models[0]
        self._target = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_GEOM, "target")
        self._finger = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_GEOM, "finger")
        sizes = np.stack([m.geom_size for m in models])
        self._radii = sizes[:, self._target, 0] + sizes[:, self._finger, 0]

    def outputs(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> Outputs:
        xpos = gathered["geom_xpos"]
        d = xpos[:, self._target, :2] - xpos[:, self._finger, :2]
        obs = np.concatenate([qpos, d, qvel], axis=1, dtype=np.float32)
        squares = d * d
        dist = np.sqrt(squares[:, 0] + squares[:, 1])
        # rewards.tolerance with bounds (0, radii) and margin 0: 1.0 where 0 <= dist <= radii, else 0.0. A square
        # root is never below 0 (and a NaN fails either test), so the upper bound alone decides.
        reward = (dist <= self._radii).astype(np.float64)
        return obs, reward, np.zeros(len(obs), bool)


class ArmReachKernel(Kernel):
    """``sim2real/arm-reach``: one damped-least-squares IK step per action (vectorised over worlds), ``mj_step``
    over 10 substeps then ``mj_forward``; observation ``[ee, target, qpos, qvel]``, reward ``-|ee - target|``,
    terminated (and ``is_success``) when the distance is below the success threshold."""

    options = ("max_episode_steps", "success_threshold", "textures")
    obs_dim = 16
    fields = ("site_xpos",)
    scheme = "forward"
    jacobian_site = "ee"
    diverged_reward = "computed"
    reports_success = True

    def __init__(self) -> None:
        self._ee = -1
        self._qpos_idx = self._dof_idx = np.zeros(0, np.int64)
        self._low = self._high = self._target = self._threshold = np.zeros(0)
        self._max_delta = 0.0
        self._damping_eye = np.zeros((3, 3))

    def substeps(self, env: Any) -> int:
        return int(env.unwrapped.n_substeps)

    def step_limit(self, env: Any) -> float:
        return float(env.unwrapped.max_episode_steps)

    def bind(self, models: Sequence[mujoco.MjModel], envs: Sequence[Any]) -> None:
        arm = envs[0].unwrapped
        self._ee = arm._ee_site
        self._qpos_idx, self._dof_idx = arm._qpos_idx, arm._dof_idx
        self._low, self._high = arm._ctrl_low, arm._ctrl_high
        self._max_delta = arm.MAX_DELTA
        self._damping_eye = arm._damping_eye
        self._target = np.stack([env.unwrapped._target_pos for env in envs])
        self._threshold = np.array([env.unwrapped.success_threshold for env in envs])

    def controls(self, actions: np.ndarray, qpos: np.ndarray, gathered: dict[str, np.ndarray]) -> np.ndarray:
        dx = np.clip(actions, -self._max_delta, self._max_delta)
        jacs = gathered["jacobian"][:, :, self._dof_idx]
        dq = np.empty((len(dx), len(self._dof_idx)))
        # One world at a time, the single env's expression on same-shaped contiguous operands: these products go
        # through BLAS, whose kernel (and so the last bit of a small product: `a @ a.T` is a syrk, a stacked matmul
        # is not) depends on the CPU; only the same call is bitwise the same everywhere.
        for i, jac in enumerate(jacs):
            dq[i] = jac.T @ np.linalg.solve(jac @ jac.T + self._damping_eye, dx[i])
        return np.clip(qpos[:, self._qpos_idx] + dq, self._low, self._high)

    def outputs(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> Outputs:
        ee = gathered["site_xpos"][:, self._ee]
        obs = np.concatenate([ee, self._target, qpos[:, self._qpos_idx], qvel[:, self._dof_idx]], axis=1)
        d = ee - self._target
        distance = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])
        return obs.astype(np.float32), -distance, distance < self._threshold


class ManipulatorKernel(Kernel):
    """dm-control ``manipulator`` (bring/insert, ball/peg; fully observable): observation ``[arm_pos (sin, cos
    per joint), arm_vel, touch, hand_pos, object_pos, object_vel, target_pos]``; the task's shaped reward through
    dm-control's own ``rewards.tolerance`` on ``(N,)`` arrays; never terminates. Names are resolved once, so no
    step goes through dm-control's named indexer."""

    options = ("time_limit", "textures")
    obs_dim = 44
    fields = ("xpos", "xquat", "site_xpos", "sensordata")

    def __init__(self, use_peg: bool) -> None:
        self._use_peg = use_peg
        self._ids: dict[str, Any] = {}

    def bind(self, models: Sequence[mujoco.MjModel], envs: Sequence[Any]) -> None:
        from dm_control.suite import manipulator

        m = models[0]

        def ids(kind: mujoco.mjtObj, names: Sequence[str]) -> np.ndarray:
            return np.array([mujoco.mj_name2id(m, kind, name) for name in names])

        obj = "peg" if self._use_peg else "ball"
        arm = ids(mujoco.mjtObj.mjOBJ_JOINT, manipulator._ARM_JOINTS)
        obj_joints = ids(mujoco.mjtObj.mjOBJ_JOINT, [f"{obj}_{d}" for d in "xzy"])
        bodies = ids(mujoco.mjtObj.mjOBJ_BODY, ["hand", obj, "target_peg" if self._use_peg else "target_ball"])
        sites = ids(mujoco.mjtObj.mjOBJ_SITE, self._site_names())
        touch = ids(mujoco.mjtObj.mjOBJ_SENSOR, manipulator._TOUCH_SENSORS)
        self._ids = {
            "arm_q": m.jnt_qposadr[arm],
            "arm_v": m.jnt_dofadr[arm],
            "obj_v": m.jnt_dofadr[obj_joints],
            "bodies": bodies,
            "sites": sites,
            "touch": m.sensor_adr[touch],
            "close": manipulator._CLOSE,
        }

    def _site_names(self) -> list[str]:
        if self._use_peg:  # (site1, site2) pairs of site_distance, in _peg_reward's order
            return ["peg_grasp", "grasp", "peg_pinch", "pinch", "peg", "target_peg", "target_peg_tip", "peg_tip"]
        return ["ball", "target_ball"]

    def _pose(self, xpos: np.ndarray, xquat: np.ndarray, body: int) -> np.ndarray:
        return np.concatenate([xpos[:, body][:, [0, 2]], xquat[:, body][:, [0, 2]]], axis=1)

    def outputs(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> Outputs:
        from dm_control.utils import rewards

        ids = self._ids
        n = len(qpos)
        joint_pos = qpos[:, ids["arm_q"]]
        arm_pos = np.stack([np.sin(joint_pos), np.cos(joint_pos)], axis=2).reshape(n, -1)
        xpos, xquat = gathered["xpos"], gathered["xquat"]
        hand, obj, target = ids["bodies"]
        obs = np.concatenate(
            [
                arm_pos,
                qvel[:, ids["arm_v"]],
                np.log1p(gathered["sensordata"][:, ids["touch"]]),
                self._pose(xpos, xquat, hand),
                self._pose(xpos, xquat, obj),
                qvel[:, ids["obj_v"]],
                self._pose(xpos, xquat, target),
            ],
            axis=1,
            dtype=np.float32,
        )
        site_xpos = gathered["site_xpos"]
        close = ids["close"]

        def is_close(pair: int) -> np.ndarray:
            a, b = ids["sites"][2 * pair], ids["sites"][2 * pair + 1]
            d = site_xpos[:, a] - site_xpos[:, b]
            # dm-control's np.linalg.norm is sqrt(x.dot(x)), a BLAS dot whose kernel (and last bit) depends on the
            # CPU: the same call per world is bitwise the single env's on every machine.
            distance = np.sqrt(np.array([row.dot(row) for row in d]))
            return np.asarray(rewards.tolerance(distance, (0, close), close * 2))

        if self._use_peg:
            grasping = (is_close(0) + is_close(1)) / 2
            bringing = (is_close(2) + is_close(3)) / 2
            reward = np.maximum(bringing, grasping / 3)
        else:
            reward = is_close(0)
        return obs, reward, np.zeros(n, bool)


class MjcfKernel(Kernel):
    """An MJCF model as ``sim2real.make("model:<path>")`` builds it (:class:`sim2real.mjcf_env.MjcfEnv`): actions
    clipped to the actuators' control ranges into ``ctrl``, ``mj_step`` over the substeps then ``mj_forward``;
    observation ``[qpos, qvel]`` (float32), reward ``-sum((qpos - home)**2)`` over the hinge and slide joints; never
    terminates. Its shapes come from the model (:meth:`configure`)."""

    options = ("max_episode_steps", "control_timestep", "reset_noise")
    scheme = "forward"
    diverged_reward = "computed"
    bare_warnings = (int(mujoco.mjtWarning.mjWARN_BADQACC),)  # MjcfEnv.step's `diverged`

    def __init__(self) -> None:
        self._low = self._high = self._home = np.zeros(0)
        self._scored = np.zeros(0, np.int64)

    def configure(self, env: Any) -> None:
        base = env.unwrapped
        self.obs_dim = int(base.model.nq + base.model.nv)
        self._low, self._high = base._low, base._high
        self._scored = base._scored
        self._home = base.home[base._scored]

    def substeps(self, env: Any) -> int:
        return int(env.unwrapped.n_substeps)

    def step_limit(self, env: Any) -> float:
        return float(env.unwrapped.max_episode_steps)

    def observe(self, env: Any) -> np.ndarray:
        return np.asarray(env.unwrapped._obs())

    def controls(self, actions: np.ndarray, qpos: np.ndarray, gathered: dict[str, np.ndarray]) -> np.ndarray:
        return np.clip(actions, self._low, self._high)

    def outputs(self, qpos: np.ndarray, qvel: np.ndarray, gathered: dict[str, np.ndarray]) -> Outputs:
        obs = np.concatenate([qpos, qvel], axis=1).astype(np.float32)
        # C order: a column gather comes out in Fortran order, whose strided rows take another BLAS dot kernel.
        error = np.ascontiguousarray(qpos[:, self._scored] - self._home)
        # MjcfEnv's `error @ error` is a BLAS dot whose last bit depends on the CPU's kernel: the same call per world,
        # each on a contiguous row as the single env's.
        reward = np.array([-float(row @ row) for row in error])
        return obs, reward, np.zeros(len(qpos), bool)


#: Task id -> kernel factory: the tasks the batched engine runs besides ``model:<path>`` ids (:data:`MODEL_KERNEL`);
#: others fall back to per-env stepping.
KERNELS: dict[str, Callable[[], Kernel]] = {
    "dmc/reacher-easy": ReacherKernel,
    "dmc/reacher-hard": ReacherKernel,
    "sim2real/arm-reach": ArmReachKernel,
    "dmc/manipulator-bring_ball": lambda: ManipulatorKernel(use_peg=False),
    "dmc/manipulator-insert_ball": lambda: ManipulatorKernel(use_peg=False),
    "dmc/manipulator-bring_peg": lambda: ManipulatorKernel(use_peg=True),
    "dmc/manipulator-insert_peg": lambda: ManipulatorKernel(use_peg=True),
}


#: The kernel of every ``model:<path>`` id (an MJCF file as :class:`sim2real.mjcf_env.MjcfEnv`).
MODEL_KERNEL: Callable[[], Kernel] = MjcfKernel


def kernel_factory(task_id: Any) -> Callable[[], Kernel] | None:
    """The kernel factory of ``task_id``: :data:`KERNELS`' entry, :data:`MODEL_KERNEL` for a ``model:<path>`` id,
    else None (an env with a step of its own: a ``gym/*`` or ``env:`` id, an env object).

    Example:
        >>> kernel_factory("model:robot.xml") is MjcfKernel, kernel_factory("gym/Reacher-v5")
        (True, None)
    """
    if not isinstance(task_id, str):
        return None
    if task_id.startswith("model:") and len(task_id) > len("model:"):
        return MODEL_KERNEL
    return KERNELS.get(task_id)


def kernel_for(task_id: str) -> Kernel:
    """A fresh kernel for ``task_id``.

    Raises:
        ValueError: a task without a batched kernel (the message lists those that have one).
    """
    factory = kernel_factory(task_id)
    if factory is None:
        raise ValueError(
            f"`task` must be one of {sorted(KERNELS)} or 'model:<path>' for the batched engine. Received {task_id!r}."
        )
    return factory()
