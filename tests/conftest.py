"""Shared fixtures: headless GL before mujoco loads, and a bitwise snapshot of a whole MjModel."""

from __future__ import annotations

import os
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np


def model_arrays(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Copies of every numeric array of ``model`` (and of ``model.opt``), for bitwise comparison."""
    out: dict[str, np.ndarray] = {}
    for owner, prefix in ((model, ""), (model.opt, "opt.")):
        for name in dir(owner):
            if name.startswith("_"):
                continue
            try:
                value = getattr(owner, name)
            except Exception:
                continue
            if isinstance(value, np.ndarray) and value.dtype.kind in "fiub":
                out[prefix + name] = value.copy()
    return out


def assert_same_model(before: dict[str, np.ndarray], model: mujoco.MjModel) -> None:
    """Every array of ``model`` equals the snapshot bitwise."""
    after = model_arrays(model)
    changed = [k for k in before if before[k].tobytes() != after[k].tobytes()]
    assert not changed, f"fields not restored bitwise: {changed}"


def assert_restored(before: dict[str, np.ndarray], model: mujoco.MjModel, twin: mujoco.MjModel) -> None:
    """``model`` equals ``before`` bitwise, except fields the env itself changed: those must equal
    the model of an unwrapped twin put through the same calls."""
    own = model_arrays(twin)
    expected = {k: (own[k] if own[k].tobytes() != v.tobytes() else v) for k, v in before.items()}
    assert_same_model(expected, model)


def reset_and_compare(batched: Any, singles: list[Any], seeds: list[int] | None) -> tuple[np.ndarray, dict[str, Any]]:
    """Resets batched worlds and their single envs with ``seeds`` and checks world ``i`` against env ``i``: the same
    first observation and bitwise the same reported draws. Returns the batched reset's (obs, params)."""
    obs, params = batched.reset(seed=seeds)
    for i, env in enumerate(singles):
        o, info = env.reset(seed=None if seeds is None else seeds[i])
        assert np.array_equal(o, obs[i])
        reported = info["sim2real"]["params"]
        assert sorted(reported) == sorted(params)
        for key, value in reported.items():
            assert params[key][i] == value, key  # bitwise, the same draw
    return obs, params
