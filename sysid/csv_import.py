"""Real drivers' CSV logs: column mapping, units, scale/offset, a jittery time column, gaps, and format detection.

:func:`load_csv` turns a robot driver's CSV into a :class:`~sysid.logs.TrajectoryLog` at the control rate:

* **units** per column (:data:`UNITS`: ``s``, ``ms``, ``us`` for time; ``rad``, ``deg``, ``m``, ``mm`` for
  positions; ``rad/s``, ``deg/s``, ``m/s``, ``mm/s`` for velocities) and then ``scale``/``offset``:
  ``value = scale * (raw in SI units) + offset`` (offset in the log's units: rad, rad/s, s, actuator units);
* **time** converted to seconds and checked against ``meta["control_timestep"]``: a median spacing more than 20%
  away is an error (it names the column and, when the ratio is ~1000 or ~10^6, the unit it looks like);
* **jitter**: a segment gets one row per point of its control grid ``t0 + k * control_timestep``: the sample
  nearest that point, kept at its own time (``log.time``; :func:`sysid.fit` predicts every row at its time), and
  the command of the nearest row, held from the grid point for its control step. A point that no sample rounds to
  is interpolated (a hinge's or a slide's position by cubic Hermite through the logged velocity, the rest
  linearly; ``meta["csv"]["interpolated_rows"]`` counts them). Interpolating every sample onto the grid instead
  made fits of right models "not ok": a servo's acceleration jumps at every command, so a velocity sampled 2 ms off
  the grid cannot be carried onto it. The largest deviation from the grid is ``meta["csv"]["max_jitter_s"]``;
* **gaps**: a spacing over 1.5 control steps (dropped rows) ends the segment; the log continues in a new segment
  (the ``episode`` key numbers the segments, so the fit restarts from the logged state there) and a
  :class:`CsvWarning` says where. Nothing is interpolated across a gap;
* **degrees**: with ``model``, a limited hinge's position column past 2π (a limited slide's past 100x its range:
  millimetres) warns, naming the column; a header unit the loader cannot convert (``lift [in]``) is refused.

Errors (:class:`~sysid.logs.LogError`) name the file, the row (as numbered in the file: ``#`` comment rows, above the
header too, are skipped but counted) and the column. :func:`log_format` tells a ``.npz`` log from a CSV by its start.

Example:
    >>> import os, tempfile, warnings
    >>> path = os.path.join(tempfile.mkdtemp(), "robot.csv")
    >>> rows = ["t_ms,q_deg,dq,u"] + [f"{10 * k + (1 if k % 2 else 0)},{k},0,1" for k in range(6) if k != 3]
    >>> _ = open(path, "w").write("\\n".join(rows) + "\\n")
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     log = load_csv(path, {"time": "t_ms", "qpos": "q_deg", "qvel": "dq", "ctrl": "u"},
    ...                    meta={"timestep": 0.01, "control_timestep": 0.01}, units={"t_ms": "ms", "q_deg": "deg"})
    >>> log.episode.tolist(), log.meta["csv"]["segments"], log.meta["csv"]["max_jitter_s"]
    ([0, 0, 0, 1, 1], 2, 0.001)
    >>> str(caught[0].message).split(";")[0]
    "'robot.csv': 1 gap(s) in time column 't_ms', the first before row 5 (0.02 s after the previous row, 2 control steps)"
    >>> log_format(path)
    'csv'
"""

from __future__ import annotations

import contextlib
import difflib
import fnmatch
import itertools
import math
import os
import re
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sysid._csv_units import (
    _GAP,
    UNITS,
    _check_velocity_units,
    _header_unit,
    _slide_columns,
    _time_origin,
    _velocity_of,
    check_header_units,
    data_rows,
    header_row,
    row_numbers,
)
from sysid.logs import LogError, TrajectoryLog, _check_model, log_format

__all__ = ["UNITS", "CsvWarning", "load_column_map", "load_csv", "log_format"]

#: The unit kinds each key's columns take: a servo's command or a sensor is a position or a velocity (in degrees, say),
#: never a time; an episode index takes none.
_KIND_OF_KEY = {
    "time": ("time",),
    "qpos": ("position",),
    "qvel": ("velocity",),
    "ctrl": ("position", "velocity"),
    "sensordata": ("position", "velocity"),
    "act": ("position", "velocity"),
    "episode": (),
}
_KEYS = ("time", "qpos", "qvel", "ctrl", "sensordata", "episode", "act")
_STATE_KEYS = ("qpos", "qvel", "sensordata", "act")
_SPACING_TOLERANCE = 0.2


