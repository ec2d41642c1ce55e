"""Recording trajectory logs for system identification, and calibrated environments.

* :func:`parse_set` turns ``'dof_damping[*]=*1.3'`` (scale), ``'+0.1'`` (add) or ``'=0.5'`` (set) into an effect.
* :func:`record` runs an excitation policy open loop on a task's model (optionally perturbed, with action
  latency and sensor noise) and returns a :class:`sysid.TrajectoryLog` — what ``sim2real record`` writes.
* :class:`RecordTrajectory` records any gymnasium MuJoCo env step by step (closed loop, any policy).
* :func:`calibrate` writes fitted values (a :class:`sysid.FitResult` or ``{address: value}``) into an env's model;
  ``sim2real.make(task, params=result)`` uses it.

Example:
    >>> import sim2real as s2r
    >>> parse_set("dof_damping[*]=*1.3")
    Damping(scale=Constant(value=1.3), joints='*')
    >>> log = record("dmc/reacher-easy", sets=["dof_damping[*]=*1.5"], policy="multisine", episodes=2, steps=50, seed=0)
    >>> log.qpos.shape, round(log.meta["true_params"]["dof_damping[shoulder]"], 6)
    ((100, 2), 0.015)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from noise_models.timing import ActionLatency, ObservationLatency, convert_time
from randomizers import Effect, PhysicsRandomizer
from randomizers.parameters import effect_for, parse_assignment
from sim2real.calibration import calibrate
from sim2real.home import parse_home, plan_excitation, resolve_home
from sim2real.physics import PhysicsHandle, find_physics
from sim2real.sources import Source, open_source, parse_source_id

__all__ = ["RecordTrajectory", "calibrate", "parse_set", "record"]

# `calibrate` lives beside the physics handle (sim2real.calibration); re-exported here, where it used to be.

def parse_set(text: str) -> Effect:
    """An effect from ``ADDRESS=*X`` (scale), ``ADDRESS=+X`` (add) or ``ADDRESS=X`` (set)
    (:func:`randomizers.parameters.parse_assignment`, then :func:`randomizers.parameters.effect_for`).

    Example:
        >>> parse_set("geom_friction[finger*][0]=0.8")
        Friction(set=Constant(value=0.8), geoms='finger*')
        >>> parse_set("dof_damping=*2")
        Traceback (most recent call last):
        ...
        ValueError: `--set` must look like 'dof_damping[*]=*1.3' (scale), 'dof_damping[*]=+0.1' (add) or \
'dof_damping[*]=0.5' (set). Received 'dof_damping=*2'.
    """
    return effect_for(*parse_assignment(text))


def control_limits(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of every actuator's control: its ``ctrlrange`` where limited, else [-1, 1]."""
    low = np.where(model.actuator_ctrllimited.astype(bool), model.actuator_ctrlrange[:, 0], -1.0)
    high = np.where(model.actuator_ctrllimited.astype(bool), model.actuator_ctrlrange[:, 1], 1.0)
    return low, high


