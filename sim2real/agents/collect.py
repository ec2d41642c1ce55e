"""Where training collects its frames: N worlds of the batched engine, or one env (today's TorchRL path).

:func:`choose_collection` decides from the task, the effects and the config, and says why when it falls back;
:func:`make_collection_env` builds the TorchRL env to collect from. On the batched path that env is one
:class:`~sim2real.batched.torchrl_env.BatchedTorchRLEnv` with ``batch_size=[N]`` (plus ``RewardSum``): one
policy forward and one engine step per N frames instead of N TorchRL env steps, and world ``i`` is the single env
``sim2real.wrap(sim2real.make(task), *effects, seed=(seed, i))``, so the keyed-stream promise holds per world.
The engine's observations and rewards are float32 already, so there is no ``DoubleToFloat`` on this path.

What falls back to one env (``Collection.reason`` says which): ``engine="per-env"``, an env object instead of a
task id, and whatever :func:`sim2real.batched.supports` refuses (tasks without a batched kernel, per-step effects,
visual effects, signal models it does not batch such as ``SampleAndHold`` or a jittered latency). An ADR
controller is batched too: every world pins its own boundaries from its own stream and reports its episodes to the
one controller, in world order (:mod:`sim2real.batched.adr`).

SAC keeps collecting one env step at a time (:mod:`sim2real.agents.sac_loop`): its runs are update-bound. In a
default ``SACConfig(frames=4000)`` run on reacher-easy, env steps took 3.7% of the CPU time, the exploration
forwards 4.7% and the updates 75% (BENCHMARKS.md, issue 15 PPO collection), so batched collection could save at
most ~8% while changing what a SAC run is (N transitions per policy sample).

Example:
    >>> import sim2real as s2r
    >>> from sim2real.agents import PPOConfig
    >>> choose_collection("dmc/reacher-easy", [s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], PPOConfig())
    Collection(engine='batched', num_envs=20, reason=None)
    >>> print(choose_collection("dmc/reacher-easy", [], PPOConfig(frames_per_batch=1000)))
    batched engine, 20 worlds x 50 steps per batch
    >>> print(choose_collection("dmc/jaco-reach_site", [], PPOConfig()))
    per-env (one TorchRL env): no batched kernel for task 'dmc/jaco-reach_site'
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["Collection", "choose_collection", "make_collection_env", "make_train_env", "worlds_for"]

BATCHED = "batched"
PER_ENV = "per-env"


@dataclass(frozen=True)
class Collection:
    """How a training run collects its frames.

    Attributes:
        engine: ``"batched"`` (N worlds of :mod:`sim2real.batched` in one TorchRL env) or ``"per-env"`` (one env).
        num_envs: worlds stepped together (1 on the per-env path).
        reason: why the run collects per env (None on the batched engine).
        steps_per_batch: each world's steps per collected batch (``frames_per_batch / num_envs``); 0 when not
            tied to a batch (SAC).
        env: what the per-env path steps: ``"TorchRL"`` (PPO's collector; SAC on an env object) or
            ``"gymnasium"`` (SAC on a task id or gymnasium env, stepped directly).
    """

    engine: str
    num_envs: int
    reason: str | None = None
    steps_per_batch: int = 0
    env: str = "TorchRL"

    def __repr__(self) -> str:
        return f"Collection(engine={self.engine!r}, num_envs={self.num_envs}, reason={self.reason!r})"

    def __str__(self) -> str:
        if self.engine == BATCHED:
            per = f" x {self.steps_per_batch} steps per batch" if self.steps_per_batch else ""
            return f"batched engine, {self.num_envs} worlds{per}"
        return f"per-env (one {self.env} env): {self.reason}"


def worlds_for(frames_per_batch: int, num_envs: int) -> int:
    """The largest world count ``<= num_envs`` that divides ``frames_per_batch`` (so a batch holds exactly
    ``frames_per_batch`` frames, ``frames_per_batch / worlds`` from each world).

    Example:
        >>> worlds_for(1000, 16), worlds_for(4000, 16), worlds_for(200, 16), worlds_for(97, 16)
        (10, 16, 10, 1)
    """
    n = max(1, min(int(num_envs), int(frames_per_batch)))
    while frames_per_batch % n:
        n -= 1
    return n


def _per_env(reason: str) -> Collection:
    return Collection(PER_ENV, 1, reason)


def choose_collection(task_or_env: Any, effects: Sequence[Any], config: Any) -> Collection:
    """The collection path :func:`~sim2real.agents.train` takes for ``task_or_env`` under ``effects``.

    Args:
        task_or_env: what ``train`` was given (a task id, a gymnasium env or a TorchRL env).
        effects: the run's effects, its ADR controller included.
        config: a :class:`~sim2real.agents.PPOConfig` (its ``engine``, ``num_envs`` and ``frames_per_batch``).

    Returns:
        A :class:`Collection`: batched when ``config.engine`` is ``"auto"`` and the engine supports the task and
        effects, else per-env with the reason.
    """
    from sim2real.batched import supports
    from sim2real.wrapping import _flatten

    if getattr(config, "engine", PER_ENV) == PER_ENV:
        return _per_env("engine='per-env' was asked for")
    if not isinstance(task_or_env, str):
        return _per_env(
            f"an env object ({type(task_or_env).__name__}) was given; the batched engine builds its worlds from a "
            "task id"
        )
    flat = _flatten(effects)
    reason = supports(task_or_env, *flat)
    if reason is not None:
        return _per_env(reason)
    n = worlds_for(config.frames_per_batch, config.num_envs)
    return Collection(BATCHED, n, None, config.frames_per_batch // n)


def make_collection_env(task_or_env: Any, effects: Sequence[Any], seed: int, collection: Collection) -> Any:
    """The TorchRL env to collect from on ``collection``'s path, seeded with ``seed``.

    Per env: :func:`~sim2real.agents.make_train_env`. Batched: ``BatchedTorchRLEnv(task, N, *effects, seed=seed)``
    with ``RewardSum`` (the episode return under ``"episode_reward"``); its first full reset seeds world ``i``
    with ``seed + i`` (gymnasium's vector convention), later resets continue each world's own streams.

    Example:
        >>> env = make_collection_env("dmc/reacher-easy", [], 0, Collection("batched", 2, None, 5))
        >>> td = env.rollout(3)
        >>> td.batch_size, td["next", "episode_reward"].shape
        (torch.Size([2, 3]), torch.Size([2, 3, 1]))
        >>> env.close()
    """
    if collection.engine != BATCHED:
        return make_train_env(task_or_env, effects, seed)
    from torchrl.envs import RewardSum, TransformedEnv

    from sim2real.batched.torchrl_env import BatchedTorchRLEnv
    from sim2real.wrapping import _flatten

    base = BatchedTorchRLEnv(task_or_env, collection.num_envs, *_flatten(effects), seed=seed)
    env = TransformedEnv(base, RewardSum(), auto_unwrap=False)
    env.set_seed(seed)
    return env


def make_train_env(task_or_env: Any, effects: Sequence[Any] = (), seed: int = 0) -> Any:
    """The TorchRL env ``train`` learns on: ``GymWrapper(make(task))`` (or the given env), ``sim2real.wrap``
    with ``effects``, then ``DoubleToFloat`` and ``RewardSum`` (the episode return under ``"episode_reward"``).

    Args:
        task_or_env: a task id, a gymnasium env or a TorchRL ``EnvBase`` with a flat ``"observation"``.
        effects: physics effects and signal models for :func:`sim2real.wrap`.
        seed: seeds the env and the effect streams.

    Raises:
        TypeError: an unsupported env, or one without a single ``"observation"`` vector.
        ValueError: an unknown task id.
    """
    import gymnasium as gym
    from torchrl.envs import Compose, DoubleToFloat, EnvBase, GymWrapper, RewardSum, TransformedEnv

    import sim2real

    if isinstance(task_or_env, str):
        env: Any = _with_success(GymWrapper(sim2real.make(task_or_env)))
    elif isinstance(task_or_env, gym.Env):
        env = _with_success(GymWrapper(task_or_env))
    elif isinstance(task_or_env, EnvBase):
        env = task_or_env
    else:
        raise TypeError(
            "`task_or_env` must be a task id (e.g. 'sim2real/arm-reach'), a gymnasium env or a TorchRL EnvBase. "
            f"Received {type(task_or_env).__name__}."
        )
    if effects:
        env = sim2real.wrap(env, *effects, seed=seed)
    obs_spec = env.observation_spec.get("observation", None)
    if obs_spec is None or len(obs_spec.shape) != 1:
        keys = list(env.observation_spec.keys(True, True))
        raise TypeError(
            "`task_or_env` must give one flat `observation` vector (use flatten=True for dm-control). "
            f"Received observation keys {keys}."
        )
    # auto_unwrap=False: keep a wrapped env intact instead of merging (and mutating) its transforms.
    env = TransformedEnv(env, Compose(DoubleToFloat(), RewardSum()), auto_unwrap=False)
    env.set_seed(seed)
    return env


def _with_success(env: Any) -> Any:
    """``env`` (a TorchRL ``GymWrapper``) carrying the task's ``info["is_success"]`` as an ``"is_success"`` entry when
    its gymnasium env sets one at step (``sim2real/arm-reach``), so episode metrics such as ADR's ``"auto"`` see the
    task's success instead of falling back to the return. Whether the task sets it is read from the info of one
    unseeded reset (the task's reset reports the keys its steps carry; the run seeds the env before it collects, so
    the probe changes no trajectory: checked on arm-reach with a Damping effect, 250 random steps, bitwise equal
    observations and rewards with and without the probe)."""
    base = env._env
    _, info = base.reset()
    if "is_success" not in info:
        return env
    return env.set_info_dict_reader(_SuccessReader())


class _SuccessReader:
    """TorchRL info reader: ``info["is_success"]`` (a Python or numpy bool, False when absent) as ``"is_success"``."""

    def __init__(self) -> None:
        import torch
        from torchrl.data import Composite, Unbounded

        self._spec = Composite(is_success=Unbounded(shape=(), dtype=torch.bool))
        self._torch = torch

    @property
    def info_spec(self) -> Any:
        return self._spec

    def __call__(self, info_dict: Any, tensordict: Any) -> Any:
        flag = bool(info_dict.get("is_success", False)) if isinstance(info_dict, dict) else False
        tensordict.set("is_success", self._torch.tensor(flag))
        return tensordict
