"""The signal models' clock: :class:`SignalClock` connects a :class:`noise_models.SignalCorruptor` to an env's
physics (finds MuJoCo, sets the time base, intercepts physics stepping for physics-rate latency and control jitter),
:func:`action_delay_path` says where ActionLatency acts, and :class:`NoCopy` is what every layer holding such a clock
answers to ``pickle`` and ``copy.deepcopy``. Used by the gymnasium, dm_env and TorchRL signal layers
(:mod:`sim2real.wrappers.signals`, :mod:`sim2real.wrappers.torchrl`)."""

from __future__ import annotations

from types import MethodType
from typing import Any

import mujoco
import numpy as np

from noise_models import ActionLatency, ControlJitter, Layout, SignalCorruptor
from noise_models.timing import convert_time, elapsed_steps
from sim2real.physics import PhysicsHandle, StepInterception, declared_control_period, find_physics

__all__ = ["NoCopy", "SignalClock", "action_delay_path"]


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
            timestep = declared_control_period(env)
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
                dt = declared_control_period(env)
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
        self._remove: StepInterception | None = None
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
        if self._remove is not None:
            self._remove.bypass(False)  # back in its place if the last episode left the physics step alone
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

    def ring_actions(self, env: Any) -> list[Any] | None:
        """Right after :meth:`begin_episode`: this episode's latency of whole control steps as a ring of actions the
        caller delays itself, or None (the physics-step hook's ring of ``ctrl`` rows applies it).

        Only where the two are the same: ``env`` is sim2real's adapter around a dm-control suite env whose task
        copies the action into ``data.ctrl`` as it is (``Task.before_step``, ``Physics.set_control``; every suite
        task) in float64. The ring holds ``lag + 1`` references to the reset command at first; the caller stores
        the action of control step ``k`` (counted from 0) at ``k % len(ring)`` and sends ``ring[(k + 1) %
        len(ring)]``: the command of ``lag`` steps before, as the hook would write it. The hook has nothing to do
        this episode and leaves the physics step's chain until the next :meth:`begin_episode` puts it back in its
        place (the caller leaves ``_in_step`` False, so it would only pass the steps through). Not when another
        hook sits on the physics step above this one (a recorder reading the command the env wrote: it would read
        the delayed one).
        """
        if self._ring is None or not _action_is_ctrl(env, self.handle):
            return None
        hook = self._remove
        assert hook is not None  # _ring implies the hook
        if not hook.on_top():
            return None  # another hook on the physics step (a recorder) reads ctrl as the env wrote it
        hook.bypass(True)
        self._ring = None
        lag = self.corruptor.command_lag
        assert lag is not None  # _ring implies a whole-step lag
        return [np.array(self.handle.data.ctrl)] * (lag + 1)  # type: ignore[union-attr]  # _ring implies a handle

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
            if not self._in_step:  # outside a control step, or the wrapper delays the actions (ring_actions)
                run(nstep)
                return
            ring = self._ring
            if ring is None:
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


def _action_is_ctrl(env: Any, handle: PhysicsHandle | None) -> bool:
    """Whether ``env``'s action reaches ``data.ctrl`` as it is, bitwise: sim2real's adapter (float64 actions)
    directly around a dm-control suite ``control.Environment`` whose task and physics set the control with the
    library's own ``Task.before_step`` and ``Physics.set_control`` (a copy), the physics the one ``handle`` holds."""
    from dm_control.mujoco import Physics
    from dm_control.rl.control import Environment
    from dm_control.suite.base import Task

    from sim2real.adapters import DmEnvToGym

    if type(env) is not DmEnvToGym or handle is None or env._action_dtype != np.float64:
        return False
    inner = env.dm_env
    if type(inner) is not Environment:
        return False
    task, physics = inner.task, inner.physics
    return (
        physics is handle.owner.physics
        and getattr(type(task), "before_step", None) is Task.before_step
        and "before_step" not in vars(task)
        and getattr(type(physics), "set_control", None) is Physics.set_control
        and "set_control" not in vars(physics)
    )


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
