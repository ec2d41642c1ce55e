"""dm_env (dm-control suite and composer) environments as gymnasium environments.

:class:`DmEnvToGym` declares float32 ``Box`` spaces, flattens dict observations in spec order
(or keeps them as a ``Dict`` space with ``flatten=False``), honours ``reset(seed=...)`` by
re-seeding the task's own ``RandomState`` in place (and any other numpy or ``random`` generator the env keeps
on itself, its task or the dm_envs it wraps; a deterministic dm_env takes a seed with nothing to re-seed), ends an
episode whose physics diverged with
``truncated=True`` and ``info["diverged"] = True`` instead of raising (a reset that diverges
returns ``info["diverged"] = True`` and its next step ends the episode), and exposes the dm_env and
its physics.

Example:
    >>> from dm_control import suite
    >>> env = DmEnvToGym(suite.load("reacher", "easy"))
    >>> env.observation_space.shape, env.action_space.dtype
    ((6,), dtype('float32'))
    >>> obs, info = env.reset(seed=0)
    >>> obs2, _ = env.reset(seed=0)
    >>> bool((obs == obs2).all())
    True
"""

from __future__ import annotations

import random
import zlib
from collections import OrderedDict
from typing import Any

import dm_env
import gymnasium as gym
import numpy as np
from gymnasium import spaces

__all__ = ["DmEnvToGym"]


def _random_state(env: Any) -> np.random.RandomState | None:
    """The RandomState a dm-control env draws its episodes from (suite task or composer env)."""
    state = getattr(env, "random_state", None)  # composer
    if isinstance(state, np.random.RandomState):
        return state
    task = getattr(env, "task", None)  # suite control.Environment
    state = getattr(task, "random", None)
    return state if isinstance(state, np.random.RandomState) else None


_RANDOM_SOURCES = (np.random.Generator, np.random.RandomState, np.random.BitGenerator, random.Random)


def _inner_random_state(
    env: Any, path: str = "env", depth: int = 0
) -> tuple[np.random.RandomState | None, list[tuple[str, Any]]]:
    """The dm-control RandomState of ``env`` or of a dm_env it wraps (a user's wrapper that does not forward
    ``task``/``random_state``), and the wrappers above the env that owns it, outermost first, with their
    attribute paths (``"env"``, ``"env._env"``)."""
    state = _random_state(env)
    if state is not None or depth > 8:
        return state, []
    for name, value in getattr(env, "__dict__", {}).items():
        if isinstance(value, dm_env.Environment) and value is not env:
            state, above = _inner_random_state(value, f"{path}.{name}", depth + 1)
            if state is not None:
                return state, [(path, env), *above]
    return None, []


def _generators(obj: Any) -> list[tuple[str, Any]]:
    """The random generators kept directly on ``obj``'s attributes, ``(name, generator)``, in attribute order."""
    return [(name, value) for name, value in getattr(obj, "__dict__", {}).items() if isinstance(value, _RANDOM_SOURCES)]


def _random_sources(env: Any) -> list[tuple[str, Any]]:
    """Every random generator a dm_env without a dm-control RandomState keeps among the attributes of the env,
    of its ``task`` and of the dm_envs it wraps, with its path (``"env._rng"``), each object once (a generator
    hidden deeper, e.g. in a list, or the global ``np.random``, is not seen)."""
    stack: list[tuple[str, Any]] = [("env", env)]
    seen: set[int] = set()
    found: list[tuple[str, Any]] = []
    while stack:
        path, obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        try:
            attributes = vars(obj)
        except TypeError:  # no __dict__ (slots, builtins)
            continue
        for name, value in _generators(obj):
            if id(value) not in seen:
                seen.add(id(value))
                found.append((f"{path}.{name}", value))
        for name, value in attributes.items():
            if isinstance(value, dm_env.Environment) or name in ("task", "_task"):
                stack.append((f"{path}.{name}", value))
    return found


def _describe(source: Any) -> str:
    kind = type(source)
    module = "numpy.random" if kind.__module__.startswith("numpy.random") else kind.__module__
    return f"{module}.{kind.__name__}"


def _reseed(source: Any, seed: int, path: str) -> None:
    """Re-seeds ``source`` (a numpy Generator, BitGenerator or RandomState, or a ``random.Random``) in place from
    ``seed`` and its attribute ``path`` (two generators of one env get different streams; the same seed and path,
    the same stream)."""
    child = np.random.SeedSequence(seed, spawn_key=(zlib.crc32(path.encode()),))
    if isinstance(source, np.random.Generator):
        source.bit_generator.state = type(source.bit_generator)(child).state
    elif isinstance(source, np.random.BitGenerator):
        source.state = type(source)(child).state
    elif isinstance(source, np.random.RandomState):
        source.seed(int(child.generate_state(1)[0]))
    else:
        source.seed(int(child.generate_state(1, np.uint64)[0]))


