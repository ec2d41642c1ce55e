"""TorchRL transform that randomises physics: :class:`RandomizePhysicsTransform`.

The draws of the episode travel in every TensorDict under ``"sim2real_params"`` (float64, one
entry per address in :attr:`RandomizePhysicsTransform.param_names`), and a physics divergence sets
``"sim2real_diverged"`` together with ``"truncated"``/``"done"``.

Example:
    >>> from torchrl.envs import DMControlEnv, TransformedEnv
    >>> from randomizers import Friction, Uniform
    >>> env = TransformedEnv(DMControlEnv("reacher", "easy"),
    ...                      RandomizePhysicsTransform([Friction(scale=Uniform(0.5, 1.5))], seed=0))
    >>> td = env.reset()
    >>> td["sim2real_params"].shape
    torch.Size([10])
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Sequence
from typing import Any

import torch
from tensordict import NestedKey, TensorDictBase, unravel_key
from torchrl.data import Binary, Composite, Unbounded
from torchrl.envs.transforms import Transform

from noise_models.timing import ControlJitter
from randomizers import Effect, PhysicsRandomizer
from randomizers.seeding import SeedLike
from sim2real.physics import PhysicsHandle
from sim2real.wrappers.clock import NoCopy
from sim2real.wrappers.gym import require_physics, settle_draws

__all__ = ["CorruptSignalsTransform", "RandomizePhysicsTransform"]

PARAMS_KEY = "sim2real_params"
DIVERGED_KEY = "sim2real_diverged"
SIGNAL_PARAMS_KEY = "sim2real_signal_params"
SUBSTEPS_KEY = "sim2real_substeps"
PUSHES_KEY = "sim2real_pushes"


def _no_exceptions(physics: Any, saved: list[tuple[Any, bool]]) -> None:
    """Turns off dm-control's exceptions on MuJoCo warnings for ``physics``, keeping its own setting in ``saved``
    for ``close`` to restore: one entry, the env's current physics (a composer env frees its old physics when it
    recompiles, so that one needs nothing back and is not kept alive)."""
    # A transform cannot catch an exception raised inside the base env's step, so let MuJoCo's
    # auto-reset happen and detect the divergence from the warning counters instead.
    if hasattr(physics, "_warnings_cause_exception"):
        if not saved or not _same(saved[0][0], physics):
            saved[:] = [(physics, physics._warnings_cause_exception)]
        physics._warnings_cause_exception = False


def _same(a: Any, b: Any) -> bool:
    """Whether two physics (a composer env hands out weak proxies, which compare their referents) are one."""
    try:
        return bool(a is b or a == b)
    except ReferenceError:  # the older one was freed
        return False


class _SeedRelay:
    """What ``set_seed(s)`` on the env of a sim2real transform runs: TorchRL's ``TransformedEnv.set_seed`` seeds only
    its base env, so the base env's ``_set_seed`` (what every ``set_seed`` calls) is this, which seeds the base env as
    before and leaves ``s`` for ``owner``, whose next reset restarts its streams at ``(wrap seed, s)``: what
    gymnasium's ``reset(seed=s)`` does. A ``SerialEnv`` or ``ParallelEnv`` hands each worker its own seed, so their
    draws differ; the same seed gives the same draws. A plain object (not a closure): the env still pickles and
    copies as far as its transforms allow."""

    def __init__(self, base: Any, owner: Transform) -> None:
        self.base, self.owner = base, owner
        self.previous = base.__dict__.get("_set_seed")  # another sim2real transform's relay on the same env

    def __call__(self, seed: int | None) -> None:
        if self.previous is not None:
            self.previous(seed)
        else:
            type(self.base)._set_seed(self.base, seed)
        if seed is not None:
            self.owner.__dict__["_next_seed"] = int(seed)


def _follow_set_seed(parent: Any, owner: Transform) -> None:
    """Makes ``set_seed`` on ``parent``'s env reach ``owner`` (see :class:`_SeedRelay`); :func:`_unfollow_set_seed`
    undoes it when ``owner`` closes."""
    base = parent.base_env
    relay = _SeedRelay(base, owner)
    base._set_seed = relay  # an instance attribute: EnvBase.set_seed calls self._set_seed
    owner.__dict__["_relay"] = relay


def _unfollow_set_seed(owner: Transform) -> None:
    """Takes ``owner``'s relay out of its base env's ``set_seed`` chain, so the base env is left as it was found
    (no instance ``_set_seed`` when no other transform installed one). A clone sharing the relay leaves it alone."""
    relay = owner.__dict__.get("_relay")
    if not isinstance(relay, _SeedRelay) or relay.owner is not owner:
        return
    owner.__dict__.pop("_relay")
    base = relay.base
    current = base.__dict__.get("_set_seed")
    if current is relay:
        if relay.previous is None:
            del base.__dict__["_set_seed"]
        else:
            base.__dict__["_set_seed"] = relay.previous
        return
    while isinstance(current, _SeedRelay):  # a later transform's relay calls this one: skip it in the chain
        if current.previous is relay:
            current.previous = relay.previous
            return
        current = current.previous


class RandomizePhysicsTransform(Transform):
    """Applies physics effects on every reset of the TorchRL env it is appended to.

    With :class:`~randomizers.Push` effects, ``"sim2real_pushes"`` (float64, ``(push effects, 4)``) holds what each
    applies during the step: the body id it pushes (-1 when idle) and the force in newtons (world frame).

    Args:
        effects: physics effects from :mod:`randomizers`.
        seed: root seed of the effect streams; ``env.set_seed(s)`` restarts them at ``(seed, s)`` for the next reset.
    """

    def __init__(self, effects: Sequence[Effect], seed: SeedLike = None) -> None:
        super().__init__(in_keys=[], out_keys=[PARAMS_KEY, DIVERGED_KEY])
        self.randomizer = PhysicsRandomizer(effects, seed)
        self._pushes_count = 0  # Push effects among the bound randomizer's (set by _bound, read per step)
        self._handle: PhysicsHandle | None = None
        self._hook: Any = None
        self._names: tuple[str, ...] = ()
        self.reapplied: tuple[str, ...] = ()
        self._reset_diverged = False
        self._exceptions_saved: list[tuple[Any, bool]] = []  # (dm-control physics, its own setting), for close

    # -- binding ---------------------------------------------------------------------------------
    def _bound(self) -> PhysicsHandle:
        if self._handle is None:
            parent = self.parent
            if parent is None:
                raise RuntimeError("RandomizePhysicsTransform must be appended to a TransformedEnv before use.")
            _refuse_second(parent, "physics", "sim2real_params", RandomizePhysicsTransform)
            base = parent.base_env
            handle = require_physics(base, self.randomizer.effects)
            self.randomizer.bind(handle.model, handle.data)
            if handle.source.startswith("dm_control"):
                _no_exceptions(handle.owner.physics, self._exceptions_saved)
            if handle.recompiles:
                self._hook = handle.on_recompile(self._recompiled)
            self._handle = handle
            # Addresses come from a throwaway draw so the spec is known before the first reset.
            self._names = tuple(self.randomizer.nominal_params())
            self._pushes_count = self.randomizer.push_count
            _follow_set_seed(parent, self)
        return self._handle

    def _recompiled(self, model: Any, data: Any) -> None:
        self.randomizer.bind(model, data)
        self.randomizer.apply()
        _no_exceptions(self._handle.owner.physics, self._exceptions_saved)  # type: ignore[union-attr]

    @property
    def param_names(self) -> tuple[str, ...]:
        """The address of each entry of ``"sim2real_params"``."""
        self._bound()
        return self._names

    @property
    def current_params(self) -> dict[str, float]:
        """Address -> value in use this episode."""
        return self.randomizer.current_params

    def _params_tensor(self, batch: torch.Size) -> torch.Tensor:
        # Built once per episode (and after each step of a step-scheduled effect), copied per step.
        cached = self.__dict__.get("_params_cache")
        if cached is None:
            params = self.randomizer.current_params
            cached = torch.tensor([params.get(name, float("nan")) for name in self._names], dtype=torch.float64)
            self.__dict__["_params_cache"] = cached
        return cached.expand(*batch, cached.numel()).clone()

    # -- TorchRL hooks ---------------------------------------------------------------------------
    def _reset_env_preprocess(self, tensordict: TensorDictBase | None) -> TensorDictBase | None:
        handle = self._bound()
        self.randomizer.begin_episode(self.__dict__.pop("_next_seed", None))  # set_seed(s): streams of (seed, s)
        self.__dict__["_params_cache"] = None
        if not handle.recompiles:
            self.randomizer.apply()
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        # Draws the task's own reset overwrote (finger's hinge damping) are written again; the state is kept
        # and mj_forward recomputes what derives from it. The reset observation stays the base env's: a
        # transform cannot recompute it without bypassing transforms before it; only force- or
        # acceleration-derived sensors can differ.
        self.reapplied, _ = settle_draws(self._bound(), self.randomizer)
        tensordict_reset.set(PARAMS_KEY, self._params_tensor(tensordict_reset.batch_size))
        # dm-control's exceptions are off (see _no_exceptions): a reset that diverged shows in the warnings.
        self._reset_diverged = self._bound().diverged()
        tensordict_reset.set(
            DIVERGED_KEY, torch.full((*tensordict_reset.batch_size, 1), self._reset_diverged, dtype=torch.bool)
        )
        if self._pushes_count:
            tensordict_reset.set(PUSHES_KEY, self._pushes(tensordict_reset.batch_size))
        return tensordict_reset

    def _pushes(self, batch: torch.Size) -> torch.Tensor:
        state = torch.from_numpy(self.randomizer.push_state())
        return state.expand(*batch, *state.shape).clone()

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.randomizer.has_step_effects:
            self.randomizer.step()
            self.__dict__["_params_cache"] = None
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        handle = self._bound()
        batch = next_tensordict.batch_size
        diverged = handle.diverged() or self._reset_diverged
        next_tensordict.set(PARAMS_KEY, self._params_tensor(batch))
        next_tensordict.set(DIVERGED_KEY, torch.full((*batch, 1), diverged, dtype=torch.bool))
        if self._pushes_count:  # the pushes this step applied, as gymnasium's info["sim2real"]["events"]
            next_tensordict.set(PUSHES_KEY, self._pushes(batch))
        if diverged:
            for key in ("truncated", "done"):
                if key in next_tensordict:
                    next_tensordict.set(key, torch.ones_like(next_tensordict.get(key)))
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        self._bound()
        batch = observation_spec.shape
        observation_spec[PARAMS_KEY] = Unbounded(
            shape=(*batch, len(self._names)), dtype=torch.float64, device=observation_spec.device
        )
        observation_spec[DIVERGED_KEY] = Binary(
            n=1, shape=(*batch, 1), dtype=torch.bool, device=observation_spec.device
        )
        if self._pushes_count:
            observation_spec[PUSHES_KEY] = Unbounded(
                shape=(*batch, self._pushes_count, 4), dtype=torch.float64, device=observation_spec.device
            )
        return observation_spec

    def restore_nominal(self) -> None:
        """Writes every touched model field back to its nominal value (bitwise)."""
        self.randomizer.restore_nominal()

    def close(self) -> None:
        """Restores the nominal model, unhooks recompiles, gives dm-control physics back its own
        ``_warnings_cause_exception`` setting and takes the ``set_seed`` relay off the base env."""
        self.restore_nominal()
        if self._hook is not None and self._handle is not None:
            self._handle.remove_hook(self._hook)
            self._hook = None
        for physics, setting in self._exceptions_saved:
            # A composer env freed its physics when it closed (a dead weak proxy): nothing left to restore.
            with contextlib.suppress(ReferenceError):
                physics._warnings_cause_exception = setting
        self._exceptions_saved.clear()
        _unfollow_set_seed(self)
        super().close() if hasattr(super(), "close") else None


class CorruptSignalsTransform(NoCopy, Transform):
    """Applies noise and timing models (:mod:`noise_models`) inside a TorchRL ``TransformedEnv``:
    observation pipelines, latency and sample-and-hold on the observation entries, action noise on
    the env's action entry (``"action"``, or its one ``action_key``), and physics-rate action latency / control
    jitter inside the base env's physics step.

    The per-episode draws travel in every TensorDict under ``"sim2real_signal_params"`` (float64,
    one entry per name in :attr:`param_names`) and are on :attr:`current_params`; physics draws of a
    :class:`RandomizePhysicsTransform` stay in ``"sim2real_params"``. With ControlJitter,
    ``"sim2real_substeps"`` (int64) holds the physics substeps of the control step just taken.

    Args:
        models: ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold, ControlJitter.
        seed: root seed of the models' streams; ``env.set_seed(s)`` restarts them at ``(seed, s)`` for the next reset.
        observation_keys: the entries treated as the observation (default: every floating-point
            entry of the observation spec except ``sim2real_*``, nested ones included), concatenated in this
            order. A nested entry is a tuple key, ``("robot", "qpos")``, and goes by ``"robot.qpos"`` in
            ``select=`` and in the reported names.

    Example:
        >>> from torchrl.envs import DMControlEnv, TransformedEnv
        >>> from noise_models import Gaussian, ObservationLatency, ObservationNoise
        >>> env = TransformedEnv(DMControlEnv("reacher", "easy"),
        ...                      CorruptSignalsTransform([ObservationNoise(Gaussian(std=0.01)),
        ...                                               ObservationLatency(steps=2)], seed=0))
        >>> td = env.rollout(3)
        >>> env.transform.current_params["obs_latency_steps"]
        2
        >>> env.transform.param_names[-2:], td["sim2real_signal_params"][0, -2:].tolist()
        (('obs_latency_steps', 'obs_latency'), [2.0, 0.04])
    """

    def __init__(
        self, models: Sequence[Any], seed: SeedLike = None, observation_keys: Sequence[NestedKey] | None = None
    ) -> None:
        from noise_models import SignalCorruptor

        super().__init__(in_keys=[], out_keys=[])
        self.corruptor = SignalCorruptor(models, seed)
        self._observation_keys = None if observation_keys is None else list(observation_keys)
        self._clock: Any = None
        self._keys: list[str] = []
        self._names: tuple[str, ...] = ()
        self._params: torch.Tensor | None = None
        self._action_key: NestedKey = "action"
        self._jitter = False

    @property
    def current_params(self) -> dict[str, float]:
        """Name -> value drawn for this episode."""
        return self.corruptor.current_params

    def _bound(self) -> Any:
        if self._clock is None:
            import numpy as np

            from noise_models import Layout
            from sim2real.wrappers.clock import SignalClock

            parent = self.parent
            if parent is None:
                raise RuntimeError("CorruptSignalsTransform must be appended to a TransformedEnv before use.")
            _refuse_second(parent, "signal", "sim2real_signal_params", CorruptSignalsTransform)
            obs_spec = parent.full_observation_spec
            known = [unravel_key(k) for k in obs_spec.keys(True, True)]
            if self._observation_keys is None:
                # Entries of nested Composite specs (``("robot", "qpos")``) are observations too.
                keys = [
                    k for k in known if not _key_name(k).startswith("sim2real_") and obs_spec[k].dtype.is_floating_point
                ]
            else:
                keys = [unravel_key(k) for k in self._observation_keys]
                missing = [k for k in keys if k not in known]
                if missing:
                    raise ValueError(
                        f"`observation_keys` names {missing}, which the env does not observe. Known keys: "
                        f"{sorted(str(k) for k in known)}."
                    )
            self._keys = keys
            shapes = [(k, tuple(obs_spec[k].shape[len(parent.batch_size) :])) for k in keys]
            slices, named, start, lows, highs = [], [], 0, [], []
            for k, shape in shapes:
                n = int(np.prod(shape))
                slices.append((k, slice(start, start + n), shape))
                named.append((_key_name(k), slice(start, start + n), shape))
                start += n
                low, high = _spec_bounds(obs_spec[k], n)
                lows.append(low)
                highs.append(high)
            low_all, high_all = np.concatenate(lows), np.concatenate(highs)
            finite = bool(np.isfinite(low_all).any() or np.isfinite(high_all).any())
            if len(shapes) == 1 and len(shapes[0][1]) == 1:
                # One flat vector from a gymnasium env that says what its parts are (DmEnvToGym's
                # observation_layout, reached through TorchRL's GymWrapper): select by part, as on the gym side.
                named = _observation_parts(parent, start) or named
            obs_layout = Layout(
                start,
                keys=tuple(named),
                low=low_all if finite else None,
                high=high_all if finite else None,
                dict_signal=len(keys) > 1,
            )
            self._shapes = dict(shapes)
            self._slices = slices
            # The env's own action entry: "action" for TorchRL's wrappers, ("arm", "torque") for an env that says so.
            action_keys = [unravel_key(k) for k in parent.action_keys]
            act_layout, act_dtype = None, np.float64
            if len(action_keys) == 1:
                self._action_key = action_keys[0]
                aspec = parent.full_action_spec[self._action_key]
                self._action_shape = tuple(aspec.shape[len(parent.batch_size) :])
                n_act = int(np.prod(self._action_shape))
                alow, ahigh = _spec_bounds(aspec, n_act)
                afinite = bool(np.isfinite(alow).any() or np.isfinite(ahigh).any())
                act_layout = Layout(n_act, low=alow if afinite else None, high=ahigh if afinite else None)
                act_dtype = _numpy_dtype(aspec.dtype)
            elif self.corruptor.has_action:
                raise ValueError(
                    "action models (ActionNoise, ActionLatency) need an env with one action entry. Received an env "
                    f"with {len(action_keys)}: {action_keys}."
                )
            obs_dtype = _numpy_dtype(obs_spec[keys[0]].dtype) if keys else np.float64
            if self.corruptor.timing:
                _warn_frame_skip_twice(parent)
            self._clock = SignalClock(
                parent.base_env,
                self.corruptor,
                obs_layout,
                act_layout,
                obs_dtype,
                act_dtype,
                repeat=_action_repeat(parent),
            )
            # Whether each control step draws its physics substeps (ControlJitter reaching the physics).
            self._jitter = self._clock.hooked and ControlJitter in self.corruptor.timing
            # The names come from a throwaway draw so the spec is known before the first reset.
            self.corruptor.begin_episode()
            self._names = tuple(self.corruptor.current_params)
            self.corruptor.episode = -1
            _follow_set_seed(parent, self)
        return self._clock

    @property
    def action_latency_path(self) -> str | None:
        """``"ctrl"`` or ``"action"``: what ActionLatency delays (None without it); see
        :class:`~sim2real.wrappers.CorruptSignals`."""
        return self._bound().action_path

    @property
    def param_names(self) -> tuple[str, ...]:
        """The name of each entry of ``"sim2real_signal_params"``."""
        self._bound()
        return self._names

    def _params_tensor(self, batch: torch.Size) -> torch.Tensor:
        if self._params is None:
            params = self.corruptor.current_params
            self._params = torch.tensor([float(params[n]) for n in self._names], dtype=torch.float64)
        return self._params.expand(*batch, len(self._names)).clone()

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        self._bound()
        observation_spec[SIGNAL_PARAMS_KEY] = Unbounded(
            shape=(*observation_spec.shape, len(self._names)), dtype=torch.float64, device=observation_spec.device
        )
        if self._jitter:
            observation_spec[SUBSTEPS_KEY] = Unbounded(
                shape=(*observation_spec.shape, 1), dtype=torch.int64, device=observation_spec.device
            )
        return observation_spec

    def _substeps(self, batch: torch.Size, reset: bool = False) -> torch.Tensor:
        # The substeps run in this control step: all of the draw, or its share of the env steps TorchRL's own
        # frame_skip took before the episode ended (the nominal count at reset).
        clock = self._bound()
        value = clock.nominal if reset else clock._passed * clock._target // clock.nominal
        return torch.full((*batch, 1), int(value), dtype=torch.int64)

    def _flat(self, td: TensorDictBase) -> Any:
        # On the CPU ``Tensor.numpy()`` is a view of the tensor's memory: one entry reaches the corruptor without a
        # copy (a latency or hold buffer copies what it keeps: TorchRL may reuse the tensor, as envs their buffers).
        keys = self._keys
        if len(keys) == 1:
            return td.get(keys[0]).detach().cpu().numpy().reshape(-1)
        import numpy as np

        return np.concatenate([td.get(k).detach().cpu().numpy().reshape(-1) for k in keys])

    def _write(self, td: TensorDictBase, vec: Any) -> None:
        for k, sl, _shape in self._slices:
            old = td.get(k)
            td.set(k, torch.from_numpy(vec[sl].reshape(old.shape)).to(old.dtype))

    def _reset_env_preprocess(self, tensordict: TensorDictBase | None) -> TensorDictBase | None:
        self._bound()
        self.corruptor.begin_episode(self.__dict__.pop("_next_seed", None))  # set_seed(s): streams of (seed, s)
        self._params = None
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        clock = self._bound()
        clock.begin_episode()
        self.__dict__["_needs_now"] = self.corruptor.episode_reads_time
        if self.corruptor.has_observation:
            self._write(tensordict_reset, self.corruptor.first_observation(self._flat(tensordict_reset)))
        tensordict_reset.set(SIGNAL_PARAMS_KEY, self._params_tensor(tensordict_reset.batch_size))
        if self._jitter:
            tensordict_reset.set(SUBSTEPS_KEY, self._substeps(tensordict_reset.batch_size, reset=True))
        return tensordict_reset

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        clock = self._bound()
        if self.corruptor.has_action:
            action = tensordict.get(self._action_key)
            shape = tuple(action.shape[len(tensordict.batch_size) :])
            if shape != self._action_shape:
                from sim2real.wrappers.signals import wrong_action_shape

                raise ValueError(wrong_action_shape(shape, self._action_shape))
            out = self.corruptor.act(action.detach().cpu().numpy().reshape(-1))
            tensordict.set(self._action_key, torch.from_numpy(out.reshape(action.shape)).to(action.dtype))
        clock.begin_step()
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        clock = self._bound()
        clock._in_step = False
        if clock.hooked and not self.__dict__.get("_reached") and clock.check_reached():
            self.__dict__["_reached"] = True  # the hook is reached (see CorruptSignals); not checked again
        if self.corruptor.has_observation:
            now = clock.now() if self.__dict__.get("_needs_now", True) else 0
            self._write(next_tensordict, self.corruptor.observe(self._flat(next_tensordict), now))
        next_tensordict.set(SIGNAL_PARAMS_KEY, self._params_tensor(next_tensordict.batch_size))
        if self._jitter:  # this control step's draw, as gymnasium's info["sim2real"]["substeps"]
            next_tensordict.set(SUBSTEPS_KEY, self._substeps(next_tensordict.batch_size))
        return next_tensordict

    def close(self) -> None:
        if self._clock is not None:
            self._clock.close()
            self._clock = None
        _unfollow_set_seed(self)
        super().close() if hasattr(super(), "close") else None


def _refuse_second(parent: Any, kind: str, key: str, cls: type) -> None:
    """A second transform of ``kind`` would write ``key`` over the first one's draws (gymnasium merges the reports of
    stacked layers; a TensorDict entry holds one): refused, saying to pass every effect to one ``wrap``."""
    from torchrl.envs.transforms import Compose

    transform = getattr(parent, "transform", None)
    for t in transform if isinstance(transform, Compose) else (transform,):
        if isinstance(t, cls) or isinstance(getattr(t, "physics", None), cls):
            raise ValueError(
                f"`env` already has a sim2real {kind} transform ({type(t).__name__}) writing {key!r}: give every "
                f"{kind} effect to one sim2real.wrap call (a second transform would overwrite its draws)."
            )


def _action_repeat(parent: Any) -> int:
    """How many times TorchRL steps the env that holds the model per step of ``parent``: a ``GymWrapper``'s or
    ``GymEnv``'s ``frame_skip`` (its ``wrapper_frame_skip`` loop) times each ``FrameSkipTransform`` before this
    transform. A control step of the transform is that many steps of the env, so its physics steps are that many
    times the env's ``frame_skip``."""
    # From __dict__, as TorchRL reads it: a batched env's __getattr__ would start (or recurse into) its workers.
    repeat = vars(parent.base_env).get("wrapper_frame_skip", 1)
    repeat = repeat if isinstance(repeat, int) and not isinstance(repeat, bool) and repeat >= 1 else 1
    for skip in _frame_skips(parent):
        repeat *= skip
    return repeat


