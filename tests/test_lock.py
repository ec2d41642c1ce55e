"""requirements.lock: complete, hashed, consistent with pyproject.toml, and what the environment actually holds."""

from __future__ import annotations

import importlib.metadata as metadata
import re
import subprocess
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11 (the lock is for 3.11)
ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "requirements.lock"
ENTRY = re.compile(r"^(?P<name>[A-Za-z0-9][A-Za-z0-9._-]*)==(?P<version>\S+)(?P<cont>(?: \\\n(?:    .*\\\n)*    .*)?)", re.M)


def _locked() -> dict[str, tuple[str, list[str]]]:
    out = {}
    for m in ENTRY.finditer(LOCK.read_text()):
        out[canonicalize_name(m["name"])] = (m["version"], re.findall(r"--hash=sha256:([0-9a-f]{64})", m["cont"]))
    return out


def test_every_locked_package_is_pinned_with_hashes() -> None:
    locked = _locked()
    lines = [ln for ln in LOCK.read_text().splitlines() if ln and not ln.startswith((" ", "#"))]
    assert len(lines) == len(locked) > 100  # every requirement line is a `name==version` entry
    assert all(hashes for _, hashes in locked.values()), [n for n, (_, h) in locked.items() if not h]


def test_lock_satisfies_pyproject_and_constraints() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = list(project["dependencies"])
    for extra in ("dev", "ray"):
        wanted += project["optional-dependencies"][extra]
    wanted += [ln for ln in (ROOT / "constraints.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    locked = _locked()
    for text in wanted:
        req = Requirement(text)
        name = canonicalize_name(req.name)
        assert name in locked, f"{req.name} (pyproject/constraints) is missing from requirements.lock"
        assert req.specifier.contains(Version(locked[name][0]), prereleases=True), (text, locked[name][0])
        for extra in req.extras:  # e.g. gymnasium[mujoco], ray[default]: their extras' packages are locked too
            dist_reqs = metadata.requires(req.name) or []
            for dep in map(Requirement, dist_reqs):
                if dep.marker is not None and dep.marker.evaluate({"extra": extra}) and not dep.marker.evaluate(
                    {"extra": ""}
                ):
                    assert canonicalize_name(dep.name) in locked, f"{dep.name} ({req.name}[{extra}]) is not locked"


def test_torch_line_admits_the_cpu_wheel_and_pypi_builds() -> None:
    version, hashes = _locked()["torch"]
    assert "+" not in version and version == "2.13.0"  # a plain pin matches 2.13.0+cpu and PyPI's 2.13.0
    assert len(hashes) > 2


@pytest.mark.skipif(sys.version_info[:2] != (3, 11), reason="the lock is for CPython 3.11")
def test_installed_environment_is_the_lock() -> None:
    """The environment the tests run in was installed from the lock (setup.sh), version for version."""
    installed = {canonicalize_name(d.metadata["Name"]): d.version for d in metadata.distributions()}
    wrong = {
        name: (version, installed.get(name))
        for name, (version, _) in _locked().items()
        if installed.get(name) is None or Version(installed[name]).public != Version(version).public
    }
    assert not wrong, f"installed differs from requirements.lock (locked, installed): {wrong}"


def test_refresh_script_rejects_unknown_arguments() -> None:
    run = subprocess.run([str(ROOT / "scripts" / "refresh-lock.sh"), "--frobnicate"], capture_output=True, text=True)
    assert run.returncode == 2
    assert run.stderr == "refresh-lock.sh: unknown argument '--frobnicate' (allowed: --check)\n"
