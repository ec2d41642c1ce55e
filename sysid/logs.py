"""Trajectory logs: the ``.npz`` format sysid fits from, its loaders and validation (simulated logs:
:func:`sysid.record.record_log`).

A log is a time series sampled at the control rate. Row ``t`` holds the measured state at ``time[t]``
and the control command issued at that instant (held for one control step):

============  ============  ========================================================================
key           shape         meaning (units)
============  ============  ========================================================================
time          (T,)          seconds; strictly increasing within each episode
qpos          (T, nq)       joint positions (rad for hinges, m for slides; quaternions unitless)
qvel          (T, nv)       joint velocities (rad/s, m/s)
ctrl          (T, nu)       actuator commands in the actuator's own units (N·m, rad for servos, ...)
sensordata    (T, ns)       optional; MuJoCo sensor readings at the state of row ``t``
obs           (T, ...)      optional; whatever the policy observed (free-form, not used by the fit)
episode       (T,)          optional; integer episode index, non-decreasing; episodes start afresh
act           (T, na)       optional; actuator activations (only for models with ``na > 0``)
meta          ()            JSON string: ``task``, ``timestep`` (s), ``control_timestep`` (s),
                            ``joint_names``, ``actuator_names``, ``sensor_names`` and, for
                            simulated logs, ``true_params`` ({address: value}),
                            ``true_latency_seconds`` ({"action": s, "obs": s}), ``noise_std``
                            ({channel: sigma}; a list where a channel's entries differ) and
                            ``noise_std_per_entry`` ({channel: [sigma of each column]}, columns
                            as :func:`channel_names` orders them); an older log's
                            ``true_latency_steps`` (control steps) is read as seconds
============  ============  ========================================================================

Every loader validates and raises :class:`LogError` (a ``ValueError``) naming the key, what is allowed
and what was received. :func:`save_log` writes a temporary file and renames it, so a crash never leaves a
half-written log.

Example:
    >>> import mujoco, numpy as np, tempfile, os
    >>> from sysid.record import record_log
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body><joint name="hinge" damping="0.1"/>'
    ...     '<geom size=".1" pos="0 0 -.2"/></body></worldbody>'
    ...     '<actuator><motor name="m" joint="hinge"/></actuator></mujoco>')
    >>> ctrl = np.zeros((50, 1)); ctrl[10:20] = 0.5
    >>> log = record_log(model, ctrl, n_substeps=5, task="pendulum")
    >>> log.qpos.shape, log.meta["control_timestep"]
    ((50, 1), 0.01)
    >>> path = os.path.join(tempfile.mkdtemp(), "log.npz")
    >>> save_log(log, path)
    >>> load_log(path, model=model).qpos.shape
    (50, 1)
"""

from __future__ import annotations

import itertools
import json
import math
import os
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from noise_models.timing import convert_time
from randomizers.addressing import joint_dofs
from randomizers.files import atomic_write, check_suffix

__all__ = [
    "OPTIONAL_KEYS",
    "REQUIRED_KEYS",
    "LogError",
    "TrajectoryLog",
    "channel_names",
    "check_log_path",
    "load_log",
    "log_format",
    "save_log",
    "validate_log",
]

#: Keys every ``.npz`` log must hold.
REQUIRED_KEYS: tuple[str, ...] = ("time", "qpos", "qvel", "ctrl", "meta")
#: Keys a log may hold.
OPTIONAL_KEYS: tuple[str, ...] = ("sensordata", "obs", "episode", "act")
_META_REQUIRED = ("timestep", "control_timestep")


class LogError(ValueError):
    """A trajectory log (file, arrays or CSV) is malformed or does not fit the model."""


