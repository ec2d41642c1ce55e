"""A real driver's CSV: degrees, milliseconds, a jittery clock and dropped rows, one test per defect (issue 17).

The "robot" is a generated 6-DoF servo arm (sysid.synthetic.generate_arm) simulated at the physics rate; the
driver samples it every control step with a jittery clock and writes degrees, deg/s and milliseconds.
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

import sysid
from sim2real.cli import main
from sysid import CsvWarning, LogError, load_csv
from sysid.synthetic import generate_arm

SUBSTEPS = 10
STEPS = 150
HEADER = ["t_ms", *(f"q{i}_deg" for i in range(6)), *(f"dq{i}_dps" for i in range(6)), *(f"u{i}" for i in range(6))]
COLUMNS = {"time": "t_ms", "qpos": "q*_deg", "qvel": "dq*_dps", "ctrl": "u*"}
UNITS = {"t_ms": "ms", "q*_deg": "deg", "dq*_dps": "deg/s"}


@pytest.fixture(scope="module")
def arm(tmp_path_factory: pytest.TempPathFactory) -> tuple[mujoco.MjModel, Path]:
    path = tmp_path_factory.mktemp("arm") / "arm.xml"
    path.write_text(generate_arm(dof=6, seed=4, actuators="position"))
    return mujoco.MjModel.from_xml_path(str(path)), path


@pytest.fixture(scope="module")
def fine(arm: tuple[mujoco.MjModel, Path]) -> sysid.TrajectoryLog:
    """The truth at the physics rate: servo set-points around home, held for a control step each."""
    model, _ = arm
    home = model.key_qpos[0]
    t = np.arange(STEPS) * SUBSTEPS * model.opt.timestep
    ctrl = home + 0.15 * np.sin(2 * math.pi * np.outer(t, [0.7, 1.1, 1.3, 0.9, 1.7, 0.5]))
    return sysid.record_log(model, np.repeat(ctrl, SUBSTEPS, axis=0), initial_qpos=home)


def _meta(model: mujoco.MjModel) -> dict[str, float]:
    return {"timestep": float(model.opt.timestep), "control_timestep": SUBSTEPS * float(model.opt.timestep)}


def _write(path: Path, fine: sysid.TrajectoryLog, rows: np.ndarray, *, noise: float = 0.0) -> None:
    """The driver's CSV of the physics-rate rows ``rows`` (one per control step); ctrl is the held command;
    ``noise`` rad (and 10x that in rad/s) of seeded sensor noise."""
    angle = 180 / math.pi
    time = fine.time[rows] * 1e3
    commands = fine.ctrl[np.round(rows / SUBSTEPS).astype(int) * SUBSTEPS]  # row k carries command k
    rng = np.random.default_rng(1)
    qpos = fine.qpos[rows] + rng.normal(0, noise, (rows.size, 6))
    qvel = fine.qvel[rows] + rng.normal(0, 10 * noise, (rows.size, 6))
    table = np.column_stack([time, qpos * angle, qvel * angle, commands])
    np.savetxt(path, table, delimiter=",", header=",".join(HEADER), comments="", fmt="%.17g")


def _grid() -> np.ndarray:
    return np.arange(STEPS) * SUBSTEPS


def test_degrees_warn_naming_the_column_and_units_convert_them(tmp_path, arm, fine) -> None:
    model, _ = arm
    path = tmp_path / "robot.csv"
    _write(path, fine, _grid())
    # the velocities in deg/s prove it: the load is refused (it used to go on with the angles as radians)
    with (
        pytest.warns(
            CsvWarning,
            match=r"column 'q\d_deg' \(qpos of hinge '\w+', range .*\) reaches \|q\| = .* > 2π: "
            r"it looks like degrees; add units: \{q\d_deg: deg\}",
        ),
        pytest.raises(LogError, match=r"they look like degrees against rad/s; add units: \{q0_deg: deg\}"),
    ):
        load_csv(path, COLUMNS, meta=_meta(model), model=model, units={"t_ms": "ms", "dq*_dps": "deg/s"})
    with warnings.catch_warnings():
        warnings.simplefilter("error", CsvWarning)
        log = load_csv(path, COLUMNS, meta=_meta(model), model=model, units=UNITS)
    np.testing.assert_allclose(log.qpos, fine.qpos[_grid()], rtol=0, atol=1e-12)
    np.testing.assert_allclose(log.qvel, fine.qvel[_grid()], rtol=0, atol=1e-12)
    assert log.meta["csv"]["units"] == {
        "t_ms": "ms",
        **{f"q{i}_deg": "deg" for i in range(6)},
        **{f"dq{i}_dps": "deg/s" for i in range(6)},
    }
    with pytest.raises(
        LogError,
        match=re.escape(
            "`units` of column 'q0_deg' (mapped to qpos) must be one of ['rad', "
            "'deg', 'm', 'mm']. Received 'deg/s' (a velocity unit)."
        ),
    ):
        load_csv(path, COLUMNS, meta=_meta(model), units={**UNITS, "q0_deg": "deg/s"})


def test_milliseconds_read_as_seconds_fail_on_the_spacing_check(tmp_path, arm, fine) -> None:
    model, _ = arm
    path = tmp_path / "robot.csv"
    _write(path, fine, _grid())
    message = (
        f"CSV file {str(path)!r}: time column 't_ms' has a median spacing of 20 s, but meta['control_timestep'] is "
        "0.02 s (the log must hold one row per control step). It looks like ms: add units: {t_ms: ms}."
    )
    with pytest.raises(LogError, match=re.escape(message)):
        load_csv(path, COLUMNS, meta=_meta(model), units={"q*_deg": "deg", "dq*_dps": "deg/s"})
    log = load_csv(path, COLUMNS, meta=_meta(model), units=UNITS)
    np.testing.assert_allclose(log.time, fine.time[_grid()], rtol=0, atol=1e-12)
    # a log at twice the control period is refused too, without a unit hint
    with pytest.raises(
        LogError,
        match=r"median spacing of 0\.04 s, but meta\['control_timestep'\] is 0\.02 s \(the "
        r"log must hold one row per control step\)\.$",
    ):
        load_csv(path, COLUMNS, meta={"timestep": 0.002, "control_timestep": 0.02}, units={**UNITS}, scale={"t_ms": 2})


def test_jittered_rows_keep_their_sample_times_and_a_missing_grid_point_is_interpolated(tmp_path, arm, fine) -> None:
    model, _ = arm
    rng = np.random.default_rng(0)
    jitter = rng.integers(-2, 3, size=STEPS)  # physics steps of 2 ms: up to +-4 ms on a 20 ms period
    jitter[0] = jitter[-1] = 0
    rows = _grid() + jitter
    path = tmp_path / "robot.csv"
    _write(path, fine, rows)
    log = load_csv(path, COLUMNS, meta=_meta(model), model=model, units=UNITS)
    assert log.meta["csv"]["max_jitter_s"] == pytest.approx(np.abs(jitter).max() * model.opt.timestep, abs=1e-12)
    assert log.meta["csv"]["resampled"] is True
    assert log.meta["csv"]["interpolated_rows"] == 0
    # one row per grid point, each the sample taken nearest it, at its own time (the fit predicts it there)
    np.testing.assert_allclose(log.time, fine.time[rows], rtol=0, atol=1e-9)
    np.testing.assert_allclose(log.qpos, fine.qpos[rows], rtol=0, atol=1e-12)
    np.testing.assert_allclose(log.qvel, fine.qvel[rows], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(log.ctrl, fine.ctrl[_grid()])  # commands are held, never interpolated
    # grid point 41 gets no sample (40 is sampled 4 ms late, 41 at 12 ms: nearer 42, whose sample is dropped): it
    # is interpolated on the grid, positions by cubic Hermite through the logged velocities
    rows = _grid().copy()
    rows[40] += 2
    rows[41] += 6
    rows = np.delete(rows, 42)
    _write(path, fine, rows)
    log = load_csv(path, COLUMNS, meta=_meta(model), model=model, units=UNITS)
    assert log.meta["csv"]["interpolated_rows"] == 1 and log.meta["csv"]["gaps"] == []
    assert log.num_steps == STEPS
    assert log.time[41] == pytest.approx(fine.time[410], abs=1e-12)
    np.testing.assert_allclose(log.time[[40, 42]], fine.time[[402, 416]], rtol=0, atol=1e-12)
    linear = np.array([np.interp(fine.time[410], fine.time[[402, 416]], fine.qpos[[402, 416], c]) for c in range(6)])
    hermite = np.abs(log.qpos[41] - fine.qpos[410]).max()
    assert hermite < 0.1 * np.abs(linear - fine.qpos[410]).max(), hermite


def test_a_gap_starts_a_new_segment_and_is_never_interpolated(tmp_path, arm, fine) -> None:
    model, _ = arm
    rows = np.delete(_grid(), [60, 61, 62])  # the driver dropped three rows
    path = tmp_path / "robot.csv"
    _write(path, fine, rows)
    with pytest.warns(CsvWarning) as caught:
        log = load_csv(path, COLUMNS, meta=_meta(model), model=model, units=UNITS)
    assert str(caught[0].message) == (
        "'robot.csv': 1 gap(s) in time column 't_ms', the first before row 62 (0.08 s after the previous row, 4 "
        "control steps); the log continues in a new segment after each gap (nothing is interpolated across it)"
    )
    assert log.meta["csv"]["gaps"] == [{"row": 62, "dt_s": pytest.approx(0.08)}]
    assert log.meta["csv"]["segments"] == 2
    assert log.episode_bounds() == [(0, 60), (60, STEPS - 3)]
    np.testing.assert_allclose(log.time, fine.time[rows], rtol=0, atol=1e-12)  # no row was invented in the gap
    # the fit restarts from the logged state after the gap: a noise-free log gives the truth back
    result = sysid.fit(log, model, ["dof_damping[shoulder]"], progress=False)
    assert result.estimates[0] == pytest.approx(model.dof_damping[1], rel=1e-3)


def test_errors_name_file_row_and_column(tmp_path, arm, fine) -> None:
    model, _ = arm
    path = tmp_path / "robot.csv"
    _write(path, fine, _grid())
    lines = path.read_text().splitlines()
    cells = lines[7].split(",")
    cells[3] = "n/a"
    lines[7] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(
        LogError, match=re.escape(f"`path` {str(path)!r} row 8, column 'q2_deg' must hold a number. Received 'n/a'.")
    ):
        load_csv(path, COLUMNS, meta=_meta(model), units=UNITS)
    with pytest.raises(
        LogError,
        match=re.escape(
            f"`path` {str(path)!r} is a CSV text file, not a .npz trajectory log; read it with "
            "sysid.load_csv(path, columns, meta) or `sim2real sysid fit LOG.csv --columns MAP.yaml`."
        ),
    ):
        sysid.load_log(path)


def test_cli_fits_a_driver_csv_through_a_column_map(tmp_path, arm, fine, capsys) -> None:
    model, xml = arm
    csv_path = tmp_path / "robot.csv"
    _write(csv_path, fine, np.delete(_grid(), [70]), noise=1e-3)
    columns = tmp_path / "map.yaml"
    columns.write_text(
        "columns: {time: t_ms, qpos: 'q*_deg', qvel: 'dq*_dps', ctrl: 'u*'}\n"
        "units: {t_ms: ms, 'q*_deg': deg, 'dq*_dps': deg/s}\n"
    )
    out = tmp_path / "fit.json"
    args = ["sysid", "fit", str(csv_path), "--model", str(xml), "--params", "dof_damping[elbow]", "--quiet"]
    assert main([*args, "--out", str(out)]) == 2
    assert capsys.readouterr().err == (
        f"sim2real sysid: error: {str(csv_path)!r} is a CSV file; give --columns MAP.yaml (column mapping, units, "
        "scale/offset; see sysid.load_csv) to read it.\n"
    )
    assert not out.exists()
    assert main([*args, "--columns", str(columns), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "1 gap(s) in time column 't_ms', the first before row 72" in captured.err
    fit = sysid.FitResult.from_json(out)
    elbow = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "elbow")
    low, high = fit.ci95[0]
    assert low <= model.dof_damping[model.jnt_dofadr[elbow]] <= high
    assert getattr(fit, "ok", True)  # FitResult.ok: the fit quality checks of issue 17 part A
