"""A training run's status in its own log folder: ``run.json`` says whether the run is still running, completed,
was interrupted (Ctrl-C, SIGTERM, SIGHUP) or failed (an exception), after how many frames, and which checkpoint it
wrote, so a folder of CSVs cut short never reads as a run that simply ended there.

:func:`~sim2real.agents.train` writes ``"running"`` as soon as the logger has made the folder and its final status
when it returns or raises (re-raising as before); ``sim2real train`` adds the checkpoint once it is written. A run
killed with SIGKILL (or by a power cut) stays ``"running"``. Every write is atomic (a temporary file, then a
rename), and nothing the logger wrote is touched.

Example:
    >>> import tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> run = RunStatus("interrupted", "ppo_x_seed0", "ppo", "sim2real/arm-reach", 0, 4000, 2000, signal="SIGTERM")
    >>> write_run_status(folder, run).name
    'run.json'
    >>> read_run_status(folder) == run
    True
    >>> run.where("runs/ppo_x_seed0")
    "the partial run (2000 of 4000 frames) is in 'runs/ppo_x_seed0', marked interrupted in its run.json"
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal as signal_module
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "RUN_FILE",
    "STATUSES",
    "RunStatus",
    "mark",
    "marked_run",
    "read_run_status",
    "status_for",
    "write_run_status",
]

#: The status file's name inside a run's log folder.
RUN_FILE = "run.json"
#: What ``status`` may be.
STATUSES = ("running", "completed", "interrupted", "failed")
#: The attribute :func:`~sim2real.agents.train` sets on the exception it re-raises (see :func:`marked_run`).
_MARK = "_sim2real_run"


@dataclass(frozen=True)
class RunStatus:
    """The content of a run's ``run.json``.

    Attributes:
        status: ``"running"``, ``"completed"``, ``"interrupted"`` or ``"failed"``.
        run_id: the run's id (its log folder's name; stored in its checkpoint).
        algo: ``"ppo"`` or ``"sac"``.
        task: the task id, or None for an env object without a gymnasium ``spec``.
        seed: the seed.
        frames_asked: the frame budget (``config.frames``; PPO rounds it up to whole batches).
        frames: frames of the last batch trained on and logged (the last row of the CSVs).
        signal: the signal that interrupted the run (``"SIGINT"`` for Ctrl-C, ``"SIGTERM"``, ``"SIGHUP"``), else None.
        error: ``"TypeName: message"`` of the exception a failed run raised, else None.
        checkpoint: the checkpoint this run wrote (an absolute path), else None: an interrupted or failed run
            writes none, so no checkpoint of it exists.
    """

    status: str
    run_id: str
    algo: str
    task: str | None
    seed: int
    frames_asked: int
    frames: int
    signal: str | None = None
    error: str | None = None
    checkpoint: str | None = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"`status` must be one of {list(STATUSES)}. Received {self.status!r}.")

    def where(self, folder: str | os.PathLike[str]) -> str:
        """The words a command prints about the run in ``folder``, e.g. ``the partial run (2000 of 4000 frames) is
        in 'runs/ppo_x_seed0', marked interrupted in its run.json``."""
        return f"the partial run ({self.frames} of {self.frames_asked} frames) is in {str(folder)!r}, marked {self.status} in its {RUN_FILE}"

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunStatus:
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})  # keys a later version adds are skipped


def status_for(err: BaseException) -> tuple[str, str | None, str | None]:
    """``(status, signal, error)`` of a run ended by ``err``: ``KeyboardInterrupt`` (and the CLI's ``Interrupted``,
    which carries the kill's ``signum``) is ``"interrupted"``, anything else ``"failed"``.

    Example:
        >>> status_for(KeyboardInterrupt()), status_for(ValueError("bad"))
        (('interrupted', 'SIGINT', None), ('failed', None, 'ValueError: bad'))
    """
    if isinstance(err, KeyboardInterrupt):
        signum = getattr(err, "signum", signal_module.SIGINT)
        return "interrupted", signal_module.Signals(signum).name, None
    text = str(err)
    return "failed", None, type(err).__name__ + (f": {text}" if text else "")


def write_run_status(folder: str | os.PathLike[str], run: RunStatus) -> Path:
    """Writes ``run`` to ``folder/run.json`` atomically (replacing the previous status); returns the path.

    Ctrl-C or a kill arriving during the write waits until the file is whole (:func:`held_signals`).
    """
    from randomizers.files import atomic_write
    from sim2real.output_paths import held_signals

    path = Path(folder) / RUN_FILE
    with held_signals():
        atomic_write(path, json.dumps(run.to_dict(), indent=2) + "\n", make_parents=False)
    return path


def read_run_status(folder: str | os.PathLike[str]) -> RunStatus | None:
    """The status in ``folder/run.json``, or None when the folder has none (a run logged before it existed).

    Raises:
        ValueError: the file is not a run status.
    """
    path = Path(folder) / RUN_FILE
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    try:
        return RunStatus.from_dict(json.loads(text))
    except (TypeError, ValueError) as err:
        raise ValueError(f"{str(path)!r} is not a run status ({RUN_FILE} written by sim2real train): {err}") from None


def marked_run(err: BaseException) -> tuple[Path, RunStatus] | None:
    """``(log folder, status)`` of the run :func:`~sim2real.agents.train` marked before re-raising ``err``, or None
    (no logger, or ``err`` came before the logger made its folder)."""
    mark = getattr(err, _MARK, None)
    return mark if isinstance(mark, tuple) else None


def mark(err: BaseException, folder: Path, run: RunStatus) -> None:
    """Records on ``err`` where its run is marked (read back by :func:`marked_run`), and says so in a note that
    Python prints under the traceback."""
    setattr(err, _MARK, (folder, run))
    err.add_note(f"sim2real: {run.where(folder)}")