def _as_array(value: Any, key: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise LogError(f"`{key}` must be a numeric array. Received {type(value).__name__}: {err}.") from err


def _latency_in_seconds(meta: Mapping[str, Any]) -> dict[str, Any]:
    """Older logs stored ``true_latency_steps`` (control steps); the log format keeps every time in seconds."""
    out = dict(meta)
    legacy = out.pop("true_latency_steps")
    if not isinstance(legacy, Mapping):
        raise LogError(f"`meta['true_latency_steps']` must map 'action'/'obs' to control steps. Received {legacy!r}.")
    substeps = max(1, round(float(out["control_timestep"]) / float(out["timestep"])))
    seconds = {
        str(side): convert_time(
            float(steps), "control_steps", "seconds", timestep=float(out["timestep"]), substeps=substeps
        )
        for side, steps in legacy.items()
    }
    out.setdefault("true_latency_seconds", seconds)
    return out


@dataclass(frozen=True, eq=False)
class TrajectoryLog:
    """A logged trajectory (one or several episodes) at the control rate.

    Attributes:
        time: (T,) seconds.
        qpos: (T, nq) measured joint positions.
        qvel: (T, nv) measured joint velocities.
        ctrl: (T, nu) commands issued at ``time[t]`` and held for one control step.
        sensordata: (T, ns) sensor readings, or None.
        obs: (T, ...) policy observations, or None (not used by the fit).
        episode: (T,) integer episode index (non-decreasing), or None for a single episode.
        act: (T, na) actuator activations, or None.
        meta: ``task``, ``timestep``, ``control_timestep``, ``joint_names``, ``actuator_names``,
            ``sensor_names``, optionally ``true_params`` and ``true_latency_seconds``.

    Construction validates shapes, finiteness and time order (see :func:`validate_log`); arrays are
    stored read-only.
    """

    time: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    sensordata: np.ndarray | None = None
    obs: np.ndarray | None = None
    episode: np.ndarray | None = None
    act: np.ndarray | None = None
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key in ("time", "qpos", "qvel", "ctrl", "sensordata", "act"):
            value = getattr(self, key)
            if value is None:
                if key in REQUIRED_KEYS:
                    raise LogError(f"`{key}` is required in a trajectory log. Received None.")
                continue
            array = _as_array(value, key).copy()
            array.flags.writeable = False
            object.__setattr__(self, key, array)
        if self.obs is not None:
            obs = np.array(self.obs)
            obs.flags.writeable = False
            object.__setattr__(self, "obs", obs)
        if self.episode is not None:
            raw = np.asarray(self.episode)
            if raw.dtype.kind == "f" and np.all(np.isfinite(raw)) and np.all(raw == np.round(raw)):
                raw = raw.astype(np.int64)
            if raw.dtype.kind not in "iu":
                raise LogError(f"`episode` must hold integer episode indices. Received dtype {raw.dtype}.")
            episode = raw.astype(np.int64).copy()
            episode.flags.writeable = False
            object.__setattr__(self, "episode", episode)
        if not isinstance(self.meta, Mapping):
            raise LogError(f"`meta` must be a mapping (JSON object). Received {type(self.meta).__name__}.")
        object.__setattr__(self, "meta", dict(self.meta))
        validate_log(self)
        if "true_latency_steps" in self.meta:
            object.__setattr__(self, "meta", _latency_in_seconds(self.meta))

    @property
    def num_steps(self) -> int:
        """Rows T."""
        return int(self.time.shape[0])

    @property
    def timestep(self) -> float:
        """Physics timestep in seconds (``meta["timestep"]``)."""
        return float(self.meta["timestep"])

    @property
    def control_timestep(self) -> float:
        """Control period in seconds (``meta["control_timestep"]``)."""
        return float(self.meta["control_timestep"])

    @property
    def n_substeps(self) -> int:
        """Physics steps per control step."""
        return max(1, round(self.control_timestep / self.timestep))

    def episode_bounds(self) -> list[tuple[int, int]]:
        """``[(start, stop), ...]`` row ranges of each episode, in order."""
        if self.episode is None:
            return [(0, self.num_steps)]
        cuts = np.flatnonzero(np.diff(self.episode) != 0) + 1
        edges = [0, *cuts.tolist(), self.num_steps]
        return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]

    def select_rows(self, rows: slice | np.ndarray) -> TrajectoryLog:
        """A new log holding only ``rows`` (same meta)."""

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[rows]

        return replace(
            self,
            time=self.time[rows],
            qpos=self.qpos[rows],
            qvel=self.qvel[rows],
            ctrl=self.ctrl[rows],
            sensordata=pick(self.sensordata),
            obs=pick(self.obs),
            episode=pick(self.episode),
            act=pick(self.act),
        )

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The ``.npz`` payload: every present key, ``meta`` as a JSON string."""
        out: dict[str, np.ndarray] = {"time": self.time, "qpos": self.qpos, "qvel": self.qvel, "ctrl": self.ctrl}
        for key in OPTIONAL_KEYS:
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        out["meta"] = np.array(json.dumps(_jsonable(self.meta), sort_keys=True))
        return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _first_bad(array: np.ndarray) -> str:
    flat = np.flatnonzero(~np.isfinite(array.reshape(array.shape[0], -1)))
    count = int(flat.size)
    if array.ndim == 1:
        row = int(flat[0])
        return f"{count} non-finite value(s), first at row {row}: {float(array[row])!r}"
    cols = int(np.prod(array.shape[1:]))
    row, col = divmod(int(flat[0]), cols)
    return f"{count} non-finite value(s), first at row {row}, column {col}: {float(array.reshape(array.shape[0], -1)[row, col])!r}"


def validate_log(log: TrajectoryLog, model: mujoco.MjModel | None = None) -> TrajectoryLog:
    """Checks shapes, finiteness, time order and meta; with ``model``, also nq/nv/nu/nsensordata.

    Args:
        log: the log to check.
        model: when given, the log's widths must match this model's.

    Returns:
        ``log`` unchanged, for chaining.

    Raises:
        LogError: the first problem found, naming the key, what is allowed and what was received.

    Example:
        >>> import numpy as np
        >>> meta = {"timestep": 0.01, "control_timestep": 0.01}
        >>> TrajectoryLog(time=[0.0, 0.02, 0.01], qpos=np.zeros((3, 1)), qvel=np.zeros((3, 1)),
        ...               ctrl=np.zeros((3, 1)), meta=meta)
        Traceback (most recent call last):
        ...
        sysid.logs.LogError: `time` must be strictly increasing within each episode. Received time[2]=0.01 \