def _frame_skips(parent: Any) -> list[int]:
    """The ``frame_skip`` of each ``FrameSkipTransform`` of ``parent`` (a transform or a ``Compose`` of them)."""
    from torchrl.envs.transforms import Compose, FrameSkipTransform

    transform = getattr(parent, "transform", None)
    return [
        int(t.frame_skip)
        for t in (transform if isinstance(transform, Compose) else (transform,))
        if isinstance(t, FrameSkipTransform)
    ]


def _warn_frame_skip_twice(parent: Any) -> None:
    """Warns when TorchRL repeats an env's whole step ``frame_skip`` times because the env has a ``frame_skip``
    attribute (``EnvBase`` appends a ``FrameSkipTransform`` then), while sim2real reads that attribute as the env's
    physics steps per step, as gymnasium's MujocoEnv means it: timing models then count ``frame_skip ** 2`` physics
    steps per TorchRL step, right only if the env's ``_step`` itself runs ``frame_skip`` physics steps and the user
    wants TorchRL to repeat that again."""
    base = parent.base_env
    skip = vars(base).get("frame_skip")  # (from __dict__, as TorchRL reads it)
    if not isinstance(skip, int) or isinstance(skip, bool) or skip <= 1:
        return
    if getattr(type(base), "_has_frame_skip", False) or skip not in _frame_skips(parent):
        return
    warnings.warn(
        f"TorchRL repeats each step of {type(base).__name__} {skip} times (it appends FrameSkipTransform({skip}) to "
        f"an EnvBase with a `frame_skip` attribute), and sim2real reads that attribute as the env's physics steps "
        f"per step: latency and jitter count {skip * skip} physics steps per TorchRL step. If the env's _step already "
        "runs `frame_skip` physics steps, set `_has_frame_skip = True` on its class so TorchRL does not repeat it; if "
        "it runs one, name the attribute otherwise.",
        UserWarning,
        stacklevel=2,
    )


