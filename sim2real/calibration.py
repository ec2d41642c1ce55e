"""Calibration: fitted parameter values written into an env's MuJoCo model as its new nominal values.

It sits beside the physics handle (:mod:`sim2real.physics`) and below the task registry, so ``sim2real.make(task,
params=fit)`` reaches it without importing recording, pixels or the wrappers. :func:`noise_select` says where a fit's
position and velocity noise go in an env's observation, for ``FitResult.to_effects(noise_select=...)``.

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

__all__ = ["calibrate", "noise_select"]


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


#: Observation part names that hold the model's ``qpos`` / ``qvel`` (checked by size too).
_PARTS = {"qpos": ("qpos", "position"), "qvel": ("qvel", "velocity")}


def noise_select(env: Any) -> dict[str, Any] | None:
    """Where a fit's ``qpos`` and ``qvel`` channels sit in ``env``'s observation, for
    :meth:`sysid.FitResult.to_effects` (``noise_select=``), or None when that is not known (the export then
    falls back to one noise level for the whole observation).

    Known: a :class:`~sim2real.mjcf_env.MjcfEnv` (``qpos`` then ``qvel``: index lists; one entry per joint, e.g.
    ``qpos[lift]``, when the joints differ in units: a slide's metres next to hinges' radians), and
    observations with named parts (dict spaces, dm-control's flattened parts) called ``qpos``/``position`` of the
    model's ``nq`` values or ``qvel``/``velocity`` of its ``nv``; wrappers must keep the base env's observation
    space.

    Example:
        >>> import sim2real as s2r
        >>> noise_select(s2r.make("dmc/reacher-easy"))
        {'qpos': 'position', 'qvel': 'velocity'}
        >>> noise_select(s2r.make("dmc/manipulator-bring_ball")) is None  # sines and cosines, not qpos
        True
    """
    import gymnasium as gym

    handle = find_physics(env)
    base = getattr(env, "unwrapped", None)
    if handle is None or not isinstance(base, gym.Env) or env.observation_space != base.observation_space:
        return None
    nq, nv = int(handle.model.nq), int(handle.model.nv)
    from sim2real.mjcf_env import MjcfEnv

    if isinstance(base, MjcfEnv):
        return _by_joint(handle.model) or {"qpos": list(range(nq)), "qvel": list(range(nq, nq + nv))}
    space = base.observation_space
    if isinstance(space, gym.spaces.Dict):
        parts = [(k, int(np.prod(sub.shape))) for k, sub in space.spaces.items() if sub.shape is not None]
    else:
        parts = [(k, sl.stop - sl.start) for k, sl, _ in getattr(base, "observation_layout", ())]
    out = {}
    for signal, size in (("qpos", nq), ("qvel", nv)):
        hits = [k for k, n in parts if k in _PARTS[signal] and n == size]
        if len(hits) == 1:
            out[signal] = hits[0]
    return out or None


def _by_joint(model: mujoco.MjModel) -> dict[str, list[int]] | None:
    """One ``{channel: indices}`` entry per joint of an :class:`~sim2real.mjcf_env.MjcfEnv`'s ``qpos`` and ``qvel``
    when slides (m) sit next to other joints (rad), else None. One level pooled over a linear axis and hinges
    exported the hinges' ~1e-3 rad as the noise of a slide whose encoder the fit measured at 1e-5 m (and biased the
    hinges' level). A free joint among hinges alone keeps the pooled levels (its position and quaternion are pooled
    either way)."""
    from sysid.logs import channel_names

    kinds = {int(t) for t in model.jnt_type}
    slide = int(mujoco.mjtJoint.mjJNT_SLIDE)
    if slide not in kinds or kinds == {slide}:
        return None
    names = channel_names(model)
    out: dict[str, list[int]] = {}
    for key, offset in (("qpos", 0), ("qvel", int(model.nq))):
        for index, channel in enumerate(names[key]):
            joint = channel.split("]")[0] + "]"  # 'qpos[puck][3]' -> 'qpos[puck]'
            out.setdefault(joint, []).append(offset + index)
    return out
