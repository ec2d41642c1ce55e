"""Sensor and actuator imperfections around any env: :class:`CorruptSignals` (gymnasium) and
:class:`CorruptSignalsDmEnv` (dm_env), both driven by a :class:`noise_models.SignalCorruptor`.

One wrapper carries every signal model (observation/action noise pipelines, latencies,
sample-and-hold, control jitter): they share one clock (physics steps since reset, read from
MuJoCo's ``data.time``), and one Python layer on the hot path costs less than one per model
(measured in ``benchmarks/bench_overhead.py``).

Where the env has MuJoCo inside, time counts physics steps and ``ActionLatency`` /
``ControlJitter`` act inside the env's physics step (dm-control ``Physics.step``, gymnasium's
``MujocoEnv._step_mujoco_simulation``, or a ``_simulate(nstep)`` method). Without MuJoCo, time
counts control steps, ``seconds=`` uses the env's ``dt`` when it has one, and ControlJitter is
rejected.

Reports: the per-episode draws join ``info["sim2real"]["params"]``; with ControlJitter,
``info["sim2real"]["substeps"]`` holds the physics substeps of the control step just taken.

Declared spaces are left unchanged: observation noise is clipped to finite bounds of the
observation space (dm-control and gymnasium MuJoCo observations are unbounded, so nothing is
clipped there) and action noise to the action space (``ActionNoise(clip=False)`` turns that off).

Example:
    >>> import sim2real
    >>> from noise_models import ActionLatency, Bias, Gaussian, ObservationLatency, ObservationNoise
    >>> from randomizers import Uniform
    >>> env = CorruptSignals(sim2real.make("dmc/reacher-easy"),
    ...                      [ObservationNoise(Gaussian(std=0.01), Bias(Uniform(-0.02, 0.02))),
    ...                       ObservationLatency(steps=3), ActionLatency(seconds=0.02)], seed=0)
    >>> obs, info = env.reset(seed=0)
    >>> params = info["sim2real"]["params"]
    >>> params["obs_latency_steps"], params["action_latency_steps"], round(params["obs_bias[0]"], 4)
    (3, 1, -0.0187)
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from types import MethodType
from typing import Any

import dm_env
import gymnasium as gym
import mujoco
import numpy as np

from noise_models import ActionLatency, ControlJitter, Layout, SignalCorruptor, SignalModel
from noise_models.seeding import SeedLike
from noise_models.timing import convert_time, elapsed_steps
from sim2real.physics import PhysicsHandle, find_physics
from sim2real.wrappers.dm import DmEnvWrapper

__all__ = [
    "CorruptSignals",
    "CorruptSignalsDmEnv",
    "NoCopy",
    "SignalClock",
    "action_delay_path",
    "box_layout",
    "wrong_action_shape",
]


def _finite_bounds(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    low = np.asarray(low, dtype=np.float64).ravel()
    high = np.asarray(high, dtype=np.float64).ravel()
    if not (np.isfinite(low).any() or np.isfinite(high).any()):
        return None, None
    return low, high


def box_layout(space: gym.spaces.Box, keys: tuple[tuple[str, slice, tuple[int, ...]], ...] = ()) -> Layout:
    """The :class:`noise_models.Layout` of a float Box space (bounds kept for clipping)."""
    if not np.issubdtype(space.dtype, np.floating):
        raise TypeError(f"noise models need a float Box space. Received a Box of dtype {space.dtype}.")
    low, high = _finite_bounds(space.low, space.high)
    return Layout(int(np.prod(space.shape)), keys=keys, low=low, high=high)


class _DictCodec:
    """Flattens a dict signal to one vector (key order) and back."""

    def __init__(self, shapes: Sequence[tuple[str, tuple[int, ...]]], mapping: type = dict) -> None:
        self.keys = [k for k, _ in shapes]
        self.shapes = dict(shapes)
        self.mapping = mapping
        slices, start = [], 0
        for k, shape in shapes:
            n = int(np.prod(shape))
            slices.append((k, slice(start, start + n), tuple(shape)))
            start += n
        self.layout_keys = tuple(slices)
        self.size = start

    def flat(self, obs: Any) -> np.ndarray:
        return np.concatenate([np.ravel(obs[k]) for k in self.keys])

    def unflat(self, vec: np.ndarray, like: Any) -> Any:
        out = self.mapping() if not isinstance(like, dict) else type(like)()
        for k, sl, shape in self.layout_keys:
            out[k] = vec[sl].reshape(shape)
        return out


class NoCopy:
    """Refuses pickling and deep copies with a message that says what to do instead; a shallow ``copy.copy`` (what
    TorchRL's ``Transform.clone`` makes) shares everything and stays allowed."""

    def __copy__(self) -> Any:
        cls = type(self)
        twin = cls.__new__(cls)
        twin.__dict__.update(self.__dict__)
        for name, value in self.__dict__.items():  # a one-shot first-step check answers to the copy
            if isinstance(value, MethodType) and value.__self__ is self:
                twin.__dict__[name] = MethodType(value.__func__, twin)
        return twin

    def __deepcopy__(self, memo: Any) -> Any:
        self.__reduce_ex__(4)

    def __reduce_ex__(self, protocol: Any) -> Any:
        # A copy would share what no copy can own: the per-episode noise closures hold the original's generators
        # and buffers (copy.deepcopy keeps functions as they are), and the physics-step hook is installed on the env
        # as a closure over the original's clock.
        raise TypeError(
            f"{type(self).__name__} cannot be pickled or deep-copied: its signal models run in closures over its own "
            "random streams and its physics-step hook is installed on the env it wraps. Make another with the same "
            "models and seed instead (gymnasium.make(env.spec), or sim2real.wrap(new_env, *effects, seed=seed)): "
            "draws are keyed by the seed, so its episodes match."
        )


class SignalClock(NoCopy):
    """Connects a :class:`SignalCorruptor` to an env's physics: layouts are given by the wrapper,
    this finds MuJoCo, sets the time base, and intercepts physics stepping when needed.

    Args:
        env: the env to find MuJoCo in (may have none).
        corruptor: the engine (not yet bound).
        obs: observation layout; action: action layout; dtypes of both signals.
        handle: the physics handle when the caller found it already.
        repeat: how many times ``env`` steps with each action (TorchRL's own action repeat: a
            ``GymWrapper(..., frame_skip=2)`` runs the wrapped env's step twice per control step), so a control
            step is ``repeat`` times the physics steps of one step of the env that holds the model.
    """

    def __init__(
        self,
        env: Any,
        corruptor: SignalCorruptor,
        obs: Layout | None,
        action: Layout | None,
        obs_dtype: Any,
        action_dtype: Any,
        handle: PhysicsHandle | None = None,
        repeat: int = 1,
    ) -> None:
        self.corruptor = corruptor
        self.handle = handle if handle is not None else find_physics(env)
        handle = self.handle
        if handle is not None:
            timestep: float | None = float(handle.model.opt.timestep)
            substeps = (handle.substeps or 1) * repeat
        else:
            timestep = _control_dt(env)
            substeps = 1
        self.timestep = timestep
        #: seconds per physics step (only read when a MuJoCo handle exists, where it is the model's timestep)
        self.physics_dt: float = timestep if timestep is not None else 1.0
        self.nominal = substeps
        #: Where ActionLatency acts: "ctrl" (the actuator command, at physics rate), "action" (the policy's
        #: action, by whole control steps) or None without ActionLatency. See :func:`action_delay_path`.
        self.action_path: str | None = None
        if ActionLatency in corruptor.timing:
            self.action_path = "action" if handle is None else action_delay_path(handle.model, action)
            if handle is not None and self.action_path == "action" and handle.substeps is None:
                # Physics steps per action are needed to delay actions by the drawn physics-step latency.
                dt = _control_dt(env)
                if dt is None or timestep is None:
                    raise TypeError(
                        "ActionLatency delays this env's action (it does not map onto `ctrl`), which needs the "
                        "physics steps per action: give the env a `frame_skip` (or `n_substeps`) attribute or a "
                        f"`dt`. Received an env of type {type(env).__qualname__} with neither."
                    )
                substeps = max(1, round(convert_time(dt, "seconds", "physics_steps", timestep=timestep))) * repeat
                self.nominal = substeps
        corruptor.bind(
            obs=obs,
            action=action,
            timestep=timestep,
            substeps=substeps,
            physics=handle is not None,
            obs_dtype=obs_dtype,
            action_dtype=action_dtype,
            action_delay=self.action_path or "ctrl",
        )
        self._remove: Any = None
        self._hook: Any = None
        if handle is not None and handle.recompiles:
            self._hook = handle.on_recompile(lambda model, data: None)  # keeps handle.data current
        if corruptor.needs_physics_hook:
            self._remove = handle.intercept_step(self._stepper, self._direct)  # type: ignore[union-attr]
        self._latency = corruptor.has_action and handle is not None and self.action_path != "action"
        # Composer steps one substep at a time and its hooks may rewrite ctrl between substeps.
        self._whole_steps = handle is not None and not handle.recompiles
        self._fixed = self._latency and ControlJitter not in corruptor.timing
        self._in_step = False
        self._passed = 0
        self._target = substeps
        self._t0 = 0.0
        self._control = 0
        # Set per episode (begin_episode) when the latency is whole control steps: the command ring's rows and
        # ``data.ctrl`` (as memoryviews) and the commands sent so far.
        self._ring: list[memoryview] | None = None
        self._ctrl: memoryview = memoryview(b"")
        self._sent = 0

    @property
    def hooked(self) -> bool:
        """Whether the env's physics stepping is intercepted (physics-rate ActionLatency, ControlJitter)."""
        return self._remove is not None

    def check_reached(self) -> bool:
        """Right after a control step of an env whose stepping is intercepted: True when the step went through the
        hook, False when its physics did not advance (nothing to tell yet).

        Raises:
            TypeError: the physics advanced without the hook (an env whose ``step`` calls ``mujoco.mj_step``
                itself instead of ``do_simulation``/``_simulate``): what is reported would not be applied.
        """
        if self._passed:
            return True
        if self.now() == 0:
            return False
        owner = self.handle.owner  # type: ignore[union-attr]
        hook = "_simulate(nstep)" if callable(getattr(owner, "_simulate", None)) else "do_simulation(ctrl, n_frames)"
        timing = self.corruptor.timing
        names = ["ActionLatency"] if ActionLatency in timing and self.action_path == "ctrl" else []
        names += ["ControlJitter"] if ControlJitter in timing else []
        raise TypeError(
            f"{type(owner).__module__}.{type(owner).__qualname__} advanced its physics without calling {hook}, so "
            f"{' and '.join(names)} (acting inside that call) would be reported but not applied. Step MuJoCo "
            f"through {hook} in the env's `step`."
        )

    def now(self) -> int:
        """Time since reset: physics steps with MuJoCo, else control steps."""
        if self.handle is None:
            return self._control
        return elapsed_steps(self._t0, self.handle.data.time, self.physics_dt)

    def begin_episode(self) -> None:
        """Call right after the env's reset."""
        self._control = 0
        self._ring = None
        if self.handle is not None:
            if self.handle.rebuilt() and self._remove is not None:
                # The env compiled a new model in its reset: the physics-step interception moves to it.
                self._remove()
                self._remove = self.handle.intercept_step(self._stepper, self._direct)
            data = self.handle.data
            self._t0 = float(data.time)
            c = self.corruptor
            c.reset_commands(np.array(data.ctrl))
            if c.command_lag is not None and self._whole_steps and self._remove is not None:
                # Latency of whole control steps: the episode's ring rows and ``data.ctrl`` looked up once (an
                # env that does not recompile keeps its MjData), each step then copies two rows. As memoryviews
                # (float64, contiguous, the same shape): a slice assignment copies the bytes for half what numpy's
                # ``x[...] = y`` costs on a few floats, the same values.
                self._ring = [memoryview(row) for row in c.command_ring]
                self._ctrl = memoryview(data.ctrl)
                self._sent = 0

    def begin_step(self) -> None:
        self._control += 1
        self._passed = 0
        self._in_step = True

    def _direct(self, run: Any, runner: Any) -> Any:
        """dm-control's ``Physics.step`` as one function (see ``PhysicsHandle.intercept_step``): a latency of whole
        control steps (the episode's command ring, set by begin_episode) handled in it, the rest by
        :meth:`_stepper`."""
        stepper = self._stepper

        def step(nstep: int = 1) -> None:
            ring = self._ring
            if ring is None or not self._in_step:
                stepper(run, nstep, runner)
                return
            if self._passed == 0:  # as in _stepper
                ctrl = self._ctrl
                k = self._sent
                self._sent = k + 1
                size = len(ring)
                ring[k % size][:] = ctrl
                ctrl[:] = ring[(k + 1) % size]
            else:  # as in _stepper
                self._ctrl[:] = ring[self._sent % len(ring)]
            self._passed += nstep
            run(nstep)

        return step

    def _stepper(self, run: Any, nstep: int, runner: Any = None) -> None:
        if not self._in_step:  # physics stepped outside a control step (e.g. inside reset)
            run(nstep)
            return
        ring = self._ring
        if ring is not None:
            # Latency of whole control steps (set up by begin_episode): apply the command sent ``lag`` control
            # steps ago; ``ring`` holds the last ``lag + 1`` commands, all the reset command at first.
            if self._passed == 0:
                ctrl = self._ctrl
                k = self._sent
                self._sent = k + 1
                size = len(ring)
                ring[k % size][:] = ctrl  # memoryviews: a byte copy
                ctrl[:] = ring[(k + 1) % size]
            else:
                # A later call in the same control step (TorchRL's frame_skip steps the env again, and its step writes
                # the undelayed action to ctrl): the command of this control step again.
                self._ctrl[:] = ring[self._sent % len(ring)]
            self._passed += nstep
            run(nstep)
            return
        if self._fixed:  # latency without control jitter: the substeps asked for are the substeps run
            data = self.handle.data  # type: ignore[union-attr]
            start = elapsed_steps(self._t0, data.time, self.physics_dt)
            if self._passed == 0:
                pieces = self.corruptor.command_segments(data.ctrl, start, nstep)
            else:
                pieces = self.corruptor.continue_segments(start, nstep)
            self._passed += nstep
            if len(pieces) == 1:
                data.ctrl[:] = pieces[0][0]
                run(nstep)
            else:
                runner.split(pieces)
            return
        corruptor = self.corruptor
        first = self._passed == 0
        if first:
            self._target = corruptor.substeps(self.nominal)
        nominal = self.nominal
        before = self._passed * self._target // nominal
        self._passed += nstep
        k = self._passed * self._target // nominal - before
        if k <= 0:
            return
        if not self._latency:
            run(k)
            return
        data = self.handle.data  # type: ignore[union-attr]
        start = self.now()
        pieces = corruptor.command_segments(data.ctrl, start, k) if first else corruptor.continue_segments(start, k)
        if len(pieces) == 1:
            data.ctrl[:] = pieces[0][0]
            run(k)
        else:
            runner.split(pieces)

    def close(self) -> None:
        if self._remove is not None:
            self._remove()
            self._remove = None
        if self._hook is not None and self.handle is not None:
            self.handle.remove_hook(self._hook)
            self._hook = None


def action_delay_path(model: Any, action: Layout | None) -> str:
    """Where ActionLatency must act on an env with MuJoCo inside: ``"ctrl"`` when the env's action is
    its actuator command, ``"action"`` when it is not.

    The action does not map onto ``ctrl`` when its size differs from ``model.nu``, or when a mocap
    body is welded to the robot: such envs move the hand by writing ``data.mocap_pos``/``mocap_quat``
    in their own Python ``step``, which a physics-rate ``ctrl`` delay never reaches (only a gripper
    on ``ctrl`` would be delayed). There the policy's action is delayed instead, by whole control steps.
    """
    if action is None or action.size != model.nu:
        return "action"
    weld = int(mujoco.mjtEq.mjEQ_WELD)
    site = int(mujoco.mjtObj.mjOBJ_SITE)
    for i in range(model.neq):
        if int(model.eq_type[i]) != weld:
            continue
        ends: tuple[int, ...] = (int(model.eq_obj1id[i]), int(model.eq_obj2id[i]))
        if int(model.eq_objtype[i]) == site:
            ends = tuple(int(model.site_bodyid[j]) for j in ends)
        if any(model.body_mocapid[b] >= 0 for b in ends):
            return "action"
    return "ctrl"


def wrong_action_shape(received: tuple[int, ...], expected: tuple[int, ...]) -> str:
    """The message for an action whose shape is not the declared one (noise and latency layers)."""
    return f"`action` must have the shape of the env's action space, {expected}. Received an array of shape {received}."


def _control_dt(env: Any) -> float | None:
    for obj in (env, getattr(env, "unwrapped", None)):
        for name in ("dt", "control_timestep"):
            value = getattr(obj, name, None)
            if callable(value):
                try:
                    value = value()
                except TypeError:
                    value = None
            if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0:
                return float(value)
    return None


def _gym_signal(space: gym.Space, keys: tuple[tuple[str, slice, tuple[int, ...]], ...] = ()) -> tuple[Any, Any, Any]:
    """(layout, codec, dtype) of a gymnasium space (codec None for a 1-D Box)."""
    if isinstance(space, gym.spaces.Box):
        layout = box_layout(
            space, keys if keys and sum(sl.stop - sl.start for _, sl, _ in keys) == int(np.prod(space.shape)) else ()
        )
        codec = None if len(space.shape) == 1 else space.shape
        return layout, codec, space.dtype
    if isinstance(space, gym.spaces.Dict):
        parts = []
        boxes: list[gym.spaces.Box] = []  # in the codec's key order
        for k, sub in space.spaces.items():
            if not isinstance(sub, gym.spaces.Box) or not np.issubdtype(sub.dtype, np.floating):
                raise TypeError(f"noise models need float Box entries in a Dict space; key {k!r} is {sub!r}.")
            parts.append((k, tuple(sub.shape)))
            boxes.append(sub)
        dict_codec = _DictCodec(parts)
        lows = np.concatenate([np.ravel(box.low).astype(np.float64) for box in boxes])
        highs = np.concatenate([np.ravel(box.high).astype(np.float64) for box in boxes])
        low, high = _finite_bounds(lows, highs)
        dtype = np.result_type(*[box.dtype for box in boxes])
        layout = Layout(dict_codec.size, keys=dict_codec.layout_keys, low=low, high=high, dict_signal=True)
        return layout, dict_codec, dtype
    return None, None, None


class CorruptSignals(NoCopy, gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Applies noise and timing models (:mod:`noise_models`) to a gymnasium env's observations and
    actions; reports every per-episode draw in ``info["sim2real"]["params"]``.

    With ActionLatency, ``info["sim2real"]["action_latency_path"]`` says what is delayed (also
    :attr:`action_latency_path`): ``"ctrl"``, the actuator command at physics rate, or ``"action"``,
    the policy's action by whole control steps, for envs whose action does not map onto ``ctrl``
    (a size other than ``model.nu``, or a hand moved through a mocap weld; see
    :func:`action_delay_path`). On the ``"action"`` path the drawn latency is rounded to whole
    control steps, reported as applied (``action_latency_steps`` in physics steps,
    ``action_latency`` in seconds, ``action_latency_control_steps``), and the env gets a zero action
    until the first action arrives.

    Args:
        env: any gymnasium env with Box (or Dict of Box) observations and a Box action space.
        models: ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold, ControlJitter.
        seed: root seed of the models' streams; ``reset(seed=s)`` re-roots them at ``(seed, s)``.
    """

    def __init__(self, env: gym.Env, models: Sequence[SignalModel], seed: SeedLike = None) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, models=tuple(models), seed=seed)
        super().__init__(env)
        self.corruptor = SignalCorruptor(models, seed)
        keys = getattr(env.unwrapped, "observation_layout", ())
        obs_layout, self._obs_codec, obs_dtype = _gym_signal(env.observation_space, keys)
        act_layout, self._act_codec, act_dtype = _gym_signal(env.action_space)
        self._act_shape = tuple(env.action_space.shape or ())
        if self.corruptor.has_action and not isinstance(env.action_space, gym.spaces.Box):
            raise TypeError(f"action models need a Box action space. Received {env.action_space!r}.")
        self.clock = SignalClock(env, self.corruptor, obs_layout, act_layout, obs_dtype, act_dtype)
        self._has_obs = self.corruptor.has_observation
        self._has_action = self.corruptor.has_action
        # Whether this episode's observations read the step's time (decided at reset; until then, whether they may).
        self._needs_now = self.corruptor.observation_needs_time
        self._jitter = self.corruptor.needs_physics_hook and ControlJitter in self.corruptor.timing
        self._extra_report = self._jitter or self.clock.action_path is not None
        self._closed = False
        if self.clock.hooked:
            # Checked on the first step that moves the physics, then the class's step runs again (an instance
            # attribute costs later steps nothing).
            self.step = self._checked_step  # type: ignore[method-assign]

    def _checked_step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        out = type(self).step(self, action)
        if self.clock.check_reached():
            del self.step
        return out

    @property
    def current_params(self) -> dict[str, float]:
        """Name -> value drawn for this episode."""
        return self.corruptor.current_params

    @property
    def action_latency_path(self) -> str | None:
        """``"ctrl"`` or ``"action"``: what ActionLatency delays (None without it)."""
        return self.clock.action_path

    def _obs_in(self, obs: Any) -> np.ndarray:
        codec = self._obs_codec
        if codec is None:
            return obs
        if isinstance(codec, tuple):
            return np.reshape(obs, -1)
        return codec.flat(obs)

    def _obs_out(self, vec: np.ndarray, like: Any) -> Any:
        codec = self._obs_codec
        if codec is None:
            return vec
        if isinstance(codec, tuple):
            return vec.reshape(codec)
        return codec.unflat(vec, like)

    def _report(self, info: dict[str, Any]) -> None:
        report = info.get("sim2real")
        if report is None:
            c = self.corruptor
            info["sim2real"] = report = {"params": c.current_params.copy(), "episode": c.episode, "diverged": False}
        else:  # the inner wrapper built fresh dicts for this call: extend them in place
            report["params"].update(self.corruptor.current_params)
        if self._jitter:
            report["substeps"] = self.clock._target  # this control step's draw
        if self.clock.action_path is not None:
            report["action_latency_path"] = self.clock.action_path

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        c = self.corruptor
        self.clock._in_step = False  # in case the last step raised
        c.begin_episode(seed)
        obs, info = self.env.reset(seed=seed, options=options)
        self.clock.begin_episode()
        self._needs_now = c.episode_reads_time
        if self._has_obs:
            obs = self._obs_out(c.first_observation(self._obs_in(obs)), obs)
        self._report(info)
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        c = self.corruptor
        clock = self.clock
        if self._has_action:
            if type(action) is not np.ndarray:
                action = np.asarray(action, dtype=c.action_dtype)
            if action.shape != self._act_shape:  # one tuple compare: numpy's broadcasting errors name nothing
                raise ValueError(wrong_action_shape(action.shape, self._act_shape))
            codec = self._act_codec
            # The shape is checked: the corruptor's episode path directly (act() would check it again).
            action = c.hot_act(action) if codec is None else c.hot_act(action.reshape(-1)).reshape(codec)
        clock._control += 1
        clock._passed = 0
        clock._in_step = True
        obs, reward, terminated, truncated, info = self.env.step(action)
        clock._in_step = False
        if self._has_obs:
            now = 0
            if self._needs_now:
                handle = clock.handle
                now = clock._control if handle is None else elapsed_steps(clock._t0, handle.data.time, clock.physics_dt)
            if self._obs_codec is None:
                obs = c.hot_observe(obs, now)
            else:
                obs = self._obs_out(c.hot_observe(self._obs_in(obs), now), obs)
        report = info.get("sim2real")
        if report is None or self._extra_report:
            self._report(info)
        else:  # the inner wrapper built fresh dicts for this call: extend them in place
            report["params"].update(c.current_params)
        return obs, reward, terminated, truncated, info

    def release(self) -> gym.Env:
        """Detaches from the wrapped env and returns it, still open, for reuse: physics stepping is no
        longer intercepted. The wrapper is closed afterwards."""
        if not self._closed:
            self._closed = True
            self.clock.close()
        return self.env

    def close(self) -> None:
        self.release()
        super().close()


class CorruptSignalsDmEnv(NoCopy, DmEnvWrapper):
    """:class:`CorruptSignals` for dm_env environments (dm-control suite and composer).

    dm_env timesteps carry no info dict: the draws are on :attr:`current_params`. Dict observations
    keep their keys; report names use ``[key][j]`` (e.g. ``obs_noise_std[position][0]``).

    Example:
        >>> from dm_control import suite
        >>> from noise_models import Gaussian, ObservationNoise
        >>> from randomizers import Uniform
        >>> env = CorruptSignalsDmEnv(suite.load("reacher", "easy"),
        ...                           [ObservationNoise(Gaussian(std=Uniform(0.0, 0.1)), select="velocity")], seed=0)
        >>> timestep = env.reset()
        >>> sorted(env.current_params)
        ['obs_noise_std[velocity][0]', 'obs_noise_std[velocity][1]']
    """

    def __init__(self, env: dm_env.Environment, models: Sequence[SignalModel], seed: SeedLike = None) -> None:
        if not isinstance(env, dm_env.Environment):
            raise TypeError(f"`env` must be a dm_env.Environment. Received {type(env).__name__}.")
        self._env = env
        self.corruptor = SignalCorruptor(models, seed)
        spec = env.observation_spec()
        self._single = not isinstance(spec, dict)
        specs = OrderedDict(observation=spec) if self._single else spec
        self._codec = _DictCodec([(k, tuple(s.shape)) for k, s in specs.items()], OrderedDict)
        dtype = np.result_type(*[s.dtype for s in specs.values()])
        obs_layout = Layout(self._codec.size, keys=self._codec.layout_keys, dict_signal=not self._single)
        aspec = env.action_spec()
        low, high = _finite_bounds(
            np.broadcast_to(getattr(aspec, "minimum", -np.inf), aspec.shape),
            np.broadcast_to(getattr(aspec, "maximum", np.inf), aspec.shape),
        )
        act_layout = Layout(int(np.prod(aspec.shape)), low=low, high=high)
        self._action_shape = tuple(aspec.shape)
        self.clock = SignalClock(env, self.corruptor, obs_layout, act_layout, dtype, aspec.dtype)
        self._reset_next_step = True
        self._has_obs = self.corruptor.has_observation
        self._has_action = self.corruptor.has_action
        self._needs_now = self.corruptor.observation_needs_time  # this episode's, from its first observation on
        self._closed = False
        if self.clock.hooked:  # checked until a step moves the physics (see CorruptSignals)
            self._inner_step = self._checked_inner_step  # type: ignore[method-assign]

    def _checked_inner_step(self, action: Any) -> dm_env.TimeStep:
        timestep = type(self)._inner_step(self, action)
        if self.clock.check_reached():
            del self._inner_step
        return timestep

    @property
    def current_params(self) -> dict[str, float]:
        """Name -> value drawn for this episode: the wrapped env's draws (e.g. physics effects inside) and
        this wrapper's, as gymnasium's ``info["sim2real"]["params"]`` merges them."""
        inner = getattr(self._env, "current_params", None)
        merged = dict(inner) if isinstance(inner, dict) else {}
        merged.update(self.corruptor.current_params)
        return merged

    @property
    def action_latency_path(self) -> str | None:
        """``"ctrl"`` or ``"action"``: what ActionLatency delays (None without it); see :class:`CorruptSignals`."""
        return self.clock.action_path

    def _observation(self, timestep: dm_env.TimeStep, first: bool) -> dm_env.TimeStep:
        if not self._has_obs:
            return timestep
        obs = timestep.observation
        flat = self._codec.flat({"observation": obs} if self._single else obs)
        c = self.corruptor
        if first:
            self._needs_now = c.episode_reads_time
            vec = c.first_observation(flat)
        else:
            vec = c.hot_observe(flat, self.clock.now() if self._needs_now else 0)
        out = self._codec.unflat(vec, OrderedDict())
        return timestep._replace(observation=out["observation"] if self._single else out)

    def _inner_reset(self) -> dm_env.TimeStep:
        """The reset of what the signal models wrap (the fused layer resets its physics half here)."""
        return self._env.reset()

    def _inner_step(self, action: Any) -> dm_env.TimeStep:
        """The step of what the signal models wrap (the fused layer steps its physics half here)."""
        return self._env.step(action)

    def reset(self) -> dm_env.TimeStep:
        self.corruptor.begin_episode()
        timestep = self._inner_reset()
        self.clock.begin_episode()
        self._reset_next_step = False
        return self._observation(timestep, True)

    def step(self, action: Any) -> dm_env.TimeStep:
        if self._reset_next_step:
            return self.reset()
        if self._has_action:
            action = np.asarray(action, dtype=self.corruptor.action_dtype)
            if action.shape != self._action_shape:
                raise ValueError(wrong_action_shape(action.shape, self._action_shape))
            action = self.corruptor.act(action.reshape(-1)).reshape(self._action_shape)
        self.clock.begin_step()
        try:
            timestep = self._inner_step(action)
        finally:
            self.clock._in_step = False
        if timestep.first():  # the env reset itself after a last step: a new episode of draws
            self.corruptor.begin_episode()
            self.clock.begin_episode()
            return self._observation(timestep, True)
        self._reset_next_step = timestep.last()
        return self._observation(timestep, False)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.clock.close()
        self._env.close()
