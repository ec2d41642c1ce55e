"""Units of a driver's CSV (internal to :mod:`sysid.csv_import`): the unit table, units a header names in
brackets, clocks counted from the Unix epoch, and velocities whose unit contradicts their positions'."""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Collection

import mujoco
import numpy as np

from sysid.logs import LogError

__all__ = ["UNITS"]

_GAP = 1.5  # a spacing over this many control steps is a gap (dropped rows)

#: Unit name -> (kind, factor to SI).
UNITS: dict[str, tuple[str, float]] = {
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "us": ("time", 1e-6),
    "ns": ("time", 1e-9),
    "rad": ("position", 1.0),
    "deg": ("position", math.pi / 180.0),
    "m": ("position", 1.0),
    "mm": ("position", 1e-3),
    "rad/s": ("velocity", 1.0),
    "deg/s": ("velocity", math.pi / 180.0),
    "m/s": ("velocity", 1.0),
    "mm/s": ("velocity", 1e-3),
}
#: How drivers spell units in a header's brackets, beyond the names of :data:`UNITS`.
_ALIASES = {
    "sec": "s",
    "msec": "ms",
    "usec": "us",
    "µs": "us",
    "nsec": "ns",
    "degree": "deg",
    "degrees": "deg",
    "°": "deg",
    "deg/sec": "deg/s",
    "°/s": "deg/s",
    "rad/sec": "rad/s",
}


_BRACKETS = re.compile(r"[\[(]\s*([^\[\]()]+?)\s*[\])]\s*$")  # what a header's name ends with in brackets
#: Units a driver writes that :data:`UNITS` does not convert: a time, position or velocity column whose header names
#: one (``lift [in]``) is refused rather than read as SI (inches read as metres: 39x too large, silently).
_UNREAD = frozenset(
    "in inch inches ft feet yd cm dm um µm nm mrad urad µrad rev revs turn turns grad gon arcmin arcsec rpm min h hr "  # noqa: SIM905
    "tick ticks count counts cnt enc step steps".split()
)


def unread_unit(name: str) -> str | None:
    """The unit a column's header names in brackets that :data:`UNITS` cannot convert (``lift [in]``, ``j1 [rev/s]``,
    any rate not in the table), else None (no brackets, a unit it reads, or an index or name such as ``q[0]``).

    Example:
        >>> unread_unit("lift [in]"), unread_unit("j1 (rev/min)"), unread_unit("q [deg]"), unread_unit("qpos[elbow]")
        ('in', 'rev/min', None, None)
    """
    found = _BRACKETS.search(name)
    if found is None or _header_unit(name) is not None:
        return None
    unit = found.group(1)
    return unit if unit.lower() in _UNREAD or "/" in unit else None


#: The SI units a time, qpos or qvel column is read in (what `scale` converts a unit the loader cannot read into).
_SI_OF_KEY = {"time": "s", "qpos": "m or rad", "qvel": "m/s or rad/s"}


def check_header_units(header: list[str], mapped: dict[int, str], declared: set[int], where: str) -> None:
    """Refuses a time, qpos or qvel column whose header names a unit the loader cannot convert
    (:func:`unread_unit`), unless ``declared`` (the columns the user gave a unit or a scale) holds it."""
    for i in sorted(mapped):
        unread = unread_unit(header[i]) if mapped[i] in _SI_OF_KEY else None
        if unread is not None and i not in declared:
            raise LogError(
                f"column {header[i]!r} of CSV file {where} names the unit {unread!r} in its header, which the loader "
                f"does not convert; it reads {', '.join(UNITS)}. Convert it with scale: {{{header[i]!r}: "
                f"<{_SI_OF_KEY[mapped[i]]} per {unread}>}}, or give units: {{{header[i]!r}: <its unit>}} if the header "
                "is wrong."
            )


def _header_unit(name: str) -> str | None:
    """The unit of :data:`UNITS` a column's name ends with in brackets (``j1_vel [deg/s]``, ``t (ns)``), else None.

    Example:
        >>> _header_unit("j1_vel [deg/s]"), _header_unit("stamp (ns)"), _header_unit("q[0]"), _header_unit("u [Nm]")
        ('deg/s', 'ns', None, None)
    """
    found = _BRACKETS.search(name)
    if found is None:
        return None
    unit = _ALIASES.get(found.group(1).lower(), found.group(1).lower())
    return unit if unit in UNITS else None


