"""The environment side of ADR: a :class:`~randomizers.PhysicsRandomizer` whose ADR effects draw from the live ranges.

:class:`ADRRandomizer` draws every effect exactly as :class:`~randomizers.PhysicsRandomizer` does (same keyed
streams, same order), except that an ADR effect samples its *current range* instead of its hard limits, and the
one dimension an episode pins writes its boundary value into every target. The pin comes from a stream of its own,
``"ADR[boundary]"``, keyed like every other by (seed, episode): so enabling ADR never shifts another effect's draws,
and an ADR effect whose range equals its distribution draws exactly what it drew without ADR.

Example:
    >>> import mujoco
    >>> from randomizers import ADR, Damping, Mass, Uniform
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="arm"><joint name="hinge" damping="1"/>'
    ...     '<geom size=".1"/></body></worldbody></mujoco>')
    >>> adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, t_low=0.2, t_high=0.8, p_boundary=0.0)
    >>> r = ADRRandomizer([Mass(scale=Uniform(0.8, 1.2))], adr, seed=0)
    >>> r.bind(model, mujoco.MjData(model)); r.begin_episode(); r.apply()
    >>> r.current_params["dof_damping[hinge]"], r.pin  # the range starts at the nominal point
    (1.0, None)
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from randomizers.adr import ADR, Episode, Pin
from randomizers.effects import Effect
from randomizers.randomizer import PhysicsRandomizer, _Slot
from randomizers.seeding import SeedLike

__all__ = ["BOUNDARY_STREAM", "ADRRandomizer"]

#: The stream name of the boundary choice (not a valid effect key, so it can never collide with one).
BOUNDARY_STREAM = "ADR[boundary]"


class ADRRandomizer(PhysicsRandomizer):
    """Draws ``effects`` and the ADR controller's effects; pins a boundary in some episodes.

    Args:
        effects: effects outside ADR (drawn from their own distributions, as always).
        adr: the controller (may be shared by many randomizers; each draws its own pins).
        seed: root seed of every stream, the boundary stream included.

    Attributes:
        pin: this episode's :class:`~randomizers.adr.Pin`, or None.
    """

    def __init__(self, effects: Iterable[Effect], adr: ADR, seed: SeedLike = None) -> None:
        if not isinstance(adr, ADR):
            raise TypeError(f"`adr` must be an ADR controller (randomizers.ADR). Received {adr!r}.")
        super().__init__((*tuple(effects), *adr.effects), seed)
        self.adr = adr
        first = len(self.effects) - len(adr.effects)
        self._dims: dict[int, int] = {id(s): i for i, s in enumerate(self._slots[first:])}
        self._boundary = self._streams.generator(BOUNDARY_STREAM)
        self._planned = False
        self.pin: Pin | None = None

    def begin_episode(self, seed: SeedLike = None) -> None:
        """Draws the episode's pin (own stream) and values; ADR effects sample the controller's current ranges."""
        self._planned = False
        super().begin_episode(seed)  # re-roots the streams on a reset seed; ADR slots are filled below
        self._streams.start(self._boundary, BOUNDARY_STREAM, self.episode)
        self.pin = self.adr.choose(self._boundary)
        self._planned = True
        for slot in self._slots:
            if id(slot) in self._dims:
                slot.draws = self._sample(slot)

    def _sample(self, slot: _Slot) -> np.ndarray:  # type: ignore[override]
        index = self._dims.get(id(slot))
        if index is None:
            return PhysicsRandomizer._sample(slot)
        count = slot.binding.draw_count()
        if not self._planned:
            return np.empty(count)  # replaced once the pin is known
        pin = self.pin
        if pin is not None and pin.key == self.adr.keys[index]:
            return self.adr.pinned(index, pin.value, slot.gen, count)
        return np.asarray(self.adr.distribution(index).sample(slot.gen, count), dtype=np.float64)

    def end_episode(self, episode: Episode) -> bool:
        """Reports the finished episode to the controller; True when a boundary moved."""
        return self.adr.record(self.pin, self.adr.score(episode), episode.length)