class CsvWarning(UserWarning):
    """A CSV log loaded, but something in it deserves a look (gaps, angles that look like degrees)."""


def load_column_map(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Reads a column map YAML (what ``sim2real sysid fit LOG.csv --columns MAP.yaml`` takes)::

        columns: {time: t_ms, qpos: "q*_deg", qvel: "dq*", ctrl: "u*"}   # required; see load_csv
        units: {t_ms: ms, "q*_deg": deg}                                  # optional
        scale: {"u*": 0.5}                                                # optional
        offset: {q2_deg: 0.01}                                            # optional, log units
        meta: {control_timestep: 0.02}                                    # optional; default: the model's
        delimiter: ","                                                    # optional

    Raises:
        LogError: the file does not parse, is not a mapping, lacks ``columns`` or holds an unknown key.
    """
    import yaml

    where = repr(os.fspath(path))
    try:
        config = yaml.safe_load(Path(path).read_text())
    except OSError as err:
        raise LogError(f"--columns {where}: cannot read it: {err.strerror or err}.") from err
    except yaml.YAMLError as err:
        raise LogError(f"--columns {where}: not valid YAML: {err}") from err
    allowed = ("columns", "units", "scale", "offset", "meta", "delimiter")
    if not isinstance(config, Mapping) or "columns" not in config:
        raise LogError(
            f"--columns {where} must be a mapping with a `columns:` key (and optionally "
            f"{', '.join(allowed[1:])}). Received {type(config).__name__}."
        )
    unknown = sorted(set(config) - set(allowed))
    if unknown:
        raise LogError(f"--columns {where}: keys must be among {list(allowed)}. Received unknown {unknown}.")
    for key in ("columns", "units", "scale", "offset", "meta"):
        if key in config and not isinstance(config[key], Mapping):
            raise LogError(f"--columns {where}: `{key}` must be a mapping. Received {config[key]!r}.")
    return dict(config)


def _hits(pattern: str, names: Sequence[str]) -> list[int]:
    """Indices of ``names`` that ``pattern`` selects: the name itself, else an fnmatch pattern, else the pattern with
    its ``[`` taken literally. Drivers write units in brackets (``shoulder_pos [rad]``), which fnmatch reads as a
    character class, so the header's own name matched nothing.

    Example:
        >>> _hits("q [rad]", ["t", "q [rad]"]), _hits("*_pos [rad]", ["a_pos [rad]", "b_pos [rad]"])
        ([1], [0, 1])
        >>> _hits("q[01]", ["q0", "q1", "q2"])
        [0, 1]
    """
    exact = [i for i, name in enumerate(names) if name == pattern]
    if exact:
        return exact
    hits = [i for i, name in enumerate(names) if fnmatch.fnmatchcase(name, pattern)]
    if hits or "[" not in pattern:
        return hits
    literal = pattern.replace("[", "[[]")  # fnmatch's escape for a literal '['
    return [i for i, name in enumerate(names) if fnmatch.fnmatchcase(name, literal)]


def _resolve_columns(spec: str | Sequence[str], header: list[str], key: str, where: str) -> list[int]:
    patterns = [spec] if isinstance(spec, str) else list(spec)
    if not patterns or not all(isinstance(p, str) for p in patterns):
        raise LogError(f"`columns['{key}']` must be a column name, a pattern or a list of them. Received {spec!r}.")
    out: list[int] = []
    for pattern in patterns:
        hits = _hits(pattern, header)
        if not hits:
            close = difflib.get_close_matches(pattern, header, n=3, cutoff=0.5)
            hint = f" Close matches: {', '.join(repr(c) for c in close)}." if close else ""
            other = [d for d in (";", "\t", "|") if len(header) == 1 and d in header[0]]
            if other:
                hint += (
                    f" The header looks separated by {other[0]!r}: give delimiter={other[0]!r} (in a column map too)."
                )
            raise LogError(
                f"`columns['{key}']` names column {pattern!r}, which {where} does not have.{hint} "
                f"Received columns: {', '.join(repr(h) for h in header)}."
            )
        out.extend(hits)
    return out


def _per_column(
    option: Mapping[str, Any] | None, name: str, header: list[str], mapped: dict[int, str], where: str
) -> dict[int, Any]:
    """``{column index: value}`` for an option keyed by column names or patterns (every one must hit a mapped
    column)."""
    out: dict[int, Any] = {}
    if option is None:
        return out
    if not isinstance(option, Mapping):
        raise LogError(f"`{name}` must map CSV column names (or patterns) to values. Received {option!r}.")
    for pattern, value in option.items():
        names = list(mapped)
        hits = [names[k] for k in _hits(str(pattern), [header[i] for i in names])]
        if not hits:
            raise LogError(
                f"`{name}` names column {pattern!r}, which is not a mapped column of {where}. "
                f"Mapped columns: {', '.join(repr(header[i]) for i in sorted(mapped))}."
            )
        for i in hits:
            out[i] = value
    return out


def _number(value: Any, name: str, column: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise LogError(f"`{name}` of column {column!r} must be a finite number. Received {value!r}.")
    return float(value)


def _table(
    header: list[str], used: list[int], where: str, path: str | os.PathLike[str], delimiter: str, first: int = 1
) -> tuple[np.ndarray, list[int] | None]:
    """The numbers below the header (unused columns NaN) and, when some cells are empty, each row's number in the
    file (None: every cell holds a number). numpy parses the file in C; when it cannot, the rows are read one by one
    to name the first bad row and column. Blank and ``#`` comment rows are skipped either way."""
    with contextlib.suppress(ValueError):
        block = np.loadtxt(path, delimiter=delimiter, skiprows=first, usecols=used, ndmin=2, quotechar='"')
        if block.shape[0] >= 2 and np.all(np.isfinite(block)):
            table = np.full((block.shape[0], len(header)), np.nan)
            table[:, used] = block
            return table, None
    numbered = data_rows(path, delimiter)
    if len(numbered) < 2:
        raise LogError(
            f"`path` {where} must hold a header row and at least 2 data rows. Received {len(numbered) + 1} row(s)."
        )
    for line, row in numbered:
        if len(row) != len(header):
            raise LogError(
                f"`path` {where} row {line} must have {len(header)} fields like the header. Received {len(row)} "
                "(truncated file?)."
            )
    table = np.full((len(numbered), len(header)), np.nan)
    for r, (line, row) in enumerate(numbered):
        for c in used:
            cell = row[c].strip()
            try:
                table[r, c] = float(cell) if cell else math.nan
            except ValueError:
                date = re.match(r"\d{4}-\d{2}-\d{2}[T ]\d", cell) is not None
                hint = (
                    " A date and time is not read: write the time as a number of s, ms, us or ns (e.g. nanoseconds "
                    "since the Unix epoch) and name its unit in `units`."
                    if date
                    else ""
                )
                raise LogError(
                    f"`path` {where} row {line}, column {header[c]!r} must hold a number. Received {row[c]!r}.{hint}"
                ) from None
            if cell and not math.isfinite(table[r, c]):  # empty cells are judged by _hold_commands
                raise LogError(
                    f"`path` {where} row {line}, column {header[c]!r} must hold a finite number (dropped rows are "
                    f"removed, not left empty). Received {row[c]!r}."
                )
    return table, [line for line, _ in numbered]


def _hold_commands(
    table: np.ndarray,
    header: list[str],
    index: dict[str, list[int]],
    dt: float,
    where: str,
    lines: list[int],
) -> tuple[np.ndarray, list[int], int, int, int]:
    """Commands logged at another rate than the states: an empty command cell holds the previous command of its
    segment (the driver sent none that step), a row of commands alone (every state cell empty) is merged into the
    rows after it, and state rows before their segment's first command are dropped: nothing says what was sent
    there (a hold never crosses a gap of dropped rows or an episode boundary). Any other empty cell is an error
    naming its row (``lines``: each table row's number in the file) and column. ``table`` is in SI units.

    Returns:
        The table of state rows, their numbers in the file, and the counts of held cells' rows, merged command
        rows and dropped rows.
    """
    ctrl = index["ctrl"]
    state = [i for key in _STATE_KEYS if key in index for i in index[key]]
    required = [index[key][0] for key in ("time", "episode") if key in index]
    blank = np.isnan(table)
    commands_only = blank[:, state].all(axis=1) & ~blank[:, ctrl].all(axis=1)
    bad = blank[:, required].any(axis=1) | (blank[:, state].any(axis=1) & ~commands_only)
    if bad.any():
        r = int(np.flatnonzero(bad)[0])
        c = next(i for i in required + state if blank[r, i])
        raise LogError(
            f"`path` {where} row {lines[r]}, column {header[c]!r} must hold a finite "
            "number (dropped rows are removed, "
            "not left empty; only command columns may be empty, or every state column of a row of commands). "
            "Received ''."
        )
    if not blank[:, ctrl].any():
        return table, lines, 0, 0, 0
    rows = np.arange(table.shape[0])
    # segment starts among the state rows (a gap or a new episode); a command row belongs to the next state row
    states = np.flatnonzero(~commands_only)
    t = table[states, index["time"][0]]
    new = np.concatenate([[True], np.diff(t) > _GAP * dt])
    if "episode" in index:
        new[1:] |= np.diff(table[states, index["episode"][0]]) != 0
    at = np.searchsorted(states, states[new])  # each segment's first state row, as an index into `states`
    opens = np.where(at > 0, states[np.maximum(at - 1, 0)] + 1, 0)  # its first file row (its command rows too)
    start = opens[np.searchsorted(opens, rows, side="right") - 1]
    for c in ctrl:
        last = np.maximum.accumulate(np.where(blank[:, c], -1, rows))
        table[:, c] = np.where(last >= start, table[np.maximum(last, 0), c], np.nan)
    keep = ~commands_only & ~np.isnan(table[:, ctrl]).any(axis=1)
    held = int((blank[:, ctrl].any(axis=1) & keep).sum())
    if keep.sum() < 2:
        raise LogError(f"`path` {where} must hold at least 2 rows of states with every command column logged.")
    kept = [line for line, k in zip(lines, keep.tolist(), strict=True) if k]
    return table[keep], kept, held, int(commands_only.sum()), int((~commands_only & ~keep).sum())


def _check_degrees(qpos: np.ndarray, names: list[str], explicit: set[str], model: mujoco.MjModel, where: str) -> None:
    """Warns when a limited hinge's column passes 2π (degrees, it looks like) or a limited slide's passes 100x the
    reach of its range (millimetres: a 5 cm axis read as 50 m passed every other check when its velocity was in
    mm/s too)."""
    hinge, slide = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
    for j in range(model.njnt):
        if int(model.jnt_type[j]) not in (hinge, slide) or not model.jnt_limited[j]:
            continue
        k = int(model.jnt_qposadr[j])
        if k >= qpos.shape[1] or names[k] in explicit:
            continue
        peak = float(np.max(np.abs(qpos[:, k])))
        joint = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}"
        low, high = model.jnt_range[j]
        if model.jnt_type[j] == hinge and peak > 2 * math.pi:
            said = f"(qpos of hinge {joint!r}, range [{low:.3g}, {high:.3g}] rad) reaches |q| = {peak:.4g} > 2π"
            unit = "deg"
        elif model.jnt_type[j] == slide and peak > 100 * max(abs(low), abs(high)) > 0:
            said = f"(qpos of slide {joint!r}, range [{low:.3g}, {high:.3g}] m) reaches |q| = {peak:.4g} m"
            unit = "mm"
        else:
            continue
        warnings.warn(
            f"{where}: column {names[k]!r} {said}: it looks like {'degrees' if unit == 'deg' else 'millimetres'}; "
            f"add units: {{{names[k]}: {unit}}}.",
            CsvWarning,
            stacklevel=3,
        )


def _owners(model: mujoco.MjModel, key: str) -> list[list[str]]:
    """Per column of ``key`` in the model's order, the names a driver may call it by: the joint owning a ``qpos``/
    ``qvel`` entry; an actuator and the joint it drives for ``ctrl``. Empty where nothing has a name."""
    obj = mujoco.mjtObj
    if key == "ctrl":
        out = []
        for a in range(model.nu):
            names = [mujoco.mj_id2name(model, obj.mjOBJ_ACTUATOR, a) or ""]
            if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
                names.append(mujoco.mj_id2name(model, obj.mjOBJ_JOINT, int(model.actuator_trnid[a, 0])) or "")
            out.append([n for n in names if n])
        return out
    address, width = (model.jnt_qposadr, model.nq) if key == "qpos" else (model.jnt_dofadr, model.nv)
    owner = np.searchsorted(np.asarray(address), np.arange(width), side="right") - 1
    names = [mujoco.mj_id2name(model, obj.mjOBJ_JOINT, j) or "" for j in range(model.njnt)]
    return [[names[j]] if names[j] else [] for j in owner]


def _named(column: str, candidates: set[str]) -> str | None:
    """The longest of ``candidates`` that ``column`` holds as a whole word (``_``, ``-``, spaces and the ends
    delimit it), case-insensitively; None when there is none."""
    hits = [
        name
        for name in candidates
        if re.search(rf"(?<![A-Za-z0-9]){re.escape(name)}(?![A-Za-z0-9])", column, flags=re.IGNORECASE)
    ]
    return max(hits, key=len) if hits else None


def _check_order(key: str, columns: list[str], model: mujoco.MjModel, where: str) -> None:
    """Refuses columns that name the model's joints (or actuators) in another order than the model's: a pattern
    takes columns in the file's order and a list in the given one, so a driver that writes its joints in its own
    order would otherwise feed one joint's angles to another, silently. Columns that do not each name a different
    element are left as they are (nothing to check them against)."""
    owners = _owners(model, key)
    if len(columns) != len(owners) or not all(owners) or len({tuple(o) for o in owners}) != len(owners):
        return
    lookup = {name: i for i, names in enumerate(owners) for name in names}
    named = [_named(column, set(lookup)) for column in columns]
    if any(n is None for n in named):
        return
    slots = [lookup[n] for n in named if n is not None]
    if sorted(slots) != list(range(len(owners))) or slots == sorted(slots):
        return
    ordered = [columns[slots.index(i)] for i in range(len(owners))]
    kind = "actuators" if key == "ctrl" else "joints"
    raise LogError(
        f"`columns['{key}']` must list the CSV columns in the model's order of {kind} "
        f"({', '.join(repr(o[0]) for o in owners)}). Received them in the order {columns} (a pattern takes the "
        f"file's order) from CSV file {where}; map them explicitly: {key}: [{', '.join(ordered)}]."
    )


def _segments(
    time: np.ndarray, episode: np.ndarray | None, dt: float, column: str, where: str, lines: list[int]
) -> tuple[list[tuple[int, int]], list[dict[str, float]]]:
    """Row ranges of the segments (episodes split at gaps) and the gaps found (``lines``: each row's number in the
    file, which errors and gaps name)."""
    edges = [0, time.shape[0]]
    if episode is not None:
        edges += (np.flatnonzero(np.diff(episode) != 0) + 1).tolist()
    steps = np.diff(time)
    same = np.ones(steps.shape, dtype=bool) if episode is None else np.diff(episode) == 0
    back = np.flatnonzero((steps <= 0) & same)
    if back.size:
        i = int(back[0]) + 1
        start = int(edges[0] if episode is None else np.flatnonzero(episode == episode[i])[0])
        hint = (
            " The clock restarts there: if the file holds several episodes, map the column that numbers them as "
            "columns['episode']."
            if episode is None and time[i] <= time[start] + dt
            else ""
        )
        raise LogError(
            f"{where} row {lines[i]}, time column {column!r} must increase within a segment. Received "
            f"{float(time[i]):.9g} s after {float(time[i - 1]):.9g} s.{hint}"
        )
    inner = steps[same]
    spacing = float(np.median(inner)) if inner.size else dt
    if abs(spacing - dt) > _SPACING_TOLERANCE * dt:
        ratio = spacing / dt
        hint = ""
        for unit, factor in (("ms", 1e3), ("us", 1e6), ("ns", 1e9)):
            if abs(ratio / factor - 1) < _SPACING_TOLERANCE:
                hint = f" It looks like {unit}: add units: {{{column}: {unit}}}."
        rows = round(1 / ratio)
        if rows >= 2 and abs(ratio * rows - 1) < 0.05:
            hint = (
                f" That is {rows} rows per control step: if the states are logged faster than the commands, set "
                f"meta: {{control_timestep: {spacing:.6g}}} (in the column map; a command is held until the next "
                f"one), or keep every {rows}th row."
            )
        raise LogError(
            f"{where}: time column {column!r} has a median spacing of {spacing:.6g} s, but meta['control_timestep'] "
            f"is {dt:.6g} s (the log must hold one row per control step).{hint}"
        )
    gap_rows = np.flatnonzero(same & (steps > _GAP * dt)) + 1
    gaps = [{"row": lines[int(i)], "dt_s": round(float(steps[i - 1]), 12)} for i in gap_rows]
    edges = sorted(set(edges) | set(gap_rows.tolist()))
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a], gaps