def _skipped(row: list[str]) -> bool:
    """A blank row or a ``#`` comment row (a driver's ``# firmware v2`` line): no reader of the CSV counts it."""
    return not any(c.strip() for c in row) or row[0].lstrip().startswith("#")


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def header_row(path: str | os.PathLike[str], delimiter: str) -> tuple[int, list[str]]:
    """The header as ``(row number in the file, stripped names)``: the first row that is neither blank nor a ``#``
    comment, so comment rows a driver writes above its header are skipped; when that row holds numbers only, the
    comment row just above it is the header (``numpy.savetxt(header=...)`` writes it as ``# t,q0,...``).
    ``(0, [])`` for a file without one.

    Example:
        >>> import os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "log.csv")
        >>> _ = open(path, "w").write("# arm driver v2, 125 Hz\\n\\nt [ms],q [deg]\\n0,1\\n")
        >>> header_row(path, ",")
        (3, ['t [ms]', 'q [deg]'])
        >>> _ = open(path, "w").write("# t,q\\n0,1\\n8,2\\n")
        >>> header_row(path, ",")
        (1, ['t', 'q'])
    """
    comment: tuple[int, list[str]] | None = None
    with open(path, newline="", encoding="utf-8-sig") as handle:
        for number, row in enumerate(csv.reader(handle, delimiter=delimiter), 1):
            if not _skipped(row):
                if comment is not None and all(_is_number(c.strip()) for c in row):
                    names = [comment[1][0].lstrip()[1:], *comment[1][1:]]
                    return comment[0], [h.strip() for h in names]
                return number, [h.strip() for h in row]
            if any(c.strip() for c in row):
                comment = (number, row)
    return 0, []


def data_rows(path: str | os.PathLike[str], delimiter: str) -> list[tuple[int, list[str]]]:
    """The CSV's data rows as ``(row number in the file, cells)``, as ``np.loadtxt`` reads them: after the header
    (:func:`header_row`), without blank rows and ``#`` comment rows (a driver's ``# firmware v2`` line)."""
    first, _ = header_row(path, delimiter)
    with open(path, newline="", encoding="utf-8-sig") as handle:
        return [
            (number, row)
            for number, row in enumerate(csv.reader(handle, delimiter=delimiter), 1)
            if number > first and not _skipped(row)
        ]


def row_numbers(path: str | os.PathLike[str], first: int, delimiter: str, count: int) -> list[int]:
    """Each data row's number in the file (``first``: the header's), the rows numpy's reader keeps: blank and ``#``
    comment rows are skipped but counted, so errors and gaps name the row a user finds in an editor. A line scan;
    when it does not find ``count`` rows (a quoted cell spanning lines), the CSV reader's count."""
    with open(path, encoding="utf-8-sig") as handle:
        found = [n for n, line in enumerate(handle, 1) if n > first and line.strip() and line.lstrip()[0] != "#"]
    return found if len(found) == count else [n for n, _ in data_rows(path, delimiter)]


def _time_origin(table: np.ndarray, column: int, path: str | os.PathLike[str], delimiter: str) -> str | None:
    """Rewrites a clock that counts from the Unix epoch (|t| >= 1e9 in its own unit: seconds, or nanoseconds since
    1970) as time since the first row, in place, and returns the first row's cell (None for any other clock).
    Integer stamps past 2**53 (nanoseconds) are subtracted as integers: as float64 they are rounded to 256 ns, which
    made an exact 100 Hz clock look jittery."""
    first = float(table[0, column])
    if not abs(first) >= 1e9:
        return None
    cells = [row[column].strip() for _, row in data_rows(path, delimiter)]
    if len(cells) == table.shape[0] and all(re.fullmatch(r"[+-]?\d+", c) for c in cells):
        origin = int(cells[0])
        table[:, column] = [float(int(c) - origin) for c in cells]
        return cells[0]
    table[:, column] -= first
    return cells[0] if cells else repr(first)


