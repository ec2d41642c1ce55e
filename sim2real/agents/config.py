"""Training configurations: :class:`PPOConfig` and :class:`SACConfig`, frozen and YAML round-trippable.

Example:
    >>> cfg = PPOConfig(frames=2_000, lr=1e-3)
    >>> text = cfg.to_yaml()
    >>> text.splitlines()[0]
    'algo: ppo'
    >>> PPOConfig.from_yaml(text) == cfg
    True
    >>> load_agent_config("algo: sac\\nbatch_size: 64\\n").batch_size
    64
    >>> PPOConfig(lr=-1.0)
    Traceback (most recent call last):
    ...
    ValueError: `lr` must be > 0. Received -1.0.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import math
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import yaml

__all__ = ["ACTIVATIONS", "ENGINES", "AgentConfig", "PPOConfig", "SACConfig", "load_agent_config"]

#: Activation names accepted by ``activation``.
ACTIVATIONS: tuple[str, ...] = ("tanh", "relu", "elu")

#: Collection engines accepted by ``PPOConfig.engine`` (the values ``evaluate(engine=...)`` takes).
ENGINES: tuple[str, ...] = ("auto", "per-env")

_C = TypeVar("_C", bound="_ConfigBase")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _positive_int(name: str, value: Any) -> None:
    if not _is_int(value) or value <= 0:
        raise ValueError(f"`{name}` must be a positive int. Received {value!r}.")


def _nonnegative_int(name: str, value: Any) -> None:
    if not _is_int(value) or value < 0:
        raise ValueError(f"`{name}` must be an int >= 0. Received {value!r}.")


def _positive(name: str, value: Any) -> None:
    if not _is_real(value) or value <= 0:
        raise ValueError(f"`{name}` must be > 0. Received {value!r}.")


def _nonnegative(name: str, value: Any) -> None:
    if not _is_real(value) or value < 0:
        raise ValueError(f"`{name}` must be >= 0. Received {value!r}.")


def _unit(name: str, value: Any, *, closed_low: bool = True) -> None:
    ok = _is_real(value) and (0 <= value <= 1 if closed_low else 0 < value <= 1)
    if not ok:
        bound = "[0, 1]" if closed_low else "(0, 1]"
        raise ValueError(f"`{name}` must be in {bound}. Received {value!r}.")


def _hidden(value: Any) -> None:
    if not isinstance(value, tuple) or not value or not all(_is_int(v) and v > 0 for v in value):
        raise ValueError(f"`hidden_sizes` must be a non-empty tuple of positive ints. Received {value!r}.")


def _activation(value: Any) -> None:
    if value not in ACTIVATIONS:
        raise ValueError(f"`activation` must be one of {list(ACTIVATIONS)}. Received {value!r}.")


@dataclass(frozen=True)
class _ConfigBase:
    algo: ClassVar[str] = ""
    #: Fields left out of :meth:`to_dict` while at their default, so configs that do not use a newer option keep
    #: the form checkpoints and manifests stored before it existed.
    _omit_default: ClassVar[frozenset[str]] = frozenset({"adr"})

    def __post_init__(self) -> None:
        # YAML and JSON give lists; a tuple keeps the dataclass hashable and comparable.
        hidden = self.hidden_sizes  # type: ignore[attr-defined]
        if isinstance(hidden, list):
            object.__setattr__(self, "hidden_sizes", tuple(hidden))
        # A YAML ``1e-3`` without a dot is read as a string by PyYAML's YAML 1.1 resolver.
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("float", float) and isinstance(value, str):
                with contextlib.suppress(ValueError):
                    object.__setattr__(self, f.name, float(value))
        if getattr(self, "adr", None) is not None:  # imported only then: it loads MuJoCo
            from sim2real.agents.adr_training import adr_config_text

            object.__setattr__(self, "adr", adr_config_text(self.adr))  # type: ignore[attr-defined]
        self._validate()

    def _validate(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        """Plain-type dict (``algo`` first, tuples as lists), the form stored in YAML and checkpoints."""
        out: dict[str, Any] = {"algo": self.algo}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in self._omit_default and value == f.default:
                continue
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    def to_yaml(self) -> str:
        """YAML text of :meth:`to_dict` that :meth:`from_yaml` reads back into an equal config."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    @classmethod
    def from_dict(cls: type[_C], data: dict[str, Any], *, source: str = "config") -> _C:
        """Builds a config from a mapping; ``algo`` may be present and must then match.

        Raises:
            ValueError: wrong ``algo``, unknown keys (close matches listed) or invalid values.
        """
        if not isinstance(data, dict):
            raise ValueError(f"{source}: an agent config must be a mapping of keys to values. Received {data!r}.")
        data = dict(data)
        algo = data.pop("algo", cls.algo)
        if algo != cls.algo:
            raise ValueError(f"{source}: `algo` must be {cls.algo!r} for {cls.__name__}. Received {algo!r}.")
        allowed = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(allowed))
        if unknown:
            hints = {k: difflib.get_close_matches(k, allowed, n=1) for k in unknown}
            hint = "".join(f" {k!r} -> did you mean {v[0]!r}?" for k, v in hints.items() if v)
            raise ValueError(
                f"{source}: unknown key(s) {unknown} for {cls.__name__}; allowed: {allowed}.{hint}".rstrip()
            )
        try:
            return cls(**data)
        except ValueError as err:
            raise ValueError(f"{source}: {err}") from err

    @classmethod
    def from_yaml(cls: type[_C], text_or_path: str | os.PathLike[str]) -> _C:
        """Reads a config from YAML text or from a file (a ``Path``, or a string naming an existing file).

        Raises:
            ValueError: malformed YAML, wrong ``algo``, unknown keys or invalid values.
        """
        text, source = _read(text_or_path)
        return cls.from_dict(_parse(text, source), source=source)


