"""Tendon properties (``tendon_stiffness``, ``tendon_damping``, ``tendon_frictionloss``): one value per tendon.

Grippers whose fingers a fixed tendon couples, cable-driven arms and tendon springs carry their compliance and
losses in the tendon, not in the joints; these effects perturb them exactly as :class:`randomizers.Damping` and
:class:`randomizers.Stiffness` perturb joints (``scale`` / ``add`` / ``set``, name patterns, ``shared``,
``schedule``). Tendons are selected by name (``mj_id2name(model, mjOBJ_TENDON, i)``); an unnamed tendon is
``#<id>``, as an unnamed joint is. The spring's rest length (``tendon_lengthspring``, a ``[low, high]`` dead band
per tendon) is not one of them: address it as a raw field (``tendon_lengthspring[coupling][0]``).

Example:
    >>> import mujoco
    >>> from randomizers import PhysicsRandomizer, Uniform
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body><joint name="a" type="slide"/><geom size=".1"/></body>'
    ...     '<body><joint name="b" type="slide"/><geom size=".1"/></body></worldbody><tendon>'
    ...     '<fixed name="coupling" stiffness="3" damping="0.4"><joint joint="a" coef="1"/><joint joint="b" coef="-1"/>'
    ...     '</fixed></tendon></mujoco>')
    >>> r = PhysicsRandomizer([TendonDamping(scale=Uniform(0.5, 2.0), tendons="coupling")], seed=0)
    >>> r.bind(model, mujoco.MjData(model))
    >>> r.begin_episode(); r.apply()
    >>> list(r.current_params), 0.2 <= float(model.tendon_damping[0]) <= 0.8
    (['tendon_damping[coupling]'], True)
    >>> r.restore_nominal(); float(model.tendon_damping[0])
    0.4
"""

from __future__ import annotations

from collections.abc import Sequence

from randomizers.distributions import Distribution
from randomizers.effects import ArrayEffect, Schedule

__all__ = ["TENDON_EFFECTS", "TendonDamping", "TendonFrictionLoss", "TendonStiffness"]


class _TendonEffect(ArrayEffect):
    """A per-tendon model field, selected by tendon name."""

    kind = "tendon"
    selector = "tendons"

    def __init__(
        self,
        *,
        scale: Distribution | float | None = None,
        add: Distribution | float | None = None,
        set: Distribution | float | None = None,
        tendons: str | Sequence[str] = "*",
        shared: bool = False,
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        super().__init__(scale=scale, add=add, set=set, select=tendons, shared=shared, schedule=schedule, name=name)
        self._frozen = True


class TendonStiffness(_TendonEffect):
    """Tendon spring stiffness (``tendon_stiffness``), one value per selected tendon.

    Example:
        >>> TendonStiffness(scale=-1.0)
        Traceback (most recent call last):
        ...
        ValueError: `scale` of TendonStiffness must not go below 0 (tendon_stiffness must stay non-negative). \
Received Constant(value=-1.0) with support [-1.0, -1.0].
    """

    field = "tendon_stiffness"


class TendonDamping(_TendonEffect):
    """Tendon damping (``tendon_damping``), one value per selected tendon.

    Example:
        >>> from randomizers import LogUniform
        >>> TendonDamping(scale=LogUniform(0.5, 2.0), tendons="finger*")
        TendonDamping(scale=LogUniform(low=0.5, high=2.0), tendons='finger*')
    """

    field = "tendon_damping"


class TendonFrictionLoss(_TendonEffect):
    """Dry (Coulomb) friction of each selected tendon (``tendon_frictionloss``)."""

    field = "tendon_frictionloss"


#: The tendon effects, in the order :data:`randomizers.parameters.FIELD_EFFECTS` registers them.
TENDON_EFFECTS: tuple[type[ArrayEffect], ...] = (TendonStiffness, TendonDamping, TendonFrictionLoss)
