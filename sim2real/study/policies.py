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
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.study.profile import BUDGETS, DEFAULT_TASK, StudyProfile, load_profile

__all__ = [
    "ADR_FILE",
    "ROLES",
    "TrainingTime",
    "adr_simulator",
    "effects_file",
    "prepare_checkpoints",
    "role_agent",
    "shipped",
    "study_roles",
    "train_checkpoints",
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
            f"sim2real train --task {profile.task} --algo {profile.agent.algo} --agent-config agent.yaml{config} "
            f"--seed 0 --out {role}.pt --no-log"
        )
    return commands


@dataclass(frozen=True)
class TrainingTime:
    """What one training command cost, as recorded in the manifest.

    Attributes:
        wall_s: wall-clock seconds of the command's process, start to exit.
        cpu_s: CPU seconds (user + system) of that process and its children; None when it was not measured.
    """

    wall_s: float
    cpu_s: float | None = None


def command_role(command: str) -> str:
    """The role a ``sim2real train`` command of :func:`prepare_checkpoints` trains (its ``--out <role>.pt``).

    Example:
        >>> command_role("sim2real train --task dmc/reacher-easy --algo sac --seed 0 --out adr.pt --no-log")
        'adr'
    """
    args = shlex.split(command)
    out = args[args.index("--out") + 1] if "--out" in args[:-1] else ""
    role = out.removesuffix(".pt")
    if role not in ROLES or not out.endswith(".pt"):
        raise ValueError(f"`command` must end its output in --out <role>.pt, role one of {list(ROLES)}. "
                         f"Received {command!r}.")  # fmt: skip
    return role


def train_checkpoints(
    commands: Sequence[str], folder: str | os.PathLike[str], *, parallel: int = 2, niceness: int = 0
) -> dict[str, TrainingTime]:
    """Maintainers: runs the ``sim2real train`` commands of :func:`prepare_checkpoints` in ``folder`` (which holds
    their config files), ``parallel`` at a time, and returns each role's wall and CPU time for
    :func:`write_manifest`. ``sim2real`` is this interpreter's console script; ``niceness`` is added to each
    process's nice value.

    Raises:
        ValueError: a command is not a ``sim2real train ... --out <role>.pt`` command, or ``parallel`` < 1.
        RuntimeError: a command exited non-zero (its exit code and stderr's last line are in the message).
    """
    if isinstance(parallel, bool) or not isinstance(parallel, int) or parallel < 1:
        raise ValueError(f"`parallel` must be an int >= 1. Received {parallel!r}.")
    script = Path(sys.executable).parent / "sim2real"
    program = str(script) if script.is_file() else (shutil.which("sim2real") or "sim2real")
    pending = []
    for command in commands:
        args = shlex.split(command)
        if args[:2] != ["sim2real", "train"]:
            raise ValueError(f"`commands` must be `sim2real train` commands. Received {command!r}.")
        pending.append((command_role(command), [program, *args[1:]]))
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    running: dict[int, tuple[str, subprocess.Popen[bytes], float]] = {}
    times: dict[str, TrainingTime] = {}
    while pending or running:
        while pending and len(running) < parallel:
            role, argv = pending.pop(0)
            proc = subprocess.Popen(argv, cwd=folder, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                    preexec_fn=(lambda: os.nice(niceness)) if niceness else None)  # fmt: skip
            running[proc.pid] = (role, proc, time.perf_counter())
        pid, status, usage = os.wait4(-1, 0)  # the rusage of exactly that child (and its waited-for children)
        if pid not in running:
            continue
        role, proc, start = running.pop(pid)
        wall = time.perf_counter() - start
        code = os.waitstatus_to_exitcode(status)
        proc.returncode = code
        err = proc.stderr.read().decode(errors="replace").strip().splitlines() if proc.stderr else []
        if proc.stderr:
            proc.stderr.close()
        if code != 0:
            for _, other, _ in running.values():
                other.terminate()
            raise RuntimeError(f"training {role!r} exited with {code}: {err[-1] if err else '(no stderr)'}")
        times[role] = TrainingTime(wall_s=round(wall, 1), cpu_s=round(usage.ru_utime + usage.ru_stime, 1))
    return times


def write_manifest(
    task: str = DEFAULT_TASK, commands: Sequence[str] = (), times: Mapping[str, TrainingTime] | None = None
) -> Path:
    """Maintainers: records the shipped checkpoints of ``task`` (role, file, effects YAML, agent config, the
    command and, from ``times`` (:func:`train_checkpoints`), its wall and CPU seconds) in
    ``checkpoints/manifest.json``; a checkpoint is used only when role, effects and agent match. A checkpoint
    already listed keeps its command and times unless new ones are given."""
    from randomizers.files import atomic_write
    from sim2real.agents import load_checkpoint
    from sim2real.agents.adr_training import adr_config_text

    profile = load_profile(task)
    folder = profile.folder / "checkpoints"
    # A checkpoint already listed keeps its command and times unless new ones are given.
    previous: dict[tuple[Any, Any], dict[str, Any]] = {(e.get("role"), e.get("run_id")): e for e in _manifest(profile)}
    times = dict(times or {})
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
        before = previous.get((role, ckpt.run_id), {})
        timing: dict[str, Any] = (
            {"train_wall_s": times[role].wall_s, "train_cpu_s": times[role].cpu_s}
            if role in times
            else {k: before[k] for k in ("train_wall_s", "train_cpu_s") if k in before}
        )
        entries.append(
            {
                **timing,
                "role": role,
                "file": path.name,
                "task": profile.task,
                "effects": effects,
                "agent": ckpt.config.to_dict(),
                "seed": ckpt.seed,
                "run_id": ckpt.run_id,
                "command": next((c for c in commands if f"--out {role}.pt" in c), before.get("command", "")),
            }
        )
    path = folder / "manifest.json"
    atomic_write(path, json.dumps({"checkpoints": entries}, indent=1, sort_keys=True) + "\n")
    return path
