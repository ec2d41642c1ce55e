"""sim2real.parallel: the same results on every backend, dead workers retried and reported, pinned errors.

The functions run by the workers are module-level so that they pickle by reference. Local workers import this
module through the parent's ``sys.path``; Ray workers get it by value (see the ``ray`` fixture).
"""

from __future__ import annotations

import dataclasses
import functools
import multiprocessing
import os
import re
import signal
import sys
import threading
import time
from concurrent.futures.process import _ExecutorManagerThread
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

import sim2real.parallel as parallel
from sim2real.parallel import Retry, TaskError, TaskRun, WorkerError, run_tasks, shutdown_ray

PENDULUM = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body>
      <joint name="hinge" type="hinge" axis="0 1 0" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.03"/>
      <body pos="0 0 -0.4">
        <joint name="elbow" type="hinge" axis="0 1 0" damping="0.02"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="hinge"/><motor joint="elbow"/></actuator>
</mujoco>
"""


# --------------------------------------------------------------------------- worker functions


def rollout(seed: int) -> np.ndarray:
    """A seeded double-pendulum rollout under random torques, plus a few more draws of the same generator."""
    model = mujoco.MjModel.from_xml_string(PENDULUM)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    data.qpos[:] = rng.uniform(-1.0, 1.0, model.nq)
    states = np.empty((200, model.nq + model.nv))
    for t, ctrl in enumerate(rng.normal(0.0, 0.5, (200, model.nu))):
        data.ctrl[:] = ctrl
        mujoco.mj_step(model, data)
        states[t, : model.nq] = data.qpos
        states[t, model.nq :] = data.qvel
    return np.concatenate([states.ravel(), rng.standard_normal(5)])


def die_once(item: tuple[int, str]) -> int:
    """Item ``(i, marker)``: with a marker path, the first attempt creates it and dies; others take a moment."""
    index, marker = item
    if marker and not os.path.exists(marker):
        Path(marker).touch()
        os._exit(1)
    time.sleep(0.1)
    return index * 10


def killed(index: int) -> int:
    """Item 1 kills its own worker with SIGKILL on every attempt."""
    if index == 1:
        os.kill(os.getpid(), signal.SIGKILL)
    return index


def fails_on_three(item: tuple[int, str]) -> int:
    """Item ``(i, folder)``: logs each call in ``folder`` and raises on item 3."""
    index, folder = item
    with open(os.path.join(folder, f"calls-{index}"), "a") as f:
        f.write("call\n")
    if index == 3:
        raise ValueError("bad item 3")
    return index


def interrupt_parent(item: tuple[int, str]) -> int:
    """Item ``(i, folder)``: records the worker's pid; item 0 sends Ctrl-C to the parent once item 1 has started
    (the second worker may take a while to spawn on a loaded machine), then all hang."""
    index, folder = item
    scratch = Path(folder, f".pid-{index}")
    scratch.write_text(str(os.getpid()))
    scratch.replace(Path(folder, f"pid-{index}"))  # whole or absent, even if the worker is killed meanwhile
    if index == 0:
        deadline = time.monotonic() + 30
        while not Path(folder, "pid-1").exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        os.kill(os.getppid(), signal.SIGINT)
    time.sleep(60)
    return index


def scaled(factor: int, x: int) -> int:
    return factor * x


# --------------------------------------------------------------------------- fixtures


def children() -> set[int]:
    """Pids of this process's live multiprocessing children (other tests' helpers may already exist)."""
    return {p.pid for p in multiprocessing.active_children() if p.pid is not None}


def manager_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if isinstance(t, _ExecutorManagerThread)}


@pytest.fixture(scope="module")
def ray() -> Any:
    """A local 2-CPU Ray for the module (started once: it takes seconds), shut down at the end."""
    ray = pytest.importorskip("ray")
    from ray import cloudpickle

    module = sys.modules[__name__]
    # The Ray workers' sys.path holds the working directory, not tests/, so this module goes by value.
    cloudpickle.register_pickle_by_value(module)
    ours = not ray.is_initialized()  # another module may have left its Ray running: use it, leave it
    if ours:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        if ours:
            ray.shutdown()
        cloudpickle.unregister_pickle_by_value(module)


# --------------------------------------------------------------------------- determinism


def test_results_are_bitwise_equal_on_every_backend(ray: Any) -> None:
    seeds = list(range(6))
    direct = [rollout(s) for s in seeds]
    runs = {
        "serial": run_tasks(rollout, seeds, backend="serial"),
        "local": run_tasks(rollout, seeds, backend="local", workers=2),
        "ray": run_tasks(rollout, seeds, backend="ray", workers=2),
    }
    for backend, run in runs.items():
        assert isinstance(run, TaskRun)
        assert (run.backend, run.workers, run.retried, run.restarts) == (
            backend,
            1 if backend == "serial" else 2,
            (),
            0,
        )
        assert len(run) == len(seeds)
        for got, want in zip(run, direct, strict=True):
            assert got.dtype == want.dtype and got.shape == want.shape
            assert got.tobytes() == want.tobytes(), backend
            assert got.flags.writeable, backend  # Ray would hand back read-only object-store views
    assert len({rollout(0).tobytes(), rollout(1).tobytes()}) == 2  # the seed matters


def test_result_object() -> None:
    partial = functools.partial(scaled, 3)
    parallel._pickled_fn(partial, "local")  # a partial of a module-level function is accepted
    run = run_tasks(partial, [1, 2], backend="serial")
    assert run.results == (3, 6) and list(run) == [3, 6] and run[1] == 6 and run[:1] == (3,)
    with pytest.raises(dataclasses.FrozenInstanceError):
        run.results = ()  # type: ignore[misc]
    empty = run_tasks(rollout, [], backend="local")
    assert empty == TaskRun(results=(), backend="local", workers=0)


# --------------------------------------------------------------------------- dead workers


def test_local_worker_that_dies_once_is_retried_and_reported(tmp_path: Path) -> None:
    items = [(i, str(tmp_path / "died") if i == 1 else "") for i in range(4)]
    run = run_tasks(die_once, items, backend="local", workers=2)
    assert run.results == (0, 10, 20, 30)
    # Only the item whose worker died is charged; the item running next to it lost its pool and is rerun free.
    assert run.retried == (Retry(index=1, attempt=1, reason="worker process died (exit code 1)"),)
    assert run.restarts == 1


def test_local_worker_that_always_dies_raises_worker_error() -> None:
    before = children()
    with pytest.raises(WorkerError) as info:
        run_tasks(killed, [0, 1, 2], backend="local", workers=2, retries=1)
    assert str(info.value) == (
        "task 1 of 3: the worker died on all 2 attempts (retries=1); "
        "last cause: worker process died (exit code -9, SIGKILL)"
    )
    assert (info.value.index, info.value.attempts) == (1, 2)
    assert children() <= before


def test_ray_worker_that_dies_once_is_retried_and_reported(ray: Any, tmp_path: Path) -> None:
    items = [(i, str(tmp_path / "died") if i == 2 else "") for i in range(4)]
    run = run_tasks(die_once, items, backend="ray", workers=2)
    assert run.results == (0, 10, 20, 30)
    assert [(r.index, r.attempt) for r in run.retried] == [(2, 1)]
    assert run.retried[0].reason.startswith("worker process died (WorkerCrashedError: The worker died unexpectedly")


def test_ray_worker_that_always_dies_raises_worker_error(ray: Any) -> None:
    with pytest.raises(
        WorkerError,
        match=r"^task 1 of 2: the worker died on its only attempt \(retries=0\); last cause: worker process died ",
    ):
        run_tasks(killed, [0, 1], backend="ray", retries=0)


# --------------------------------------------------------------------------- errors in fn


@pytest.mark.parametrize("backend", ["serial", "local", "ray"])
def test_exception_in_fn_is_a_task_error_and_not_retried(
    backend: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    if backend == "ray":
        request.getfixturevalue("ray")
    items = [(i, str(tmp_path)) for i in range(5)]
    workers = None if backend == "serial" else 2
    with pytest.raises(TaskError) as info:
        run_tasks(fails_on_three, items, backend=backend, workers=workers, retries=2)
    assert str(info.value) == "task 3 of 5 failed: ValueError: bad item 3"
    assert info.value.index == 3 and info.value.total == 5
    assert isinstance(info.value.__cause__, ValueError)
    assert (tmp_path / "calls-3").read_text() == "call\n"  # run once, not retried


# --------------------------------------------------------------------------- Ctrl-C


def test_keyboard_interrupt_kills_the_workers(tmp_path: Path) -> None:
    items = [(i, str(tmp_path)) for i in range(4)]
    before, threads = children(), manager_threads()
    # A shell starts background jobs with SIGINT ignored (POSIX), and Python then installs no KeyboardInterrupt
    # handler: `pytest &` or a CI runner doing that would see no Ctrl-C at all. Ctrl-C is what this test is about.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    start = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_tasks(interrupt_parent, items, backend="local", workers=2)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert time.perf_counter() - start < 45  # did not wait for the hanging items
    pids = [int(p.read_text()) for p in tmp_path.glob("pid-*")]
    assert len(pids) == 2  # queued items were cancelled, never started
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    assert children() <= before
    assert manager_threads() <= threads


# --------------------------------------------------------------------------- arguments


def test_bad_arguments_have_pinned_messages() -> None:
    with pytest.raises(
        ValueError, match=re.escape("`backend` must be one of ['serial', 'local', 'ray']. Received 'dask'.")
    ):
        run_tasks(rollout, [1], backend="dask")
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match=re.escape(f"`workers` must be a positive int or None. Received {bad!r}.")):
            run_tasks(rollout, [1], workers=bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=re.escape("`workers` must be 1 or None with backend 'serial'. Received 2.")):
        run_tasks(rollout, [1], backend="serial", workers=2)
    for bad in (-1, 1.0, "2"):
        with pytest.raises(ValueError, match=re.escape(f"`retries` must be an int >= 0. Received {bad!r}.")):
            run_tasks(rollout, [1], retries=bad)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=re.escape("`fn` must be callable. Received 3.")):
        run_tasks(3, [1])  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=re.escape("`items[1]` must be picklable to run on backend 'local'. ")):
        run_tasks(rollout, [1, threading.Lock()])


@pytest.mark.parametrize("backend", ["local", "ray"])
def test_non_picklable_fn_is_refused_before_any_worker_starts(backend: str) -> None:
    if backend == "ray":
        pytest.importorskip("ray")

    def local(x: int) -> int:
        return x

    prefix = (
        f"`fn` must be picklable to run on backend {backend!r}: use a module-level function (or a functools.partial "
        "of one), not a lambda or a local function. Received "
    )
    before = children()
    for fn, name in ((lambda x: x, "<lambda>"), (local, "local")):
        with pytest.raises(TypeError, match=re.escape(prefix) + r"\S+" + re.escape(name)):
            run_tasks(fn, [1], backend=backend)
    assert children() <= before
    # The serial backend pickles nothing, so local functions are fine there.
    assert run_tasks(local, [1], backend="serial").results == (1,)


def test_ray_backend_without_ray(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # makes `import ray` raise ImportError
    with pytest.raises(
        ImportError, match=re.escape("backend 'ray' needs Ray, which is not installed: pip install 'sim2real[ray]'")
    ):
        run_tasks(rollout, [1], backend="ray")


def test_progress_bar_goes_to_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    run_tasks(abs, [-1, 2], backend="serial", progress=True, desc="sweep")
    assert "sweep" in capsys.readouterr().err
    run_tasks(abs, [-1, 2], backend="serial", desc="sweep")
    assert capsys.readouterr().err == ""


# --------------------------------------------------------------------------- Ray start-up and shutdown


class FakeRay:
    """Records the ``ray.init``/``ray.shutdown`` calls of :func:`sim2real.parallel._ensure_ray`."""

    def __init__(self, initialized: bool = False) -> None:
        self.initialized = initialized
        self.calls: list[tuple[str, dict[str, Any]]] = []

    def is_initialized(self) -> bool:
        return self.initialized

    def init(self, **kwargs: Any) -> None:
        self.calls.append(("init", kwargs))
        self.initialized = True

    def shutdown(self) -> None:
        self.calls.append(("shutdown", {}))
        self.initialized = False


def test_ray_is_started_locally_only_without_a_cluster(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(parallel, "_RAY_STARTED_HERE", False)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    fake = FakeRay()
    monkeypatch.setitem(sys.modules, "ray", fake)
    parallel._ensure_ray(fake, 2)
    assert fake.calls == [("init", {"num_cpus": 2})]
    assert shutdown_ray() is True and fake.calls[-1] == ("shutdown", {})
    assert shutdown_ray() is False

    monkeypatch.setenv("RAY_ADDRESS", "ray://head:10001")
    fake = FakeRay()
    monkeypatch.setitem(sys.modules, "ray", fake)
    parallel._ensure_ray(fake, 2)
    assert fake.calls == [("init", {"address": "auto"})]
    assert shutdown_ray() is False and fake.initialized  # a cluster we connected to is never shut down

    fake = FakeRay(initialized=True)  # the user's own ray.init(address=...)
    parallel._ensure_ray(fake, 2)
    assert fake.calls == []


def test_shutdown_ray_leaves_a_ray_it_did_not_start(ray: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(parallel, "_RAY_STARTED_HERE", False)  # the fixture's ray.init is the user's own
    assert shutdown_ray() is False
    assert ray.is_initialized()


def sigint_in_worker(_: int) -> tuple[bool, bool]:
    """(SIGINT blocked, SIGINT ignored) inside a local worker, after its initializer."""
    return signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, []), signal.getsignal(
        signal.SIGINT
    ) is signal.SIG_IGN


def mask_at_start(queue: Any) -> None:
    queue.put(signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, []))


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")
def test_workers_start_with_ctrl_c_held_then_ignore_it() -> None:
    """A Ctrl-C (sent to the whole process group) in the second a local worker spends importing, before its
    initializer ignored SIGINT, killed it with a traceback on the user's terminal (HF measured 7 in 10 interrupts of
    an evaluate's first 0.8 s). The pool now spawns its workers with SIGINT blocked: a child inherits the mask at
    start, and the initializer ignores SIGINT, then unblocks it; the parent's own mask is restored."""
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    before = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    with parallel._ctrl_c_held():
        child = ctx.Process(target=mask_at_start, args=(queue,))
        child.start()
    assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == before
    assert queue.get(timeout=60) is True  # blocked from the child's first instruction
    child.join(timeout=60)
    run = run_tasks(sigint_in_worker, [0, 1], backend="local", workers=2)
    assert list(run) == [(False, True), (False, True)]  # ignored, no longer blocked, after _init_worker