def _hermite(grid: np.ndarray, t: np.ndarray, y: np.ndarray, slope: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolation of samples ``y`` with derivatives ``slope`` at ``t``, evaluated at ``grid``."""
    i = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, t.shape[0] - 2)
    h = t[i + 1] - t[i]
    s = np.clip((grid - t[i]) / h, 0.0, 1.0)
    s2, s3 = s * s, s * s * s
    return (
        (2 * s3 - 3 * s2 + 1) * y[i]
        + (s3 - 2 * s2 + s) * h * slope[i]
        + (3 * s2 - 2 * s3) * y[i + 1]
        + (s3 - s2) * h * slope[i + 1]
    )


def _resample(
    arrays: dict[str, np.ndarray], bounds: list[tuple[int, int]], dt: float, velocity_of: list[int | None]
) -> tuple[dict[str, np.ndarray], np.ndarray, float, int, int]:
    """Each segment on its control grid; returns the arrays, the segment index per row, the max jitter, the
    number of one-row segments dropped and the number of grid points interpolated.

    Off the grid, a grid point keeps the sample nearest it at that sample's own time (the fit predicts every row at
    its time): interpolating onto the grid leaves an error of jitter x acceleration, and a servo's velocity, whose
    acceleration jumps at every command, cannot be interpolated from samples a control step apart. A grid point
    that no sample rounds to is interpolated: a hinge's or a slide's position by cubic Hermite through the logged
    velocities, everything else linearly. Commands are taken from the row nearest each grid point."""
    out: dict[str, list[np.ndarray]] = {key: [] for key in arrays if key != "episode"}
    segment: list[np.ndarray] = []
    jitter = 0.0
    dropped = 0
    filled = 0
    for a, b in bounds:
        t = arrays["time"][a:b]
        if b - a < 2:
            dropped += 1
            continue
        k = np.round((t - t[0]) / dt)
        residual = (t - t[0]) - k * dt
        jitter = max(jitter, float(np.max(np.abs(residual))))
        n = int(np.floor((t[-1] - t[0]) / dt + 0.5)) + 1
        grid = t[0] + dt * np.arange(n)
        exact = n == t.shape[0] and bool(np.all(np.abs(residual) <= 1e-9 * dt))
        nearest = np.clip(np.searchsorted(t, grid - 0.5 * dt), 0, t.shape[0] - 1)
        # per grid point, the sample rounding to it that is nearest it (-1: none): sorted by grid point, the
        # nearest last
        pick = np.full(n, -1)
        order = np.lexsort((-np.abs(residual), k))
        ks = k[order].astype(np.intp)
        last = np.append(ks[1:] != ks[:-1], True)
        pick[ks[last]] = order[last]
        kept = pick >= 0
        filled += int(n - kept.sum()) if not exact else 0
        for key, values in arrays.items():
            if key == "episode":
                continue
            block = values[a:b]
            if key == "time":
                out[key].append(block.copy() if exact else np.where(kept, t[np.maximum(pick, 0)], grid))
            elif exact:
                out[key].append(block.copy())
            elif key == "ctrl":
                out[key].append(block[nearest])  # a command is held for its control step: never interpolated
            else:
                columns = []
                for c in range(block.shape[1]):
                    d = velocity_of[c] if key == "qpos" and c < len(velocity_of) else None
                    if d is None:
                        filled_in = np.interp(grid, t, block[:, c])
                    else:
                        filled_in = _hermite(grid, t, block[:, c], arrays["qvel"][a:b, d])
                    columns.append(np.where(kept, block[np.maximum(pick, 0), c], filled_in))
                out[key].append(np.column_stack(columns))
        segment.append(np.full(t.shape[0] if exact else n, len(segment)))
    if not segment:
        raise LogError("the CSV log has no segment of 2 or more rows between its gaps.")
    return {key: np.concatenate(v) for key, v in out.items()}, np.concatenate(segment), jitter, dropped, filled


def load_csv(
    path: str | os.PathLike[str],
    columns: Mapping[str, str | Sequence[str]],
    meta: Mapping[str, Any],
    model: mujoco.MjModel | None = None,
    delimiter: str = ",",
    *,
    units: Mapping[str, str] | None = None,
    scale: Mapping[str, float] | None = None,
    offset: Mapping[str, float] | None = None,
) -> TrajectoryLog:
    """Imports a real-robot CSV log (one header row) through a column mapping (see the module docstring).

    Args:
        path: the CSV file.
        columns: log key -> CSV column name(s) or fnmatch patterns, in order, e.g.
            ``{"time": "t", "qpos": ["j0_pos", "j1_pos"], "qvel": "j*_vel", "ctrl": ["u0", "u1"]}``.
            Keys ``time``, ``qpos``, ``qvel`` and ``ctrl`` are required; ``sensordata``, ``episode`` and
            ``act`` are optional.
        meta: at least ``timestep`` and ``control_timestep`` (seconds); ``task`` and names are kept.
        model: when given, the widths must match it and hinge angles are checked for degrees.
        delimiter: the CSV field separator.
        units: column name or pattern -> a unit of :data:`UNITS` (time columns need a time unit, ``qpos`` a
            position unit, ``qvel`` a velocity unit); unlisted columns are taken as SI already.
        scale: column name or pattern -> factor applied after the unit conversion.
        offset: column name or pattern -> added after scaling (in the log's units).

    Returns:
        A validated log with one row per control step (rows of a jittery clock at their sample times);
        ``meta["csv"]`` holds ``file``, ``units``, ``max_jitter_s``, ``gaps`` (``[{"row", "dt_s"}]``),
        ``segments``, ``resampled`` (True when rows were off the grid) and ``interpolated_rows``.

    Raises:
        LogError: a mapped column is missing (close matches listed), a cell is not a number (file, row and
            column named), a unit does not fit its column, the time spacing does not match ``control_timestep``,
            or the resulting log is invalid.
        FileNotFoundError: no such file.
    """
    where = repr(str(path))
    if not Path(path).is_file():
        raise FileNotFoundError(f"`path` {where} does not exist.")
    if not isinstance(columns, Mapping):
        raise LogError(f"`columns` must map log keys to CSV column names. Received {type(columns).__name__}.")
    unknown = [k for k in columns if k not in _KEYS]
    missing = [k for k in ("time", "qpos", "qvel", "ctrl") if k not in columns]
    if unknown or missing:
        raise LogError(
            f"`columns` must map the keys time, qpos, qvel, ctrl (and optionally sensordata, episode, act). "
            f"Received keys {sorted(columns)} (missing {missing}, unknown {unknown})."
        )
    for key in ("timestep", "control_timestep"):
        value = meta.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
            raise LogError(f"`meta['{key}']` must be a positive number of seconds. Received {value!r}.")
    header_line, header = header_row(path, delimiter)  # comment rows above the header are skipped
    index = {key: _resolve_columns(spec, header, key, f"CSV file {where}") for key, spec in columns.items()}
    mapped: dict[int, str] = {}
    for key, idx in index.items():
        for i in idx:
            if mapped.get(i, key) == key:
                mapped[i] = key
            elif "sensordata" in (key, mapped[i]):  # a joint sensor logs what qpos/qvel log: one column feeds both
                mapped[i] = mapped[i] if key == "sensordata" else key
            else:  # a pattern that also catches another key's columns ('j_*' for qpos takes the velocities too)
                raise LogError(
                    f"`columns` maps CSV column {header[i]!r} to both {mapped[i]!r} and {key!r}; a column feeds one "
                    f"key (only sensordata may share one; narrow the pattern, e.g. '*_deg'). Received "
                    f"columns={dict(columns)!r}."
                )
    table, numbered = _table(header, sorted(mapped), where, path, delimiter, header_line)
    lines = numbered if numbered is not None else row_numbers(path, header_line, delimiter, table.shape[0])
    origin = _time_origin(table, index["time"][0], path, delimiter)
    unit_of = _per_column(units, "units", header, mapped, f"CSV file {where}")
    for i in mapped:
        said = _header_unit(header[i])
        if said is None:
            continue
        if unit_of.setdefault(i, said) != said:
            raise LogError(
                f"`units` of column {header[i]!r} must agree with the unit its header names ({said!r}) in CSV file "
                f"{where}. Received {unit_of[i]!r}; drop it from `units` (the header's unit is used)."
            )
    check_header_units(header, mapped, set(unit_of) | set(_per_column(scale, "scale", header, mapped, where)), where)
    factors = np.ones(len(header))
    for i, unit in unit_of.items():
        if unit not in UNITS:
            raise LogError(f"`units` of column {header[i]!r} must be one of {list(UNITS)}. Received {unit!r}.")
        kind, factor = UNITS[unit]
        allowed = _KIND_OF_KEY.get(mapped[i])
        if allowed is not None and kind not in allowed:
            fits = [u for u, (k, _) in UNITS.items() if k in allowed]
            raise LogError(
                f"`units` of column {header[i]!r} (mapped to {mapped[i]}) must be one of {fits or 'none'}. "
                f"Received {unit!r} (a {kind} unit)."
            )
        factors[i] = factor
    scales = {i: _number(v, "scale", header[i]) for i, v in _per_column(scale, "scale", header, mapped, where).items()}
    offsets = {
        i: _number(v, "offset", header[i]) for i, v in _per_column(offset, "offset", header, mapped, where).items()
    }
    table = table * factors
    for i, value in scales.items():
        table[:, i] *= value
    for i, value in offsets.items():
        table[:, i] += value
    table, lines, held, merged, leading = _hold_commands(
        table, header, index, float(meta["control_timestep"]), where, lines
    )
    arrays = {key: table[:, idx[0]] if key in ("time", "episode") else table[:, idx] for key, idx in index.items()}
    dt = float(meta["control_timestep"])
    time_column = header[index["time"][0]]
    episode = arrays.pop("episode", None)
    if episode is not None and not np.all(episode == np.round(episode)):
        bad = int(np.flatnonzero(episode != np.round(episode))[0])
        raise LogError(
            f"{where} row {lines[bad]}, column {header[index['episode'][0]]!r} must hold integer episode indices. "
            f"Received {episode[bad]!r}."
        )
    if model is not None:
        for key in ("qpos", "qvel", "ctrl"):
            _check_order(key, [header[i] for i in index[key]], model, where)
        names = [header[i] for i in index["qpos"]]
        explicit = {header[i] for i in unit_of if mapped[i] == "qpos"}
        _check_degrees(arrays["qpos"], names, explicit, model, f"CSV file {where}")
    velocity_of = _velocity_of(model, arrays["qpos"].shape[1], arrays["qvel"].shape[1])
    slides = _slide_columns(model) if model is not None else set()
    declared = {header[i] for i in (*unit_of, *scales)}
    _check_velocity_units(
        arrays,
        episode,
        velocity_of,
        [[header[i] for i in index[k]] for k in ("qpos", "qvel")],
        declared,
        dt,
        f"CSV file {where}",
        slides,
    )
    bounds, gaps = _segments(arrays["time"], episode, dt, time_column, f"CSV file {where}", lines)
    resampled, segment, jitter, dropped, filled = _resample(arrays, bounds, dt, velocity_of)
    name = Path(path).name
    if gaps:
        first = gaps[0]
        warnings.warn(
            f"{name!r}: {len(gaps)} gap(s) in time column {time_column!r}, the first before row {first['row']} "
            f"({first['dt_s']:.6g} s after the previous row, {first['dt_s'] / dt:.3g} control steps); the log "
            "continues in a new segment after each gap (nothing is interpolated across it)"
            + (f"; {dropped} one-row segment(s) dropped" if dropped else ""),
            CsvWarning,
            stacklevel=2,
        )
    if held or merged or leading:
        warnings.warn(
            f"{name!r}: commands logged at another rate than the states: {held} row(s) without a command hold the "
            f"previous one, {merged} row(s) of commands alone were merged into the rows after them"
            + (f", {leading} row(s) before their segment's first command were dropped" if leading else ""),
            CsvWarning,
            stacklevel=2,
        )
    report = {
        "file": name,
        "held_commands": held,
        "time_origin": origin,
        "units": {header[i]: u for i, u in sorted(unit_of.items())},
        "max_jitter_s": round(jitter, 12),
        "gaps": gaps,
        "segments": int(segment.max()) + 1,
        "resampled": bool(jitter > 1e-9 * dt),
        "interpolated_rows": filled,
    }
    log = TrajectoryLog(
        **resampled,
        episode=segment if segment.max() > 0 else None,
        meta={**dict(meta), "csv": report},
    )
    if model is not None:
        try:
            _check_model(log, model)
        except LogError as err:
            raise LogError(f"CSV file {where}: {err}") from err
    return log
