"""The batched engine: N worlds of one task, each its own ``MjModel`` copy with its own draws, stepped together.

World ``i`` *is* ``sim2real.wrap(sim2real.make(task), *effects, seed=(seed, i))`` (built headless,
``textures=False``, which changes no physics): it is built and reset through
that single env (so its draws, its reported parameters and the task's own episode randomness are those of the
single env by construction: no address handling or drawing is repeated here). Only ``step`` bypasses the
Python env stack: the engine computes all controls at once, then advances every world in one call to MuJoCo's
own thread-pooled batch (:mod:`sim2real.batched.worlds`: one persistent ``mujoco.batch.Batch``, world ``i``
simulated on world ``i``'s own ``MjModel`` with its own ``MjData``), with the stages that reproduce the single
env's C calls bitwise (dm-control's legacy step: ``mj_step2``, ``mj_step`` for further substeps, ``mj_step1``;
arm-reach: ``mj_step`` over its substeps, ``mj_forward``); every world's observation and reward are one numpy
operation each over the batch's live ``(N, ...)`` arrays (:mod:`sim2real.batched.kernels`); noise and observation
latency run the same way (:mod:`sim2real.batched.signals`). ``ActionLatency`` on the actuator command is applied
inside each world's physics step as the single env's signal clock applies it (the delayed command from a
preallocated ring; in two batch calls when it arrives mid control step, one pair per distinct split point).
``threads=k`` runs the batch on k threads (the caller's included); results are bitwise the same at any k.

``mujoco.batch`` vs ``mujoco.rollout``: a rollout restarts each world from ``mjSTATE_FULLPHYSICS``, which leaves
out the solver's warm start, and returns the sensors of the *pre*-integration forward pass. A persistent batch
keeps one ``MjData`` per world (warm start and derived fields included), takes the warm start in its state rows,
and ``step(stage=mjSTAGE_VEL)`` leaves the new state's kinematics current and continues the next step from them
(dm-control's ``mj_step1`` ... ``mj_step2`` bracket). How a reset world's state is loaded into the batch, and what
is set again after a model edit, is in :mod:`sim2real.batched.worlds`. A stepped world's state lives in the batch;
``datas[i]`` copies it into the single env's ``MjData`` when read.

Example:
    >>> import sim2real as s2r
    >>> envs = make_batched("dmc/reacher-easy", 3, s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), seed=0)
    >>> obs, params = envs.reset(seed=0)
    >>> obs.shape, params["dof_damping[shoulder]"].shape
    ((3, 6), (3,))
    >>> obs, reward, terminated, truncated, diverged = envs.step(np.zeros((3, 2), np.float32))
    >>> reward.shape, bool(truncated.any())
    ((3,), False)
    >>> envs.close()
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from sim2real.batched.adr import BatchedADR, adr_of
from sim2real.batched.kernels import KERNELS, Kernel, kernel_factory, kernel_for
from sim2real.batched.signals import BatchedSignals, signals_reason
from sim2real.batched.worlds import BatchedPhysics, default_threads

__all__ = ["BatchedEnv", "make_batched", "supports"]


def supports(task: Any, *effects: Any, options: Mapping[str, Any] | None = None) -> str | None:
    """Why the batched engine cannot run ``task`` with ``effects`` and ``make`` ``options`` (None when it can).

    Example:
        >>> import sim2real as s2r
        >>> supports("dmc/reacher-easy", s2r.Mass(scale=s2r.Uniform(0.8, 1.2))) is None
        True
        >>> supports("dmc/jaco-reach_site")
        "no batched kernel for task 'dmc/jaco-reach_site'"
    """
    from randomizers import ADR, Effect, Interval, Push
    from sim2real.wrapping import _flatten

    factory = kernel_factory(task)
    if factory is None:
        if not isinstance(task, str):
            return f"no batched kernel for an env object ({type(task).__name__}): the engine builds its worlds from a task id"
        if task.startswith(("gym/", "env:")):
            return (
                f"no batched kernel for task {task!r}: its observations, rewards and ends come from the env's own "
                "Python step, which the engine cannot compute for all worlds at once (an MJCF file as "
                "'model:<path>' can be batched)"
            )
        return f"no batched kernel for task {task!r}"
    allowed = factory().options
    unknown = sorted(set(options or {}) - set(allowed))
    if unknown:
        return f"task options {unknown} are not batched (allowed: {list(allowed)})"
    # An ADR controller's effects are drawn at reset like any other (sim2real.batched.adr reports the episodes).
    flat = [x for e in _flatten(effects) for x in (e.effects if isinstance(e, ADR) else (e,))]
    reason = signals_reason([e for e in flat if not isinstance(e, Effect)])
    if reason is not None:
        return reason
    for effect in flat:
        if not isinstance(effect, Effect):
            continue
        if isinstance(effect, Push) or isinstance(effect.schedule, Interval):
            return f"{type(effect).__name__} acts during the episode (per-step effects are not batched)"
        if type(effect).__module__.startswith("randomizers.visual"):
            return f"{type(effect).__name__} is a visual effect (the batched engine does not render)"
    return None


class _WorldDatas(Sequence[mujoco.MjData]):
    """``datas[i]``: world ``i``'s ``MjData`` as the single env would hold it (copied out of the batch on read)."""

    def __init__(self, physics: BatchedPhysics) -> None:
        self._physics = physics

    def __len__(self) -> int:
        return len(self._physics.datas)

    def __getitem__(self, i: Any) -> Any:
        if isinstance(i, slice):
            return [self._physics.data(k) for k in range(len(self))[i]]
        return self._physics.data(int(i))


