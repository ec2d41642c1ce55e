"""Actuator limits for excitation: the bounds each control must stay inside and the centre a signal swings about.

Torque motors are centred on the middle of ``ctrlrange``; position servos (whose control is a set point) on the
middle of their range unless ``center`` says otherwise, and an unlimited servo on a limited joint takes the joint's
range. Every :class:`~sysid.excitation.ExcitationPolicy` reads its limits through :func:`as_limits`.

Example:
    >>> import mujoco
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body><joint name="hinge"/><geom size=".1"/></body></worldbody>'
    ...     '<actuator><motor name="motor" joint="hinge" ctrlrange="-2 2"/></actuator></mujoco>')
    >>> limits = as_limits(model, center=0.5)
    >>> limits.names, limits.center, limits.half_range, limits.servo
    (('motor',), array([0.5]), array([1.5]), array([False]))
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from randomizers.addressing import element_names

__all__ = ["ActuatorLimits", "as_limits"]


def _as_vector(value: object, nu: int, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"`{name}` must be a number or a sequence of {nu} numbers. Received {value!r}.") from None
    if arr.ndim == 0:
        arr = np.full(nu, float(arr))
    if arr.shape != (nu,):
        raise ValueError(
            f"`{name}` must be a number or a sequence of {nu} numbers (one per actuator). Received {value!r}."
        )
    return arr


def _is_position_servo(model: mujoco.MjModel) -> np.ndarray:
    gain = model.actuator_gainprm[:, 0]
    bias = model.actuator_biasprm
    return (
        (model.actuator_gaintype == mujoco.mjtGain.mjGAIN_FIXED)
        & (model.actuator_biastype == mujoco.mjtBias.mjBIAS_AFFINE)
        & (gain != 0)
        & (bias[:, 1] == -gain)
    )


@dataclass(frozen=True, eq=False)
class ActuatorLimits:
    """Per-actuator control bounds and the centre excitation swings around.

    Attributes:
        low: lower control bound, shape ``(nu,)``.
        high: upper control bound, shape ``(nu,)``.
        center: the rest value each signal oscillates about, shape ``(nu,)``, strictly inside ``(low, high)``.
        names: actuator names (``#<id>`` for unnamed ones).
        servo: whether each actuator is a position servo (its control is a joint set point), shape ``(nu,)``.

    Example:
        >>> limits = ActuatorLimits.explicit(low=[-1.0, 0.0], high=[1.0, 2.0])
        >>> limits.center, limits.half_range
        (array([0., 1.]), array([1., 1.]))
        >>> ActuatorLimits.explicit(low=[1.0], high=[-1.0])
        Traceback (most recent call last):
        ...
        ValueError: `low` must be < `high` for every actuator. Received low=[1.0], high=[-1.0].
    """

    low: np.ndarray
    high: np.ndarray
    center: np.ndarray
    names: tuple[str, ...]
    servo: np.ndarray

    def __post_init__(self) -> None:
        low, high, center = (np.asarray(a, dtype=np.float64) for a in (self.low, self.high, self.center))
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(low < high)):
            raise ValueError(
                f"`low` must be < `high` for every actuator. Received low={low.tolist()}, high={high.tolist()}."
            )
        if not np.all((center > low) & (center < high)):
            raise ValueError(
                f"`center` must lie strictly inside (low, high) for every actuator. Received center={center.tolist()}, "
                f"low={low.tolist()}, high={high.tolist()}."
            )
        for name, arr in (("low", low), ("high", high), ("center", center)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        servo = np.asarray(self.servo, dtype=bool)
        servo.setflags(write=False)
        object.__setattr__(self, "servo", servo)

    @property
    def nu(self) -> int:
        """Number of actuators."""
        return int(self.low.shape[0])

    @property
    def half_range(self) -> np.ndarray:
        """The largest swing that stays inside the bounds from the centre, shape ``(nu,)``."""
        return np.minimum(self.center - self.low, self.high - self.center)

    @classmethod
    def explicit(cls, low: Any, high: Any, center: Any = None, names: Sequence[str] | None = None) -> ActuatorLimits:
        """Limits given as arrays (or numbers broadcast over ``len(low)`` actuators); centre defaults to the middle."""
        low_arr = np.atleast_1d(np.asarray(low, dtype=np.float64))
        nu = low_arr.shape[0]
        high_arr = _as_vector(high, nu, "high")
        if low_arr.ndim != 1:
            raise ValueError(f"`low` must be a number or a 1-D sequence. Received {low!r}.")
        mid = 0.5 * (low_arr + high_arr)
        ctr = mid if center is None else _as_vector(center, nu, "center")
        names_t = tuple(names) if names is not None else tuple(f"#{i}" for i in range(nu))
        return cls(low_arr, high_arr, ctr, names_t, np.zeros(nu, dtype=bool))

    @classmethod
    def from_model(cls, model: mujoco.MjModel, center: Any = None) -> ActuatorLimits:
        """Reads ``actuator_ctrlrange`` where ``actuator_ctrllimited``; an unlimited position servo on a limited
        joint takes the joint's range. Any other unlimited actuator is an error (pass explicit limits instead).

        Example:
            >>> import mujoco
            >>> model = mujoco.MjModel.from_xml_string(
            ...     '<mujoco><worldbody><body><joint name="hinge" range="-1 1"/><geom size=".1"/></body></worldbody>'
            ...     '<actuator><position name="servo" joint="hinge" kp="5"/><motor name="free" joint="hinge"/>'
            ...     '</actuator></mujoco>')
            >>> ActuatorLimits.from_model(model)
            Traceback (most recent call last):
            ...
            ValueError: actuator 'free' has no control limits (ctrllimited is false and it is not a position servo \
on a limited joint). Pass explicit limits, e.g. ActuatorLimits.explicit(low=..., high=...).
        """
        if model.nu == 0:
            raise ValueError("`model` has no actuators (nu == 0); there is nothing to excite.")
        names = element_names(model, "actuator")
        servo = _is_position_servo(model)
        low = np.empty(model.nu)
        high = np.empty(model.nu)
        for i in range(model.nu):
            if model.actuator_ctrllimited[i]:
                low[i], high[i] = model.actuator_ctrlrange[i]
                continue
            joint = int(model.actuator_trnid[i, 0])
            joint_trn = model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT
            if servo[i] and joint_trn and model.jnt_limited[joint]:
                # A set point outside the joint range only pushes against the limit; the range is the useful span.
                gear = float(model.actuator_gear[i, 0]) or 1.0
                lo, hi = sorted(model.jnt_range[joint] / gear)
                low[i], high[i] = lo, hi
                continue
            raise ValueError(
                f"actuator {names[i]!r} has no control limits (ctrllimited is false and it is not a position servo "
                "on a limited joint). Pass explicit limits, e.g. ActuatorLimits.explicit(low=..., high=...)."
            )
        ctr = 0.5 * (low + high) if center is None else _as_vector(center, model.nu, "center")
        return cls(low, high, ctr, tuple(names), servo)


def as_limits(source: object, center: Any = None) -> ActuatorLimits:
    """An :class:`ActuatorLimits` from a model, an existing limits object or a ``(low, high)`` pair."""
    if isinstance(source, ActuatorLimits):
        if center is None:
            return source
        return ActuatorLimits(
            source.low, source.high, _as_vector(center, source.nu, "center"), source.names, source.servo
        )
    if isinstance(source, mujoco.MjModel):
        return ActuatorLimits.from_model(source, center=center)
    if isinstance(source, tuple) and len(source) == 2:
        return ActuatorLimits.explicit(source[0], source[1], center=center)
    raise TypeError(
        "`limits` must be a mujoco.MjModel, an ActuatorLimits or a (low, high) tuple. "
        f"Received {type(source).__name__}."
    )
