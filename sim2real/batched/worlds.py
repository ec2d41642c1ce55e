"""The batched worlds' physics on MuJoCo's own thread-pooled batch: :class:`BatchedPhysics`.

One persistent :class:`mujoco.batch.Batch` holds every world: simulation ``i`` runs on world ``i``'s own
``MjModel`` (``set_models``) and keeps its own ``MjData`` (``persistent=True``), so each world keeps its
constraint solver's warm start and the derived fields of its last call. A control step is one ``Batch.step``
call over the stepped worlds (MuJoCo's loop over worlds, in C, on ``threads`` threads); the observation and
reward kernels read the batch's live ``(N, ...)`` arrays (``bind``) without a per-world copy.

What reproduces the single env's C calls bitwise (checked over 1000-step rollouts of reacher, manipulator and
arm-reach with joint limits and contacts active, at 1 and 2 threads; ``tests/test_batched*.py`` check it per
task, effect, noise and latency):

* dm-control's legacy step (``mj_step2``, ``mj_step`` for further substeps, ``mj_step1``) is
  ``step(nstep=n, stage=mjSTAGE_VEL)``: the VEL stage at the new state is what ``mj_step1`` computes, and a
  persistent batch continues its next step from those stages, so that step's first substep is ``mj_step2``.
* arm-reach's ``mj_step`` over its substeps then ``mj_forward`` is ``step(nstep=n, stage=mjSTAGE_ACC)``; its
  end-effector Jacobian (``mj_jacSite`` after ``mj_forward``) is ``Batch.jac`` of the site's body at the
  site's position (``jac`` recomputes the same kinematics from the same state).
* ``ActionLatency``'s mid-step split (``r`` substeps of the older command, then ``n - r`` of the newer) is two
  calls over the worlds with the same ``r``: ``step(r)`` (its first substep continues from the VEL stage:
  ``mj_step2``), the newer commands written to ``ctrl``, then ``step(n - r, stage)`` as a whole step ends.

Loading a world after its single env's reset (the env draws and writes the model, runs ``mj_setConst``, its
task's initial state and ``mj_forward``): ``set_models`` again (the batch reads each model as it was when set),
``reset(ids, stage=mjSTAGE_NONE)`` (a fresh ``MjData``: zero warning counters, which the divergence check
compares), the single env's ``mjSTATE_INTEGRATION`` state written into the batch's state rows (time, qpos, qvel,
act, warm start, ctrl, applied forces, mocap, eq_active, userdata: everything a step reads), then
``forward(ids, stage)`` with the stage a step ends with, so that the next step continues as the single env's.

Example:
    >>> import sim2real as s2r
    >>> from sim2real.batched import make_batched
    >>> envs = make_batched("dmc/reacher-easy", 2, seed=0, threads=2)
    >>> obs, _ = envs.reset(seed=0)
    >>> envs.physics.qpos.shape, envs.physics.threads
    ((2, 2), 2)
    >>> envs.close()
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import batch as mjbatch

__all__ = ["BatchedPhysics", "CpuReadings", "busy_cores", "default_threads", "read_cpu", "usable_cores"]

_NONE = int(mujoco.mjtStage.mjSTAGE_NONE)
_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)
_ACC = int(mujoco.mjtStage.mjSTAGE_ACC)
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


@dataclass(frozen=True)
class CpuReadings:
    """What :func:`default_threads` decides from: the cores this process may use and how many of them other work
    keeps busy now.

    Attributes:
        cores: cores this process may run on (``os.sched_getaffinity``; ``os.cpu_count()`` where there is none).
        running: tasks runnable in the whole system at a few instants a fraction of a millisecond apart (the 4th
            field of ``/proc/loadavg``), each count including the thread that reads it; empty where there is no
            ``/proc/loadavg``.
        load: the one-minute load average (``os.getloadavg()``), None where there is none: read only without
            ``running``.
        elsewhere: cores of the machine this process may not run on (``os.cpu_count()`` less ``cores``: a container
            or ``taskset`` pinned to some of them). ``/proc/loadavg`` counts the tasks running there too.
        quota: the CPU time this process's cgroup may use, in cores (cgroup v2 ``cpu.max``: ``"150000 100000"`` is
            1.5; the smallest along the cgroup's path), None without a quota (``"max 100000"``) or a cgroup v2.
    """

    cores: int
    running: tuple[int, ...]
    load: float | None
    elsewhere: int = 0
    quota: float | None = None


#: Readings of the runnable-task count :func:`read_cpu` takes (a task busy on another core is runnable in every one;
#: one that merely woke up for an instant is not): about 0.1 ms in all.
SAMPLES = 4


def read_cpu(samples: int = SAMPLES, *, proc: str = "/proc", cgroup: str = "/sys/fs/cgroup") -> CpuReadings:
    """This machine's :class:`CpuReadings` now (< 1 ms). ``proc`` and ``cgroup`` are where ``/proc`` and the cgroup
    v2 hierarchy are mounted (a test points them at files of its own)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - no affinity on this platform
        cores = os.cpu_count() or 1
    running: list[int] = []
    try:
        for _ in range(samples):
            with open(f"{proc}/loadavg", "rb") as f:  # "0.52 0.58 0.59 2/345 6789": runnable/total tasks in field 4
                running.append(int(f.read().split()[3].split(b"/")[0]))
    except (OSError, IndexError, ValueError):  # no /proc (macOS, Windows) or an unexpected format
        running = []
    load: float | None = None
    if not running:
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # no load average on this platform
            load = None
    elsewhere = max(0, (os.cpu_count() or cores) - cores)
    return CpuReadings(max(1, cores), tuple(running), load, elsewhere, _cgroup_quota(proc, cgroup))


