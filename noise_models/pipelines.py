"""Noise pipelines as values: :class:`ObservationNoise` and :class:`ActionNoise` (what to apply, in order,
and where); :mod:`noise_models.corruptor` compiles and runs them.

Example:
    >>> from noise_models import Gaussian
    >>> ObservationNoise(Gaussian(std=0.01), select=[0, 1], clip=False)
    ObservationNoise(Gaussian(std=0.01), select=(0, 1), clip=False)
"""

from __future__ import annotations

from typing import Any

from noise_models.processes import Process
from noise_models.values import Selection, check_selection

__all__ = ["ActionNoise", "ObservationNoise"]


class _Noise:
    side = ""
    _frozen = False

    def __init__(self, *processes: Process, select: Selection = None, clip: bool = True) -> None:
        owner = type(self).__name__
        if not isinstance(clip, bool):
            raise TypeError(f"`clip` must be a bool. Received {clip!r}.")
        if not processes:
            raise ValueError(f"{owner} needs at least one process, e.g. {owner}(Gaussian(std=0.01)).")
        for i, p in enumerate(processes):
            if not isinstance(p, Process):
                raise TypeError(
                    f"`processes[{i}]` of {owner} must be a noise process (Gaussian, UniformNoise, Bias, Drift, "
                    f"Quantize, Dropout, Stuck, Outlier, Saturate, Scale, Deadzone, Sticky). Received {p!r}."
                )
            if self.side not in p.sides:
                allowed = "Deadzone and Sticky act on actions only" if self.side == "obs" else ""
                raise ValueError(
                    f"`processes[{i}]` of {owner} is {type(p).__name__}, which does not apply to "
                    f"{'observations' if self.side == 'obs' else 'actions'} ({allowed}). Received {p!r}."
                )
        self.processes = tuple(processes)
        self.select = check_selection(select)
        self.clip = clip

    def _fields(self) -> tuple[Any, ...]:
        return (self.processes, self.select, self.clip)

    def __repr__(self) -> str:
        args = [repr(p) for p in self.processes]
        if self.select is not None:
            args.append(f"select={self.select!r}")
        if not self.clip:
            args.append("clip=False")
        return f"{type(self).__name__}({', '.join(args)})"

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self._fields() == other._fields()

    def __hash__(self) -> int:
        return hash(repr(self))

    def __setattr__(self, key: str, value: object) -> None:
        if self._frozen:
            raise AttributeError(f"{type(self).__name__} is immutable; build a new one instead.")
        super().__setattr__(key, value)

    def to_config(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": type(self).__name__, "processes": [p.to_config() for p in self.processes]}
        if self.select is not None:
            out["select"] = list(self.select) if isinstance(self.select, tuple) else self.select
        if not self.clip:
            out["clip"] = False
        return out


class ObservationNoise(_Noise):
    """A pipeline of noise processes applied, in order, to what the policy observes.

    Args:
        *processes: Gaussian, UniformNoise, Bias, Drift, Quantize, Dropout, Stuck, Outlier, Saturate, Scale.
        select: default selection for processes that have none (keys, indices or a slice).
        clip: keep what the noise changes inside the declared observation bounds, default True.

    Clipping touches only what this model changed: an entry no process selects is never clipped,
    and neither is an entry the env itself delivered outside its declared bounds (stale bounds), so
    a pipeline whose noise is zero returns the observation unchanged. An entry inside the bounds
    that the noise pushes out is clipped back, so the declared space stays truthful (dm-control and
    gymnasium MuJoCo observations are unbounded: no clipping there).

    Example:
        >>> from noise_models import Gaussian, Quantize
        >>> ObservationNoise(Gaussian(std=0.01), Quantize(0.001), select="position")
        ObservationNoise(Gaussian(std=0.01), Quantize(resolution=0.001), select='position')
    """

    side = "obs"

    def __init__(self, *processes: Process, select: Selection = None, clip: bool = True) -> None:
        super().__init__(*processes, select=select, clip=clip)
        object.__setattr__(self, "_frozen", True)


class ActionNoise(_Noise):
    """A pipeline of noise processes applied, in order, to the policy's action before the env gets it.

    Args:
        *processes: any process, including the action-only Deadzone and Sticky.
        select: default selection (indices or a slice) for processes that have none.
        clip: clip the result to the action space (actuators have limits), default True.

    Example:
        >>> from noise_models import Deadzone, Gaussian
        >>> ActionNoise(Gaussian(std=0.05), Deadzone(0.01))
        ActionNoise(Gaussian(std=0.05), Deadzone(width=0.01))
    """

    side = "action"

    def __init__(self, *processes: Process, select: Selection = None, clip: bool = True) -> None:
        super().__init__(*processes, select=select, clip=clip)
        object.__setattr__(self, "_frozen", True)