def _check_count(num_envs: Any) -> int:
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise ValueError(f"`num_envs` must be an int >= 1. Received {num_envs!r}.")
    return int(num_envs)


def _is_seed(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, np.integer)) and bool(value >= 0)


def _reset_seeds(seed: Any, idx: np.ndarray) -> list[int | None]:
    """The reset seed of each world of ``idx`` (see :meth:`BatchedEnv.reset`), or a ValueError naming ``seed``.

    Example:
        >>> _reset_seeds(5, np.arange(2)), _reset_seeds([None, 7], np.arange(2))
        ([5, 6], [None, 7])
        >>> _reset_seeds(1.5, np.arange(2))
        Traceback (most recent call last):
        ...
        ValueError: `seed` must be None, an int >= 0 or a sequence of one int >= 0 or None per reset world (2). Received 1.5 (float).
    """
    if seed is None:
        return [None] * len(idx)
    if _is_seed(seed):
        return [int(seed) + int(i) for i in idx]
    allowed = f"None, an int >= 0 or a sequence of one int >= 0 or None per reset world ({len(idx)})"
    if isinstance(seed, (Sequence, np.ndarray)) and not isinstance(seed, (str, bytes)):
        seeds = list(seed)
        wrong = [s for s in seeds if s is not None and not _is_seed(s)]
        if len(seeds) == len(idx) and not wrong:
            return [None if s is None else int(s) for s in seeds]
        what = f"{len(seeds)} seeds" if len(seeds) != len(idx) else f"the entries {wrong!r}"
        raise ValueError(f"`seed` must be {allowed}. Received {what}: {seed!r}.")
    raise ValueError(f"`seed` must be {allowed}. Received {seed!r} ({type(seed).__name__}).")


def _check_indices(indices: Any, n: int) -> np.ndarray:
    """``indices`` as int64 world numbers in ``[0, n)``, or a ValueError naming ``indices``."""
    idx = np.asarray(indices).reshape(-1)
    if idx.dtype == bool or not (np.issubdtype(idx.dtype, np.integer) or idx.size == 0):
        raise ValueError(f"`indices` must be world numbers (ints in [0, {n})). Received {indices!r}.")
    idx = idx.astype(np.int64)
    outside = idx[(idx < 0) | (idx >= n)]
    if outside.size:
        raise ValueError(f"`indices` must be world numbers in [0, {n}). Received {outside.tolist()} among them.")
    return idx