def suite_observation(env: Any) -> Any:
    """A dm-control suite env's observation of its current physics state (None for other envs)."""
    from dm_control.rl import control

    if not isinstance(env, control.Environment):
        return None
    observation = env.task.get_observation(env.physics)
    if getattr(env, "_flat_observation", False):
        observation = control.flatten_observation(observation)
    return observation


def _physics_error() -> type[Exception]:
    from dm_control.rl.control import PhysicsError

    return PhysicsError


def _box(spec: Any, dtype: type = np.float32) -> spaces.Box:
    shape = tuple(spec.shape)
    low = np.broadcast_to(np.asarray(getattr(spec, "minimum", -np.inf), dtype=np.float64), shape)
    high = np.broadcast_to(np.asarray(getattr(spec, "maximum", np.inf), dtype=np.float64), shape)
    return spaces.Box(low=low.astype(dtype), high=high.astype(dtype), shape=shape, dtype=dtype)


class DmEnvToGym(gym.Env):
    """A gymnasium view of a ``dm_env.Environment``.

    Args:
        env: a dm-control suite or composer environment (any ``dm_env.Environment`` works; physics
            access and seeding need dm-control).
        flatten: concatenate the observation dict into one float32 vector (spec order). With
            False, observations are a dict of float32 arrays under a ``spaces.Dict``.
        render_mode: None or ``"rgb_array"``.
        width: rendered image width in pixels.
        height: rendered image height in pixels.
        camera: camera name or id used by :meth:`render`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}  # noqa: RUF012 - gymnasium API

    def __init__(
        self,
        env: dm_env.Environment,
        *,
        flatten: bool = True,
        render_mode: str | None = None,
        width: int = 240,
        height: int = 240,
        camera: int | str = 0,
    ) -> None:
        if not isinstance(env, dm_env.Environment):
            raise TypeError(f"`env` must be a dm_env.Environment. Received {type(env).__name__}.")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"`render_mode` must be one of [None, 'rgb_array']. Received {render_mode!r}.")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                raise ValueError(f"`{name}` must be a positive int. Received {value!r}.")
        self.dm_env = env
        self.flatten = bool(flatten)
        self.render_mode = render_mode
        self.width, self.height, self.camera = width, height, camera
        obs_spec = env.observation_spec()
        if not isinstance(obs_spec, dict):
            obs_spec = OrderedDict(observation=obs_spec)
            self._single = True
        else:
            self._single = False
        self._keys = list(obs_spec)
        self._sizes = [int(np.prod(obs_spec[k].shape)) for k in self._keys]
        if self.flatten:
            self.observation_space: spaces.Space[Any] = spaces.Box(
                -np.inf, np.inf, shape=(sum(self._sizes),), dtype=np.float32
            )
        else:
            self.observation_space = spaces.Dict(
                {k: spaces.Box(-np.inf, np.inf, shape=tuple(obs_spec[k].shape), dtype=np.float32) for k in self._keys}
            )
        action_spec = env.action_spec()  # a suite env builds it from the model's ranges on every call
        self.action_space = _box(action_spec)
        self._action_dtype = action_spec.dtype
        self._physics_error = _physics_error()
        self._last_obs: Any = None
        self._reset_diverged = False
        physics = getattr(env, "physics", None)
        self.control_timestep: float | None = (
            float(env.control_timestep()) if hasattr(env, "control_timestep") else None
        )
        self.n_substeps = (
            round(self.control_timestep / float(physics.timestep()))
            if physics is not None and self.control_timestep
            else None
        )

    @property
    def observation_layout(self) -> tuple[tuple[str, slice, tuple[int, ...]], ...]:
        """``(key, slice, shape)`` of each dm-control observation inside the flat vector, so noise
        models can select keys of a flattened observation."""
        out, start = [], 0
        for key, size in zip(self._keys, self._sizes, strict=True):
            out.append((key, slice(start, start + size), (size,)))
            start += size
        return tuple(out)

    @property
    def physics(self) -> Any:
        """The dm-control ``Physics`` of the current episode."""
        return self.dm_env.physics

    def _observation(self, observation: Any) -> Any:
        if self._single:
            observation = {"observation": observation}
        if not self.flatten:
            return {k: np.asarray(observation[k], dtype=np.float32) for k in self._keys}
        return np.concatenate([observation[k] for k in self._keys], axis=None, dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Starts an episode; a ``seed`` re-seeds the task's RandomState in place first.

        The RandomState of a suite or composer env wrapped in a user's dm_env wrapper (one that does not forward
        ``task``) is found and re-seeded too. A hand-written dm_env's own generators (a numpy ``Generator``,
        ``BitGenerator`` or ``RandomState``, or a ``random.Random``, kept as attributes of the env, its ``task``,
        the dm_envs it wraps, or of wrappers above a suite task) are re-seeded in place, each from the seed and its
        attribute path, so the same seed gives the same episode; a generator shared with other code is re-seeded
        with it. A dm_env with no generator among those attributes is taken as deterministic: the seed only seeds
        ``self.np_random``, so ``gymnasium``'s ``check_env`` runs on it. Randomness drawn from the global
        ``np.random``, or kept deeper (in a list), cannot be seen.

        Raises:
            ValueError: ``options`` given, or a ``seed`` for an env whose generator cannot be re-seeded in place.
        """
        super().reset(seed=seed)
        if options:
            raise ValueError(f"`options` is not supported by dm-control environments. Received {options!r}.")
        if seed is not None:
            state, wrappers = _inner_random_state(self.dm_env)
            if state is not None:
                state.seed(int(np.random.SeedSequence(seed).generate_state(1)[0]))
                # Generators of the user's wrappers above the task would go unseeded beside its RandomState.
                sources = [
                    (f"{path}.{name}", g) for path, w in wrappers for name, g in _generators(w) if g is not state
                ]
            else:
                sources = _random_sources(self.dm_env)
            for path, source in sources:
                try:
                    _reseed(source, seed, path)
                except (TypeError, ValueError, AttributeError) as exc:  # a bit generator that takes no SeedSequence
                    raise ValueError(
                        f"`seed` cannot be honoured: {type(self.dm_env).__name__} draws from {path} "
                        f"({_describe(source)}), which DmEnvToGym cannot re-seed in place ({exc}). Seed the env in "
                        f"its factory and call reset() without a seed. Received seed={seed!r}."
                    ) from None
        self._reset_diverged = False
        try:
            timestep = self.dm_env.reset()
        except self._physics_error:
            # The task's reset stepped the physics into divergence (e.g. settling under an extreme draw).
            # As in step: flag it instead of raising; the next step ends the episode (truncated).
            self._reset_diverged = True
            obs = self._fallback_observation()
            self._last_obs = obs
            return obs, {"diverged": True}
        obs = self._observation(timestep.observation)
        self._last_obs = obs
        return obs, {}

    def _fallback_observation(self) -> Any:
        """The observation of the state MuJoCo fell back to, where finite; zeros otherwise."""
        try:
            observation = suite_observation(self.dm_env)
        except Exception:  # a diverged physics may fail anywhere; the fallback covers it
            observation = None
        obs = None if observation is None else self._observation(observation)
        if obs is not None:
            flat = obs if self.flatten else np.concatenate([np.ravel(v) for v in obs.values()])
            if np.isfinite(flat).all():
                return obs
        space = self.observation_space
        if self.flatten:
            return np.zeros(space.shape, np.float32)
        assert isinstance(space, spaces.Dict)  # __init__ builds a Dict space whenever flatten is False
        return {k: np.zeros(b.shape, np.float32) for k, b in space.items()}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """One control step; a physics divergence ends the episode (truncated) with the last good obs."""
        if self._reset_diverged:  # nothing to step: the reset already diverged
            return self._last_obs, 0.0, False, True, {"diverged": True}
        try:
            timestep = self.dm_env.step(np.asarray(action, dtype=self._action_dtype))
        except self._physics_error:
            return self._last_obs, 0.0, False, True, {"diverged": True}
        obs = self._observation(timestep.observation)
        self._last_obs = obs
        terminated = truncated = False
        if timestep.step_type == dm_env.StepType.LAST:
            terminated = timestep.discount == 0.0
            truncated = not terminated
        return obs, float(timestep.reward or 0.0), terminated, truncated, {}

    def observe(self) -> Any:
        """The observation of the current physics state, computed again (dm-control suite tasks), or None
        where recomputing it is not side-effect free (composer observables are buffered and noisy)."""
        observation = suite_observation(self.dm_env)
        if observation is None:
            return None
        self._last_obs = self._observation(observation)
        return self._last_obs

    def render(self) -> np.ndarray | None:
        """An RGB frame (``height`` x ``width`` x 3, uint8) when ``render_mode="rgb_array"``."""
        if self.render_mode is None:
            return None
        return self.physics.render(height=self.height, width=self.width, camera_id=self.camera)

    def close(self) -> None:
        close = getattr(self.dm_env, "close", None)
        if close is not None:
            close()