def record(
    task: str | Source,
    *,
    sets: Sequence[str] = (),
    effects: Sequence[Any] = (),
    policy: str = "multisine",
    episodes: int = 4,
    steps: int = 200,
    seed: int = 0,
    obs_noise: float = 0.0,
    latency: int = 0,
    obs_latency: int = 0,
    amplitude: float = 0.5,
    home: str | Sequence[float] | None = None,
    gravity_comp: bool = False,
    progress: bool | None = None,
) -> Any:
    """Records an excitation log of ``task`` (exact physics through ``mujoco.rollout``).

    Args:
        task: a task id (``sim2real tasks``), a ``model:``/``env:`` id or a :class:`sim2real.sources.Source`
            (``--model robot.xml``, ``--env package.module:factory``); composer tasks are not supported (their
            model changes each reset).
        sets: perturbations in :func:`parse_set` form, applied to the model the log is recorded on.
        effects: perturbations as effect objects (e.g. ``FitResult.to_effects()``): physics effects are drawn
            once (seed ``seed``) and applied like ``sets``; an ``ActionLatency``/``ObservationLatency`` with a
            fixed ``seconds``/``steps`` (physics steps) sets the latency, which must come to whole control steps
            (the open-loop recorder delays by control steps); other models are refused.
        policy: excitation signal, one of :data:`sysid.EXCITATIONS` (``random``, ``multisine``, ``chirp``, ``prbs``).
        episodes: episodes; each starts from the task's own reset state for ``reset(seed=seed + e)``.
        steps: control steps per episode.
        seed: seeds the excitation, the initial states and the sensor noise.
        obs_noise: standard deviation of Gaussian noise on the logged qpos, qvel and sensordata.
        latency: action latency in **control steps** (the actuators apply ``ctrl[t - latency]``).
        obs_latency: sensor latency in **control steps** (``sensordata`` lags the state).
        amplitude: excitation amplitude as a fraction of each actuator's half-range, in (0, 1].
        home: where episodes start and what the excitation swings around: ``"current"`` (the env's own reset
            state for ``reset(seed=seed + e)``, servos centred on the middle of their range: the default for task
            ids), ``"keyframe"`` (the keyframe named ``home``, else the first, else ``qpos0``: the default for
            models and env factories) or explicit joint positions. With a fixed home pose servos swing around
            it, and the amplitude is halved until every limited joint stays inside its range
            (:func:`sim2real.home.plan_excitation`); ``meta["excitation"]["notes"]`` says when.
        gravity_comp: add the torque that holds the arm against gravity at its current pose to the torque
            motors' commands (needs a fixed home pose); the logged ``ctrl`` is what was sent.
        progress: a progress bar on stderr (episodes simulated for the joint-limit check, then the recording);
            None shows it when stderr is a terminal.

    Returns:
        A :class:`sysid.TrajectoryLog` whose ``meta`` holds the task, the true parameter values of every
        perturbed address, the true latencies and the excitation (home pose, amplitude used, notes).
    """
    import sysid
    from sim2real.tasks import make

    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"`episodes` must be an int >= 1. Received {episodes!r}.")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 2:
        raise ValueError(f"`steps` must be an int >= 2. Received {steps!r}.")
    if not (isinstance(obs_noise, (int, float)) and obs_noise >= 0):
        raise ValueError(f"`obs_noise` must be a number >= 0. Received {obs_noise!r}.")
    physical = [parse_set(s) for s in sets]
    latencies: list[Any] = []
    for i, item in enumerate(effects):
        if isinstance(item, Effect):
            physical.append(item)
        elif isinstance(item, (ActionLatency, ObservationLatency)):
            latencies.append(item)
        else:
            raise TypeError(
                f"`effects[{i}]` must be a physics effect or an ActionLatency/ObservationLatency. Received {item!r}."
            )
    source = task if isinstance(task, Source) else parse_source_id(task)
    chosen = parse_home(home)
    if chosen is None:
        chosen = "current" if source.kind == "task" else "keyframe"
    if gravity_comp and chosen == "current":
        raise ValueError("`gravity_comp` needs a fixed home pose: give home='keyframe' or joint positions.")
    if source.kind == "task":
        env: Any = make(source.value)
        handle = _require(env, source.value)
    else:
        env, handle = open_source(source)
    if handle.recompiles:
        _close(env)
        raise ValueError(
            f"`task` {source.label!r} recompiles its model every episode; record a dm-control suite, gym or "
            "sim2real task, an MJCF file or an env factory."
        )
    substeps = handle.substeps or 1
    for model_ in latencies:
        delay = _control_steps(model_, float(handle.model.opt.timestep), substeps)
        if isinstance(model_, ActionLatency):
            latency = delay
        else:
            obs_latency = delay
    effects = physical
    starts = []
    if chosen == "current":
        for e in range(episodes):
            if isinstance(env, gym.Env):
                env.reset(seed=seed + e)
            elif e == 0 and callable(getattr(env, "reset", None)):
                env.reset()  # dm_env / TorchRL: their own reset state, the same for every episode
            starts.append((np.array(handle.data.qpos), np.array(handle.data.qvel)))
    model = handle.model
    true_params: dict[str, float] = {}
    if effects:
        randomizer = PhysicsRandomizer(effects, seed=seed)
        randomizer.bind(model, handle.data)
        randomizer.begin_episode()
        randomizer.apply()
        true_params = dict(randomizer.current_params)
        model = _copy_model(model)
        randomizer.restore_nominal()
    dt = float(model.opt.timestep) * substeps
    excitation_meta: dict[str, Any] = {"policy": policy, "amplitude": float(amplitude), "gravity_comp": gravity_comp}
    bar = _bar(progress)
    try:
        if chosen == "current":
            excitation = sysid.make_excitation(policy, control_limits(model), amplitude=amplitude, seed=seed)
            ctrl = np.stack([excitation.signal(steps, dt, t0=e * steps * dt) for e in range(episodes)])
            excitation_meta.update(home="current", notes=[])
        else:
            pose = resolve_home(chosen, model)
            plan = plan_excitation(
                model, pose, policy=policy, amplitude=amplitude, steps=steps, episodes=episodes, substeps=substeps,
                seed=seed, gravity_comp=gravity_comp, latency=latency, tick=lambda: bar.update(1),
            )
            ctrl = plan.ctrl
            starts = [(plan.home, np.zeros(model.nv))] * episodes
            excitation_meta.update(
                home=plan.home.tolist(), amplitude=plan.amplitude, requested_amplitude=plan.requested,
                notes=list(plan.notes),
            )
    except ValueError:
        bar.close()
        _close(env)
        raise
    bar.set_postfix_str(f"recording {episodes} episode(s)")
    log = sysid.record_log(
        model,
        ctrl,
        n_substeps=substeps,
        initial_qpos=np.stack([q for q, _ in starts]),
        initial_qvel=np.stack([v for _, v in starts]),
        action_latency=latency,
        obs_latency=obs_latency,
        noise_std=obs_noise if obs_noise > 0 else None,
        rng=np.random.default_rng([seed, 0x10C]) if obs_noise > 0 else None,
        task=source.id,
        true_params=true_params,
    )
    bar.update(episodes)
    bar.close()
    _close(env)
    return replace(log, meta={**log.meta, "excitation": excitation_meta})


