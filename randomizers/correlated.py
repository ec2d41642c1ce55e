"""A joint effect: one vector draw per episode written into several addresses at once.

:class:`Correlated` is what a fit's posterior becomes (``FitResult.to_effects(kind="posterior")``): the fitted
parameters drawn together from ``MultivariateNormal(estimate, covariance)`` truncated to their bounds, so two
parameters the data could only tell apart in combination stay consistent in every episode. It is an ordinary
effect: its own keyed stream (named ``Correlated[<addresses>]`` or ``name``), every address reported in the info
dict, composed with the other effects by ``sim2real.wrap``, restored bitwise on close, and YAML round trips.

Example:
    >>> import mujoco
    >>> from randomizers import MultivariateNormal, PhysicsRandomizer
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="arm"><joint name="a" damping="1"/><geom size=".1"/></body>'
    ...     '</worldbody><actuator><motor name="m" joint="a"/></actuator></mujoco>')
    >>> effect = Correlated(["dof_damping[a]", "actuator_gain[m]"],
    ...                     MultivariateNormal((1.0, 1.0), ((0.01, 0.009), (0.009, 0.01)), low=(0.0, 0.0)))
    >>> r = PhysicsRandomizer([effect], seed=0)
    >>> r.bind(model, mujoco.MjData(model))
    >>> r.begin_episode(); r.apply()
    >>> sorted(r.current_params) == ["actuator_gain[m]", "dof_damping[a]"]
    True
    >>> float(model.dof_damping[0]) == r.current_params["dof_damping[a]"]
    True
    >>> r.restore_nominal(); float(model.dof_damping[0])
    1.0
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from randomizers.distributions import MultivariateNormal
from randomizers.effects import Binding, Effect, Schedule, _check_schedule
from randomizers.parameters import Address, Operation, ParameterBinding, ParameterSet

__all__ = ["Correlated", "CorrelatedBinding"]

_OPERATIONS = ("scale", "add", "set")


class Correlated(Effect):
    """Writes one draw of a :class:`~randomizers.MultivariateNormal` into ``addresses`` (one component each).

    Args:
        addresses: P exact addresses (no wildcards: each names one scalar), e.g. ``["dof_damping[elbow]",
            "actuator_gain[elbow]"]``; fields without an effect (``actuator_biasprm[m][1]``) are written directly.
        distribution: a :class:`~randomizers.MultivariateNormal` with P components.
        operation: ``"set"`` (the draw is the value, default), ``"scale"`` (nominal times draw) or ``"add"``.
        schedule: ``"reset"`` (default), ``"startup"`` or an :class:`~randomizers.Interval`.
        name: stable stream name (default ``Correlated[<addresses joined by |>]``).

    Example:
        >>> Correlated(["dof_damping[a]"], MultivariateNormal((1.0,), ((0.1,),)), operation="mix")
        Traceback (most recent call last):
        ...
        ValueError: `operation` of Correlated must be one of ['scale', 'add', 'set']. Received 'mix'.
    """

    def __init__(
        self,
        addresses: Sequence[str],
        distribution: MultivariateNormal,
        *,
        operation: Operation = "set",
        schedule: Schedule = "reset",
        name: str | None = None,
    ) -> None:
        if isinstance(addresses, str) or not isinstance(addresses, Sequence) or not addresses:
            raise ValueError(
                f"`addresses` of Correlated must be a non-empty list of addresses. Received {addresses!r}."
            )
        parsed = tuple(Address.parse(a) for a in addresses)
        wild = [str(a) for a in parsed if any(c in a.element for c in "*?[")]
        if wild:
            raise ValueError(f"`addresses` of Correlated must name single elements (no patterns). Received {wild}.")
        if len(set(parsed)) != len(parsed):
            raise ValueError(f"`addresses` of Correlated must be distinct. Received {[str(a) for a in parsed]}.")
        if not isinstance(distribution, MultivariateNormal):
            raise TypeError(f"`distribution` of Correlated must be a MultivariateNormal. Received {distribution!r}.")
        if distribution.size != len(parsed):
            raise ValueError(
                f"`distribution` of Correlated must have one component per address ({len(parsed)}). "
                f"Received {distribution.size} components."
            )
        if operation not in _OPERATIONS:
            raise ValueError(f"`operation` of Correlated must be one of {list(_OPERATIONS)}. Received {operation!r}.")
        if name is not None and (not isinstance(name, str) or not name):
            raise TypeError(f"`name` of Correlated must be a non-empty string. Received {name!r}.")
        self.addresses = parsed
        self.distribution = distribution
        self.operation: Operation = operation
        self.schedule = _check_schedule(schedule)
        self.name = name
        self._frozen = True

    def _fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {"addresses": [str(a) for a in self.addresses], "distribution": self.distribution}
        if self.operation != "set":
            out["operation"] = self.operation
        if self.schedule != "reset":
            out["schedule"] = self.schedule
        if self.name is not None:
            out["name"] = self.name
        return out

    @property
    def key(self) -> str:
        return self.name if self.name is not None else f"Correlated[{'|'.join(self.addresses)}]"

    def bind(self, model: mujoco.MjModel) -> CorrelatedBinding:
        """Resolves every address against ``model`` and snapshots the nominal values.

        Raises:
            ValueError: an address names no element (close matches listed) or more than one scalar.
        """
        space = ParameterSet(model, list(self.addresses))
        if space.size != len(self.addresses):
            extra = [str(a) for a in space.addresses if a not in self.addresses]
            raise ValueError(
                f"`addresses` of Correlated must each name one scalar; {extra} came from multi-dof joints: "
                "name each component, e.g. 'dof_damping[free][0]'."
            )
        return CorrelatedBinding(self, space.bind(model))


class CorrelatedBinding(Binding):
    """A :class:`Correlated` effect resolved against one model (driven by :class:`randomizers.PhysicsRandomizer`
    like every other binding: one draw of P values per episode)."""

    def __init__(self, effect: Correlated, parameters: ParameterBinding) -> None:
        self.effect = effect
        self.model = parameters.model
        self._parameters = parameters
        self.addresses = parameters.addresses
        self.nominal = parameters.nominal.copy()
        self.size = len(self.addresses)
        self.set_const_inputs = parameters.set_const_inputs

    @property
    def needs_set_const(self) -> bool:
        """Whether ``mujoco.mj_setConst`` must run after :meth:`apply`."""
        return bool(self.set_const_inputs)

    def draw_count(self) -> int:
        """One vector draw per sample."""
        return 1

    def values(self, draws: np.ndarray) -> np.ndarray:
        """Absolute values from one (1, P) or (P,) draw."""
        draw = np.asarray(draws, dtype=np.float64).reshape(self.size)
        op = self.effect.operation
        if op == "scale":
            return self.nominal * draw
        if op == "add":
            return self.nominal + draw
        return draw.copy()

    def apply(self, values: np.ndarray) -> None:
        """Writes ``values`` (P,) into the model."""
        self._parameters.apply(values)

    def restore(self) -> None:
        """Writes the nominal snapshot back (bitwise)."""
        self._parameters.restore()
