"""Scripted controllers for the arm tasks: plain, batched ``obs -> action`` callables (numpy only).

Studies compare them with learned policies, and tests use them so they need no training.

Example:
    >>> import numpy as np
    >>> import sim2real
    >>> env, ctrl = sim2real.make("sim2real/arm-reach"), ReachController()
    >>> obs, info = env.reset(seed=0)
    >>> done = False
    >>> while not done:
    ...     obs, reward, terminated, truncated, info = env.step(ctrl(obs))
    ...     done = terminated or truncated
    >>> info["is_success"]
    True
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

__all__ = ["BASELINES", "ReachController", "ReacherPD", "baseline_for"]


def _check_gain(name: str, value: Any, *, allow_zero: bool = False) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value < 0 or (value == 0 and not allow_zero):
        raise ValueError(f"`{name}` must be {'>= 0' if allow_zero else '> 0'}. Received {value!r}.")
    return float(value)


def _check_obs(obs: Any, dim: int, who: str) -> np.ndarray:
    arr = np.asarray(obs, dtype=np.float64)
    if arr.ndim not in (1, 2) or arr.shape[-1] != dim:
        raise ValueError(f"{who} expects observations of shape ({dim},) or (B, {dim}). Received shape {arr.shape}.")
    return arr


class ReachController:
    """Proportional end-effector controller for ``sim2real/arm-reach``: ``clip(kp * (target - ee), ±max_delta)``.

    The task's actions are end-effector displacements that its joint position servos track; those servos
    (``kv`` gains in the MJCF) already supply the damping, so the derivative term of the Cartesian law is
    left to them and the controller stays stateless, which keeps it exact under batching.

    Args:
        kp: proportional gain (1.0 commands the whole remaining error, saturated).
        max_delta: per-axis saturation in metres (the task clips at 0.05).

    Raises:
        ValueError: a gain that is not > 0.

    Example:
        >>> ReachController()(np.r_[0.0, 0.0, 0.3, 0.02, -0.1, 0.3, np.zeros(10)])
        array([ 0.02, -0.05,  0.  ], dtype=float32)
    """

    task: ClassVar[str] = "sim2real/arm-reach"
    batched: ClassVar[bool] = True
    obs_dim: ClassVar[int] = 16

    def __init__(self, kp: float = 1.0, max_delta: float = 0.05) -> None:
        self.kp = _check_gain("kp", kp)
        self.max_delta = _check_gain("max_delta", max_delta)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Action(s) for one ``(16,)`` observation or a ``(B, 16)`` batch."""
        arr = _check_obs(obs, self.obs_dim, type(self).__name__)
        error = arr[..., 3:6] - arr[..., 0:3]
        return np.clip(self.kp * error, -self.max_delta, self.max_delta).astype(np.float32)

    def __repr__(self) -> str:
        return f"ReachController(kp={self.kp}, max_delta={self.max_delta})"


class ReacherPD:
    """Jacobian-transpose PD controller for ``dmc/reacher-easy`` / ``dmc/reacher-hard``.

    The observation is ``[q1, q2, to_target_x, to_target_y, dq1, dq2]``; the finger of the two-link arm
    (links of :attr:`LINKS` metres) is pulled towards the target by ``tau = J(q)^T kp * to_target - kd * dq``,
    clipped to the ``[-1, 1]`` torque commands.

    Args:
        kp: Cartesian stiffness (command units per metre).
        kd: joint damping (command units per rad/s).

    Raises:
        ValueError: ``kp`` not > 0 or ``kd`` < 0.

    Example:
        >>> ReacherPD()(np.array([0.0, 0.0, 0.0, 0.1, 0.0, 0.0]))
        array([1. , 0.6], dtype=float32)
    """

    task: ClassVar[str] = "dmc/reacher-easy"
    batched: ClassVar[bool] = True
    obs_dim: ClassVar[int] = 6
    #: Shoulder-to-wrist and wrist-to-finger lengths of the dm-control reacher, metres.
    LINKS: ClassVar[tuple[float, float]] = (0.12, 0.12)

    def __init__(self, kp: float = 50.0, kd: float = 0.1) -> None:
        self.kp = _check_gain("kp", kp)
        self.kd = _check_gain("kd", kd, allow_zero=True)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Action(s) for one ``(6,)`` observation or a ``(B, 6)`` batch."""
        arr = _check_obs(obs, self.obs_dim, type(self).__name__)
        q1, q2 = arr[..., 0], arr[..., 1]
        fx, fy = self.kp * arr[..., 2], self.kp * arr[..., 3]
        l1, l2 = self.LINKS
        s1, c1, s12, c12 = np.sin(q1), np.cos(q1), np.sin(q1 + q2), np.cos(q1 + q2)
        # J = [[-l1 s1 - l2 s12, -l2 s12], [l1 c1 + l2 c12, l2 c12]]; tau = J^T f.
        tau1 = (-l1 * s1 - l2 * s12) * fx + (l1 * c1 + l2 * c12) * fy
        tau2 = -l2 * s12 * fx + l2 * c12 * fy
        tau = np.stack((tau1, tau2), axis=-1) - self.kd * arr[..., 4:6]
        return np.clip(tau, -1.0, 1.0).astype(np.float32)

    def __repr__(self) -> str:
        return f"ReacherPD(kp={self.kp}, kd={self.kd})"


#: Task id -> scripted baseline class.
BASELINES: dict[str, type[ReachController] | type[ReacherPD]] = {
    "sim2real/arm-reach": ReachController,
    "dmc/reacher-easy": ReacherPD,
    "dmc/reacher-hard": ReacherPD,
}


def baseline_for(task: str) -> ReachController | ReacherPD:
    """The scripted baseline of ``task`` with default gains.

    Raises:
        ValueError: ``task`` has no scripted baseline (the ones that do are listed).

    Example:
        >>> baseline_for("sim2real/arm-reach")
        ReachController(kp=1.0, max_delta=0.05)
    """
    cls = BASELINES.get(task)
    if cls is None:
        raise ValueError(f"`task` must be one of {list(BASELINES)} to have a scripted baseline. Received {task!r}.")
    return cls()