def _read_text(path: str) -> str | None:
    try:
        with open(path, "rb") as f:
            return f.read().decode()
    except (OSError, UnicodeDecodeError):
        return None


def _cgroup_quota(proc: str, cgroup: str) -> float | None:
    """The smallest cgroup v2 CPU quota (in cores) from this process's cgroup up to the root; None without one.

    The cgroup is the ``0::<path>`` line of ``/proc/self/cgroup`` (``0::/`` in a container with its own cgroup
    namespace, whose quota is then ``/sys/fs/cgroup/cpu.max``); a quota on a parent bounds its children too."""
    path = "/"
    for line in (_read_text(f"{proc}/self/cgroup") or "").splitlines():
        if line.startswith("0::"):
            path = line[3:].strip() or "/"
    parts = [p for p in path.split("/") if p]
    if ".." in parts:  # a cgroup outside this namespace's root: only the root's file is visible
        parts = []
    quotas = []
    for depth in range(len(parts), -1, -1):
        text = _read_text("/".join([cgroup, *parts[:depth], "cpu.max"]))
        quota = None if text is None else _cpu_max(text)
        if quota is not None:
            quotas.append(quota)
    return min(quotas) if quotas else None


def _cpu_max(text: str) -> float | None:
    """Cores of a cgroup v2 ``cpu.max`` (``"<quota> <period>"`` in microseconds; ``"max ..."``: none; None when
    malformed).

    Example:
        >>> _cpu_max("max 100000"), _cpu_max("150000 100000\\n"), _cpu_max("200000"), _cpu_max("x 100000")
        (None, 1.5, 2.0, None)
    """
    fields = text.split()
    if not fields or fields[0] == "max" or len(fields) > 2:
        return None
    try:
        quota, period = int(fields[0]), int(fields[1]) if len(fields) == 2 else 100000
    except ValueError:
        return None
    return quota / period if quota > 0 and period > 0 else None


def usable_cores(readings: CpuReadings) -> int:
    """Cores' worth of CPU this process may use: the cores it may run on, at most its cgroup's quota rounded up
    (a quota of 1.5 cores gives 2 threads: together they use all 1.5, throttled at once in each period, where one
    thread would use 1).

    Example:
        >>> usable_cores(CpuReadings(cores=8, running=(), load=None, quota=1.5))
        2
    """
    if readings.quota is None:
        return max(1, readings.cores)
    return max(1, min(readings.cores, math.ceil(readings.quota)))


