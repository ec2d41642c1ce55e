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
from typing import Any

import dm_env
import gymnasium as gym
import numpy as np

from noise_models import ControlJitter, Layout, SignalCorruptor, SignalModel
from noise_models.seeding import SeedLike
from noise_models.timing import elapsed_steps
from sim2real.wrappers.clock import NoCopy, SignalClock
from sim2real.wrappers.dm import DmEnvWrapper

__all__ = [
    "CorruptSignals",
    "CorruptSignalsDmEnv",
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


def wrong_action_shape(received: tuple[int, ...], expected: tuple[int, ...]) -> str:
    """The message for an action whose shape is not the declared one (noise and latency layers)."""
    return f"`action` must have the shape of the env's action space, {expected}. Received an array of shape {received}."


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
    :func:`~sim2real.wrappers.clock.action_delay_path`). On the ``"action"`` path the drawn latency is rounded to whole
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
        # Removed once, if still installed: a caller may hold this bound method past a reset that removed it (or a
        # later step of an episode that installed another), and call it again.
        if self.clock.check_reached() and self.__dict__.get("step") == self._checked_step:
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
        # Each key leaves with its spec's dtype (the models work on one vector of the widest dtype): an integer key
        # that a noise model selects becomes that float dtype, and observation_spec says so.
        noisy = np.zeros(self._codec.size, dtype=bool)
        for pipe in self.corruptor._obs_pipes:
            for idx in pipe.indices:
                noisy[idx] = True
        self._out_dtypes = {
            k: np.dtype(dtype) if noisy[sl].any() and not np.issubdtype(specs[k].dtype, np.floating) else specs[k].dtype
            for k, sl, _ in self._codec.layout_keys
        }
        self._cast = [(k, t) for k, t in self._out_dtypes.items() if t != np.dtype(dtype)]
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
        for k, t in self._cast:  # (an exact round trip for a key no noise selects)
            out[k] = out[k].astype(t)
        return timestep._replace(observation=out["observation"] if self._single else out)

    def observation_spec(self) -> Any:
        """The wrapped env's, with the dtype of an integer key a noise model selects made the models' float dtype."""
        spec = self._env.observation_spec()
        if not self._has_obs:
            return spec
        if self._single:
            dtype = self._out_dtypes["observation"]
            return spec if spec.dtype == dtype else spec.replace(dtype=dtype)
        return type(spec)(
            (k, s if s.dtype == self._out_dtypes[k] else s.replace(dtype=self._out_dtypes[k])) for k, s in spec.items()
        )

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
