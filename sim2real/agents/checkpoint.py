"""Checkpoints: policy weights plus everything needed to rebuild, trust and trace them.

A checkpoint is one ``torch.save`` file holding only plain types and tensors, so it loads with
``torch.load(weights_only=True)`` (no pickled code runs). It is written atomically: a crash never leaves
a half-written file under the final name.

Keys: ``format`` / ``format_version``, ``algo``, ``config`` (the config as a dict), ``task``, ``obs_dim``,
``action_low`` / ``action_high``, ``state_dict`` (the actor's weights), ``seed``, ``run_id``,
``git_commit`` (None outside a git checkout), ``versions`` (python, numpy, torch, torchrl, tensordict,
mujoco, sim2real), ``created`` (UTC, ISO 8601) and, for a ``model:<path>`` task, ``model_sha256`` (the MJCF file's
digest: a project folder moved elsewhere still matches its checkpoints).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import math
import os
import platform
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from sim2real.agents.config import PPOConfig, SACConfig, config_class

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "Checkpoint",
    "CheckpointError",
    "check_checkpoints",
    "load_checkpoint",
    "save_checkpoint",
]

#: Marker stored under ``"format"``.
FORMAT = "sim2real.agents.checkpoint"
#: Version of the layout; bumped on incompatible changes.
FORMAT_VERSION = 1

_REQUIRED = (
    "format",
    "format_version",
    "algo",
    "config",
    "task",
    "obs_dim",
    "action_low",
    "action_high",
    "state_dict",
    "seed",
    "run_id",
    "git_commit",
    "versions",
)


class CheckpointError(ValueError):
    """A checkpoint that cannot be read, is inconsistent, or does not fit the task it is used for."""


@dataclass(frozen=True)
class Checkpoint:
    """A loaded checkpoint.

    Attributes:
        policy: the rebuilt TorchRL actor with the saved weights (``"observation"`` -> ``"action"``).
        config: the training config.
        task: task id the policy was trained on, or None.
        seed: training seed.
        run_id: id of the training run.
        git_commit: commit of the sim2real checkout that trained it, or None.
        versions: package name -> version at save time.
        created: UTC time of saving, ISO 8601.
        path: the file it was read from.
        effects: the training randomisation as YAML (``sim2real.dump_config``), or None when trained without
            effects or saved without them.
        adr: the ADR controller's final state as JSON (``randomizers.ADR.from_state(checkpoint.adr)``), or None.
    """

    policy: Any
    config: PPOConfig | SACConfig
    task: str | None
    seed: int
    run_id: str
    git_commit: str | None
    versions: dict[str, str]
    created: str
    path: Path
    effects: str | None = None
    adr: str | None = None


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in ("numpy", "torch", "torchrl", "tensordict", "mujoco", "sim2real"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "unknown"
    return out


def git_commit() -> str | None:
    """HEAD of the git checkout sim2real runs from, or None (not a checkout, or git missing)."""
    here = Path(__file__).resolve().parent
    try:
        done = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = done.stdout.strip()
    return commit if done.returncode == 0 and len(commit) == 40 else None


def save_checkpoint(
    path: str | os.PathLike[str],
    policy: Any,
    config: PPOConfig | SACConfig,
    seed: int,
    run_id: str,
    *,
    task: str | None = None,
    effects: str | None = None,
    adr: str | None = None,
) -> None:
    """Writes ``policy`` (an actor from :func:`~sim2real.agents.train`) and its provenance to ``path`` atomically.

    Args:
        path: destination file (parents are created).
        policy: the actor (``TrainResult.policy`` or ``Checkpoint.policy``).
        config: the config it was trained with.
        seed: training seed.
        run_id: id of the training run.
        task: task id it was trained on (checked again on load when given there).
        effects: the training randomisation as YAML text (:func:`sim2real.dump_config`), kept for provenance.
        adr: the ADR controller's state as JSON (``ADR.to_json()``), saved with the policy it trained.

    Raises:
        TypeError: ``policy`` was not built by sim2real.agents, or ``config`` is not a PPO/SAC config.
    """
    import torch

    from randomizers.files import atomic_write
    from sim2real.agents.nets import actor_dims

    if not isinstance(config, (PPOConfig, SACConfig)):
        raise TypeError(f"`config` must be a PPOConfig or SACConfig. Received {type(config).__name__}.")
    obs_dim, low, high = actor_dims(policy)
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "algo": config.algo,
        "config": config.to_dict(),
        "task": task,
        "obs_dim": obs_dim,
        "action_low": low,
        "action_high": high,
        "state_dict": {k: v.detach().clone().cpu() for k, v in policy.state_dict().items()},
        "seed": int(seed),
        "run_id": str(run_id),
        "git_commit": git_commit(),
        "versions": _versions(),
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "effects": effects,
        "adr": adr,
        # A model: task is named by its file's absolute path; its bytes' digest lets a moved project still match.
        "model_sha256": _model_digest(task),
    }
    atomic_write(path, lambda tmp: torch.save(payload, tmp))


def _model_digest(task: str | None) -> str | None:
    """SHA-256 of the MJCF file of a ``model:<path>`` task id (None for other ids or a file that cannot be read)."""
    if task is None or not task.startswith("model:"):
        return None
    try:
        return hashlib.sha256(Path(task[len("model:") :]).read_bytes()).hexdigest()
    except OSError:
        return None


def _same_task(recorded: str, digest: Any, task: str) -> bool:
    """Whether a checkpoint that recorded ``recorded`` (and its MJCF's ``digest``) was trained on ``task``: the same
    id, or for ``model:`` ids the same MJCF bytes at another path (a project folder moved or copied elsewhere)."""
    if recorded == task:
        return True
    return recorded.startswith("model:") and isinstance(digest, str) and digest == _model_digest(task)


def _shape(value: Any) -> tuple[int, ...]:
    return tuple(value.shape)


def load_checkpoint(path: str | os.PathLike[str], *, task: str | None = None) -> Checkpoint:
    """Reads a checkpoint written by :func:`save_checkpoint` (``torch.load(weights_only=True)``).

    Args:
        path: the file.
        task: when given, a checkpoint that records its task must have been trained on this task id.

    Returns:
        A :class:`Checkpoint` whose ``policy`` is rebuilt from the config and loaded with the weights.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        CheckpointError: the file is corrupt or truncated, not a sim2real checkpoint, missing keys, holds a key
            of the wrong type or range (``obs_dim`` not an int >= 1, action bounds of different lengths or not
            ``low < high``, ...), holds weights that do not fit its own architecture (tampered), or was trained on
            another task.
    """
    import torch

    from sim2real.agents.nets import build_actor

    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"`path` {str(file)!r} does not exist or is not a file.")
    try:
        data = torch.load(file, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises RuntimeError, UnpicklingError, EOFError... for broken files
        reason = str(err).strip().splitlines()[0] if str(err).strip() else ""
        raise CheckpointError(
            f"checkpoint {str(file)!r} is corrupt or not a torch file "
            f"({type(err).__name__}{': ' + reason if reason else ''})."
        ) from err
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CheckpointError(f"checkpoint {str(file)!r} is not a sim2real.agents checkpoint (no {FORMAT!r} marker).")
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise CheckpointError(f"checkpoint {str(file)!r} is missing key(s) {missing}.")
    if data["format_version"] != FORMAT_VERSION:
        raise CheckpointError(
            f"checkpoint {str(file)!r} has format_version {data['format_version']!r}; this sim2real reads "
            f"{FORMAT_VERSION}."
        )
    _check_fields(data, file)
    # A checkpoint saved without its task cannot be checked by name; evaluate() then checks its sizes.
    if task is not None and data["task"] is not None and not _same_task(data["task"], data.get("model_sha256"), task):
        hint = ""
        if data["task"].startswith("model:") and task.startswith("model:"):
            hint = (
                " (another MJCF file: its contents differ from the one the policy was trained on)"
                if data.get("model_sha256")
                else " (the checkpoint records no digest of its MJCF, so a moved model cannot be recognised)"
            )
        raise CheckpointError(f"checkpoint {str(file)!r} was trained on task {data['task']!r}, not on {task!r}{hint}.")
    try:
        config = config_class(data["algo"]).from_dict(data["config"], source=f"checkpoint {str(file)!r} config")
    except (TypeError, ValueError) as err:
        raise CheckpointError(f"checkpoint {str(file)!r}: {err}" if str(file) not in str(err) else str(err)) from err
    actor = build_actor(
        config.algo,
        data["obs_dim"],
        [float(v) for v in data["action_low"]],
        [float(v) for v in data["action_high"]],
        config.hidden_sizes,
        config.activation,
        config.init_log_std,
        getattr(config, "angle_obs", ()),
    )
    _load_weights(actor, data["state_dict"], file)
    return Checkpoint(
        policy=actor,
        config=config,
        task=data["task"],
        seed=int(data["seed"]),
        run_id=str(data["run_id"]),
        git_commit=data["git_commit"],
        versions=dict(data["versions"]),
        created=str(data.get("created", "")),
        path=file,
        effects=data["effects"] if isinstance(data.get("effects"), str) else None,
        adr=data["adr"] if isinstance(data.get("adr"), str) else None,
    )


def check_checkpoints(
    paths: Sequence[str | os.PathLike[str]], task: str, task_options: Mapping[str, Any] | None = None
) -> None:
    """Loads each checkpoint for ``task`` and checks that its sizes fit the task's spaces, so a broken, tampered,
    foreign or mismatched one fails in the caller's process (``evaluate`` calls this before starting workers).

    Raises:
        FileNotFoundError: a path does not exist.
        CheckpointError: see :func:`load_checkpoint`; or the policy's observation or action size differs from
            the task's (``sim2real.make(task, **task_options)``).
    """
    from sim2real.agents.nets import actor_dims
    from sim2real.tasks import make

    loaded = [(path, load_checkpoint(path, task=task)) for path in paths]
    if not loaded:
        return
    env = make(task, **dict(task_options or {}))
    try:
        obs, act = math.prod(env.observation_space.shape or ()), math.prod(env.action_space.shape or ())
    finally:
        env.close()
    for path, ckpt in loaded:
        obs_dim, low, _ = actor_dims(ckpt.policy)
        if (obs_dim, len(low)) != (obs, act):
            raise CheckpointError(
                f"checkpoint {os.fspath(path)!r} takes observations of size {obs_dim} and gives actions of size "
                f"{len(low)}; task {task!r} has {obs} and {act}."
            )


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _bounds(data: dict[str, Any], key: str, file: Path) -> list[float]:
    value = data[key]
    if (
        not isinstance(value, (list, tuple))
        or not value
        or not all((_is_int(v) or isinstance(v, float)) and math.isfinite(v) for v in value)
    ):
        raise CheckpointError(
            f"checkpoint {str(file)!r}: `{key}` must be a non-empty list of finite numbers. Received {value!r}."
        )
    return [float(v) for v in value]


def _check_fields(data: dict[str, Any], file: Path) -> None:
    """Every key has the type and range :func:`save_checkpoint` writes, so a tampered or foreign file fails here
    with its name and the key, not inside torch or a worker process."""
    where = f"checkpoint {str(file)!r}"
    expected: tuple[tuple[str, Any, str], ...] = (
        ("algo", str, "a str"),
        ("task", (str, type(None)), "a str or None"),
        ("config", dict, "a mapping"),
        ("state_dict", dict, "a mapping of names to tensors"),
        ("run_id", str, "a str"),
        ("git_commit", (str, type(None)), "a str or None"),
        ("versions", dict, "a mapping"),
    )
    for key, kind, text in expected:
        if not isinstance(data[key], kind):
            shown = repr(data[key]) if len(repr(data[key])) <= 60 else f"a {type(data[key]).__name__}"
            raise CheckpointError(f"{where}: `{key}` must be {text}. Received {shown}.")
    if "effects" in data and not isinstance(data["effects"], (str, type(None))):
        raise CheckpointError(f"{where}: `effects` must be a str or None. Received {data['effects']!r}.")
    if "adr" in data and not isinstance(data["adr"], (str, type(None))):
        raise CheckpointError(f"{where}: `adr` must be a str or None. Received {data['adr']!r}.")
    for key, low in (("obs_dim", 1), ("seed", 0)):
        if not _is_int(data[key]) or data[key] < low:
            raise CheckpointError(f"{where}: `{key}` must be an int >= {low}. Received {data[key]!r}.")
    action_low = _bounds(data, "action_low", file)
    action_high = _bounds(data, "action_high", file)
    if len(action_low) != len(action_high):
        raise CheckpointError(
            f"{where}: `action_low` and `action_high` must have the same length. Received {len(action_low)} and "
            f"{len(action_high)}."
        )
    for i, (lo, hi) in enumerate(zip(action_low, action_high, strict=True)):
        if not lo < hi:
            raise CheckpointError(
                f"{where}: `action_low` must be < `action_high` in every entry. Received {lo!r} >= {hi!r} at index {i}."
            )


def _load_weights(actor: Any, state: Any, file: Path) -> None:
    import torch

    expected = actor.state_dict()
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise CheckpointError(f"checkpoint {str(file)!r}: `state_dict` must map names to tensors.")
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        raise CheckpointError(
            f"checkpoint {str(file)!r} does not match its architecture: missing weights {missing}, "
            f"unexpected weights {unexpected}."
        )
    for name, tensor in expected.items():
        if _shape(state[name]) != _shape(tensor):
            raise CheckpointError(
                f"checkpoint {str(file)!r} does not match its architecture: weight {name!r} has shape "
                f"{_shape(state[name])}, expected {_shape(tensor)}."
            )
        if tensor.is_floating_point() and not bool(torch.isfinite(state[name]).all()):
            raise CheckpointError(f"checkpoint {str(file)!r}: weight {name!r} holds NaN or infinite values.")
    actor.load_state_dict(state)
