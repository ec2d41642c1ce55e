"""Camera effects: the vertical field of view and the pose (position, orientation, optional look-at target).

Example:
    >>> from randomizers.distributions import Uniform
    >>> CameraFovy(scale=Uniform(0.9, 1.1)).key
    'CameraFovy[cameras=*]'
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from randomizers.addressing import Address
from randomizers.addressing import select as _select
from randomizers.distributions import Constant, Distribution, as_distribution
from randomizers.effects import ArrayEffect, Binding, Effect, Operation, Schedule, _check_schedule
from randomizers.visual.arguments import (
    Product,
    _channels,
    _check_bool,
    _check_name,
    _one_operation,
    _patterns,
    _shown,
)

__all__ = ["CameraFovy", "CameraPose"]

# ----------------------------------------------------------------------------- cameras


class CameraFovy(ArrayEffect):
    """Vertical field of view of the selected cameras (``cam_fovy``, degrees, kept in (0, 180)).

    Example:
        >>> from randomizers import Uniform
        >>> CameraFovy(scale=Uniform(0.9, 1.1), cameras="overview")
        CameraFovy(scale=Uniform(low=0.9, high=1.1), cameras='overview')
        >>> CameraFovy(set=Uniform(30, 200))
        Traceback (most recent call last):
        ...
        ValueError: `set` of CameraFovy must stay in (0, 180) degrees. Received Uniform(low=30.0, high=200.0).
    """

    field = "cam_fovy"
    kind = "camera"
    selector = "cameras"

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        cameras: str | Sequence[str] = "*",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(scale=scale, add=add, set=set, select=cameras, shared=shared, schedule=schedule, name=name)
        low, high = self.distribution.support
        if self.operation == "set" and (low <= 0 or high >= 180):
            raise ValueError(f"`set` of CameraFovy must stay in (0, 180) degrees. Received {self.distribution!r}.")
        self._frozen = True

    def _targets(self, model: mujoco.MjModel) -> tuple[list[int], list[int] | None, list[Address]]:
        chosen = _select(model, self.kind, self.patterns, self.selector)
        return [i for i, _ in chosen], None, [Address("cam_fovy", n) for _, n in chosen]

    def bind(self, model: mujoco.MjModel) -> Binding:
        """Resolves the cameras; rejects a distribution that could leave (0, 180) degrees for one of them."""
        binding = super().bind(model)
        low, high = self.distribution.support
        ends = np.stack([binding.values(np.array([low])), binding.values(np.array([high]))])
        bad = np.flatnonzero(~((ends > 0) & (ends < 180)).all(axis=0))
        if bad.size:
            k = int(bad[0])
            raise ValueError(
                f"`{self.operation}` of CameraFovy would take {binding.addresses[k]} (nominal "
                f"{float(binding.nominal[k])!r}) outside (0, 180) degrees. Received {self.distribution!r}."
            )
        return binding


def _look_at_quat(eye: np.ndarray, target: np.ndarray, up: np.ndarray, roll: float) -> np.ndarray:
    """Quaternion of a MuJoCo camera (looks along -z, y up) at ``eye`` aimed at ``target``."""
    z = eye - target
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-9:  # looking straight along ``up``: any perpendicular will do
        x = np.cross(np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(roll), math.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.stack([x, y, z], axis=1).reshape(-1))
    return quat


class _PoseBinding(Binding["CameraPose"]):
    def __init__(self, effect: CameraPose, model: mujoco.MjModel, chosen: list[tuple[int, str]]) -> None:
        self.effect = effect
        self.model = model
        self.rows = np.array([i for i, _ in chosen], dtype=np.intp)
        self.addresses = tuple(
            [Address("cam_pos", n, c) for _, n in chosen for c in range(3)]
            + [Address("cam_quat", n, c) for _, n in chosen for c in range(4)]
        )
        self.size = len(self.addresses)
        self._pos = model.cam_pos[self.rows].copy()
        self._quat = model.cam_quat[self.rows].copy()
        self.nominal = np.concatenate([self._pos.reshape(-1), self._quat.reshape(-1)])
        flat = np.zeros((len(self.rows), 9))
        for k, q in enumerate(self._quat):
            mujoco.mju_quat2Mat(flat[k], q)
        mats = flat.reshape(-1, 3, 3)
        self._up = mats[:, :, 1]  # camera y axes in the parent frame
        forward = -mats[:, :, 2]
        if effect.look_at is not None:
            self.targets = np.tile(np.asarray(effect.look_at, dtype=np.float64), (len(self.rows), 1))
        else:
            self.targets = self._default_targets(model, forward)

    def _default_targets(self, model: mujoco.MjModel, forward: np.ndarray) -> np.ndarray:
        # The nominal look-at: the point of the optical axis nearest the model's centre (at the
        # default pose, in the camera's parent body frame); the extent ahead when that is behind.
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        out = np.empty((len(self.rows), 3))
        for k, cam in enumerate(self.rows):
            body = int(model.cam_bodyid[cam])
            rot = data.xmat[body].reshape(3, 3)
            center = rot.T @ (np.asarray(model.stat.center) - data.xpos[body])
            depth = float(forward[k] @ (center - self._pos[k]))
            if depth <= 1e-6:
                depth = float(model.stat.extent)
            out[k] = self._pos[k] + depth * forward[k]
        return out

    def draw_count(self) -> int:
        return 4 if self.effect.shared else 4 * len(self.rows)

    def values(self, draws: np.ndarray) -> np.ndarray:
        effect: CameraPose = self.effect
        d = np.broadcast_to(np.asarray(draws, dtype=np.float64).reshape(-1, 4), (len(self.rows), 4))
        op = effect.operation
        pos = self._pos * d[:, :3] if op == "scale" else self._pos + d[:, :3] if op == "add" else np.array(d[:, :3])
        quats = np.empty((len(self.rows), 4))
        for k in range(len(self.rows)):
            if np.linalg.norm(pos[k] - self.targets[k]) < 1e-9:
                raise ValueError(
                    f"CameraPose drew {self.addresses[3 * k][:-3]} at its look-at point {self.targets[k].tolist()}: "
                    f"the camera cannot aim at itself. Received {op}={_shown(effect.offsets)!r}."
                )
            quats[k] = _look_at_quat(pos[k], self.targets[k], self._up[k], float(d[k, 3]))
        return np.concatenate([pos.reshape(-1), quats.reshape(-1)])

    def apply(self, values: np.ndarray) -> None:
        n = 3 * len(self.rows)
        self.model.cam_pos[self.rows] = values[:n].reshape(-1, 3)
        self.model.cam_quat[self.rows] = values[n:].reshape(-1, 4)

    def restore(self) -> None:
        self.model.cam_pos[self.rows] = self._pos
        self.model.cam_quat[self.rows] = self._quat


class CameraPose(Effect):
    """Camera position perturbed by ``scale``/``add``/``set`` (xyz in the parent body's frame), the
    camera re-aimed at its nominal look-at point (so the scene stays in view), then rolled about
    its optical axis by ``roll`` radians.

    Args:
        scale | add | set: the position operation, one distribution for all three axes (drawn
            independently per axis) or a sequence of three (a number means a constant).
        cameras: name pattern(s) of the cameras (default all).
        roll: roll about the optical axis in radians (default 0).
        look_at: the point to aim at, in the parent body's frame; default: the point of the nominal
            optical axis nearest the model's centre (``model.stat.center``, default pose).
        shared: one draw for all selected cameras instead of one each.
        schedule: ``"reset"`` (default), ``"startup"`` or :class:`~randomizers.Interval`.
        name: stable stream name.

    Reported as ``cam_pos[<camera>][0..2]`` and ``cam_quat[<camera>][0..3]`` (the values written).
    Cameras whose mode aims them at a body (``targetbody``) keep the engine's aim.

    Example:
        >>> from randomizers import Uniform
        >>> CameraPose(add=Uniform(-0.05, 0.05), roll=Uniform(-0.1, 0.1), cameras="overview")
        CameraPose(add=Uniform(low=-0.05, high=0.05), cameras='overview', roll=Uniform(low=-0.1, high=0.1))
        >>> CameraPose(add=0.1, look_at=(0, 0))
        Traceback (most recent call last):
        ...
        ValueError: `look_at` of CameraPose must be None or 3 finite numbers. Received (0, 0).
    """

    def __init__(
        self,
        *,
        scale: Any = None,
        add: Any = None,
        set: Any = None,
        cameras: str | Sequence[str] = "*",
        roll: Distribution | float = 0.0,
        look_at: Sequence[float] | None = None,
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        cls = "CameraPose"
        operation, raw = _one_operation(cls, scale=scale, add=add, set=set)
        offsets = _channels(raw, operation, cls, 3)
        roll_dist = as_distribution(roll, "roll")
        if look_at is not None:
            ok = (
                isinstance(look_at, (list, tuple))
                and len(look_at) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in look_at)
            )
            if not ok:
                raise ValueError(f"`look_at` of {cls} must be None or 3 finite numbers. Received {look_at!r}.")
            look_at = tuple(float(v) for v in look_at)
        _check_bool(shared, "shared", cls)
        _check_name(name, cls)
        self.operation: Operation = operation
        self.offsets = offsets
        self.roll = roll_dist
        self.look_at = look_at
        self.distribution = Product((*offsets, roll_dist))
        self.patterns = _patterns(cameras, "cameras", cls)
        self.shared = shared
        self.schedule = _check_schedule(schedule)
        self.name = name
        self._frozen = True

    def _fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {self.operation: _shown(self.offsets)}
        out["cameras"] = self.patterns[0] if len(self.patterns) == 1 else list(self.patterns)
        if self.roll != Constant(0.0):
            out["roll"] = self.roll
        if self.look_at is not None:
            out["look_at"] = list(self.look_at)
        if self.shared:
            out["shared"] = True
        if self.schedule != "reset":
            out["schedule"] = self.schedule
        if self.name is not None:
            out["name"] = self.name
        return out

    @property
    def key(self) -> str:
        return self.name or f"CameraPose[cameras={'|'.join(self.patterns)}]"

    def bind(self, model: mujoco.MjModel) -> _PoseBinding:
        """Resolves the cameras and snapshots their nominal pose and look-at points."""
        return _PoseBinding(self, model, _select(model, "camera", self.patterns, "cameras"))
