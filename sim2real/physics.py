"""Finding the MuJoCo model inside any environment.

:func:`find_physics` looks through gymnasium wrappers, the dm_env adapter, dm-control suite and
composer environments and TorchRL ``DMControlEnv``/``GymEnv``/``TransformedEnv`` for a
``mujoco.MjModel`` and its ``MjData``.

Example:
    >>> import sim2real
    >>> handle = sim2real.find_physics(sim2real.make("dmc/reacher-easy"))
    >>> handle.source, handle.model.nu
    ('dm_control.suite', 2)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

__all__ = ["DIVERGENCE_WARNINGS", "PhysicsHandle", "StepInterception", "declared_control_period", "find_physics"]

# MuJoCo resets the state and counts these when positions, velocities or accelerations blow up.
DIVERGENCE_WARNINGS = (
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQACC),
)
_CHILD_ATTRIBUTES = ("dm_env", "env", "_env", "base_env", "unwrapped")


@dataclass
class PhysicsHandle:
    """The MuJoCo objects behind an environment.

    Attributes:
        model: the raw ``mujoco.MjModel`` (for composer envs: the current episode's).
        data: the matching ``mujoco.MjData``.
        source: ``"dm_control.suite"``, ``"dm_control.composer"`` or ``"gymnasium"``.
        owner: the object the model was found on (the dm_env for dm-control).
        warnings: a live view of ``data.warning.number`` (cheap to read every step).
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    source: str
    owner: Any
    warnings: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.warnings = self.data.warning.number

    @property
    def recompiles(self) -> bool:
        """True for composer envs, whose physics is rebuilt on every reset."""
        return self.source == "dm_control.composer"

    def diverged(self) -> bool:
        """Whether MuJoCo flagged bad positions/velocities/accelerations since the last reset."""
        w = self.warnings
        return bool(w[3] or w[4] or w[5])

    def refresh(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Points the handle at a newly compiled model (composer)."""
        self.model, self.data = model, data
        self.warnings = data.warning.number

    def rebuilt(self) -> bool:
        """Whether a gymnasium env replaced its MuJoCo model since the handle last looked (an env that compiles a
        new model in its reset, e.g. a procedural scene); the handle then points at the new model and data.
        Composer envs say so through :meth:`on_recompile` instead.

        Example:
            >>> import gymnasium as gym
            >>> env = gym.make("InvertedPendulum-v5").unwrapped
            >>> handle = find_physics(env)
            >>> handle.rebuilt()
            False
            >>> import copy
            >>> env.model = copy.copy(env.model)  # what a rebuild in reset leaves: a new model and its data
            >>> env.data = mujoco.MjData(env.model)
            >>> handle.rebuilt(), handle.model is env.model
            (True, True)
        """
        if self.source != "gymnasium":
            return False
        owner = self.owner
        model = _attribute(owner, "model")
        if model is self.model or not isinstance(model, mujoco.MjModel):
            return False
        data = _attribute(owner, "data")
        if not isinstance(data, mujoco.MjData) or data.qpos.shape != (model.nq,):
            return False
        self.refresh(model, data)
        return True

    def on_recompile(self, callback: Callable[[mujoco.MjModel, mujoco.MjData], None]) -> Callable[..., None]:
        """Registers ``callback(model, data)`` to run right after each recompile (composer only).

        Returns the hook actually registered, for :meth:`remove_hook`.
        """

        def hook(physics: Any, random_state: Any) -> None:
            model, data = physics.model.ptr, physics.data.ptr
            self.refresh(model, data)
            callback(model, data)

        self.owner.add_extra_hook("after_compile", hook)
        return hook

    def attach(self, randomizer: Any) -> Callable[..., None] | None:
        """Binds a :class:`randomizers.PhysicsRandomizer` to this physics; on composer envs also
        re-binds and applies it after every recompile. Returns the hook (None when not needed)."""
        randomizer.bind(self.model, self.data)
        if not self.recompiles:
            return None

        def rebind(model: mujoco.MjModel, data: mujoco.MjData) -> None:
            randomizer.bind(model, data)
            randomizer.apply()

        return self.on_recompile(rebind)

    def detach(self, randomizer: Any, hook: Callable[..., None] | None) -> None:
        """Undoes :meth:`attach`: restores the nominal model bitwise and unregisters ``hook``."""
        randomizer.restore_nominal()
        if hook is not None:
            self.remove_hook(hook)

    @property
    def substeps(self) -> int | None:
        """Physics steps per control step (None when the env does not say)."""
        owner = self.owner
        for name in ("_n_sub_steps", "frame_skip", "n_substeps"):
            value = _attribute(owner, name)
            if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 1:
                return int(value)
        # An env that declares its control period instead (a hand-written dm_env's control_timestep()): the
        # physics steps of the model's timestep in it.
        period = declared_control_period(owner)
        if period is not None:
            steps = period / float(self.model.opt.timestep)
            if steps >= 0.5:
                return max(1, round(steps))
        return None

    def intercept_step(
        self,
        stepper: Callable[[Any, int, Any], None],
        direct: Callable[[Any, Any], Callable[[int], None]] | None = None,
    ) -> StepInterception:
        """Routes the env's physics stepping through ``stepper(run, nstep, runner)``.

        The env asks for ``nstep`` physics steps (once per control step, or once per substep on
        composer envs); ``stepper`` decides what happens and calls ``run(k)`` to advance ``k`` steps
        with the env's own stepping code and the current ``data.ctrl``, or
        ``runner.split([(ctrl, k), ...])`` to advance in pieces with a command each, which does the
        same work as one unsplit step (no extra kinematics or collision passes). Returns the
        :class:`StepInterception` (call it to remove the interception).

        ``direct(run, runner)``, when given, returns the function installed as dm-control's ``Physics.step``
        itself (it must do what ``stepper`` does): one Python call per physics step instead of two, for a stepper
        on the hot path. Other envs ignore it. On dm-control the interceptions of one physics form a chain in the
        order they were installed (see :class:`StepInterception`): the last one installed runs first.

        Raises:
            TypeError: the env steps MuJoCo in a way that cannot be intercepted.
        """
        owner = self.owner
        if self.source.startswith("dm_control"):
            link = _Link(stepper, direct)

            def install(physics: Any) -> None:
                _DmStepChain.of(physics).add(link)

            install(owner.physics)
            hook = None
            if self.recompiles:
                hook = self.on_recompile(lambda model, data: install(owner.physics))

            def remove() -> None:
                chain = vars(owner.physics).get(_DmStepChain.ATTRIBUTE)
                if chain is not None:
                    chain.discard(link)
                if hook is not None:
                    self.remove_hook(hook)

            return StepInterception(remove, link, lambda: vars(owner.physics).get(_DmStepChain.ATTRIBUTE))
        if callable(getattr(owner, "_simulate", None)):
            original_sim = owner._simulate
            sim_runner = _Runner(original_sim, self.data)
            owner._simulate = lambda nstep: stepper(original_sim, nstep, sim_runner)
        elif callable(getattr(owner, "_step_mujoco_simulation", None)):
            gym_runner = _GymRunner(owner._step_mujoco_simulation, self.model, self.data)
            data = self.data

            def simulate(ctrl: Any, n_frames: int) -> None:
                data.ctrl[:] = ctrl
                stepper(gym_runner, n_frames, gym_runner)

            owner._step_mujoco_simulation = simulate
        else:
            raise TypeError(
                f"{type(owner).__module__}.{type(owner).__qualname__} steps MuJoCo without a hook sim2real can "
                "intercept (gymnasium's MujocoEnv._step_mujoco_simulation, a `_simulate(nstep)` method, or "
                "dm-control's Physics.step), so physics-rate action latency and ControlJitter cannot reach it. "
                "Give the env a `_simulate(nstep)` method that calls mujoco.mj_step."
            )

        def remove_gym() -> None:
            for name in ("_simulate", "_step_mujoco_simulation"):
                if name in vars(owner):
                    delattr(owner, name)

        return StepInterception(remove_gym)

    def remove_hook(self, hook: Callable[..., None]) -> None:
        """Unregisters a hook added by :meth:`on_recompile` (no-op when already gone)."""
        hooks = self.owner._hooks._after_compile.extra_hooks  # composer keeps no public remover
        if hook in hooks:
            hooks.remove(hook)


class StepInterception:
    """One interception of an env's physics step (:meth:`PhysicsHandle.intercept_step`); call it to remove it.

    On dm-control envs the interceptions of one ``Physics`` are links of one chain that owns ``physics.step``, so an
    interception that has nothing to do for an episode can leave the chain (:meth:`bypass`) and come back later in
    its place, below the ones installed after it: one Python call less per control step while it is out.
    """

    def __init__(self, remove: Callable[[], None], link: _Link | None = None, chain: Any = None) -> None:
        self._remove = remove
        self._link = link
        self._chain = chain  # () -> the current physics' _DmStepChain (or None)

    def __call__(self) -> None:
        self._remove()

    def on_top(self) -> bool:
        """Whether this interception runs first: no other interception (of sim2real or anyone) sits above it."""
        chain = self._chain() if self._chain is not None else None
        return chain is not None and chain.top_link() is self._link

    def bypass(self, out: bool) -> bool:
        """Takes this interception out of the chain (``out`` True) or puts it back in its place (False); True when
        the chain now is as asked. False where it cannot be done: not a dm-control env, or someone else's code
        patched ``physics.step`` over the chain (then nothing is changed and the interception stays in)."""
        chain = self._chain() if self._chain is not None else None
        if chain is None or self._link is None:
            return not out
        return chain.bypass(self._link, out)


class _Link:
    """One interception in a :class:`_DmStepChain`: ``stepper(run, nstep, runner)`` or its ``direct`` form."""

    __slots__ = ("direct", "out", "stepper")

    def __init__(self, stepper: Callable[[Any, int, Any], None], direct: Any) -> None:
        self.stepper = stepper
        self.direct = direct
        self.out = False

    def wrap(self, physics: Any, run: Callable[[int], None]) -> Callable[[int], None]:
        runner = _DmRunner(physics, run)
        if self.direct is not None:
            step: Callable[[int], None] = self.direct(run, runner)
            return step
        stepper = self.stepper

        def intercepted(nstep: int = 1) -> None:
            stepper(run, nstep, runner)

        return intercepted


class _DmStepChain:
    """The interceptions of one dm-control ``Physics.step``, composed over the step found before the first (the
    class's, or one someone else set): the one owner of ``physics.step`` while sim2real intercepts it. Kept on the
    physics object itself, so every handle of the same physics sees the same chain (a composer recompile makes a new
    physics and a new chain). When someone else's code replaces ``physics.step`` over the chain, the chain is
    frozen: new links start a chain over that step, and nothing already below it is bypassed or rebuilt."""

    ATTRIBUTE = "_sim2real_step_chain"

    def __init__(self, physics: Any) -> None:
        self.physics = physics
        self.base_own = vars(physics).get("step")  # someone else's step set before the first link (kept below)
        # The class's step bound to the physics itself (composer hands out a weak proxy of it).
        self.base = physics.step
        self.links: list[_Link] = []
        self.installed: Any = self.base_own

    @classmethod
    def of(cls, physics: Any) -> _DmStepChain:
        chain = vars(physics).get(cls.ATTRIBUTE)
        if chain is None or not chain.intact():
            chain = cls(physics)
            setattr(physics, cls.ATTRIBUTE, chain)
        return chain

    def intact(self) -> bool:
        return vars(self.physics).get("step") is self.installed

    def add(self, link: _Link) -> None:
        if link not in self.links:  # (a physics object reused by a recompile keeps its chain)
            self.links.append(link)
        self.rebuild()

    def discard(self, link: _Link) -> None:
        """Removes ``link``; a frozen chain (someone else's step over it) is left as it is."""
        if link in self.links and self.intact():
            self.links.remove(link)
            self.rebuild()

    def top_link(self) -> _Link | None:
        if not self.intact():
            return None
        active = [link for link in self.links if not link.out]
        return active[-1] if active else None

    def bypass(self, link: _Link, out: bool) -> bool:
        if link.out == out:
            return True
        if link not in self.links or not self.intact():
            return False
        link.out = out
        self.rebuild()
        return True

    def rebuild(self) -> None:
        physics = self.physics
        base = self.base
        run = base
        for link in self.links:
            if not link.out:
                run = link.wrap(physics, run)
        if run is base and self.base_own is None:
            vars(physics).pop("step", None)
            self.installed = None
        else:
            physics.step = run
            self.installed = run


class _Runner:
    """Advances physics with the env's own stepping function; ``split`` runs pieces with a command each."""

    def __init__(self, original: Callable[[int], None], data: mujoco.MjData) -> None:
        self.original = original
        self.data = data

    def __call__(self, nstep: int) -> None:
        self.original(nstep)

    def split(self, pieces: list[tuple[np.ndarray, int]]) -> None:
        ctrl = self.data.ctrl
        for command, length in pieces:
            ctrl[:] = command
            self.original(length)


class _GymRunner(_Runner):
    """gymnasium's ``_step_mujoco_simulation``: ``mj_step`` then ``mj_rnePostConstraint`` once."""

    def __init__(self, original: Callable[[Any, int], None], model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.step_sim = original
        self.model = model
        self.data = data

    def __call__(self, nstep: int) -> None:
        self.step_sim(self.data.ctrl, nstep)

    def split(self, pieces: list[tuple[np.ndarray, int]]) -> None:
        model, data = self.model, self.data
        for command, length in pieces:
            data.ctrl[:] = command
            mujoco.mj_step(model, data, nstep=length)
        mujoco.mj_rnePostConstraint(model, data)


class _DmRunner:
    """dm-control's ``Physics.step``; ``split`` keeps its legacy step1/step2 bracketing, so the pieces cost
    what one unsplit step costs and give bitwise the same state when the command does not change."""

    def __init__(self, physics: Any, original: Callable[[int], None]) -> None:
        self.physics = physics
        self.original = original
        self.fast = bool(getattr(physics, "legacy_step", False)) and int(physics.model.opt.integrator) != int(
            mujoco.mjtIntegrator.mjINT_RK4
        )

    def __call__(self, nstep: int) -> None:
        self.original(nstep)

    def split(self, pieces: list[tuple[np.ndarray, int]]) -> None:
        physics = self.physics
        if not self.fast:
            ctrl = physics.data.ctrl
            for command, length in pieces:
                ctrl[:] = command
                self.original(length)
            return
        with physics.check_invalid_state():
            model, data = physics.model.ptr, physics.data.ptr
            first = True
            for command, length in pieces:
                data.ctrl[:] = command
                if first:
                    mujoco.mj_step2(model, data)  # finishes the step begun by the last mj_step1
                    if length > 1:
                        mujoco.mj_step(model, data, length - 1)
                    first = False
                else:
                    mujoco.mj_step(model, data, length)
            mujoco.mj_step1(model, data)


def _dm_handle(env: Any) -> PhysicsHandle | None:
    try:
        from dm_control import composer
        from dm_control.rl import control
    except ImportError:  # pragma: no cover - dm_control is a dependency
        return None
    if isinstance(env, composer.Environment):
        try:
            physics = env.physics
            return PhysicsHandle(physics.model.ptr, physics.data.ptr, "dm_control.composer", env)
        except ReferenceError:  # a closed composer env: its physics (behind a weak proxy) is freed
            return None
    if isinstance(env, control.Environment):
        physics = env.physics
        return PhysicsHandle(physics.model.ptr, physics.data.ptr, "dm_control.suite", env)
    return None


def declared_control_period(obj: Any) -> float | None:
    """The control period in seconds ``obj`` declares: a positive ``dt`` or ``control_timestep()`` of ``obj`` or of
    ``obj.unwrapped`` (gymnasium's MujocoEnv has ``dt``, a dm_env written by hand or dm-control's ``control_timestep()``),
    None when it declares none.

    Example:
        >>> import gymnasium as gym
        >>> declared_control_period(gym.make("InvertedPendulum-v5"))
        0.04
    """
    for holder in (obj, _attribute(obj, "unwrapped")):
        for name in ("dt", "control_timestep"):
            value = _attribute(holder, name)
            if callable(value):
                try:
                    value = value()
                except TypeError:  # a method that needs arguments: not a period
                    value = None
            if isinstance(value, (int, float, np.floating)) and not isinstance(value, bool) and value > 0:
                return float(value)
    return None


def _attribute(obj: Any, name: str) -> Any:
    try:
        return getattr(obj, name, None)
    except Exception:
        return None


def _holds(obj: Any, model: mujoco.MjModel) -> bool:
    """Whether ``obj`` keeps ``model`` itself (an instance attribute or a property of its class), not through a
    ``__getattr__`` that forwards to an env it wraps."""
    if "model" in getattr(obj, "__dict__", {}):
        return obj.__dict__["model"] is model
    return isinstance(getattr(type(obj), "model", None), property) and _attribute(obj, "model") is model


def _holder(obj: Any, model: mujoco.MjModel) -> Any:
    """The object that owns ``model`` below ``obj``: the env whose ``frame_skip`` is the control period's and whose
    stepping method :meth:`PhysicsHandle.intercept_step` patches. A TorchRL ``GymWrapper`` forwards ``model`` and
    ``data`` to the env it wraps but answers ``frame_skip`` (its own action repeat, 1 by default) itself."""
    queue = [obj]
    seen: set[int] = set()
    while queue:
        current = queue.pop(0)
        if current is None or id(current) in seen:
            continue
        seen.add(id(current))
        if _holds(current, model):
            return current
        for name in _CHILD_ATTRIBUTES:
            child = _attribute(current, name)
            if child is not None and child is not current:
                queue.append(child)
    return obj


def find_physics(env: Any) -> PhysicsHandle | None:
    """The MuJoCo model and data inside ``env``, or None when there is none.

    Looks at the object itself and then, breadth first, at ``dm_env``, ``env``, ``_env``,
    ``base_env`` and ``unwrapped`` attributes (gymnasium wrappers, the sim2real dm_env adapter,
    TorchRL wrappers and transformed envs).
    """
    queue = [env]
    seen: set[int] = set()
    while queue:
        obj = queue.pop(0)
        if obj is None or id(obj) in seen:
            continue
        seen.add(id(obj))
        handle = _dm_handle(obj)
        if handle is not None:
            return handle
        model = _attribute(obj, "model")
        data = _attribute(obj, "data")
        if isinstance(model, mujoco.MjModel) and isinstance(data, mujoco.MjData):
            return PhysicsHandle(model, data, "gymnasium", _holder(obj, model))
        for name in _CHILD_ATTRIBUTES:
            child = _attribute(obj, name)
            if child is not None and child is not obj:
                queue.append(child)
    return None