after time[1]=0.02.
    """
    time = log.time
    if time.ndim != 1 or time.shape[0] < 2:
        raise LogError(f"`time` must have shape (T,) with T >= 2. Received shape {time.shape}.")
    steps = time.shape[0]
    for key in ("qpos", "qvel", "ctrl", "sensordata", "act"):
        array = getattr(log, key)
        if array is None:
            continue
        if array.ndim != 2 or array.shape[0] != steps:
            width = {"qpos": "nq", "qvel": "nv", "ctrl": "nu", "sensordata": "ns", "act": "na"}[key]
            raise LogError(
                f"`{key}` must have shape (T, {width}) with T = len(time) = {steps}. Received shape {array.shape}."
            )
    if log.obs is not None and (log.obs.ndim < 1 or log.obs.shape[0] != steps):
        raise LogError(f"`obs` must have shape (T, ...) with T = len(time) = {steps}. Received shape {log.obs.shape}.")
    if log.episode is not None:
        if log.episode.shape != (steps,):
            raise LogError(
                f"`episode` must have shape (T,) with T = len(time) = {steps}. Received shape {log.episode.shape}."
            )
        back = np.flatnonzero(np.diff(log.episode) < 0)
        if back.size:
            i = int(back[0]) + 1
            raise LogError(
                "`episode` must be non-decreasing (rows of one episode are contiguous). "
                f"Received episode[{i}]={int(log.episode[i])} after episode[{i - 1}]={int(log.episode[i - 1])}."
            )
    for key in ("time", "qpos", "qvel", "ctrl", "sensordata", "act"):
        array = getattr(log, key)
        if array is not None and not np.all(np.isfinite(array)):
            raise LogError(f"`{key}` must be finite (no NaN or inf). Received {_first_bad(array)}.")
    same_episode = np.ones(steps - 1, dtype=bool) if log.episode is None else np.diff(log.episode) == 0
    bad = np.flatnonzero((np.diff(time) <= 0) & same_episode)
    if bad.size:
        i = int(bad[0]) + 1
        raise LogError(
            f"`time` must be strictly increasing within each episode. Received time[{i}]={float(time[i])!r} "
            f"after time[{i - 1}]={float(time[i - 1])!r}."
        )
    meta = log.meta
    for key in _META_REQUIRED:
        value = meta.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise LogError(f"`meta['{key}']` must be a positive number of seconds. Received {value!r}.")
    ratio = meta["control_timestep"] / meta["timestep"]
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6 * ratio:
        raise LogError(
            "`meta['control_timestep']` must be a whole multiple (>= 1) of `meta['timestep']`. "
            f"Received control_timestep={meta['control_timestep']!r}, timestep={meta['timestep']!r}."
        )
    if model is not None:
        _check_model(log, model)
    return log


def _layout(model: mujoco.MjModel, key: str) -> str:
    """What a ``qpos``/``qvel`` row of ``model`` holds, when some joint is not one column (a free body beside the
    arm, a ball joint): the width a driver that logs only the arm's hinges falls short by."""
    parts = []
    for j in range(model.njnt):
        dofs = joint_dofs(model, j)
        if dofs > 1:
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}"
            kind = "free" if dofs == 6 else "ball"
            parts.append(f"{kind} joint {name!r} ({dofs + 1 if key == 'qpos' else dofs})")
    if key not in ("qpos", "qvel"):
        return ""
    if not parts:  # e.g. a gripper's two finger slides beside a 7-DoF arm: name them so the missing ones show
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}" for j in range(model.njnt)]
        return (
            f" (its joints in order: {', '.join(names)}; a log must carry every joint's state, or be fitted on a "
            "copy of the MJCF without the joints it lacks)"
        )
    return (
        f" (it holds every joint, {', '.join(parts)} included: a log must carry those bodies' state too, or be "
        "fitted on a copy of the MJCF without them)"
    )


