"""One executor for independent work: :func:`run_tasks` on this process, a local process pool or Ray.

Evaluation sweeps, the independent stages of ``sim2real study`` and sysid multi-starts all reduce to "call ``fn``
on every item and give me the results in order". :func:`run_tasks` does that on one of three backends:

- ``"serial"``: a plain loop in this process, for debugging (breakpoints work, nothing is pickled).
- ``"local"`` (default): a ``concurrent.futures.ProcessPoolExecutor`` whose workers are started with the
  ``"spawn"`` method. Never ``"fork"``: a forked child inherits MuJoCo/EGL contexts, torch thread pools and locks
  held by other threads, none of which survive a fork.
- ``"ray"``: Ray tasks (``pip install 'sim2real[ray]'``), on this machine or on a cluster.

**Determinism.** The results do not depend on the backend or on the number of workers: ``fn`` must get everything
it needs, seeds included, in its item (and must not read global random state or mutate its item), and the results
come back in input order whatever order the workers finish in. The local and Ray backends pickle every item and
result with the same pickle protocol, so they hand ``fn`` and the caller equal objects.

**Worker deaths** (the process is killed, segfaults or calls ``os._exit``; on Ray a crashed worker, a dead node or
the out-of-memory killer) are retried up to ``retries`` times per item and reported in :attr:`TaskRun.retried`;
an item is never dropped. An item that dies more often raises :class:`WorkerError`. A Python exception raised by
``fn`` is a bug, not bad luck, and is not retried: it is raised at once as a :class:`TaskError` that names the item.

**Ray clusters.** With ``backend="ray"`` an already initialised Ray is used as it is, so to point the work at an
existing cluster either call ``ray.init(address="ray://host:10001")`` (Ray Client) or ``ray.init(address="auto")``
before :func:`run_tasks`, or set the address in the environment, e.g.
``RAY_ADDRESS=ray://host:10001 sim2real study --backend ray``: when Ray is not initialised and ``RAY_ADDRESS`` is
set, :func:`run_tasks` calls ``ray.init(address="auto")``, which connects to that address. Only when neither is
the case does it start a local Ray with ``ray.init(num_cpus=workers)``; that one stays up for later calls and
:func:`shutdown_ray` stops it. A cluster you connected to yourself is never shut down here.

Example:
    >>> from operator import neg
    >>> run = run_tasks(neg, [1, 2, 3], backend="serial")
    >>> run.results, run.backend, run.workers, run.retried
    ((-1, -2, -3), 'serial', 1, ())
    >>> list(run), len(run), run[0]
    ([-1, -2, -3], 3, -1)
    >>> run_tasks(neg, [1], backend="dask")
    Traceback (most recent call last):
    ...
    ValueError: `backend` must be one of ['serial', 'local', 'ray']. Received 'dask'.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Generic, TypeVar, overload

__all__ = ["BACKENDS", "Retry", "TaskError", "TaskRun", "WorkerError", "run_tasks", "shutdown_ray"]

#: Names accepted by ``backend``.
BACKENDS: tuple[str, ...] = ("serial", "local", "ray")

#: The start method of the local pool's workers (see the module docstring for why never ``"fork"``).
START_METHOD = "spawn"

T = TypeVar("T")
R = TypeVar("R")

_PROTOCOL = pickle.HIGHEST_PROTOCOL


@dataclass(frozen=True)
class Retry:
    """One failed attempt of an item whose worker died, after which the item was run again.

    Attributes:
        index: position of the item in ``items``.
        attempt: which attempt of that item died (1 for the first run, 2 for the first retry, ...).
        reason: what happened, e.g. ``"worker process died (exit code -9, SIGKILL)"``.
    """

    index: int
    attempt: int
    reason: str


@dataclass(frozen=True)
class TaskRun(Generic[R]):
    """What :func:`run_tasks` returns. Iterating, ``len`` and indexing go to :attr:`results`.

    Attributes:
        results: ``fn(item)`` for every item, in the order of ``items``.
        backend: the backend that ran them (``"serial"``, ``"local"`` or ``"ray"``).
        workers: processes (local), concurrent tasks (Ray) or 1 (serial); 0 when ``items`` was empty.
        retried: every attempt lost to a dead worker and run again, in the order they happened.
        restarts: times the local process pool was rebuilt after a worker died (0 on the other backends). When a
            worker dies the whole pool breaks, so items that were running next to it are run again too; they are
            not charged an attempt and not listed in :attr:`retried`.
    """

    results: tuple[R, ...]
    backend: str
    workers: int
    retried: tuple[Retry, ...] = ()
    restarts: int = 0

    def __len__(self) -> int:
        return len(self.results)

    def __iter__(self) -> Iterator[R]:
        return iter(self.results)

    @overload
    def __getitem__(self, index: int) -> R: ...

    @overload
    def __getitem__(self, index: slice) -> tuple[R, ...]: ...

    def __getitem__(self, index: int | slice) -> R | tuple[R, ...]:
        return self.results[index]


class TaskError(RuntimeError):
    """``fn`` raised on one item; the original exception is the ``__cause__``.

    Attributes:
        index: position of the item in ``items``.
        total: number of items.
    """

    def __init__(self, index: int, total: int, cause: BaseException) -> None:
        detail = f"{type(cause).__name__}: {cause}" if str(cause) else type(cause).__name__
        super().__init__(f"task {index} of {total} failed: {detail}")
        self.index = index
        self.total = total


class WorkerError(RuntimeError):
    """The worker running one item died on every attempt (``retries + 1`` of them).

    Attributes:
        index: position of the item in ``items``.
        total: number of items.
        attempts: attempts made, all lost to a dead worker.
        cause: why the last attempt was lost.
    """

    def __init__(self, index: int, total: int, attempts: int, cause: str) -> None:
        tries = "its only attempt" if attempts == 1 else f"all {attempts} attempts"
        super().__init__(
            f"task {index} of {total}: the worker died on {tries} (retries={attempts - 1}); last cause: {cause}"
        )
        self.index = index
        self.total = total
        self.attempts = attempts
        self.cause = cause


def run_tasks(
    fn: Callable[[T], R],
    items: Iterable[T],
    *,
    backend: str = "local",
    workers: int | None = None,
    retries: int = 2,
    progress: bool = False,
    desc: str = "tasks",
) -> TaskRun[R]:
    """Calls ``fn(item)`` for every item on the chosen backend and returns the results in input order.

    The results are the same on every backend and for every ``workers``: put everything ``fn`` needs, seeds
    included, into the item (see the module docstring).

    Args:
        fn: a callable taking one item. For ``"local"`` and ``"ray"`` it must be picklable by reference: a
            module-level function, or a ``functools.partial`` of one (lambdas and local functions are refused).
        items: the inputs (read once, into a list); for ``"local"`` and ``"ray"`` each must be picklable.
        backend: ``"serial"``, ``"local"`` (a spawn process pool) or ``"ray"`` (extra ``sim2real[ray]``).
        workers: processes (local) or concurrent tasks (Ray); default the CPUs this process may use (local) or
            the cluster's CPUs (Ray), never more than there are items. ``"serial"`` takes only 1 or None.
        retries: how many times an item whose worker died is run again before :class:`WorkerError`.
        progress: show a tqdm bar on stderr.
        desc: the bar's label.

    Returns:
        A :class:`TaskRun`.

    Raises:
        ValueError: an unknown ``backend`` or a bad ``workers``/``retries``.
        TypeError: ``fn`` is not callable, ``fn`` or an item is not picklable (local and Ray), or ``fn`` was
            defined in an interactive session, where spawned workers cannot import it (local).
        ImportError: ``backend="ray"`` without Ray installed.
        TaskError: ``fn`` raised on an item (the first failure seen; not retried, the original is the cause).
        WorkerError: an item's worker died on all ``retries + 1`` attempts.
        KeyboardInterrupt: re-raised after pending work is cancelled and the workers are killed.

    Example:
        >>> run_tasks(abs, [-2, 3], backend="serial").results
        (2, 3)
        >>> run_tasks(abs, [1], backend="serial", workers=2)
        Traceback (most recent call last):
        ...
        ValueError: `workers` must be 1 or None with backend 'serial'. Received 2.
        >>> run_tasks(abs, [1], retries=-1)
        Traceback (most recent call last):
        ...
        ValueError: `retries` must be an int >= 0. Received -1.
    """
    if backend not in BACKENDS:
        raise ValueError(f"`backend` must be one of {list(BACKENDS)}. Received {backend!r}.")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"`workers` must be a positive int or None. Received {workers!r}.")
    if backend == "serial" and workers not in (None, 1):
        raise ValueError(f"`workers` must be 1 or None with backend 'serial'. Received {workers!r}.")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"`retries` must be an int >= 0. Received {retries!r}.")
    if not callable(fn):
        raise TypeError(f"`fn` must be callable. Received {fn!r}.")
    if not isinstance(desc, str):
        raise TypeError(f"`desc` must be a str. Received {desc!r}.")
    ray = _import_ray() if backend == "ray" else None
    fn_bytes = _pickled_fn(fn, backend) if backend != "serial" else b""
    todo = list(items)
    n = len(todo)
    if n == 0:
        return TaskRun(results=(), backend=backend, workers=0)
    with _bar(n, progress, desc) as bar:
        if backend == "serial":
            return TaskRun(results=_run_serial(fn, todo, bar), backend=backend, workers=1)
        if backend == "local":
            _check_importable(fn)
            payloads = [_pickled_item(item, i, backend, pickle.dumps) for i, item in enumerate(todo)]
            size = min(workers or _cpu_count(), n)
            results, retried, restarts = _run_local(fn_bytes, payloads, size, retries, bar)
            return TaskRun(results=results, backend=backend, workers=size, retried=retried, restarts=restarts)
        results, retried, size = _run_ray(ray, fn, todo, workers, retries, bar)
        return TaskRun(results=results, backend=backend, workers=size, retried=retried)


# --------------------------------------------------------------------------- helpers shared by the backends


def _cpu_count() -> int:
    # The CPUs this process may run on (a container's or taskset's limit), not the machine's.
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _bar(total: int, progress: bool, desc: str) -> Any:
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="task", disable=not progress, file=sys.stderr, leave=False)


def _name(fn: Any) -> str:
    module = getattr(fn, "__module__", None)
    qualname = getattr(fn, "__qualname__", None)
    if isinstance(qualname, str):
        return f"{module}.{qualname}" if isinstance(module, str) else qualname
    return repr(fn)


def _pickled_fn(fn: Callable[..., Any], backend: str) -> bytes:
    # Checked with the standard pickle even for Ray (whose cloudpickle would take a lambda): a function that runs
    # on one backend must run on all of them.
    try:
        return pickle.dumps(fn, protocol=_PROTOCOL)
    except Exception as err:
        raise TypeError(
            f"`fn` must be picklable to run on backend {backend!r}: use a module-level function (or a "
            f"functools.partial of one), not a lambda or a local function. Received {_name(fn)} "
            f"({type(err).__name__}: {err})."
        ) from err


def _check_importable(fn: Callable[..., Any]) -> None:
    # Spawned workers re-import a script's __main__, but an interactive session (REPL, notebook) has no file to
    # import, so its functions would only fail later, inside every worker.
    main = sys.modules.get("__main__")
    target = getattr(fn, "func", fn)  # a functools.partial names its function in .func
    if getattr(target, "__module__", None) == "__main__" and not getattr(main, "__file__", None):
        raise TypeError(
            "`fn` must be importable by the worker processes of backend 'local': functions defined in an "
            "interactive session (REPL or notebook) are not; move it into a module (or use backend 'ray' or "
            f"'serial'). Received {_name(target)}."
        )


def _pickled_item(item: Any, index: int, backend: str, dumps: Callable[..., bytes]) -> bytes:
    try:
        return dumps(item, protocol=_PROTOCOL)
    except Exception as err:
        raise TypeError(
            f"`items[{index}]` must be picklable to run on backend {backend!r}. Received an object of type "
            f"{type(item).__name__} ({type(err).__name__}: {err})."
        ) from err


def _call(fn: Callable[[Any], Any], item_bytes: bytes) -> Any:
    return fn(pickle.loads(item_bytes))


_FN_CACHE: dict[bytes, Callable[[Any], Any]] = {}


def _load_fn(fn_bytes: bytes, loads: Callable[[bytes], Any]) -> Callable[[Any], Any]:
    # A worker runs many items of one call: unpickle fn once. Ray workers outlive calls, so keep only a few.
    fn = _FN_CACHE.get(fn_bytes)
    if fn is None:
        if len(_FN_CACHE) >= 8:
            _FN_CACHE.clear()
        fn = _FN_CACHE[fn_bytes] = loads(fn_bytes)
    return fn


# --------------------------------------------------------------------------- serial


def _run_serial(fn: Callable[[T], R], items: Sequence[T], bar: Any) -> tuple[R, ...]:
    results: list[R] = []
    for index, item in enumerate(items):
        try:
            results.append(fn(item))
        except Exception as err:
            raise TaskError(index, len(items), err) from err
        bar.update(1)
    return tuple(results)


# --------------------------------------------------------------------------- local process pool

# In a worker: which process started which item (pid per item index, 0 = not started), shared with the parent so
# that after a pool breaks it can tell the item whose worker died from items that only lost their pool.
_STARTED: Any = None


def _init_worker(started: Any, parent: int = 0) -> None:
    global _STARTED
    _STARTED = started
    if parent:
        _die_with(parent)
    # Ctrl-C reaches the whole process group; the parent handles it (cancels and kills the workers).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):  # started with Ctrl-C held (_ctrl_c_held): now ignored, let it go
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _die_with(parent: int) -> None:
    """Makes this worker die with the process that started it (Linux: ``PR_SET_PDEATHSIG``). A parent killed with
    SIGKILL runs no clean-up: its workers went on computing items nobody would read, holding its pipes (over 2
    minutes, HF). Elsewhere, or if prctl is refused, nothing changes."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the line above: nobody will read this worker's results
        os._exit(1)


