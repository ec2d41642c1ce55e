"""The study's policies: shipped checkpoints used only when they were trained under exactly the study's
configuration (``checkpoints/manifest.json``), trained otherwise; and the maintainers' tools that ship them."""

from __future__ import annotations

import json
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.study.profile import BUDGETS, DEFAULT_TASK, StudyProfile, load_profile

__all__ = ["ROLES", "prepare_checkpoints", "shipped", "train_one", "write_manifest"]

#: The trained policies of a study, by the simulator they were trained on.
ROLES = ("nominal", "randomized", "calibrated")


@dataclass(frozen=True)
class TrainJob:
    task: str
    role: str
    agent: Any
    effects_yaml: str | None
    seed: int
    out: str


def train_one(job: TrainJob) -> str:
    from randomizers import load_config
    from sim2real.agents import train

    effects = load_config(job.effects_yaml) if job.effects_yaml else []
    result = train(job.task, job.agent, effects=effects, seed=job.seed, progress=False, logger=None)
    result.save(job.out)
    return job.out


def effects_yaml(effects: Sequence[Any]) -> str | None:
    """The YAML a checkpoint records for its training effects (None without effects)."""
    from randomizers import dump_config

    return dump_config(list(effects)) if effects else None


def _manifest(profile: StudyProfile) -> list[dict[str, Any]]:
    path = profile.folder / "checkpoints" / "manifest.json"
    if not path.is_file():
        return []
    return list(json.loads(path.read_text()).get("checkpoints", []))


def shipped(profile: StudyProfile, role: str, effects: str | None) -> Path | None:
    """The shipped checkpoint of ``role`` trained under exactly ``effects`` and the profile's agent, if any."""
    for entry in _manifest(profile):
        if (
            entry.get("role") == role
            and entry.get("task") == profile.task
            and entry.get("effects") == effects
            and entry.get("agent") == profile.agent.to_dict()
        ):
            path = profile.folder / "checkpoints" / entry["file"]
            if path.is_file():
                return path
    return None


def prepare_checkpoints(task: str = DEFAULT_TASK, *, seed: int = 0, budget: str = "standard") -> list[str]:
    """Maintainers: writes the training configs of the shipped checkpoints into the profile's ``checkpoints/``
    folder (the calibrated one from the twin logs and fit of ``seed`` at ``budget``) and returns the
    ``sim2real train`` commands that produce them; run those, then :func:`write_manifest`."""
    import sysid
    from randomizers.files import atomic_write
    from sim2real.study.fitting import best_fit, calibrated_effects, record_twin

    profile = load_profile(task)
    spec = BUDGETS[budget]
    folder = profile.folder / "checkpoints"
    folder.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        log_path = Path(tmp) / "log.npz"
        sysid.save_log(record_twin(profile, spec, seed), log_path)
        fit = best_fit(profile, log_path, spec, seed, lambda fn, items, desc: [fn(item) for item in items])
    calibrated = calibrated_effects(
        fit, relative_width=profile.relative_width, digits=profile.digits, keep=profile.keep
    )
    atomic_write(folder / "agent.yaml", profile.agent.to_yaml())
    commands = []
    for role, effects in (("nominal", ()), ("randomized", profile.randomized), ("calibrated", tuple(calibrated))):
        text = effects_yaml(effects)
        config = ""
        if text is not None:
            atomic_write(folder / f"{role}.yaml", text)
            config = f" --config {role}.yaml"
        commands.append(
            f"sim2real train --task {profile.task} --agent-config agent.yaml{config} --seed 0 --out {role}.pt --no-log"
        )
    return commands


def write_manifest(task: str = DEFAULT_TASK, commands: Sequence[str] = ()) -> Path:
    """Maintainers: records the shipped checkpoints of ``task`` (role, file, effects YAML, agent config and the
    command) in ``checkpoints/manifest.json``; a checkpoint is used only when all of these match."""
    from randomizers.files import atomic_write
    from sim2real.agents import load_checkpoint

    profile = load_profile(task)
    folder = profile.folder / "checkpoints"
    entries = []
    for role in ROLES:
        path = folder / f"{role}.pt"
        if not path.is_file():
            continue
        ckpt = load_checkpoint(path, task=profile.task)
        config_file = folder / f"{role}.yaml"
        effects = config_file.read_text() if config_file.is_file() else None
        if ckpt.effects != effects:
            raise ValueError(f"{path} was trained under other effects than {config_file}.")
        entries.append(
            {
                "role": role,
                "file": path.name,
                "task": profile.task,
                "effects": effects,
                "agent": ckpt.config.to_dict(),
                "seed": ckpt.seed,
                "run_id": ckpt.run_id,
                "command": next((c for c in commands if f"--out {role}.pt" in c), ""),
            }
        )
    path = folder / "manifest.json"
    atomic_write(path, json.dumps({"checkpoints": entries}, indent=1, sort_keys=True) + "\n")
    return path
