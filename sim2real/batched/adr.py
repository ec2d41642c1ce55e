"""ADR on the batched engine: every world's finished episode reported to the one controller of the process.

A world of the engine is the single env ``sim2real.wrap(make(task), adr, *effects, seed=(seed, i))``, so its
reset already goes through that env's :class:`~sim2real.wrappers.AutoRandomizePhysics` layer: the pin of the
episode comes from the world's own ``"ADR[boundary]"`` stream and the draws from the controller's current ranges,
as in the single env. Only the step bypasses that layer, and with it the episode's reward sum and the report at
its end. :class:`BatchedADR` does that part for all worlds: the reward sums and lengths are ``(N,)`` arrays (one
numpy operation per step, the same float64 additions as the single env's ``float(reward)`` sums), and when
episodes end it hands each one to its world's randomizer in world order, with the task's success flag where the
single env's ``info`` carries one (arm-reach: ``terminated``; none on a step that only ends a diverged reset).

**Order.** The results of one step reach the controller in world order, and the engine's resets (the collector's
partial resets after that step, in world order) draw their pins afterwards: exactly what N single envs sharing the
controller do when stepped one after the other and reset after the step (``tests/test_adr_batched.py`` checks
every world bitwise against them, the controller's history included).

Example:
    >>> import numpy as np
    >>> import sim2real as s2r
    >>> adr = s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.0, 4.0))], delta=0.5, m=1, t_low=-1e9, t_high=-1e8,
    ...               p_boundary=1.0)
    >>> envs = s2r.batched.make_batched("sim2real/arm-reach", 2, adr, seed=0, max_episode_steps=3)
    >>> _ = envs.reset(seed=0)
    >>> for _ in range(3):
    ...     _ = envs.step(np.zeros((2, 3), np.float32))
    >>> adr.frames, len(adr.history.frames) > 1  # two episodes of 3 steps reported; a pinned boundary widened
    (6, True)
    >>> envs.close()
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from randomizers.adr import ADR, Episode
from randomizers.adr_randomizer import ADRRandomizer

__all__ = ["BatchedADR", "adr_of", "check_success_metric", "check_task_metric"]


def adr_of(effects: Sequence[Any]) -> ADR | None:
    """The ADR controller among ``effects`` (lists flattened), or None."""
    from sim2real.wrapping import _flatten

    found = [e for e in _flatten(effects) if isinstance(e, ADR)]
    return found[0] if found else None


def check_success_metric(adr: ADR, reports_success: bool, task: object = None) -> None:
    """Refuses ``metric="success"`` on a task whose episodes report no success flag, before any episode runs:
    otherwise the first finished episode raises from inside training (a whole batch collected for nothing).

    Args:
        adr: the controller.
        reports_success: whether the task reports ``info["is_success"]`` (:attr:`sim2real.batched.Kernel.reports_success`).
        task: the task, for the message (None: "this task").

    Raises:
        ValueError: naming ``metric``, the values that fit the task and what was received.

    Example:
        >>> import sim2real as s2r
        >>> adr = s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], delta=0.1, t_low=0.2, t_high=0.8,
        ...               metric="success")
        >>> check_success_metric(adr, reports_success=False, task="model:robot.xml")
        Traceback (most recent call last):
        ...
        ValueError: `metric` of ADR must be 'return' or 'auto' (its return, here) on 'model:robot.xml': its episodes report no success flag. Received 'success'.
    """
    if adr.metric == "success" and not reports_success:
        where = "this task" if task is None else repr(task)
        raise ValueError(
            f"`metric` of ADR must be 'return' or 'auto' (its return, here) on {where}: its episodes report no "
            "success flag. Received 'success'."
        )


def check_task_metric(adr: ADR, task: Any) -> None:
    """:func:`check_success_metric` for ``task`` when it has a batched kernel (a built-in task or ``model:<path>``),
    which says whether its episodes report success; other tasks are left to their first episode.

    Raises:
        ValueError: ``metric="success"`` on a task that reports no success flag.

    Example:
        >>> import sim2real as s2r
        >>> adr = s2r.ADR([s2r.Damping(scale=s2r.Uniform(0.5, 2.0))], delta=0.1, t_low=0.2, t_high=0.8,
        ...               metric="success")
        >>> check_task_metric(adr, "sim2real/arm-reach")  # the reach task reports success
        >>> check_task_metric(adr, "dmc/reacher-easy")
        Traceback (most recent call last):
        ...
        ValueError: `metric` of ADR must be 'return' or 'auto' (its return, here) on 'dmc/reacher-easy': its episodes \
report no success flag. Received 'success'.
    """
    from sim2real.batched.kernels import kernel_factory

    factory = kernel_factory(task)
    if factory is not None:
        check_success_metric(adr, factory().reports_success, task)


class BatchedADR:
    """The episode bookkeeping of ADR for N batched worlds.

    Args:
        physics: each world's physics layer (its :class:`~sim2real.wrappers.AutoRandomizePhysics`).
        reports_success: whether the task's single env reports ``info["is_success"]`` (then equal to
            ``terminated``), as :attr:`sim2real.batched.Kernel.reports_success` says.

    Raises:
        TypeError: a world whose physics layer has no ADR randomizer.
    """

    def __init__(self, physics: Sequence[Any], reports_success: bool) -> None:
        randomizers = [getattr(layer, "randomizer", None) for layer in physics]
        for i, randomizer in enumerate(randomizers):
            if not isinstance(randomizer, ADRRandomizer):
                raise TypeError(
                    f"`physics[{i}]` must be an ADR physics layer (sim2real.wrap(..., adr=...)). "
                    f"Received {type(physics[i]).__name__}."
                )
        self.randomizers: list[ADRRandomizer] = randomizers  # type: ignore[assignment]
        for randomizer in {id(r.adr): r.adr for r in self.randomizers}.values():
            check_success_metric(randomizer, reports_success)
        n = len(randomizers)
        self.reports_success = bool(reports_success)
        self.returns = np.zeros(n)
        self.lengths = np.zeros(n, np.int64)
        self.running = np.zeros(n, bool)

    def start(self, world: int) -> None:
        """A new episode in ``world`` (its reset already drew the pin)."""
        self.returns[world] = 0.0
        self.lengths[world] = 0
        self.running[world] = True

    def observe(
        self, reward: np.ndarray, terminated: np.ndarray, ended: np.ndarray, stepped: np.ndarray, stuck: np.ndarray
    ) -> None:
        """Adds one step of the worlds ``stepped`` and reports the episodes that ``ended`` on it.

        Args:
            reward: ``(N,)`` float64 rewards of the step (0 where a world was not stepped).
            terminated: ``(N,)`` the task's termination (its success flag when it reports one).
            ended: ``(N,)`` terminated or truncated.
            stepped: ``(N,)`` the worlds that took the step (a diverged reset's ending step included).
            stuck: ``(N,)`` the worlds whose step only ended a diverged reset (no ``info`` from the task).
        """
        np.add(self.returns, reward, out=self.returns, where=stepped)
        self.lengths += stepped
        done = ended & stepped & self.running
        if not done.any():
            return
        for i in np.flatnonzero(done).tolist():
            self.running[i] = False
            success = bool(terminated[i]) if self.reports_success and not stuck[i] else None
            self.randomizers[i].end_episode(Episode(float(self.returns[i]), int(self.lengths[i]), success))