KILLED_PARENT_SCRIPT = """
import os, sys, time
from pathlib import Path
from sim2real.parallel import run_tasks

def linger(i):
    Path(sys.argv[1], f"worker-{os.getpid()}").write_text("")
    time.sleep(120)
    return i

if __name__ == "__main__":
    run_tasks(linger, [0, 1], backend="local", workers=2)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_local_workers_die_with_a_parent_killed_by_sigkill(tmp_path: Path) -> None:
    """A SIGKILL of the process running a local pool leaves it no clean-up: its workers went on for minutes with
    items nobody would read (HF). They now die with it."""
    import subprocess

    script = tmp_path / "killed.py"
    script.write_text(KILLED_PARENT_SCRIPT)
    proc = subprocess.Popen([sys.executable, str(script), str(tmp_path)], cwd=Path(__file__).resolve().parents[1])
    try:
        deadline = time.monotonic() + 120
        while len(list(tmp_path.glob("worker-*"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        workers = [int(p.name.split("-")[1]) for p in tmp_path.glob("worker-*")]
        assert len(workers) == 2
    finally:
        proc.kill()
        proc.wait()
    deadline = time.monotonic() + 20
    alive = workers
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = [pid for pid in workers if _running(pid)]
    for pid in alive:  # (do not leave them behind if the test fails)
        os.kill(pid, signal.SIGKILL)
    assert alive == []


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"  # a zombie has exited
    except (FileNotFoundError, IndexError):
        return False
