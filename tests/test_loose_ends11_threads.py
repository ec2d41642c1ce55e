"""The batch's default thread count knows the CPUs this process may use (loose end 3 of session 11).

Before: ``default_threads`` took every task ``/proc/loadavg`` counts (the whole host) as busy on this process's cores,
so a container pinned to a few idle cores of a busy host got 1 thread, and a cgroup CPU quota (``docker --cpus=2``)
was not read at all: 64 threads on a 64-core host. Now the tasks the cores this process may not run on can hold are
left out, and the cgroup v2 ``cpu.max`` quota bounds the count. Every reading is fed in; nothing is timed.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sim2real.batched.worlds import CpuReadings, busy_cores, default_threads, read_cpu, usable_cores


def test_a_container_pinned_to_idle_cores_of_a_busy_host_uses_them() -> None:
    # 64-core host, 60 other tasks runnable, this process pinned to 2 cores (62 elsewhere): its 2 cores are idle
    pinned = CpuReadings(cores=2, running=(61, 61, 62, 61), load=None, elsewhere=62)
    assert (busy_cores(pinned), default_threads(64, pinned)) == (0, 2)
    # the host overloaded (70 others): 8 of them cannot fit elsewhere, so the 2 cores are busy
    overloaded = CpuReadings(cores=2, running=(71, 71, 72, 71), load=None, elsewhere=62)
    assert (busy_cores(overloaded), default_threads(64, overloaded)) == (8, 1)
    # 63 others: one of them on this process's cores
    one = CpuReadings(cores=2, running=(64,) * 4, load=None, elsewhere=62)
    assert (busy_cores(one), default_threads(64, one)) == (1, 1)
    # the load average (no /proc/loadavg) is read the same way
    assert default_threads(64, CpuReadings(cores=4, running=(), load=61.5, elsewhere=60)) == 4
    assert default_threads(64, CpuReadings(cores=4, running=(), load=63.2, elsewhere=60)) == 2
    # a whole machine (nothing elsewhere): as before
    assert default_threads(64, CpuReadings(cores=2, running=(2, 2, 3, 2), load=None)) == 1


def test_a_cgroup_quota_bounds_the_threads() -> None:
    # docker --cpus=2 on a 64-core host: every core allowed, 2 cores' worth of time
    quota = CpuReadings(cores=64, running=(1,) * 4, load=None, quota=2.0)
    assert (usable_cores(quota), default_threads(64, quota)) == (2, 2)
    assert default_threads(1, quota) == 1
    # 60 other tasks on the 64 cores leave 4 idle: still 2; 63 leave 1
    assert default_threads(64, CpuReadings(cores=64, running=(61,) * 4, load=None, quota=2.0)) == 2
    assert default_threads(64, CpuReadings(cores=64, running=(64,) * 4, load=None, quota=2.0)) == 1
    # a fraction of a core rounds up (the quota's time is used by both), never below 1, never above the cores
    assert [usable_cores(CpuReadings(cores=8, running=(), load=None, quota=q)) for q in (1.5, 0.2, 20.0)] == [2, 1, 8]


def _tree(tmp_path: Path, cgroup_line: str, files: dict[str, str]) -> tuple[str, str]:
    proc, cgroup = tmp_path / "proc", tmp_path / "cgroup"
    (proc / "self").mkdir(parents=True)
    (proc / "loadavg").write_text("3.50 2.04 1.44 3/94 27942\n")
    (proc / "self" / "cgroup").write_text(cgroup_line)
    cgroup.mkdir()
    for where, text in files.items():
        (cgroup / where).mkdir(parents=True, exist_ok=True)
        (cgroup / where / "cpu.max").write_text(text)
    return str(proc), str(cgroup)


@pytest.mark.parametrize(
    ("cgroup_line", "files", "quota"),
    [
        ("0::/\n", {".": "max 100000\n"}, None),  # a container without a quota
        ("0::/\n", {".": "150000 100000\n"}, 1.5),  # docker --cpus=1.5
        ("0::/\n", {}, None),  # no cgroup v2 (this box: v1)
        ("0::/\n", {".": "a lot\n"}, None),  # malformed: ignored
        # a pod: the container's own quota and its parents', the smallest wins
        (
            "0::/kubepods/pod1/ctr\n",
            {"kubepods": "400000 100000", "kubepods/pod1": "max 100000", "kubepods/pod1/ctr": "250000 100000"},
            2.5,
        ),
        ("0::/kubepods/pod1/ctr\n", {"kubepods": "100000 50000", "kubepods/pod1/ctr": "250000 100000"}, 2.0),
        # cgroup v1 lines only: the root's file; a path outside the namespace: the root's file
        ("4:memory:/x\n1:cpu:/\n", {".": "300000 100000"}, 3.0),
        ("0::/../sibling\n", {".": "max 100000", "sibling": "100000 100000"}, None),
    ],
)
def test_read_cpu_reads_the_quota_and_the_runnable_tasks_from_the_files_it_is_given(
    tmp_path: Path, cgroup_line: str, files: dict[str, str], quota: float | None
) -> None:
    proc, cgroup = _tree(tmp_path, cgroup_line, files)
    got = read_cpu(proc=proc, cgroup=cgroup)
    cores = len(os.sched_getaffinity(0))
    assert got == CpuReadings(cores, (3, 3, 3, 3), None, max(0, (os.cpu_count() or cores) - cores), quota)


def test_without_any_file_the_readings_are_as_before(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from sim2real.batched import worlds

    monkeypatch.setattr(worlds.os, "getloadavg", lambda: (2.5, 0.0, 0.0))
    got = read_cpu(proc=str(tmp_path / "none"), cgroup=str(tmp_path / "none"))
    assert (got.running, got.load, got.quota) == ((), 2.5, None)
