"""Rewrites the torch line of a hashed lock so that it admits the CPU wheel and PyPI's wheels of the same release.

``uv pip compile`` pins the CPU build it found (``torch==2.13.0+cpu``) with that one file's hash. Machines without
the CPU wheel take PyPI's ``torch==2.13.0`` instead; a plain ``==2.13.0`` pin matches both (PEP 440 ignores the
local label of a candidate when the pin has none), and the hashes of PyPI's files are added from its simple index.

Usage: python3 scripts/lock_torch_hashes.py LOCKFILE   (rewritten in place)
"""

from __future__ import annotations

import json
import re
import sys
import urllib.request
from pathlib import Path

_ENTRY = re.compile(r"^torch==(?P<version>[^\s\\]+)(?P<rest>(?:.*\\\n)*.*\n?)", re.MULTILINE)


def pypi_hashes(version: str) -> list[str]:
    """sha256 of every file of torch ``version`` on PyPI, from the simple index's JSON form (PEP 691)."""
    request = urllib.request.Request(
        "https://pypi.org/simple/torch/", headers={"Accept": "application/vnd.pypi.simple.v1+json"}
    )
    with urllib.request.urlopen(request, timeout=60) as response:
        data = json.load(response)
    prefix = f"torch-{version}-"
    found = sorted({f["hashes"]["sha256"] for f in data["files"] if f["filename"].startswith(prefix)})
    if not found:
        raise SystemExit(f"PyPI lists no files of torch {version}")
    return found


def main(path: str) -> None:
    lock = Path(path)
    text = lock.read_text()
    match = _ENTRY.search(text)
    if match is None:
        raise SystemExit(f"{path}: no torch== line")
    public = match["version"].split("+", 1)[0]
    entry = match.group(0)
    hashes = sorted(set(re.findall(r"--hash=sha256:([0-9a-f]{64})", entry)) | set(pypi_hashes(public)))
    comment = re.search(r"#.*", entry.splitlines()[-1])
    lines = [f"torch=={public} \\"] + [f"    --hash=sha256:{h} \\" for h in hashes]
    lines[-1] = lines[-1].removesuffix(" \\")
    if comment:
        lines[-1] += f"  {comment.group(0)}"
    lock.write_text(text.replace(entry, "\n".join(lines) + "\n"))


if __name__ == "__main__":
    main(sys.argv[1])
