"""Excitation logs recorded on a condition's own environment: the "real" twin is one :class:`Condition`.

The study's twin (held-out parameters, actuator latency, sensor noise) is evaluated through
:meth:`Condition.make_env`; :func:`record_condition` records the excitation log for system identification
through *that same wrapped environment* (:class:`sim2real.recording.RecordTrajectory`), so what the fit sees
and what the policies are scored on cannot drift apart. Effects act as they do in evaluation (the latency
wrapper delays the actuator command; the log holds the command as sent). The condition's sensor noise
(``ObservationNoise`` with one ``Gaussian`` process on every channel) is the encoders' noise: it is added to the
logged ``qpos``, ``qvel`` and ``sensordata``. Observation-side models that a state log cannot carry
(observation latency, sample-and-hold, other noise processes) are refused.

Example:
    >>> from sim2real.conditions import real
    >>> from noise_models import ActionLatency
    >>> twin = real([ActionLatency(seconds=0.04)], params={"dof_damping[shoulder]": 0.03})
    >>> log = record_condition("dmc/reacher-easy", twin, episodes=1, steps=20, seed=0)
    >>> log.qpos.shape, log.meta["true_latency_seconds"], log.meta["true_params"]["dof_damping[shoulder]"]
    ((20, 2), {'action': 0.04, 'obs': 0.0}, 0.03)
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from sim2real.conditions import Condition

__all__ = ["record_condition", "sensor_noise_std"]


def sensor_noise_std(condition: Condition) -> float:
    """The encoder noise of ``condition``: the std of its ``ObservationNoise(Gaussian)`` on every channel (0 without).

    Raises:
        ValueError: an observation-side model a state log cannot reproduce, named with the condition.
    """
    import noise_models
    from randomizers import Effect

    std = 0.0
    for model in condition.effects:
        if isinstance(model, (Effect, noise_models.ActionLatency, noise_models.ActionNoise)):
            continue  # physics and actuator-side models act on the recorded env itself
        if (
            isinstance(model, noise_models.ObservationNoise)
            and len(model.processes) == 1
            and isinstance(model.processes[0], noise_models.Gaussian)
            and model.select is None
            and not std
        ):
            std = float(model.processes[0].std)
            continue
        raise ValueError(
            f"condition {condition.name!r}: a state log can carry one ObservationNoise(Gaussian) on every channel "
            f"(the encoders' noise) besides physics and actuator-side models. Received {model!r}."
        )
    return std


def record_condition(
    task: str,
    condition: Condition,
    *,
    policy: str = "multisine",
    episodes: int = 4,
    steps: int = 200,
    seed: int = 0,
    amplitude: float = 0.5,
    task_options: dict[str, Any] | None = None,
) -> Any:
    """Records an open-loop excitation log on ``condition``'s environment (see the module docstring).

    Args:
        task: a task id (``sim2real tasks``) or a ``model:``/``env:`` id; its action must be the actuator command
            (action bounds equal to the actuators' control range).
        condition: a simulated condition, e.g. :func:`sim2real.evaluation.real` (the twin).
        policy: excitation signal, one of :data:`sysid.EXCITATIONS`.
        episodes: episodes; episode ``e`` starts from the env's reset for ``reset(seed=seed + e)``.
        steps: control steps per episode.
        seed: seeds the excitation, the condition's effects (as ``wrap(..., seed=seed)``) and the sensor noise.
        amplitude: excitation amplitude as a fraction of each actuator's half-range, in (0, 1].
        task_options: keyword arguments of :func:`sim2real.make`.

    Returns:
        A :class:`sysid.TrajectoryLog`; ``meta`` holds the draws of the condition (``true_params``: its ``params``
        and every reported value of the first episode), ``true_latency_seconds`` and ``noise_std``.
    """
    import gymnasium as gym

    import sysid
    from sim2real.recording import RecordTrajectory, control_limits

    for name, value, minimum in (("episodes", episodes, 1), ("steps", steps, 2)):
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise ValueError(f"`{name}` must be an int >= {minimum}. Received {value!r}.")
    std = sensor_noise_std(condition)
    env = condition.make_env(task, seed=seed, **(task_options or {}))
    recorder = RecordTrajectory(env, task=task)
    try:
        model = recorder.handle.model
        low, high = control_limits(model)
        space = recorder.action_space
        if not (
            isinstance(space, gym.spaces.Box)
            and space.shape == (model.nu,)
            and np.allclose(space.low, low)
            and np.allclose(space.high, high)
        ):
            raise ValueError(
                f"`task` {task!r}: record_condition drives the actuators through the action, which needs an action "
                f"equal to the actuator command (bounds {low.tolist()}..{high.tolist()}). Received action space {space}."
            )
        dt = float(model.opt.timestep) * (recorder.handle.substeps or 1)
        excitation = sysid.make_excitation(policy, (low, high), amplitude=amplitude, seed=seed)
        reported: dict[str, float] = {}
        for e in range(episodes):
            _, info = recorder.reset(seed=seed + e)
            if e == 0:
                reported = dict(info.get("sim2real", {}).get("params", {}))
            for action in excitation.signal(steps, dt, t0=e * steps * dt).astype(space.dtype):
                recorder.step(action)
        log = recorder.to_log()
    finally:
        recorder.close()
    measured: dict[str, Any] = {}
    if std > 0:
        rng = np.random.default_rng([seed, 0x7A1])
        for key in ("qpos", "qvel", "sensordata"):
            clean = getattr(log, key)
            if clean is not None:
                measured[key] = clean + rng.normal(0.0, std, size=clean.shape)
    true_params = {**{str(k): float(v) for k, v in (condition.params or {}).items()}, **reported}
    meta = {
        **log.meta,
        "true_params": true_params,
        "true_latency_seconds": {"action": float(reported.get("action_latency", 0.0)), "obs": 0.0},
        "noise_std": {"qpos": std, "qvel": std, "sensordata": std},
        "excitation": {"policy": policy, "amplitude": float(amplitude), "condition": condition.name},
    }
    return replace(log, **measured, meta=meta)