class BatchedEnv:
    """``num_envs`` worlds of one task stepped together (see the module docstring).

    Args:
        task: a task id with a batched kernel (:data:`sim2real.batched.kernels.KERNELS`) or an MJCF file as
            ``"model:<path>"`` (:class:`~sim2real.batched.kernels.MjcfKernel`).
        num_envs: worlds N.
        effects: physics effects from :mod:`randomizers` (drawn per episode; per-step effects are refused), signal
            models, and at most one :class:`~randomizers.ADR` controller shared by all worlds (each pins its own
            boundaries; the episodes are reported in world order, :mod:`sim2real.batched.adr`).
        seed: root seed; world ``i`` draws from the streams of ``(seed, i)``.
        envs: N envs from :func:`sim2real.make` to use as the worlds instead of making new ones (evaluation
            reuses its envs across conditions); :meth:`close` then releases them, restored and still open.
        stream_seeds: the root seed of each world's streams instead of ``(seed, i)`` (evaluation wraps every
            env with its own root seed and tells episodes apart by reset seed).
        end_diverged: False mirrors a task env *without* sim2real's wrappers where that differs: a gymnasium
            env (arm-reach) whose physics diverged goes on from the state MuJoCo reset to, unflagged (evaluation
            steps unrandomised conditions on bare envs). dm-control envs end such episodes either way.
        threads: threads of MuJoCo's batch that steps the worlds, the caller's included (results are bitwise the
            same at any count). None: :func:`~sim2real.batched.worlds.default_threads` (the idle cores, at most N).
        options: keyword arguments for :func:`sim2real.make` (those the task's kernel lists in ``options``).
            Worlds the engine builds itself are headless (``textures=False`` unless given: the engine never
            renders, and without reacher's 11.8 MB skybox a world is built several times faster; the physics,
            hence every observation, reward and draw, is bitwise the same).

    Attributes:
        num_envs: N.
        envs: the single envs behind the worlds (built and reset through them; do not step them).
        models: each world's ``MjModel``.
        datas: each world's ``MjData``: ``datas[i]`` copies world ``i``'s whole state out of the batch into its
            single env's ``MjData`` and returns that (contacts and constraints included).
        physics: the worlds' :class:`~sim2real.batched.worlds.BatchedPhysics` (MuJoCo's batch, live arrays).
        threads: threads of the batch.
        params: address -> ``(N,)`` values in use this episode (NaN for an address a world does not draw).
        step_limit: control steps per episode (the task's own limit).
    """

    def __init__(
        self,
        task: str,
        num_envs: int,
        effects: Sequence[Any] = (),
        *,
        seed: int = 0,
        envs: Sequence[Any] | None = None,
        stream_seeds: Sequence[Any] | None = None,
        threads: int | None = None,
        end_diverged: bool = True,
        **options: Any,
    ) -> None:
        from sim2real.physics import find_physics
        from sim2real.tasks import make
        from sim2real.wrapping import wrap

        n = _check_count(num_envs)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"`seed` must be an int >= 0. Received {seed!r}.")
        if threads is not None and (
            isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1
        ):
            raise ValueError(f"`threads` must be an int >= 1. Received {threads!r}.")
        reason = supports(task, *effects, options=options)
        if reason is not None:
            raise ValueError(
                f"`task` and `effects` must be supported by the batched engine (tasks {sorted(KERNELS)} or an MJCF "
                f"model 'model:<path>', physics "
                f"effects drawn per episode): {reason}. Received task {task!r}."
            )
        self.task = task
        self.num_envs = n
        self.seed = int(seed)
        self.kernel: Kernel = kernel_for(task)
        for argument, given in (("envs", envs), ("stream_seeds", stream_seeds)):
            if given is not None and len(given) != n:
                raise ValueError(f"`{argument}` must hold one entry per world ({n}). Received {len(given)}.")
        self._owned = envs is None
        # Headless where the task can be built so (an MJCF model has no textures option).
        built = {"textures": False, **options} if "textures" in self.kernel.options else dict(options)
        bases = [make(task, **built) for _ in range(n)] if envs is None else list(envs)
        roots = [(self.seed, i) for i in range(n)] if stream_seeds is None else list(stream_seeds)
        self.envs = [wrap(base, *effects, seed=root) for base, root in zip(bases, roots, strict=True)]
        self._bases = bases
        handles = [find_physics(env) for env in self.envs]
        self.models = [h.model for h in handles]  # type: ignore[union-attr]
        # The single envs' MjData: the state a reset leaves, which BatchedPhysics.load reads.
        self._datas = [h.data for h in handles]  # type: ignore[union-attr]
        kernel = self.kernel
        kernel.configure(self.envs[0])
        self._n_sub = kernel.substeps(self.envs[0])
        self.step_limit: float = kernel.step_limit(self.envs[0])
        m0 = self.models[0]
        # dm-control's legacy step (mj_step2 ... mj_step1) unless the physics opts out; arm-reach's "forward".
        legacy = kernel.scheme != "dm_control" or bool(
            getattr(self.envs[0].unwrapped.dm_env.physics, "legacy_step", True)
        )
        site = (
            -1
            if kernel.jacobian_site is None
            else mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_SITE, kernel.jacobian_site)
        )
        self.physics = BatchedPhysics(
            self.models,
            self._datas,
            self._n_sub,
            kernel.scheme,
            legacy=legacy,
            fields=kernel.fields,
            jacobian_site=site,
            threads=default_threads(n) if threads is None else int(threads),
        )
        self.threads = self.physics.threads
        self.datas = _WorldDatas(self.physics)
        # MuJoCo's warning counters: a step that raises one is how dm-control (any warning, PhysicsError) and
        # sim2real's gymnasium wrapper (bad qpos/qvel/qacc) see a diverged physics.
        self._watched = (
            slice(None)
            if kernel.diverged_reward == "zero"
            else [int(mujoco.mjtWarning.mjWARN_BADQPOS), int(mujoco.mjtWarning.mjWARN_BADQVEL),
                  int(mujoco.mjtWarning.mjWARN_BADQACC)]
        )  # fmt: skip
        self._obs = np.zeros((n, self.kernel.obs_dim), np.float32)  # the task's own (clean) observations
        # Signal models: each env's outermost wrapper corrupts signals - either the fused RandomizeAndCorrupt (whose
        # `env` is the base env) or CorruptSignals over RandomizePhysics (with ADR). Either way `env.env` gives the
        # clean observation: a RandomizePhysics' or the dm-control adapter's `_last_obs`, else the task's `_get_obs`.
        self._signals = BatchedSignals(n, self.envs) if hasattr(self.envs[0], "corruptor") else None
        self._inner = [env.env if self._signals is not None else env for env in self.envs]
        # ADR: a world's reset draws its pin through its own ADR layer; the step bypasses that layer, so the episode
        # sums and the reports to the shared controller happen here (sim2real.batched.adr).
        self._adr = BatchedADR(self._inner, kernel.reports_success) if adr_of(effects) is not None else None
        self._out = np.zeros((n, self.kernel.obs_dim), np.float32)  # what the policy sees
        self._steps = np.zeros(n, np.int64)
        self._reset_diverged = np.zeros(n, bool)
        self._stuck = False  # whether some world's reset diverged (its next step ends the episode unstepped)
        self._diverged = np.zeros(n, bool)
        self._every = np.ones(n, bool)  # read-only: "every world" for the signal models and ADR on a lockstep step
        self._every.flags.writeable = False
        self._none = np.zeros(n, bool)
        self._none.flags.writeable = False
        self._action_dim = int(np.prod(self.envs[0].action_space.shape))
        self.params: dict[str, np.ndarray] = {}
        self._world_params: list[dict[str, float]] = [{} for _ in range(n)]
        self._end_diverged = bool(end_diverged) or kernel.diverged_reward == "zero"
        # Without sim2real's wrappers, an env that ends its own episodes on some warnings (MjcfEnv: bad accelerations)
        # still ends them there, with its own observation and reward of the state MuJoCo reset to.
        self._bare_ends = not self._end_diverged and bool(kernel.bare_warnings)
        if self._bare_ends:
            self._watched = [int(w) for w in kernel.bare_warnings]
        self._ends = self._end_diverged or self._bare_ends  # whether a warning during a step can end an episode
        # ActionLatency on the actuator command: each world applies its delayed command inside its physics step.
        self._delayed = self._signals is not None and self._signals.action_path == "ctrl"
        self._closed = False

    @property
    def observation_dim(self) -> int:
        """Length of each world's flat float32 observation."""
        return self.kernel.obs_dim

    @property
    def action_dim(self) -> int:
        """Controls per world."""
        return int(self._action_dim)

    @property
    def steps(self) -> np.ndarray:
        """``(N,)`` control steps taken in each world's current episode (a copy)."""
        return self._steps.copy()

    def reset(
        self, seed: int | Sequence[int | None] | None = None, indices: Sequence[int] | np.ndarray | None = None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Starts a new episode in the worlds ``indices`` (default: all).

        Args:
            seed: None (each world continues its own streams), one int (world ``i`` is reset with
                ``seed + i``, as gymnasium vector envs do) or one seed per reset world.
            indices: the worlds to reset.

        Returns:
            ``(obs, params)``: ``(N, obs_dim)`` float32 observations of all worlds (a copy) and address ->
            ``(N,)`` values in use.
        """
        self._check_open()
        idx = np.arange(self.num_envs) if indices is None else _check_indices(indices, self.num_envs)
        seeds = _reset_seeds(seed, idx)  # every seed checked before any world is reset
        for i, s in zip(idx.tolist(), seeds, strict=True):
            obs, info = self.envs[i].reset(seed=s)
            self._out[i] = obs
            inner = self._inner[i]  # the layer under the signal models: its observation is the clean one
            clean = getattr(inner, "_last_obs", None)  # RandomizePhysics, the dm-control adapter
            self._obs[i] = self.kernel.observe(inner) if clean is None else clean  # a bare gymnasium task
            if self._signals is not None:
                self._signals.reset_world(i, self.envs[i], self._out[i], self._datas[i].ctrl)
            report = info["sim2real"]
            self._world_params[i] = report["params"]
            self._reset_diverged[i] = self._diverged[i] = bool(report["diverged"]) and self._end_diverged
            self._steps[i] = 0
            if self._adr is not None:
                self._adr.start(i)
        self._stuck = bool(self._reset_diverged.any())
        self.physics.load(idx)  # the reset worlds' state (and their models' draws) into MuJoCo's batch
        self.kernel.bind(self.models, self.envs)
        keys = sorted({k for p in self._world_params for k in p})
        self.params = {k: np.array([p.get(k, math.nan) for p in self._world_params], np.float64) for k in keys}
        return self._out.copy(), dict(self.params)

    def step(
        self, actions: np.ndarray, mask: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One control step of every world (of the worlds where ``mask`` is True).

        Args:
            actions: ``(N, action_dim)`` controls (cast to float64 as the dm-control adapter does).
            mask: ``(N,)`` bool, the worlds to step (the others keep their state; their rewards are 0).

        Returns:
            ``(obs, reward, terminated, truncated, diverged)``: ``(N, obs_dim)`` float32, ``(N,)`` float64 and
            three ``(N,)`` bool arrays (fresh arrays). A world whose physics diverged ends its episode with
            ``truncated=True``, ``diverged=True``, reward 0 and its last finite observation, as the single env.
        """
        shape = np.shape(actions)
        if shape != (self.num_envs, self._action_dim):
            raise ValueError(f"`actions` must have shape ({self.num_envs}, {self._action_dim}). Received {shape}.")
        if mask is None and not self._stuck:
            return self._step_every(actions)
        return self._step_masked(actions, mask)

    def _step_every(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`step` of every world when no reset left one diverged: the masked step's arithmetic with every mask
        all True, so without it (no mask built, copied or combined; the same values). A step on which a world's
        physics raised a warning is finished by the masked step's code."""
        signals = self._signals
        if signals is not None:
            actions = signals.act(actions, self._every, True)
        actions = np.asarray(actions, dtype=np.float64)
        physics, kernel, watched = self.physics, self.kernel, self._watched
        warnings = physics.warnings
        before = warnings[:, watched].sum(axis=1)
        qpos, qvel, gathered = physics.qpos, physics.qvel, physics.gathered
        controls = kernel.controls(actions, qpos, gathered)
        if self._delayed:
            self._step_delayed(None, controls)
        else:
            physics.step(None, controls)
        raised = warnings[:, watched].sum(axis=1) > before
        if self._ends and raised.any():
            every = np.ones(self.num_envs, bool)
            return self._finish(every, every.copy(), np.zeros(self.num_envs, bool), True, raised)
        # Kernels return fresh arrays: the observation is handed out as it is, and the reward and termination of a
        # step where every world was paid are the kernel's own (np.where over an all-True mask copies them).
        fresh, reward, terminated = kernel.outputs(qpos, qvel, gathered)
        np.copyto(self._obs, fresh)
        self._steps += 1
        truncated = self._steps >= self.step_limit
        if self._adr is not None:
            self._adr.observe(reward, terminated, terminated | truncated, self._every, self._none)
        if signals is not None:
            self._out = signals.observe(self._obs, self._every, self._out, True)
            fresh = self._out.copy()
        else:
            np.copyto(self._out, fresh)
        return fresh, reward, terminated, truncated, np.zeros(self.num_envs, bool)

    def _step_masked(
        self, actions: np.ndarray, mask: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`step` in general: some worlds masked out, or a diverged reset to end."""
        n = self.num_envs
        active = np.ones(n, bool) if mask is None else np.asarray(mask, dtype=bool).copy()
        everyone = mask is None or bool(active.all())
        signals = self._signals
        if signals is not None:  # a world's noise advances on every step its env takes, stepped or not
            actions = signals.act(actions, active, everyone)
        actions = np.asarray(actions, dtype=np.float64)
        stuck = active & self._reset_diverged  # a reset that diverged: the next step ends the episode unstepped
        signalled = active.copy()
        active &= ~self._reset_diverged
        physics = self.physics
        warnings = physics.warnings
        before = warnings[:, self._watched].sum(axis=1)
        qpos, gathered, kernel = physics.qpos, physics.gathered, self.kernel
        controls = kernel.controls(actions, qpos, gathered)
        ids = None if active.all() else np.flatnonzero(active).astype(np.int32)
        if self._delayed:
            self._step_delayed(ids, controls)
        else:
            physics.step(ids, controls)
        raised = warnings[:, self._watched].sum(axis=1) > before
        return self._finish(active, signalled, stuck, everyone, raised)

    def _finish(
        self, active: np.ndarray, signalled: np.ndarray, stuck: np.ndarray, everyone: bool, raised: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The rest of a step after the physics: ends, rewards, observations (``active``: the worlds stepped;
        ``signalled``: those whose env took the step; ``stuck``: those whose step only ends a diverged reset)."""
        n, kernel, physics, signals = self.num_envs, self.kernel, self.physics, self._signals
        # A warning during the step: MuJoCo reset the world (bad positions, velocities or accelerations) or
        # ran out of room. dm-control raises PhysicsError there and the adapter ends the episode with reward 0; a
        # gymnasium env's own step returns what it computes, and RandomizePhysics ends the episode. Both keep the
        # last observation.
        diverged = active & raised if self._ends else np.zeros(n, bool)
        fresh, reward, terminated = kernel.outputs(physics.qpos, physics.qvel, physics.gathered)
        keep = active & ~diverged
        if self._bare_ends:  # the bare env returns the observation of the state MuJoCo reset to
            self._obs[active] = fresh[active]
        self._obs[keep] = fresh[keep]
        paid = keep if kernel.diverged_reward == "zero" else active
        reward = np.where(paid, reward, 0.0)
        terminated = terminated & paid
        self._steps[active] += 1
        truncated = (keep & (self._steps >= self.step_limit)) | diverged | stuck
        self._diverged |= diverged
        self._reset_diverged &= ~stuck
        self._stuck = bool(self._reset_diverged.any())
        if self._adr is not None:  # after every world's step, in world order (then the collector's resets)
            self._adr.observe(reward, terminated, terminated | truncated, signalled, stuck)
        if signals is not None:
            self._out = signals.observe(self._obs, signalled, self._out, everyone)
        else:
            self._out = self._obs.copy()
        return self._out.copy(), reward, terminated, truncated, self._diverged & (diverged | stuck)

    def _step_delayed(self, ids: np.ndarray | None, controls: np.ndarray) -> None:
        """One control step of the worlds ``ids`` (None: all) with ActionLatency on the actuator command, as the
        single env's signal clock applies it.

        World ``i``'s command of control step ``k`` is sent at physics step ``k * n`` and applied from ``k * n + d``
        on (``d = q * n + r`` physics steps, this episode's draw); until then the command at reset holds. With
        ``r == 0`` (or before the first delayed command arrives) a control step runs one command, the one sent
        ``q`` steps ago, as a whole step; else two pieces, ``r`` substeps of the older command and ``n - r`` of the
        newer (:meth:`~sim2real.batched.worlds.BatchedPhysics.step_split`, one call pair per distinct ``r``).
        Worlds that reset together, drew the same latency and have all been stepped since (``command_common``)
        share one ring slot per step: the writes and reads are views, not per-world gathers.
        """
        signals = self._signals
        assert signals is not None  # _delayed implies signal models
        ring = signals.command_ring
        size = ring.shape[1]
        if ids is None:
            if signals.command_check:
                signals.command_check = False
                lag, rest, steps = signals.command_lag, signals.command_rest, self._steps
                if (steps == steps[0]).all() and (lag == lag[0]).all() and (rest == rest[0]).all():
                    signals.command_common = (int(lag[0]), int(rest[0]))
            common = signals.command_common
            if common is not None:
                q, r = common
                k = int(self._steps[0])  # the commands every world sent before this one this episode
                ring[:, k % size] = controls
                newer = ring[:, (k - q) % size]  # a slot not yet written this episode holds the reset command
                if r == 0 or k < q:
                    self.physics.step(None, newer)
                else:
                    every = np.arange(self.num_envs, dtype=np.int32)
                    self.physics.step_split(every, r, ring[:, (k - q - 1) % size], newer)
                return
            ids = np.arange(self.num_envs, dtype=np.int32)
        else:  # a masked step: the worlds' commands no longer line up
            signals.command_common = None
            signals.command_check = True
        # All the worlds' ring writes and reads at once: k = the commands a world sent before this one this episode.
        k, q, rests = self._steps[ids], signals.command_lag[ids], signals.command_rest[ids]
        ring[ids, k % size] = controls[ids]
        newer = ring[ids, (k - q) % size]  # a slot not yet written this episode holds the reset command
        whole = (rests == 0) | (k < q)
        commands = np.empty_like(controls)
        commands[ids] = newer
        self.physics.step(ids[whole], commands)
        if whole.all():
            return
        older = ring[ids, (k - q - 1) % size]
        split = ~whole
        for rest in np.unique(rests[split]).tolist():
            pick = split & (rests == rest)
            self.physics.step_split(ids[pick], rest, older[pick], newer[pick])

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("BatchedEnv is closed.")

    def close(self) -> None:
        """Closes every world's env, or releases the ``envs`` given (nominal model restored bitwise, still open)."""
        if not self._closed:
            self._closed = True
            if not self._owned:  # the given envs keep the state their worlds reached, as if stepped themselves
                for i in range(self.num_envs):
                    self.physics.data(i)
            for env, base in zip(self.envs, self._bases, strict=True):
                if self._owned:
                    env.close()
                    continue
                while env is not base:  # every sim2real layer (signals, then physics) lets go of the given env
                    env = env.release()


def make_batched(task: str, num_envs: int, *effects: Any, seed: int = 0, **options: Any) -> BatchedEnv:
    """``num_envs`` worlds of ``task`` stepped together; world ``i`` is bitwise the single env
    ``sim2real.wrap(sim2real.make(task), *effects, seed=(seed, i))`` (draws, observations, rewards, ends).

    Args:
        task: a task id with a batched kernel (``sim2real.batched.kernels.KERNELS``) or ``"model:<path>"``.
        num_envs: worlds N.
        *effects: physics effects from :mod:`randomizers` drawn per episode (lists are flattened).
        seed: root seed of every world's streams.
        **options: keyword arguments for :func:`sim2real.make`.

    Raises:
        ValueError: a task without a kernel, effects the engine cannot batch, bad counts or seeds.

    Example:
        >>> import sim2real as s2r
        >>> envs = make_batched("dmc/reacher-hard", 2, seed=3)
        >>> obs, params = envs.reset(seed=[5, 6])
        >>> single = s2r.wrap(s2r.make("dmc/reacher-hard"), seed=(3, 1))
        >>> bool((single.reset(seed=6)[0] == obs[1]).all())
        True
    """
    return BatchedEnv(task, num_envs, effects, seed=seed, **options)