@contextlib.contextmanager
def _ctrl_c_held() -> Iterator[None]:
    """Blocks SIGINT in this thread while the pool spawns its workers: they inherit the mask through exec, so a
    Ctrl-C (sent to the whole process group) waits in a worker until _init_worker ignores it, instead of killing
    it with a traceback while it starts. This process still gets it (through another thread, or when unblocked)."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _local_task(fn_bytes: bytes, index: int, item_bytes: bytes) -> Any:
    # The item arrives as bytes and is unpickled here, after it is marked started, so that a worker that dies
    # while unpickling is blamed on its item and a failing import becomes a TaskError for that item.
    if _STARTED is not None:
        _STARTED[index] = os.getpid()
    return _call(_load_fn(fn_bytes, pickle.loads), item_bytes)


def _exit_reason(code: int | None) -> str:
    if code is None:
        return "worker process died (exit code unknown)"
    if code < 0:
        try:
            return f"worker process died (exit code {code}, {signal.Signals(-code).name})"
        except ValueError:
            pass
    return f"worker process died (exit code {code})"


def _processes(pool: ProcessPoolExecutor) -> dict[int, Any]:
    # The executor's own pid -> Process map (the same dict object for the pool's whole life, filled as workers
    # spawn). It is private, so degrade to "exit codes unknown" if a Python version changes it.
    procs = getattr(pool, "_processes", None)
    return procs if isinstance(procs, dict) else {}


def _kill_pool(pool: ProcessPoolExecutor, procs: dict[int, Any]) -> None:
    """Cancels queued items and kills the workers now, without waiting for running ones (no orphans left)."""
    thread = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    alive = list(procs.values())
    for proc in alive:
        with contextlib.suppress(Exception):
            proc.kill()
    for proc in alive:
        with contextlib.suppress(Exception):
            proc.join(timeout=10)
    if thread is not None:
        thread.join(timeout=10)


def _blame(failed: list[int], started: Any, procs: dict[int, Any]) -> list[tuple[int, str]]:
    """Which of the items lost to a broken pool are charged an attempt, and why.

    When one worker dies the executor fails every unfinished future and terminates (SIGTERM) the other
    workers; an item is charged only if the process that started it ended some other way. If that cannot be
    told apart (exit codes unknown, or the worker was itself killed with SIGTERM), every item that had started
    is charged, and if none had, every lost item: each broken pool then charges someone, so retries end.
    """
    codes = {pid: proc.exitcode for pid, proc in procs.items()}
    dead = {pid: code for pid, code in codes.items() if code is not None and code != -signal.SIGTERM}
    charged = [(i, _exit_reason(dead[started[i]])) for i in failed if started[i] in dead]
    if charged:
        return charged
    seen = sorted({c for c in codes.values() if c is not None})
    unknown = f"worker pool broke, could not tell which worker died (exit codes {seen})"
    if dead and set(dead.values()) == {1} and not any(started[i] for i in range(len(started))):
        # A worker that raises while it starts exits with 1 before it takes an item. The usual cause: a spawned
        # worker imports the script that started the pool (as __mp_main__) and that script starts one at its top level.
        unknown = (
            f"every worker that died exited with code 1 before it ran an item (exit codes {seen}): a worker failed "
            "while starting (its traceback is on stderr). The usual cause: a spawned worker first imports the script "
            "that started it, so a script must start workers under `if __name__ == '__main__':`, not at its top level"
        )
    running = [(i, unknown) for i in failed if started[i] != 0]
    return running or [(i, unknown) for i in failed]


def _run_local(
    fn_bytes: bytes, payloads: list[bytes], workers: int, retries: int, bar: Any
) -> tuple[tuple[Any, ...], tuple[Retry, ...], int]:
    import multiprocessing

    ctx = multiprocessing.get_context(START_METHOD)
    n = len(payloads)
    missing = object()
    results: list[Any] = [missing] * n
    attempts = [0] * n
    retried: list[Retry] = []
    restarts = 0
    todo = list(range(n))
    while todo:
        started = ctx.RawArray("q", n)
        with _ctrl_c_held():  # the resource tracker may start here
            pool = ProcessPoolExecutor(
                max_workers=min(workers, len(todo)),
                mp_context=ctx,
                initializer=_init_worker,
                initargs=(started, os.getpid()),
            )
        procs = _processes(pool)
        failed: list[int] = []
        try:
            futures: dict[Future[Any], int] = {}
            with _ctrl_c_held():
                for position, i in enumerate(todo):
                    try:
                        futures[pool.submit(_local_task, fn_bytes, i, payloads[i])] = i
                    except BrokenProcessPool:
                        # A worker died while items were still being queued: the rest are lost to this pool too.
                        failed.extend(todo[position:])
                        break
            pending: set[Future[Any]] = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in sorted(done, key=futures.__getitem__):
                    index = futures[future]
                    err = future.exception()
                    if err is None:
                        results[index] = future.result()
                        bar.update(1)
                    elif isinstance(err, BrokenProcessPool):
                        failed.append(index)
                    else:
                        raise TaskError(index, n, err) from err
        except BaseException:
            _kill_pool(pool, procs)
            raise
        # After a break this joins the workers the executor terminated, so their exit codes are known.
        pool.shutdown(wait=True)
        if not failed:
            break
        restarts += 1
        for index, reason in _blame(sorted(failed), started, procs):
            attempts[index] += 1
            if attempts[index] > retries:
                raise WorkerError(index, n, attempts[index], reason)
            retried.append(Retry(index, attempts[index], reason))
        todo = [i for i in range(n) if results[i] is missing]
    return tuple(results), tuple(retried), restarts


# --------------------------------------------------------------------------- Ray

_RAY_STARTED_HERE = False
_RAY_REMOTE: Any = None


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as err:
        raise ImportError("backend 'ray' needs Ray, which is not installed: pip install 'sim2real[ray]'") from err
    return ray


def _ensure_ray(ray: Any, workers: int | None) -> None:
    global _RAY_STARTED_HERE
    if ray.is_initialized():
        return
    if os.environ.get("RAY_ADDRESS"):
        # "auto" resolves RAY_ADDRESS, including a ray:// (Ray Client) address.
        ray.init(address="auto")
    else:
        ray.init(num_cpus=workers)
        _RAY_STARTED_HERE = True


def shutdown_ray() -> bool:
    """Stops the local Ray that :func:`run_tasks` started (``backend="ray"`` without a running Ray or
    ``RAY_ADDRESS``); it is otherwise kept up for later calls. A Ray you initialised yourself is left alone.

    Returns:
        True if a Ray started here was shut down, False if there was none.

    Example:
        >>> _ = shutdown_ray()  # stops the Ray an earlier run_tasks(..., backend="ray") started, if any
        >>> shutdown_ray()  # nothing left to stop
        False
    """
    global _RAY_STARTED_HERE
    if not _RAY_STARTED_HERE:
        return False
    _RAY_STARTED_HERE = False
    ray = sys.modules.get("ray")
    if ray is None or not ray.is_initialized():
        return False
    ray.shutdown()
    return True


def _ray_task(fn_bytes: bytes, item_bytes: bytes) -> bytes:
    # Bytes in and out: Ray would otherwise hand numpy results back as read-only views of its object store, and
    # the results are to be the same objects whatever the backend.
    from ray import cloudpickle

    return pickle.dumps(_call(_load_fn(fn_bytes, cloudpickle.loads), item_bytes), protocol=_PROTOCOL)


def _ray_crash_errors(ray: Any) -> tuple[type[BaseException], ...]:
    names = ("WorkerCrashedError", "NodeDiedError", "LocalRayletDiedError", "OutOfMemoryError", "ObjectLostError")
    return tuple(getattr(ray.exceptions, name) for name in names if hasattr(ray.exceptions, name))


def _run_ray(
    ray: Any, fn: Callable[[Any], Any], items: list[Any], workers: int | None, retries: int, bar: Any
) -> tuple[tuple[Any, ...], tuple[Retry, ...], int]:
    global _RAY_REMOTE
    from ray import cloudpickle

    _ensure_ray(ray, workers)
    n = len(items)
    # cloudpickle so that a function defined in a driver script's __main__ also runs on the workers.
    fn_ref = ray.put(cloudpickle.dumps(fn, protocol=_PROTOCOL))
    payloads = [_pickled_item(item, i, "ray", cloudpickle.dumps) for i, item in enumerate(items)]
    if _RAY_REMOTE is None:
        # Ray's own system-failure retries (max_retries) are invisible to the caller, so retries are done here,
        # by resubmission, where each one can be reported.
        _RAY_REMOTE = ray.remote(num_cpus=1, max_retries=0, retry_exceptions=False)(_ray_task)
    size = min(workers or max(1, int(ray.cluster_resources().get("CPU", 1))), n)
    crashes = _ray_crash_errors(ray)
    missing = object()
    results: list[Any] = [missing] * n
    attempts = [0] * n
    retried: list[Retry] = []
    queue = deque(range(n))
    inflight: dict[Any, int] = {}
    try:
        while queue or inflight:
            while queue and len(inflight) < size:
                index = queue.popleft()
                inflight[_RAY_REMOTE.remote(fn_ref, payloads[index])] = index
            done, _ = ray.wait(list(inflight), num_returns=1)
            for ref in done:
                index = inflight.pop(ref)
                try:
                    results[index] = pickle.loads(ray.get(ref))
                except ray.exceptions.RayTaskError as err:
                    cause = getattr(err, "cause", None)
                    if not isinstance(cause, BaseException):
                        raise TaskError(index, n, err) from err
                    # Like the local pool's remote traceback: the RayTaskError text holds the worker's traceback.
                    cause.__cause__ = err
                    raise TaskError(index, n, cause) from cause
                except crashes as err:
                    reason = f"worker process died ({type(err).__name__}: {str(err).splitlines()[0]})"
                    attempts[index] += 1
                    if attempts[index] > retries:
                        raise WorkerError(index, n, attempts[index], reason) from err
                    retried.append(Retry(index, attempts[index], reason))
                    queue.appendleft(index)
                    continue
                bar.update(1)
    except BaseException:
        for ref in inflight:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        raise
    return tuple(results), tuple(retried), size
