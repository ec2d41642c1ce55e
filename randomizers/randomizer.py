"""The engine that draws, applies, reports and restores a set of effects on one MuJoCo model.

:class:`PhysicsRandomizer` knows nothing of environment APIs: ``sim2real`` wrappers call
:meth:`~PhysicsRandomizer.begin_episode` before the environment resets, :meth:`~PhysicsRandomizer.apply`
once the episode's model exists, and :meth:`~PhysicsRandomizer.step` before each control step.

Example:
    >>> import mujoco
    >>> from randomizers import Damping, Mass, PhysicsRandomizer, Uniform
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="arm"><joint name="hinge" damping="1"/>'
    ...     '<geom size=".1"/></body></worldbody></mujoco>')
    >>> data = mujoco.MjData(model)
    >>> r = PhysicsRandomizer([Damping(scale=Uniform(0.5, 2.0)), Mass(scale=Uniform(0.8, 1.2))], seed=0)
    >>> r.bind(model, data)
    >>> r.begin_episode()
    >>> r.apply()
    >>> sorted(r.current_params)
    ['body_mass[arm]', 'dof_damping[hinge]']
    >>> 0.5 <= r.current_params["dof_damping[hinge]"] < 2.0
    True
    >>> r.restore_nominal()
    >>> float(model.dof_damping[0])
    1.0
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import mujoco
import numpy as np

from randomizers.effects import Binding, Effect, Interval, Push, PushBinding, PushEvent
from randomizers.seeding import SeedLike, StreamFactory, normalize_seed, reseeded_root
from randomizers.setconst import SetConst

__all__ = ["PhysicsRandomizer"]


class _Slot:
    """Mutable per-effect state that survives a rebind (composer recompiles every episode)."""

    __slots__ = ("binding", "draws", "effect", "gen", "name", "next_time", "resample", "steps", "written")

    def __init__(self, effect: Effect, name: str, gen: np.random.Generator) -> None:
        self.effect = effect
        self.name = name
        self.gen = gen
        self.binding: Any = None
        self.draws: np.ndarray | None = None
        self.resample = 0
        self.steps = 0
        self.next_time: float | None = None
        self.written: np.ndarray | None = None


class PhysicsRandomizer:
    """Draws effect values per episode from keyed streams, writes them, reports and restores them.

    Each effect draws from its own stream, keyed by ``(seed, effect.key, episode)``. The key comes from
    the effect alone: its ``name=`` if given, else its kind, selection and operation
    (``Mass[bodies=torso]`` for ``scale``, ``Mass[bodies=torso,op=add]``), so adding, removing or
    reordering effects never changes another's draws. Two effects with the same key are refused; give
    one of them a ``name=``.

    Args:
        effects: the physics effects (``randomizers.effects``), applied in order.
        seed: root seed (int, tuple of ints, or None for fresh entropy).

    Raises:
        ValueError: two effects would share a stream (same key).

    Attributes:
        current_params: parameter address -> value in use this episode (a new dict whenever
            values change, never mutated, so stored copies stay true).
        events: push events of the current episode.
        episode: index of the current episode since the last seeding (-1 before the first).
    """

    def __init__(self, effects: Iterable[Effect], seed: SeedLike = None) -> None:
        effects = tuple(effects)
        for i, effect in enumerate(effects):
            if not isinstance(effect, Effect):
                raise TypeError(
                    f"`effects[{i}]` must be a physics or visual effect (Friction, Mass, Damping, Armature, "
                    "FrictionLoss, Stiffness, ActuatorGain, Gravity, Push, GeomColor, MaterialColor, Texture, Light, "
                    f"CameraPose, CameraFovy). Received {effect!r} of type {type(effect).__name__}."
                )
        self.effects = effects
        self._wrap_seed = normalize_seed(seed)
        self._base_root: tuple[int, ...] = StreamFactory(self._wrap_seed).root
        self._streams = StreamFactory(self._base_root)
        self._names = self._stream_names(effects)
        self._slots = [_Slot(e, n, self._streams.generator(n)) for e, n in zip(effects, self._names, strict=True)]
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self._set_const: SetConst | None = None
        self._step_slots: list[_Slot] = []
        self.episode = -1
        self.current_params: dict[str, float] = {}
        self.events: tuple[PushEvent, ...] = ()

    @staticmethod
    def _stream_names(effects: tuple[Effect, ...]) -> list[str]:
        # Each stream is named by its effect's own ``key`` (kind, selection, operation; or ``name=``), never
        # by its position, so adding an effect never shifts another's draws. Two effects with one key
        # would draw the same numbers: refuse rather than number them in order.
        first: dict[str, int] = {}
        for i, effect in enumerate(effects):
            key = effect.key
            if key in first:
                j = first[key]
                raise ValueError(
                    f"`effects[{i}]` and `effects[{j}]` would share the random stream {key!r} "
                    f"({effects[i]!r} and {effects[j]!r}); pass a distinct `name=` to one of them."
                )
            first[key] = i
        return list(first)

    @property
    def stream_names(self) -> tuple[str, ...]:
        """The stream name of each effect (what :func:`randomizers.seeding.stream` needs)."""
        return tuple(self._names)

    @property
    def root_seed(self) -> tuple[int, ...]:
        """The root the current streams derive from."""
        return self._streams.root

    @property
    def push_count(self) -> int:
        """How many :class:`~randomizers.Push` effects there are (the rows of :meth:`push_state`)."""
        return sum(isinstance(slot.effect, Push) for slot in self._slots)

    def push_state(self) -> np.ndarray:
        """What each :class:`~randomizers.Push` effect applies right now, one row each: the body id it pushes
        (-1 when idle) and the force in newtons (world frame). Shape ``(push_count, 4)``.

        Example:
            >>> import mujoco
            >>> from randomizers import PhysicsRandomizer, Push
            >>> model = mujoco.MjModel.from_xml_string(
            ...     '<mujoco><worldbody><body name="box"><freejoint/><geom size=".1"/></body></worldbody></mujoco>')
            >>> r = PhysicsRandomizer([Push(force=2.0, interval=1)], seed=0)
            >>> r.bind(model, mujoco.MjData(model))
            >>> r.begin_episode()
            >>> r.apply()
            >>> r.push_state().tolist()
            [[-1.0, 0.0, 0.0, 0.0]]
            >>> _ = r.step()
            >>> body, *force = r.push_state()[0]
            >>> int(body), round(float(np.linalg.norm(force)), 6)
            (1, 2.0)
        """
        rows = []
        for slot in self._slots:
            binding = slot.binding
            if isinstance(binding, PushBinding):
                active = binding.active
                if active is None or self.data is None:
                    rows.append((-1.0, 0.0, 0.0, 0.0))
                else:
                    rows.append((float(active), *self.data.xfrc_applied[active, :3].tolist()))
        return np.array(rows, dtype=np.float64).reshape(-1, 4)

    @property
    def has_step_effects(self) -> bool:
        """Whether :meth:`step` does anything (interval schedules or pushes)."""
        return bool(self._step_slots)

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Resolves every effect against ``model`` and snapshots its nominal values.

        Called again with a freshly compiled model (composer envs), it re-resolves against the new
        model; the episode's draws are kept and re-applied by :meth:`apply`.
        """
        if model is self.model and data is self.data:
            return
        for slot in self._slots:
            slot.binding = slot.effect.bind(model)
        self.model, self.data = model, data
        inputs = {i for s in self._slots for i in getattr(s.binding, "set_const_inputs", ())}
        self._set_const = SetConst(model, inputs) if inputs else None
        self._step_slots = [
            s for s in self._slots if isinstance(s.binding, PushBinding) or isinstance(s.effect.schedule, Interval)
        ]

    def begin_episode(self, seed: SeedLike = None) -> None:
        """Draws this episode's values (call before the environment resets).

        Args:
            seed: a reset seed; when given, streams restart from episode 0 of the root
                ``(wrap seed, reset seed)`` so ``reset(seed=s)`` reproduces the same draws.
        """
        if self.model is None:
            raise RuntimeError("PhysicsRandomizer.begin_episode() called before bind(model, data).")
        reset_seed = normalize_seed(seed, "seed")
        if reset_seed is not None:
            self._streams = StreamFactory(reseeded_root(self._wrap_seed, reset_seed))
            self.episode = -1
        self.episode += 1
        for slot, name in zip(self._slots, self._names, strict=True):
            slot.resample = 0
            slot.steps = 0
            slot.next_time = None
            binding = slot.binding
            if isinstance(binding, PushBinding):
                self._streams.start(slot.gen, name, self.episode)
                continue
            if slot.effect.schedule == "startup" and slot.draws is not None:
                continue
            self._streams.start(slot.gen, name, 0 if slot.effect.schedule == "startup" else self.episode)
            slot.draws = self._sample(slot)

    @staticmethod
    def _sample(slot: _Slot) -> np.ndarray:
        binding: Binding = slot.binding
        return np.asarray(slot.effect.distribution.sample(slot.gen, binding.draw_count()), dtype=np.float64)  # type: ignore[attr-defined]

    def apply(self) -> None:
        """Writes the episode's values into the bound model (then ``mj_setConst`` if masses moved)."""
        params: dict[str, float] = {}
        for slot in self._slots:
            binding = slot.binding
            if isinstance(binding, PushBinding):
                binding.begin(slot.gen)
                continue
            if slot.draws is None:
                raise RuntimeError("PhysicsRandomizer.apply() called before begin_episode().")
            values = binding.values(slot.draws)
            binding.apply(values)
            slot.written = values
            params.update(zip(binding.addresses, values.tolist(), strict=True))
        if self._set_const is not None:
            self._set_const.run()
        self.current_params = params
        self.events = ()

    def step(self) -> bool:
        """One control step of interval resamples and pushes; True when anything changed."""
        changed = False
        for slot in self._step_slots:
            binding = slot.binding
            if isinstance(binding, PushBinding):
                if binding.step(self.data):
                    self.events = tuple(binding.events)
                    changed = True
                continue
            schedule: Interval = slot.effect.schedule  # type: ignore[assignment]
            if schedule.steps is not None:
                slot.steps += 1
                due = slot.steps % schedule.steps == 0
            else:
                now = float(self.data.time)  # type: ignore[union-attr]
                if slot.next_time is None:
                    slot.next_time = now + schedule.seconds  # type: ignore[operator]
                due = now >= slot.next_time
                if due:
                    slot.next_time += schedule.seconds  # type: ignore[operator]
            if due:
                slot.resample += 1
                self._streams.start(slot.gen, slot.name, self.episode, slot.resample)
                slot.draws = self._sample(slot)
                values = binding.values(slot.draws)
                binding.apply(values)
                slot.written = values
                if binding.needs_set_const:
                    self._set_const.run()  # type: ignore[union-attr]
                self.current_params = {
                    **self.current_params,
                    **dict(zip(binding.addresses, values.tolist(), strict=True)),
                }
                changed = True
        return changed

    def reapply_overwritten(self) -> tuple[str, ...]:
        """Writes the values in use again where the model no longer holds them and returns their addresses.

        An env's own reset may write a field an effect randomises (dm-control ``finger`` resets its hinge
        damping); call this after it so the model holds what :attr:`current_params` reports.
        ``mj_setConst`` runs again when a re-written effect needs it; nothing is written otherwise.
        """
        fixed: list[str] = []
        set_const = False
        for slot in self._slots:
            binding, values = slot.binding, slot.written
            # Physics fields only: tasks reset those; visual bindings write more than one array.
            if values is None or not isinstance(binding, Binding) or type(binding).__module__ != Binding.__module__:
                continue
            held = binding._array[binding._targets]
            if np.array_equal(held, values):
                continue
            fixed.extend(a for a, h, v in zip(binding.addresses, held.tolist(), values.tolist(), strict=True) if h != v)
            binding.apply(values)
            set_const = set_const or binding.needs_set_const
        if set_const:
            self._set_const.run()  # type: ignore[union-attr]
        return tuple(fixed)

    def restore_nominal(self) -> None:
        """Puts every touched model field (and any active push) back to its nominal value, bitwise."""
        if self.model is None:
            return
        for slot in self._slots:
            binding = slot.binding
            if isinstance(binding, PushBinding):
                binding.restore(self.data)
            else:
                binding.restore()
        if self._set_const is not None:
            self._set_const.restore()
        self.current_params = self.nominal_params()

    def nominal_params(self) -> dict[str, float]:
        """Address -> nominal value for everything the effects touch."""
        out: dict[str, float] = {}
        for slot in self._slots:
            binding = slot.binding
            if isinstance(binding, Binding):
                out.update(zip(binding.addresses, binding.nominal.tolist(), strict=True))
        return out
