"""Calibration: fitted parameter values written into an env's MuJoCo model as its new nominal values.

It sits beside the physics handle (:mod:`sim2real.physics`) and below the task registry, so ``sim2real.make(task,
params=fit)`` reaches it without importing recording, pixels or the wrappers.

Example:
    >>> import sim2real as s2r
    >>> env = s2r.make("sim2real/arm-reach", params={"dof_damping[elbow_pitch]": 0.7})
    >>> float(s2r.find_physics(env).model.dof_damping[2])
    0.7
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np

from sim2real.physics import find_physics

__all__ = ["calibrate"]


def calibrate(env: Any, params: Any) -> Any:
    """Writes fitted parameter values into ``env``'s MuJoCo model (they become its nominal values).

    Args:
        env: any env :func:`sim2real.find_physics` understands.
        params: a :class:`sysid.FitResult` or a mapping ``{address: value}`` (e.g. ``result.params``).

    Returns:
        ``env`` itself. On composer envs (which recompile every reset) the values are written again after
        every recompile.
    """
    from randomizers.parameters import ParameterSet

    values = getattr(params, "params", params)
    if not isinstance(values, Mapping) or not values:
        raise TypeError(
            f"`params` must be a sysid.FitResult or a non-empty mapping {{address: value}}. Received {params!r}."
        )
    handle = find_physics(env)
    if handle is None:
        raise TypeError(f"`env` of type {type(env).__name__} has no MuJoCo model to calibrate.")
    addresses = list(values)
    vector = np.array([float(values[a]) for a in addresses])

    def write(model: mujoco.MjModel) -> None:
        space = ParameterSet(model, addresses)  # values are written as given: no bounds, fake or real
        space.write(model, dict(zip(addresses, vector, strict=True)))

    write(handle.model)
    if handle.recompiles:
        handle.on_recompile(lambda model, data: write(model))
    return env