def _key_name(key: NestedKey) -> str:
    """The name a (possibly nested) observation entry goes by in selections and reports: ``"robot.qpos"`` for
    ``("robot", "qpos")``.

    Example:
        >>> _key_name(("robot", "qpos")), _key_name("observation")
        ('robot.qpos', 'observation')
    """
    return key if isinstance(key, str) else ".".join(key)


def _observation_parts(env: Any, size: int) -> list[tuple[str, slice, tuple[int, ...]]] | None:
    """``observation_layout`` of the gymnasium env under ``env`` (TorchRL envs forward attribute lookups to the env
    they wrap) when it is a layout of ``size`` entries, else None."""
    try:
        parts = getattr(env, "observation_layout", None)
    except Exception:  # a forwarding __getattr__ that fails for another reason: no layout
        return None
    if not isinstance(parts, tuple) or not parts:
        return None
    try:
        out = [(str(k), sl, tuple(shape)) for k, sl, shape in parts]
    except (TypeError, ValueError):
        return None
    if sum(sl.stop - sl.start for _, sl, _ in out if isinstance(sl, slice)) != size:
        return None
    return out


def _spec_bounds(spec: Any, n: int) -> tuple[Any, Any]:
    import numpy as np

    space = getattr(spec, "space", None)
    low, high = getattr(space, "low", None), getattr(space, "high", None)
    if low is None or high is None:
        return np.full(n, -np.inf), np.full(n, np.inf)
    low_np = np.broadcast_to(
        low.detach().cpu().numpy().astype(np.float64), (n,) if low.numel() in (1, n) else low.shape
    )
    high_np = np.broadcast_to(high.detach().cpu().numpy().astype(np.float64), low_np.shape)
    return np.ravel(low_np)[-n:].copy(), np.ravel(high_np)[-n:].copy()


def _numpy_dtype(dtype: torch.dtype) -> Any:
    return torch.empty((), dtype=dtype).numpy().dtype