def _bar(progress: bool | None) -> Any:
    """The progress bar of :func:`record` (tqdm on stderr; disabled unless asked for or stderr is a terminal)."""
    import sys

    from tqdm import tqdm

    show = sys.stderr.isatty() if progress is None else bool(progress)
    return tqdm(desc="record", unit="episode", file=sys.stderr, disable=not show, leave=False)


def _close(env: Any) -> None:
    close = getattr(env, "close", None)
    if callable(close):
        close()


def _control_steps(model: Any, timestep: float, substeps: int) -> int:
    """A fixed latency model's delay in whole control steps (what the open-loop recorder can reproduce)."""
    if model.jitter is not None or not isinstance(model.steps if model.steps is not None else model.seconds, float):
        raise ValueError(f"`effects` may hold only fixed latencies without jitter. Received {model!r}.")
    if model.steps is not None:
        control = convert_time(model.steps, "physics_steps", "control_steps", timestep=timestep, substeps=substeps)
    else:
        control = convert_time(model.seconds, "seconds", "control_steps", timestep=timestep, substeps=substeps)
    if abs(control - round(control)) > 1e-6:
        raise ValueError(
            f"`effects` latency {model!r} is {control:g} control steps ({substeps} physics steps each); the open-loop "
            "recorder delays by whole control steps."
        )
    return round(control)


def _copy_model(model: mujoco.MjModel) -> mujoco.MjModel:
    import copy

    return copy.copy(model)


def _require(env: Any, task: str) -> PhysicsHandle:
    handle = find_physics(env)
    if handle is None:
        raise ValueError(f"`task` {task!r} has no MuJoCo model to record.")
    return handle


