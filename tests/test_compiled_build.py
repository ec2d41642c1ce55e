"""The optional C extensions of the hot step are what their sources say (not a build left over from older sources),
and turn off as documented."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from noise_models import compiled

ROOT = Path(__file__).resolve().parents[1]
SOURCES = {
    "noise_models._hot": ROOT / "noise_models/_hot.c",
    "sim2real.wrappers._hotstep": ROOT / "sim2real/wrappers/_hotstep.c",
}


@pytest.mark.parametrize("module", sorted(SOURCES))
def test_a_built_extension_is_not_older_than_its_source(module: str) -> None:
    if not compiled.available():
        pytest.skip("the C extensions are not built here (no compiler at install time): the Python path runs")
    built = Path(importlib.import_module(module).__file__ or "")
    source = SOURCES[module]
    if built.parent != source.parent:
        pytest.skip(f"{module} is installed from {built.parent}, not built beside its source (not an editable install)")
    assert built.stat().st_mtime >= source.stat().st_mtime, (
        f"{built.name} is older than {source.name}: rebuild with "
        "`.venv/bin/python -m pip install --no-deps --no-build-isolation -e .`"
    )


def test_the_environment_variable_turns_the_compiled_path_off(monkeypatch: pytest.MonkeyPatch) -> None:
    for value, on in (("1", False), ("yes", False), ("0", True), ("", True)):
        monkeypatch.setenv(compiled.ENV, value)
        assert compiled.enabled() is (on and compiled.available()), value
    monkeypatch.delenv(compiled.ENV)
    assert compiled.enabled() is compiled.available()