def _check_model(log: TrajectoryLog, model: mujoco.MjModel) -> None:
    widths = {"qpos": ("nq", model.nq), "qvel": ("nv", model.nv), "ctrl": ("nu", model.nu)}
    widths["sensordata"] = ("nsensordata", model.nsensordata)
    widths["act"] = ("na", model.na)
    for key, (name, expected) in widths.items():
        array = getattr(log, key)
        if array is not None and array.shape[1] != expected:
            raise LogError(
                f"`{key}` must have {name}={expected} columns to match the model{_layout(model, key)}. Received "
                f"{array.shape[1]} columns (shape {array.shape})."
            )
    timestep = float(model.opt.timestep)
    if abs(log.timestep - timestep) > 1e-9 * timestep:
        raise LogError(
            f"`meta['timestep']` must equal the model's opt.timestep={timestep!r}. Received {log.timestep!r}."
        )


def check_log_path(path: str | os.PathLike[str], argument: str = "`path`") -> Path:
    """The path :func:`save_log` writes, checked (a ``.npz`` name); callers check it before recording.

    Example:
        >>> check_log_path("run.dat", "--out")
        Traceback (most recent call last):
        ...
        ValueError: --out must end in '.npz' (a trajectory log). Received 'run.dat'.
    """
    return check_suffix(path, argument, (".npz",), "a trajectory log")


def save_log(log: TrajectoryLog, path: str | os.PathLike[str]) -> None:
    """Writes ``log`` as an uncompressed ``.npz`` atomically (temporary file in the same folder, then rename).

    Args:
        log: the log.
        path: destination; ``.npz`` is appended by numpy if missing, so give it explicitly.
    """
    if not isinstance(log, TrajectoryLog):
        raise TypeError(f"`log` must be a TrajectoryLog. Received {type(log).__name__}.")
    target = check_log_path(path)
    arrays = log.to_arrays()

    def write(tmp: str) -> None:
        with open(tmp, "wb") as handle:
            # allow_pickle spelled out (its default) so the type checker does not match it against **arrays
            np.savez(handle, allow_pickle=True, **arrays)
            handle.flush()
            os.fsync(handle.fileno())

    atomic_write(target, write)