class RecordTrajectory(gym.Wrapper):
    """Records a gymnasium MuJoCo env step by step into a :class:`sysid.TrajectoryLog` (any policy, closed loop).

    Row ``t`` holds the true state before control step ``t`` (``time``, ``qpos``, ``qvel``, ``sensordata``),
    the observation the policy acted on, and the actuator command the env issued for that step (read when
    the physics step starts, so an outer latency model does not hide it). Put noise or latency models
    inside (``RecordTrajectory(sim2real.wrap(env, ...))``) to record a "real" twin.

    Example:
        >>> import sim2real as s2r
        >>> env = RecordTrajectory(s2r.make("dmc/reacher-easy"))
        >>> obs, _ = env.reset(seed=0)
        >>> for _ in range(5):
        ...     obs, *_ = env.step(env.action_space.sample())
        >>> env.to_log().qpos.shape
        (5, 2)
    """

    def __init__(self, env: gym.Env, task: str = "") -> None:
        super().__init__(env)
        handle = find_physics(env)
        if handle is None:
            raise TypeError(f"`env` of type {type(env).__name__} has no MuJoCo model to record.")
        self.handle = handle
        self.task = task
        self._rows: dict[str, list[np.ndarray]] = {k: [] for k in ("time", "qpos", "qvel", "ctrl", "sensordata", "obs")}
        self._episode: list[int] = []
        self._episodes = -1
        self._obs: Any = None
        self._command: np.ndarray | None = None
        self._first = False
        self._remove: Any = None
        try:
            self._remove = handle.intercept_step(self._capture)
        except TypeError:
            self._remove = None  # fall back to the ctrl left after the step
        self.true_params: dict[str, float] = {}

    def _capture(self, run: Any, nstep: int, runner: Any = None) -> None:
        if self._first:
            self._command = np.array(self.handle.data.ctrl)
            self._first = False
        run(nstep)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._episodes += 1
        self._obs = obs
        if self._episodes == 0:
            self.true_params = dict(info.get("sim2real", {}).get("params", {}))
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        data = self.handle.data
        state = (float(data.time), np.array(data.qpos), np.array(data.qvel), np.array(data.sensordata))
        self._first = True
        self._command = None
        result = self.env.step(action)
        command = self._command if self._command is not None else np.array(data.ctrl)
        rows = self._rows
        for key, value in zip(("time", "qpos", "qvel", "sensordata"), state, strict=True):
            rows[key].append(np.asarray(value))
        rows["ctrl"].append(command)
        rows["obs"].append(np.array(self._obs, dtype=np.float64).ravel())
        self._episode.append(self._episodes)
        self._obs = result[0]
        return result

    def to_log(self) -> Any:
        """The rows recorded so far as a validated :class:`sysid.TrajectoryLog`."""
        import sysid

        if not self._rows["time"]:
            raise ValueError("nothing recorded yet: call reset() and step() first.")
        model = self.handle.model
        substeps = self.handle.substeps or 1
        names = sysid.channel_names(model)
        arrays = {k: np.array(v) for k, v in self._rows.items()}
        episode = np.array(self._episode)
        time = arrays["time"]
        return sysid.TrajectoryLog(
            time=time,
            qpos=arrays["qpos"],
            qvel=arrays["qvel"],
            ctrl=arrays["ctrl"],
            sensordata=arrays["sensordata"] if model.nsensordata else None,
            obs=arrays["obs"],
            episode=episode if episode.max() > 0 else None,
            meta={
                "task": self.task,
                "timestep": float(model.opt.timestep),
                "control_timestep": float(model.opt.timestep) * substeps,
                "joint_names": [
                    mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}" for j in range(model.njnt)
                ],
                "actuator_names": [n[5:-1] if n.startswith("ctrl[") else n for n in names["ctrl"]],
                "sensor_names": names["sensordata"],
                "true_params": self.true_params,
            },
        )

    def close(self) -> None:
        if self._remove is not None:
            self._remove()
            self._remove = None
        super().close()
