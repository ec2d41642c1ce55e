"""The study's policies: shipped checkpoints used only when they were trained under exactly the study's
configuration (``checkpoints/manifest.json``), trained otherwise; and the maintainers' tools that ship them.

The ``adr`` policy trains under automatic domain randomisation (:class:`randomizers.ADR`) from the nominal point: its
agent config carries the profile's ADR config (``sim2real train --adr adr.yaml``) and its effects file holds only the
signal models (``--config adr_signals.yaml``); the sim it ends up trained in (its final ranges) is
:func:`adr_simulator`.

Example:
    >>> from sim2real.study import load_profile
    >>> profile = load_profile()
    >>> effects_file("adr"), effects_file("randomized")
    ('adr_signals.yaml', 'randomized.yaml')
    >>> study_roles(profile)[:3], role_agent(profile, "nominal").adr is None
    (('nominal', 'randomized', 'calibrated'), True)
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.study.profile import BUDGETS, DEFAULT_TASK, StudyProfile, load_profile

__all__ = [
    "ADR_FILE",
    "ROLES",
    "adr_simulator",
    "effects_file",
    "prepare_checkpoints",
    "role_agent",
    "shipped",
    "study_roles",
    "train_one",
    "write_manifest",
]

#: The trained policies of a study, by the simulator they were trained on (``adr``: ranges grown by ADR).
ROLES = ("nominal", "randomized", "calibrated", "adr")
#: The ``--adr`` file of the shipped ADR checkpoint, next to it.
ADR_FILE = "adr.yaml"


def study_roles(profile: StudyProfile) -> tuple[str, ...]:
    """The trained policies of ``profile``'s study: :data:`ROLES`, without ``adr`` when it has no ADR config."""
    return tuple(r for r in ROLES if r != "adr" or profile.adr is not None)


def role_agent(profile: StudyProfile, role: str) -> Any:
    """The agent config ``role`` trains with: the profile's, plus its ADR config for ``adr``."""
    from sim2real.agents.config import replace

    if role not in ROLES:
        raise ValueError(f"`role` must be one of {list(ROLES)}. Received {role!r}.")
    if role != "adr":
        return profile.agent
    if profile.adr is None:
        raise ValueError(f"`role` 'adr' needs an `adr` section in {profile.folder / 'study.yaml'}. Received none.")
    return replace(profile.agent, adr=profile.adr)


def effects_file(role: str) -> str:
    """The name of ``role``'s effects file (``--config``) next to the shipped checkpoints."""
    return "adr_signals.yaml" if role == "adr" else f"{role}.yaml"


def adr_simulator(checkpoint: str | Path, signals: Sequence[Any] = ()) -> list[Any]:
    """The sim an ADR checkpoint ended its training in: its controller's final ranges as ordinary effects
    (:meth:`randomizers.ADR.effects_at_ranges`), plus ``signals``.

    Raises:
        ValueError: the checkpoint holds no ADR state (it was not trained with ADR).
    """
    from randomizers import ADR
    from sim2real.agents import load_checkpoint

    state = load_checkpoint(checkpoint).adr
    if state is None:
        raise ValueError(
            f"`checkpoint` must be trained with ADR (hold its final ranges). Received {str(checkpoint)!r}."
        )
    return [*ADR.from_state(state).effects_at_ranges(), *signals]


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
    """The shipped checkpoint of ``role`` trained under exactly ``effects`` and the role's agent (:func:`role_agent`,
    the ADR config included), if any."""
    agent = role_agent(profile, role).to_dict()
    for entry in _manifest(profile):
        if (
            entry.get("role") == role
            and entry.get("task") == profile.task
            and entry.get("effects") == effects
            and entry.get("agent") == agent
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
    role_effects = {"nominal": (), "randomized": profile.randomized, "calibrated": tuple(calibrated)}
    role_effects["adr"] = profile.adr_signals
    for role in study_roles(profile):
        text = effects_yaml(role_effects[role])
        config = ""
        if text is not None:
            atomic_write(folder / effects_file(role), text)
            config = f" --config {effects_file(role)}"
        if role == "adr":
            atomic_write(folder / ADR_FILE, str(profile.adr))
            config += f" --adr {ADR_FILE}"
        commands.append(
            f"sim2real train --task {profile.task} --agent-config agent.yaml{config} --seed 0 --out {role}.pt --no-log"
        )
    return commands


def write_manifest(task: str = DEFAULT_TASK, commands: Sequence[str] = ()) -> Path:
    """Maintainers: records the shipped checkpoints of ``task`` (role, file, effects YAML, agent config and the
    command) in ``checkpoints/manifest.json``; a checkpoint is used only when all of these match."""
    from randomizers.files import atomic_write
    from sim2real.agents import load_checkpoint
    from sim2real.agents.adr_training import adr_config_text

    profile = load_profile(task)
    folder = profile.folder / "checkpoints"
    # A checkpoint already listed keeps its command unless a new one is given.
    previous = {(e.get("role"), e.get("run_id")): e.get("command", "") for e in _manifest(profile)}
    entries = []
    for role in ROLES:
        path = folder / f"{role}.pt"
        if not path.is_file():
            continue
        ckpt = load_checkpoint(path, task=profile.task)
        config_file = folder / effects_file(role)
        effects = config_file.read_text() if config_file.is_file() else None
        if ckpt.effects != effects:
            raise ValueError(f"{path} was trained under other effects than {config_file}.")
        adr_file = folder / ADR_FILE
        if role == "adr" and (not adr_file.is_file() or ckpt.config.adr != adr_config_text(adr_file.read_text())):
            raise ValueError(f"{path} was trained under another ADR config than {adr_file}.")
        entries.append(
            {
                "role": role,
                "file": path.name,
                "task": profile.task,
                "effects": effects,
                "agent": ckpt.config.to_dict(),
                "seed": ckpt.seed,
                "run_id": ckpt.run_id,
                "command": next(
                    (c for c in commands if f"--out {role}.pt" in c), previous.get((role, ckpt.run_id), "")
                ),
            }
        )
    path = folder / "manifest.json"
    atomic_write(path, json.dumps({"checkpoints": entries}, indent=1, sort_keys=True) + "\n")
    return path