def log_format(path: str | os.PathLike[str]) -> str:
    """``"npz"`` (a zip archive), ``"csv"`` (text with a delimiter on its first row that is not blank or a ``#``
    comment) or ``"unknown"``.

    Example:
        >>> import os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "x.bin")
        >>> _ = open(path, "wb").write(bytes(range(256)))
        >>> log_format(path)
        'unknown'
    """
    with open(path, "rb") as handle:
        head = handle.read(4096)
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return "unknown"
    # the first row that is neither blank nor a '#' comment (a driver's '# firmware v2' line above its header)
    first = next((line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")), "")
    return "csv" if any(d in first for d in (",", ";", "\t")) else "unknown"


def load_log(path: str | os.PathLike[str], model: mujoco.MjModel | None = None) -> TrajectoryLog:
    """Reads and validates a ``.npz`` log.

    Args:
        path: the file.
        model: when given, the log must match its nq, nv, nu (and nsensordata, na, timestep).

    Raises:
        FileNotFoundError: no such file.
        LogError: truncated/corrupt file, missing key, wrong shape, NaN/inf, non-monotonic time, bad meta,
            or widths that do not match ``model``.
    """
    where = str(path)
    if not Path(path).is_file():
        raise FileNotFoundError(f"`path` {where!r} does not exist.")
    if log_format(path) == "csv":
        raise LogError(
            f"`path` {where!r} is a CSV text file, not a .npz trajectory log; read it with "
            "sysid.load_csv(path, columns, meta) or `sim2real sysid fit LOG.csv --columns MAP.yaml`."
        )
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as err:
        size = Path(path).stat().st_size
        raise LogError(
            f"`path` {where!r} must be a complete .npz trajectory log. Received a truncated or corrupt file "
            f"({size} bytes; {type(err).__name__}: {err})."
        ) from err
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise LogError(
            f"`{missing[0]}` is missing from {where!r}; a log needs keys {', '.join(REQUIRED_KEYS)}. "
            f"Received keys {', '.join(sorted(arrays)) or 'none'}."
        )
    unknown = sorted(set(arrays) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
    if unknown:
        raise LogError(
            f"{where!r} holds unknown key(s) {', '.join(unknown)}; allowed are "
            f"{', '.join(REQUIRED_KEYS + OPTIONAL_KEYS)}."
        )
    try:
        meta = json.loads(str(arrays.pop("meta")))
    except json.JSONDecodeError as err:
        raise LogError(f"`meta` must be a JSON string. Received text that does not parse: {err}.") from err
    try:
        log = TrajectoryLog(**arrays, meta=meta)
    except LogError as err:
        raise LogError(f"{where}: {err}") from err
    if model is not None:
        try:
            _check_model(log, model)
        except LogError as err:
            raise LogError(f"{where}: {err}") from err
    return log


def channel_names(model: mujoco.MjModel) -> dict[str, list[str]]:
    """Names of the columns of ``qpos``, ``qvel``, ``ctrl`` and ``sensordata`` for ``model``.

    Hinge/slide joints give ``qpos[name]``; multi-dimensional joints and sensors get ``[k]`` suffixes.

    Example:
        >>> import mujoco
        >>> m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><body><joint name="j"/><geom size=".1"/>'
        ...     '</body></worldbody><sensor><jointpos name="p" joint="j"/></sensor></mujoco>')
        >>> channel_names(m)["sensordata"]
        ['p']
    """
    qpos: list[str] = []
    qvel: list[str] = []
    for j in range(model.njnt):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}"
        kv = joint_dofs(model, j)  # a free joint once got one name for its 7 qpos columns (see joint_dofs)
        kq = kv + 1 if kv > 1 else 1  # free and ball joints add a quaternion's fourth number
        qpos += [f"qpos[{name}]"] if kq == 1 else [f"qpos[{name}][{k}]" for k in range(kq)]
        qvel += [f"qvel[{name}]"] if kv == 1 else [f"qvel[{name}][{k}]" for k in range(kv)]
    ctrl = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) or f"#{i}" for i in range(model.nu)]
    sensors: list[str] = []
    for s in range(model.nsensor):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SENSOR, s) or f"sensor#{s}"
        dim = int(model.sensor_dim[s])
        sensors += [name] if dim == 1 else [f"{name}[{k}]" for k in range(dim)]
    return {"qpos": qpos, "qvel": qvel, "ctrl": [f"ctrl[{c}]" for c in ctrl], "sensordata": sensors}
