"""ADR across processes and machines: synchronous rounds on the serial, local or Ray backend.

A controller cannot be shared between processes, so a distributed ADR run goes in rounds: every worker gets a
copy of the controller (:meth:`randomizers.ADR.worker_copy`: the round's ranges, no updates), runs its episodes
with it and sends the results it collected back; the driver then records all of them with
:meth:`randomizers.ADR.apply_results`.

**What order means.** Results are applied in *item order*, and within one item in the order its episodes ended
(:func:`sim2real.parallel.run_tasks` returns results in input order whatever order the workers finish in). So the
controller's state after a round depends only on its state before, the items (seeds included) and ``fn`` — not on
the backend, the number of workers or which worker was fastest.

Example:
    >>> from randomizers import ADR, Damping, Pin, Uniform
    >>> def pinned_high(worker, metric):  # a worker's episode: 10 frames at the upper boundary
    ...     worker.record(Pin("Damping[joints=*]", "high", worker.ranges["Damping[joints=*]"][1]), metric, frames=10)
    >>> adr = ADR([Damping(scale=Uniform(0.0, 2.0))], delta=0.5, m=2, t_low=0.2, t_high=0.8)
    >>> rnd = run_adr_round(pinned_high, adr, [1.0, 0.9], backend="serial")
    >>> rnd.moves, adr.ranges["Damping[joints=*]"], adr.frames
    (1, (1.0, 1.5), 20)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from randomizers.adr import ADR, EpisodeResult
from sim2real.parallel import run_tasks

__all__ = ["ADRRound", "run_adr_round"]


@dataclass(frozen=True)
class ADRRound:
    """What one round did.

    Attributes:
        outputs: ``fn``'s return value for each item, in item order.
        results: the episodes each item's worker collected, in item order (the order they were applied in).
        moves: boundary moves the round caused.
    """

    outputs: tuple[Any, ...]
    results: tuple[tuple[EpisodeResult, ...], ...]
    moves: int


def _round_task(
    task: tuple[Callable[[ADR, Any], Any], dict[str, Any], Any, Any],
) -> tuple[tuple[EpisodeResult, ...], Any]:
    fn, state, metric, item = task
    worker = ADR.from_state(state, metric)
    worker.collected = []
    output = fn(worker, item)
    return tuple(worker.collected), output


def run_adr_round(
    fn: Callable[[ADR, Any], Any],
    adr: ADR,
    items: Sequence[Any],
    *,
    backend: str = "local",
    workers: int | None = None,
) -> ADRRound:
    """Runs ``fn(worker_adr, item)`` for every item on ``backend``, then applies the collected results in item order.

    Args:
        fn: a module-level (picklable) function; it builds its envs with ``sim2real.wrap(..., adr=worker_adr,
            seed=...)`` (a seed in its item) and runs episodes. What it returns comes back in ``outputs``.
        adr: the controller (stays here; workers get copies of its current state).
        items: one per task, everything ``fn`` needs (seeds included).
        backend: ``"serial"``, ``"local"`` or ``"ray"`` (see :func:`sim2real.parallel.run_tasks`).
        workers: processes for ``"local"``/``"ray"``.

    Raises:
        TypeError: ``adr`` is not an ADR, ``items`` not a list, or the metric is a callable that cannot be pickled for
            the backend.
    """
    if not isinstance(adr, ADR):
        raise TypeError(f"`adr` must be an ADR controller (sim2real.ADR). Received {adr!r}.")
    if isinstance(items, (str, bytes)) or not isinstance(items, Sequence):
        raise TypeError(f"`items` of run_adr_round must be a list (one item per task). Received {items!r}.")
    state = adr.state()
    metric = adr.metric
    run = run_tasks(_round_task, [(fn, state, metric, item) for item in items], backend=backend, workers=workers)
    moves = 0
    for results, _ in run.results:
        moves += adr.apply_results(results)
    return ADRRound(
        outputs=tuple(out for _, out in run.results),
        results=tuple(results for results, _ in run.results),
        moves=moves,
    )