def busy_cores(readings: CpuReadings) -> int:
    """Cores among those this process may run on that other work keeps busy: the fewest tasks runnable at any
    reading, less the reading thread itself (a task that runs on another core the whole time counts; a burst that
    was over by the next reading does not), less the cores this process may not run on (``elsewhere``: the
    machine's other tasks fill those first). Without those counts, the one-minute load average above 1 (this
    process), rounded down, less ``elsewhere``; with neither, 0.

    Example:
        >>> busy_cores(CpuReadings(cores=2, running=(2, 3, 2, 2), load=None))  # one task on the other core
        1
        >>> busy_cores(CpuReadings(cores=2, running=(1, 2, 1, 1), load=None))  # a burst: idle
        0
        >>> busy_cores(CpuReadings(cores=2, running=(62, 63, 62, 62), load=None, elsewhere=62))  # pinned, host busy
        0
    """
    if readings.running:
        others = min(readings.running) - 1
    elif readings.load is not None:
        others = math.floor(readings.load - 1.0)
    else:
        return 0
    return max(0, others - readings.elsewhere)


def default_threads(num_envs: int, readings: CpuReadings | None = None) -> int:
    """The batch's threads when the caller gives none: the cores other work leaves idle now, at most ``num_envs``.

    The rule: ``min(num_envs, usable_cores, cores - busy_cores)``, at least 1, where

    * ``cores`` are the cores this process may run on (``os.sched_getaffinity``: a container's cpuset, ``taskset``);
    * :func:`usable_cores` bounds them by the cgroup v2 CPU quota (``cpu.max``, rounded up), if any;
    * :func:`busy_cores` are the tasks other work keeps runnable now (the runnable tasks of the whole machine in
      ``/proc/loadavg``, sampled a few times over about 0.1 ms, the fewest of them, less this thread; a runnable
      thread of this process's own, e.g. a spinning OpenMP worker, counts as busy too), less the cores of the
      machine this process may not run on: ``/proc/loadavg`` counts the whole host, so a container pinned to 2
      idle cores of a 64-core host with 60 runnable tasks sees them all, and only what the other 62 cores cannot
      hold can be on its own (before, it counted all 60 against its 2 cores and took 1 thread).

    A batch call returns when its slowest thread has finished, so a thread that waits for a busy core holds every
    world up: on the 2-core box at load 6-7, 2 threads stepped 64 reacher worlds at 0.71 and 64 manipulator worlds
    at 0.65 of 1 thread (``benchmarks/bench_eval.py --before``). The one-minute load average the choice used to
    come from lags both ways (``benchmarks/bench_threads.py``, 64 reacher worlds, wall time): at a load of 1.76 with
    two other tasks runnable it still chose 2 threads, 81 ms against 54 ms for 1; on a box gone idle with the load
    still at 2.18 it chose 1 thread, 56 ms against 35 ms for 2. Results do not depend on it.

    Args:
        num_envs: the worlds.
        readings: the machine's readings (None: :func:`read_cpu` now).

    Example:
        >>> default_threads(64, CpuReadings(cores=2, running=(1, 1, 1, 1), load=None))
        2
        >>> default_threads(64, CpuReadings(cores=2, running=(2, 2, 3, 2), load=None))
        1
        >>> default_threads(64, CpuReadings(cores=4, running=(61,) * 4, load=None, elsewhere=60))  # pinned to 4 idle
        4
        >>> default_threads(64, CpuReadings(cores=64, running=(1,) * 4, load=None, quota=2.0))  # docker --cpus=2
        2
        >>> default_threads(1)
        1
    """
    r = read_cpu() if readings is None else readings
    return max(1, min(int(num_envs), usable_cores(r), r.cores - busy_cores(r)))