def _velocity_of(model: mujoco.MjModel | None, nq: int, nv: int) -> list[int | None]:
    """Per ``qpos`` column, the ``qvel`` column holding its derivative (a hinge's or a slide's), else None (free and
    ball joints: a quaternion's derivative is not a velocity column). Without a model, ``nq == nv`` means every
    joint is a hinge or a slide."""
    if model is None:
        return list(range(nq)) if nq == nv else [None] * nq
    out: list[int | None] = [None] * nq
    smooth = {int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)}
    for j in range(model.njnt):
        if int(model.jnt_type[j]) in smooth:
            k, d = int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])
            if k < nq and d < nv:
                out[k] = d
    return out


def _slide_columns(model: mujoco.MjModel) -> set[int]:
    """The ``qpos`` columns of the model's slide joints (lengths in m, velocities in m/s)."""
    slide = mujoco.mjtJoint.mjJNT_SLIDE
    return {int(model.jnt_qposadr[j]) for j in range(model.njnt) if model.jnt_type[j] == slide}


def _check_velocity_units(
    arrays: dict[str, np.ndarray],
    episode: np.ndarray | None,
    velocity_of: list[int | None],
    names: list[list[str]],
    declared: set[str],
    dt: float,
    where: str,
    slides: Collection[int] = (),
) -> None:
    """Refuses velocities in deg/s against positions in rad (and positions in degrees against rad/s) when neither
    says its unit: a hinge's logged velocity about 57.3x (or 1/57.3 of) the rate of change of its logged position.
    Read as rad/s, deg/s velocities made the fit of a 7-DoF arm unstable and "not ok" without saying why. A slide's
    (``slides``: its ``qpos`` columns) are judged against 1000: mm/s against metres read its 0.26 m/s as 261 m/s."""
    t, q, v = arrays["time"], arrays["qpos"], arrays["qvel"]
    step = np.diff(t)
    pair = (step > 0) & (step < _GAP * dt)
    if episode is not None:
        pair &= np.diff(episode) == 0
    if pair.sum() < 4:
        return
    found: dict[tuple[str, str], list[tuple[str, str]]] = {}
    for k, d in enumerate(velocity_of):
        if d is None:
            continue
        rate = np.diff(q[:, k])[pair] / step[pair]
        mid = 0.5 * (v[:-1, d] + v[1:, d])[pair]
        if not np.all(np.isfinite(mid)) or not float(rate @ rate) > 0 or not np.std(mid) > 0:
            continue
        if not float(np.corrcoef(rate, mid)[0, 1]) > 0.9:  # too little motion (or noise) to judge the unit
            continue
        ratio = float(mid @ rate) / float(rate @ rate)
        position, velocity = names[0][k], names[1][d]
        unit, factor = ("mm", 1000.0) if k in slides else ("deg", 180 / math.pi)
        if abs(ratio / factor - 1) < 0.25 and velocity not in declared:
            found.setdefault(("fast", unit), []).append((velocity, position))
        elif abs(ratio * factor - 1) < 0.25 and position not in declared:
            found.setdefault(("slow", unit), []).append((velocity, position))
    for side, unit in (("fast", "deg"), ("fast", "mm"), ("slow", "deg"), ("slow", "mm")):
        pairs = found.get((side, unit))
        if not pairs:
            continue
        times, si = ("57.3x", "rad") if unit == "deg" else ("1000x", "m")
        velocities, positions = ", ".join(repr(a) for a, _ in pairs), ", ".join(repr(b) for _, b in pairs)
        if side == "fast":
            raise LogError(
                f"{where}: velocity column(s) {velocities} hold {times} the rate of change of their position "
                f"column(s) ({positions}): they look like {unit}/s against positions in {si}; add units: "
                f"{{{pairs[0][0]}: {unit}/s}} (a pattern may name them all)."
            )
        raise LogError(
            f"{where}: position column(s) {positions} change {times} faster than their velocity column(s) "
            f"({velocities}) say: they look like {'degrees' if unit == 'deg' else 'millimetres'} against {si}/s; "
            f"add units: {{{pairs[0][1]}: {unit}}} (a pattern may name them all)."
        )