def _read(text_or_path: str | os.PathLike[str]) -> tuple[str, str]:
    if isinstance(text_or_path, os.PathLike) or (
        isinstance(text_or_path, str) and "\n" not in text_or_path and Path(text_or_path).is_file()
    ):
        path = Path(text_or_path)
        return path.read_text(encoding="utf-8"), str(path)
    if not isinstance(text_or_path, str):
        raise TypeError(f"`text_or_path` must be YAML text or a path. Received {text_or_path!r}.")
    return text_or_path, "config"


def _parse(text: str, source: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ValueError(f"{source}: not valid YAML: {err}") from err


@dataclass(frozen=True)
class PPOConfig(_ConfigBase):
    """Proximal policy optimisation (TorchRL ``ClipPPOLoss`` + ``GAE``).

    Attributes:
        frames: total environment steps collected.
        frames_per_batch: steps per collection (one GAE + ``epochs`` of updates each).
        epochs: passes over each batch.
        minibatch_size: samples per gradient step; must divide into ``frames_per_batch``.
        lr: Adam learning rate (actor and critic share one optimiser).
        gamma: discount.
        gae_lambda: GAE lambda.
        clip_epsilon: PPO ratio clip.
        entropy_coef: entropy bonus weight.
        critic_coef: value-loss weight.
        max_grad_norm: gradient-norm clip.
        hidden_sizes: hidden widths of the actor and critic MLPs.
        activation: one of :data:`ACTIVATIONS`.
        init_log_std: initial log standard deviation of the (pre-tanh) Gaussian policy.
        reward_scale: rewards are multiplied by this before learning (logged returns stay unscaled).
        obs_norm_frames: random-action steps (not counted in ``frames``) whose observation mean and standard
            deviation (floored at 0.01) fix the networks' input normalisation; 0 disables it.
        bc_baseline: scripted baseline (class name from :data:`~sim2real.agents.BASELINES`, e.g. ``"ReacherPD"``)
            whose actions the actor imitates before PPO starts (behaviour-cloning warm start), or None.
        bc_frames: env steps of the baseline recorded for the warm start (not counted in ``frames``; on the
            training env, so under its randomisation); 0 disables it.
        bc_epochs: passes of mean-squared-error regression of the actor's deterministic action on them.
        adr: automatic domain randomisation for the run: YAML of an ADR config (``effects`` with Uniform or
            LogUniform hard limits, ``delta``, ``t_low``, ``t_high``, optional ``p_boundary``, ``m``, ``metric``,
            ``initial``; see :meth:`randomizers.ADR.from_config`), stored canonicalised; None for none.
        engine: one of :data:`ENGINES`. ``"auto"`` collects from ``num_envs`` worlds of the batched engine
            (:mod:`sim2real.batched`) when it supports the task and effects, else from one env as ``"per-env"``
            does (:func:`sim2real.agents.collect.choose_collection`; ``TrainResult.collection`` says which ran).
        num_envs: most batched worlds collected from at once; a run uses the largest count up to this that
            divides ``frames_per_batch`` (each world then takes ``frames_per_batch / worlds`` steps per batch).
    """

    algo: ClassVar[str] = "ppo"

    frames: int = 50_000
    frames_per_batch: int = 1_000
    epochs: int = 10
    minibatch_size: int = 250
    lr: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coef: float = 1e-4
    critic_coef: float = 0.5
    max_grad_norm: float = 1.0
    hidden_sizes: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    init_log_std: float = 0.0
    reward_scale: float = 1.0
    obs_norm_frames: int = 2_000
    bc_baseline: str | None = None
    bc_frames: int = 0
    bc_epochs: int = 20
    adr: str | None = None
    engine: str = "auto"
    num_envs: int = 20

    _omit_default: ClassVar[frozenset[str]] = frozenset({"adr", "engine", "num_envs"})

    def _validate(self) -> None:
        _positive_int("frames", self.frames)
        _positive_int("frames_per_batch", self.frames_per_batch)
        _positive_int("epochs", self.epochs)
        if self.engine not in ENGINES:
            raise ValueError(f"`engine` must be one of {list(ENGINES)}. Received {self.engine!r}.")
        _positive_int("num_envs", self.num_envs)
        from sim2real.agents.baselines import BASELINES

        names = sorted({cls.__name__ for cls in BASELINES.values()})
        if self.bc_baseline is not None and self.bc_baseline not in names:
            raise ValueError(f"`bc_baseline` must be None or one of {names}. Received {self.bc_baseline!r}.")
        _nonnegative_int("bc_frames", self.bc_frames)
        _positive_int("bc_epochs", self.bc_epochs)
        if self.bc_frames > 0 and self.bc_baseline is None:
            raise ValueError(f"`bc_frames` > 0 needs a `bc_baseline`. Received bc_frames={self.bc_frames}.")
        _positive_int("minibatch_size", self.minibatch_size)
        if self.minibatch_size > self.frames_per_batch:
            raise ValueError(
                f"`minibatch_size` must be <= `frames_per_batch` ({self.frames_per_batch}). "
                f"Received {self.minibatch_size}."
            )
        _positive("lr", self.lr)
        _unit("gamma", self.gamma)
        _unit("gae_lambda", self.gae_lambda)
        _positive("clip_epsilon", self.clip_epsilon)
        _nonnegative("entropy_coef", self.entropy_coef)
        _nonnegative("critic_coef", self.critic_coef)
        _positive("max_grad_norm", self.max_grad_norm)
        _hidden(self.hidden_sizes)
        _activation(self.activation)
        if not _is_real(self.init_log_std):
            raise ValueError(f"`init_log_std` must be a finite number. Received {self.init_log_std!r}.")
        _positive("reward_scale", self.reward_scale)
        _nonnegative_int("obs_norm_frames", self.obs_norm_frames)


@dataclass(frozen=True)
class SACConfig(_ConfigBase):
    """Soft actor-critic with twin Q networks and a learned temperature (:mod:`sim2real.agents.sac`: the update
    written on plain tensors, a uniform replay buffer). Log-probabilities, the entropy target ``-act_dim`` and the
    critics' action input live in the normalised action box ``[-1, 1]``.

    Attributes:
        frames: total environment steps collected.
        frames_per_batch: steps per collection.
        init_random_frames: steps taken with uniform random actions before learning starts.
        buffer_size: replay capacity in transitions.
        batch_size: transitions per gradient step.
        utd_ratio: gradient steps per collected step (updates-to-data ratio).
        lr: Adam learning rate of actor, critics and temperature.
        gamma: discount.
        tau: soft target-update rate.
        alpha_init: initial entropy temperature (learned towards ``target_entropy``).
        target_entropy: entropy the temperature is tuned towards, in nats of the policy in the normalised action
            box; None means ``-act_dim``. Higher keeps more exploration late in training.
        n_step: environment steps summed into each stored transition's return (``sum_k gamma^k r_k``, bootstrapped
            with ``gamma^n``; shorter at an episode's end); 1 is plain one-step SAC.
        hidden_sizes: hidden widths of the actor and Q MLPs.
        activation: one of :data:`ACTIVATIONS`.
        init_log_std: initial log standard deviation of the (pre-tanh) Gaussian policy.
        reward_scale: rewards are multiplied by this before learning (logged returns stay unscaled).
        obs_norm_frames: random-action steps (not counted in ``frames``) whose observation mean and standard
            deviation (floored at 0.01) fix the networks' input normalisation; 0 disables it.
        adr: automatic domain randomisation for the run: YAML of an ADR config (``effects`` with Uniform or
            LogUniform hard limits, ``delta``, ``t_low``, ``t_high``, optional ``p_boundary``, ``m``, ``metric``,
            ``initial``; see :meth:`randomizers.ADR.from_config`), stored canonicalised; None for none.
        angle_obs: indices of observation entries that are joint angles in radians; the actor and critics see
            ``sin`` and ``cos`` of each instead of the raw value (see :class:`~sim2real.agents.nets.Normalize`).
            An unbounded hinge's raw angle leaves the range the networks were trained on once the joint has turned
            past +-pi (dm-control reacher's shoulder); empty (the default) feeds every entry raw. The env and its
            observations are unchanged: this is part of the policy, stored with its checkpoint.
        mean_action_every: every ``k``-th training episode after the random warm-up acts with the actor's mean
            action (no sampling; its transitions are stored and counted in ``frames`` as usual), so the critics see
            where the deterministic policy that is evaluated comes to rest; 0 (the default) samples every episode.
        action_repeat: training only: each action the actor chooses is held for this many environment steps and
            stored as one transition (the held steps' rewards summed, ``gamma`` per held block; shorter at an
            episode's end). ``frames`` and ``utd_ratio`` still count environment steps, so ``utd_ratio=1/k`` is one
            update per decision. The trained policy is deployed acting at every step (evaluation, the study).
    """

    algo: ClassVar[str] = "sac"

    frames: int = 50_000
    frames_per_batch: int = 200
    init_random_frames: int = 1_000
    buffer_size: int = 100_000
    batch_size: int = 256
    utd_ratio: float = 0.25
    lr: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.005
    alpha_init: float = 1.0
    hidden_sizes: tuple[int, ...] = (256, 256)
    activation: str = "relu"
    init_log_std: float = 0.0
    reward_scale: float = 1.0
    obs_norm_frames: int = 2_000
    adr: str | None = None
    target_entropy: float | None = None
    n_step: int = 1
    angle_obs: tuple[int, ...] = ()
    mean_action_every: int = 0
    action_repeat: int = 1

    _omit_default: ClassVar[frozenset[str]] = frozenset(
        {"adr", "target_entropy", "n_step", "angle_obs", "mean_action_every", "action_repeat"}
    )

    def _validate(self) -> None:
        if isinstance(self.angle_obs, list):  # YAML and JSON give lists
            object.__setattr__(self, "angle_obs", tuple(self.angle_obs))
        angles = self.angle_obs
        if (
            not isinstance(angles, tuple)
            or not all(_is_int(i) and i >= 0 for i in angles)
            or len(set(angles)) != len(angles)
        ):
            raise ValueError(f"`angle_obs` must be a tuple of distinct ints >= 0. Received {angles!r}.")
        _positive_int("frames", self.frames)
        _positive_int("frames_per_batch", self.frames_per_batch)
        _nonnegative_int("init_random_frames", self.init_random_frames)
        _positive_int("n_step", self.n_step)
        _nonnegative_int("mean_action_every", self.mean_action_every)
        _positive_int("action_repeat", self.action_repeat)
        if self.target_entropy is not None and not _is_real(self.target_entropy):
            raise ValueError(f"`target_entropy` must be None or a finite number. Received {self.target_entropy!r}.")
        _positive_int("buffer_size", self.buffer_size)
        _positive_int("batch_size", self.batch_size)
        _positive("utd_ratio", self.utd_ratio)
        _positive("lr", self.lr)
        _unit("gamma", self.gamma)
        _unit("tau", self.tau, closed_low=False)
        _positive("alpha_init", self.alpha_init)
        _hidden(self.hidden_sizes)
        _activation(self.activation)
        if not _is_real(self.init_log_std):
            raise ValueError(f"`init_log_std` must be a finite number. Received {self.init_log_std!r}.")
        _positive("reward_scale", self.reward_scale)
        _nonnegative_int("obs_norm_frames", self.obs_norm_frames)


AgentConfig = PPOConfig | SACConfig

_BY_ALGO: dict[str, type[PPOConfig] | type[SACConfig]] = {"ppo": PPOConfig, "sac": SACConfig}


def config_class(algo: str) -> type[PPOConfig] | type[SACConfig]:
    """The config class for ``algo`` (``"ppo"`` or ``"sac"``).

    Raises:
        ValueError: unknown ``algo``.
    """
    try:
        return _BY_ALGO[algo]
    except (KeyError, TypeError):
        raise ValueError(f"`algo` must be one of {list(_BY_ALGO)}. Received {algo!r}.") from None


def load_agent_config(text_or_path: str | os.PathLike[str] | dict[str, Any]) -> PPOConfig | SACConfig:
    """Reads a PPO or SAC config (chosen by its ``algo`` key) from YAML text, a file or a dict.

    Raises:
        ValueError: missing or unknown ``algo``, unknown keys, invalid values or malformed YAML.
    """
    if isinstance(text_or_path, dict):
        data: Any = text_or_path
        source = "config"
    else:
        text, source = _read(text_or_path)
        data = _parse(text, source)
    if not isinstance(data, dict) or "algo" not in data:
        raise ValueError(f"{source}: an agent config needs an `algo` key, one of {list(_BY_ALGO)}.")
    try:
        cls = config_class(data["algo"])
    except ValueError as err:
        raise ValueError(f"{source}: {err}") from err
    return cls.from_dict(data, source=source)


def replace(config: _C, **changes: Any) -> _C:
    """A copy of ``config`` with ``changes`` applied and validated (``dataclasses.replace``)."""
    return dataclasses.replace(config, **changes)