class BatchedPhysics:
    """Every world's MuJoCo simulation in one persistent ``mujoco.batch.Batch`` (see the module docstring).

    Args:
        models: each world's ``MjModel`` (the single env's, edited in place by its draws).
        datas: each world's single-env ``MjData`` (the state a reset leaves is read from it).
        substeps: physics steps per control step.
        scheme: ``"dm_control"`` or ``"forward"`` (:attr:`sim2real.batched.kernels.Kernel.scheme`).
        legacy: dm-control's legacy step (``mj_step2`` ... ``mj_step1``); False: plain ``mj_step``.
        fields: derived ``MjData`` fields the kernel reads (bound as live ``(N, ...)`` arrays).
        jacobian_site: site id whose translational Jacobian is kept in ``gathered["jacobian"]``, or -1.
        threads: threads of the batch (the caller's included).

    Attributes:
        qpos, qvel: live ``(N, nq)``, ``(N, nv)`` views of the state rows.
        gathered: field -> live ``(N, ...)`` array (read-only), plus ``"jacobian"`` ``(N, 3, nv)`` with a site.
        warnings: live ``(N, mjNWARNING)`` warning counters.
        threads: threads of the batch.
    """

    def __init__(
        self,
        models: Sequence[mujoco.MjModel],
        datas: Sequence[mujoco.MjData],
        substeps: int,
        scheme: str,
        *,
        legacy: bool = True,
        fields: Sequence[str] = (),
        jacobian_site: int = -1,
        threads: int = 1,
    ) -> None:
        self.models, self.datas = list(models), list(datas)
        m0 = self.models[0]
        n = len(self.models)
        self.batch = mjbatch.Batch(m0, n, int(threads), persistent=True)
        self.batch.set_models(self.models)
        self.threads = int(self.batch.nthread)
        self.n_sub = int(substeps)
        if scheme == "forward":  # mj_step over the substeps, then mj_forward
            self._final, self._first_piece = _ACC, _NONE
        elif legacy:  # mj_step2, mj_step(n - 1), mj_step1 (RK4: mj_step(n), mj_step1; the same stages here)
            rk4 = m0.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
            self._final, self._first_piece = _VEL, (_VEL if rk4 else _NONE)
        else:  # mj_step over the substeps
            self._final, self._first_piece = _NONE, _NONE
        # After a load the batch runs the forward stages a step ends with (at least VEL: the single env's reset
        # ran mj_forward, and recomputing the position and velocity stages gives the same values).
        self._load_stage = max(self._final, _VEL)
        b = self.batch
        self.qpos, self.qvel, self.ctrl = b.bind("qpos"), b.bind("qvel"), b.bind("ctrl")
        self.gathered: dict[str, np.ndarray] = {f: b.bind(f) for f in fields}
        self.warnings = b.warning[:, :, 1]
        self._site = int(jacobian_site)
        if self._site >= 0:
            self._site_xpos = b.bind("site_xpos")
            self._site_body = int(m0.site_bodyid[self._site])
            self.gathered["jacobian"] = np.zeros((n, 3, m0.nv))

    def load(self, worlds: Sequence[int] | np.ndarray) -> None:
        """Takes ``worlds``' state from their single envs after a reset (see the module docstring)."""
        ids = np.asarray(worlds, dtype=np.int32).reshape(-1)
        if not len(ids):
            return
        ids.sort()
        b = self.batch
        b.set_models(self.models)
        b.reset(ids, stage=_NONE)
        state = b.state
        for i in ids.tolist():
            mujoco.mj_getState(self.models[i], self.datas[i], state[i], _STATE)
        b.forward(ids, stage=self._load_stage)
        self._jacobian(ids)

    def step(self, ids: np.ndarray | None, controls: np.ndarray) -> None:
        """One control step of the worlds ``ids`` (sorted int32, or None for all) under ``controls`` (N, nu)."""
        if ids is None:
            self.ctrl[...] = controls
        else:
            if not len(ids):
                return
            self.ctrl[ids] = controls[ids]
        self.batch.step(ids, self.n_sub, self._final)
        self._jacobian(ids)

    def step_split(self, ids: np.ndarray, rest: int, older: np.ndarray, newer: np.ndarray) -> None:
        """One control step of ``ids`` whose delayed command arrives after ``rest`` substeps: ``older`` (one row
        per id) until then, ``newer`` after."""
        b = self.batch
        self.ctrl[ids] = older
        b.step(ids, rest, self._first_piece)
        self.ctrl[ids] = newer
        b.step(ids, self.n_sub - rest, self._final)
        self._jacobian(ids)

    def data(self, i: int) -> mujoco.MjData:
        """World ``i``'s whole ``MjData`` (contacts and constraints included), copied into its single env's."""
        return self.batch.get_data(int(i), self.datas[int(i)])

    def _jacobian(self, ids: np.ndarray | None) -> None:
        if self._site < 0:
            return
        point = self._site_xpos[:, self._site] if ids is None else self._site_xpos[ids, self._site]
        jacp, _ = self.batch.jac(self._site_body, point, ids)
        if ids is None:
            self.gathered["jacobian"][...] = jacp
        else:
            self.gathered["jacobian"][ids] = jacp
