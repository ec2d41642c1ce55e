"""Recording trajectory logs for system identification, and calibrated environments.

* :func:`parse_set` turns ``'dof_damping[*]=*1.3'`` (scale), ``'+0.1'`` (add) or ``'=0.5'`` (set) into an effect.
* :func:`record` runs an excitation policy open loop on a task's model (optionally perturbed, with action
  latency and sensor noise) and returns a :class:`sysid.TrajectoryLog` — what ``sim2real record`` writes.
* :func:`parse_obs_noise` reads ``--obs-noise``: one sigma, or per channel and per joint
  (``'qpos=0.001,qpos[lift]=0.0001,qvel=0.01'``).
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

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from noise_models.timing import ActionLatency, ObservationLatency, convert_time
from randomizers import Effect, PhysicsRandomizer
from randomizers.addressing import joint_dofs, select
from randomizers.parameters import effect_for, parse_assignment
from sim2real.calibration import calibrate
from sim2real.home import parse_home, plan_excitation, resolve_home
from sim2real.physics import PhysicsHandle, find_physics
from sim2real.sources import Source, open_source, parse_source_id

__all__ = ["OBS_NOISE_FORMS", "ObsNoise", "RecordTrajectory", "calibrate", "parse_obs_noise", "parse_set", "record"]

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


#: What ``--obs-noise`` accepts (quoted by every refusal).
OBS_NOISE_FORMS = (
    "S (every channel) or comma-separated entries CHANNEL=S or CHANNEL[JOINT]=S, later entries overriding earlier "
    "ones (CHANNEL: qpos, qvel or sensordata; JOINT, for qpos and qvel only: a hinge or slide joint's name or an "
    "fnmatch pattern; S: a standard deviation >= 0 in the entry's units, rad or m for qpos, rad/s or m/s for qvel)"
)
_NOISE_CHANNELS = ("qpos", "qvel", "sensordata")
_NOISE_ENTRY = re.compile(r"^(?P<channel>[A-Za-z_]\w*)(?:\[(?P<joints>.*)\])?$")


def _obs_noise_error(problem: str, text: str) -> ValueError:
    return ValueError(f"`--obs-noise` {problem}; it must be {OBS_NOISE_FORMS}. Received {text!r}.")


@dataclass(frozen=True)
class ObsNoise:
    """A parsed ``--obs-noise`` spec: its entries in order, each ``(channel, joints, std)``.

    ``channel`` is None for a bare number (every channel), ``joints`` the fnmatch pattern of a per-joint entry
    (else None). :meth:`resolve` turns it into :func:`sysid.record_log`'s ``noise_std`` for one model.
    """

    text: str
    entries: tuple[tuple[str | None, str | None, float], ...]

    def resolve(self, model: mujoco.MjModel) -> float | dict[str, np.ndarray]:
        """One sigma (a spec that is a single number, drawn exactly as a float ``obs_noise``), else per channel
        one sigma per entry: ``{"qpos": (nq,), "qvel": (nv,), "sensordata": (nsensordata,)}``.

        Raises:
            ValueError: a pattern matches no joint, or matches a ball or free joint (their qpos holds a
                quaternion, on which independent Gaussian noise is no rotation error; give the whole channel).
        """
        if len(self.entries) == 1 and self.entries[0][0] is None:
            return self.entries[0][2]
        sigma = {
            "qpos": np.zeros(model.nq),
            "qvel": np.zeros(model.nv),
            "sensordata": np.zeros(model.nsensordata),
        }
        for channel, joints, std in self.entries:
            if channel is None:
                for array in sigma.values():
                    array[:] = std
            elif joints is None:
                sigma[channel][:] = std
            else:
                try:
                    chosen = select(model, "joint", joints, "--obs-noise")
                except ValueError as err:
                    raise ValueError(f"{err} It must be {OBS_NOISE_FORMS}. Received {self.text!r}.") from None
                for j, name in chosen:
                    if joint_dofs(model, j) > 1:
                        kind = "free" if joint_dofs(model, j) == 6 else "ball"
                        raise _obs_noise_error(
                            f"entry {channel}[{joints}] matches {kind} joint {name!r}, whose qpos holds a "
                            "quaternion (independent Gaussian noise on it is no rotation error): per-joint entries "
                            f"take hinge and slide joints only, so narrow the pattern or give the whole channel "
                            f"({channel}=S)",
                            self.text,
                        )
                    start = int(model.jnt_qposadr[j] if channel == "qpos" else model.jnt_dofadr[j])
                    sigma[channel][start] = std
        return sigma


def parse_obs_noise(text: str | float) -> ObsNoise:
    """``--obs-noise``: one sigma for every logged channel (``'0.01'``), or comma-separated ``CHANNEL=S`` and
    ``CHANNEL[JOINT]=S`` entries, later ones overriding earlier ones (``'qpos=0.001,qpos[lift]=0.0001'``).

    CHANNEL is ``qpos``, ``qvel`` or ``sensordata``; JOINT (qpos and qvel only) is a hinge or slide joint's name
    or an fnmatch pattern, and S its standard deviation in the entry's units: rad and rad/s for a hinge, m and
    m/s for a slide. A whole-channel entry (``qpos=S``) also noises a ball or free joint's quaternion entries
    with independent Gaussian noise (the log then holds non-unit quaternions); per-joint entries refuse ball and
    free joints. Joint patterns are resolved against the model by :meth:`ObsNoise.resolve`.

    Example:
        >>> parse_obs_noise("qpos=0.001, qvel[elbow*]=0.02").entries
        (('qpos', None, 0.001), ('qvel', 'elbow*', 0.02))
        >>> parse_obs_noise("qpso=0.1")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: `--obs-noise` entry 'qpso=0.1' names unknown channel 'qpso'; it must be S (every channel) ...
    """
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        text = repr(float(text))
    if not isinstance(text, str):
        raise _obs_noise_error(f"must be a string or a number, not {type(text).__name__}", repr(text))
    if not text.strip():
        raise _obs_noise_error("is empty", text)
    entries: list[tuple[str | None, str | None, float]] = []
    for raw in text.split(","):
        entry = raw.strip()
        if "=" in entry:
            left, _, value_text = entry.partition("=")
            match = _NOISE_ENTRY.match(left.strip())
            if match is None or (match["joints"] is not None and not match["joints"].strip()):
                raise _obs_noise_error(f"entry {entry!r} is not S, CHANNEL=S or CHANNEL[JOINT]=S", text)
            channel, joints = match["channel"], match["joints"]
            if channel not in _NOISE_CHANNELS:
                raise _obs_noise_error(f"entry {entry!r} names unknown channel {channel!r}", text)
            if joints is not None and channel == "sensordata":
                raise _obs_noise_error(f"entry {entry!r} names joints, which only qpos and qvel entries take", text)
        else:
            channel, joints, value_text = None, None, entry
        try:
            value = float(value_text)
        except ValueError:
            raise _obs_noise_error(f"entry {entry!r} is not S, CHANNEL=S or CHANNEL[JOINT]=S", text) from None
        if not math.isfinite(value) or value < 0:
            raise _obs_noise_error(f"entry {entry!r} has standard deviation {value!r}, not a finite number >= 0", text)
        entries.append((channel, joints.strip() if joints is not None else None, value))
    return ObsNoise(text, tuple(entries))


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
    obs_noise: float | str = 0.0,
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
        obs_noise: standard deviation of Gaussian noise on the logged qpos, qvel and sensordata, or a
            ``--obs-noise`` spec per channel and joint (:func:`parse_obs_noise`:
            ``"qpos=0.001,qpos[lift]=0.0001,qvel=0.01"``); the log's ``meta["noise_std_per_entry"]`` holds the
            sigma of every column.
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
    if isinstance(obs_noise, str):
        noise_spec: ObsNoise | None = parse_obs_noise(obs_noise)  # before any work: a typo costs nothing
    elif (
        isinstance(obs_noise, (int, float))
        and not isinstance(obs_noise, bool)
        and math.isfinite(obs_noise)
        and obs_noise >= 0
    ):
        noise_spec = None
    else:
        raise ValueError(
            f"`obs_noise` must be a finite number >= 0 or an --obs-noise spec string ({OBS_NOISE_FORMS}). "
            f"Received {obs_noise!r}."
        )
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
    noise_std: float | dict[str, np.ndarray] = float(obs_noise) if noise_spec is None else 0.0
    if noise_spec is not None:
        try:
            noise_std = noise_spec.resolve(model)  # joint patterns, before the joint-limit check's episodes
        except ValueError:
            _close(env)
            raise
    sigmas = list(noise_std.values()) if isinstance(noise_std, dict) else [noise_std]
    noisy = any(bool(np.any(np.asarray(s) > 0)) for s in sigmas)
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
        noise_std=noise_std if noisy else None,
        rng=np.random.default_rng([seed, 0x10C]) if noisy else None,
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
