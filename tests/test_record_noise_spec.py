"""Per-channel and per-joint sensor noise of `sim2real record --obs-noise` and `sysid.record_log(noise_std=...)`.

An arm with a slide joint (m) and two hinges (rad) needs a different sigma per joint: these tests compare noisy logs
with noise-free twins of the same seed and controls and check each column's empirical std against the requested one
with a chi-square 99.9% interval, so one shared sigma cannot pass.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy import stats

import sysid
from sim2real.cli import main
from sim2real.recording import OBS_NOISE_FORMS, parse_obs_noise, record
from sim2real.sources import Source
from sysid import record_log

ARM = """
<mujoco model="noise_arm">
  <option timestep="0.005" gravity="0 0 0"/>
  <worldbody>
    <body name="base">
      <joint name="lift" type="slide" axis="0 0 1" damping="2"/>
      <geom type="box" size=".05 .05 .05" mass="1"/>
      <body name="upper" pos="0 0 .1">
        <joint name="shoulder" type="hinge" axis="0 1 0" damping="0.2"/>
        <geom type="capsule" fromto="0 0 0 .3 0 0" size=".03" mass=".5"/>
        <body name="fore" pos=".3 0 0">
          <joint name="elbow" type="hinge" axis="0 1 0" damping="0.1"/>
          <geom type="capsule" fromto="0 0 0 .25 0 0" size=".025" mass=".3"/>
          <site name="tip" pos=".25 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="lift_m" joint="lift" gear="2" ctrlrange="-1 1"/>
    <motor name="shoulder_m" joint="shoulder" gear="2" ctrlrange="-1 1"/>
    <motor name="elbow_m" joint="elbow" gear="1" ctrlrange="-1 1"/>
  </actuator>
  <sensor>
    <jointpos name="elbow_pos" joint="elbow"/>
    <framepos name="tip_pos" objtype="site" objname="tip"/>
  </sensor>
</mujoco>
"""
# A free-floating object beside the arm: its qpos holds a quaternion.
FREE = ARM.replace(
    "  </worldbody>",
    '    <body name="box" pos="1 0 0"><freejoint name="box_free"/><geom size=".05" mass=".2"/></body>\n  </worldbody>',
)


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(ARM)


@pytest.fixture(scope="module")
def arm_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("arm") / "arm.xml"
    path.write_text(ARM)
    return path


def _controls(episodes: int, steps: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(-0.5, 0.5, (episodes, steps // 5, 3)), 5, axis=1)


def _assert_std_per_column(noisy: np.ndarray, clean: np.ndarray, sigma: np.ndarray, what: str) -> None:
    """Each column's noise (noisy - clean) has std ``sigma[k]``: sum(e²)/σ² ~ χ²(n) holds in its 99.9% interval;
    a column of sigma 0 is the clean column bitwise."""
    noise = noisy - clean
    n = noise.shape[0]
    low, high = stats.chi2.ppf([0.0005, 0.9995], n)
    for k, s in enumerate(sigma):
        if s == 0:
            assert np.array_equal(noisy[:, k], clean[:, k]), f"{what}[{k}] has noise where none was asked for"
            continue
        statistic = float(np.sum(noise[:, k] ** 2) / s**2)
        assert low <= statistic <= high, (
            f"{what}[{k}]: empirical std {np.sqrt(np.mean(noise[:, k] ** 2)):.3g}, requested {s:.3g} "
            f"(chi2 {statistic:.0f} outside [{low:.0f}, {high:.0f}])"
        )


def test_record_log_per_entry_sigmas_reach_each_column(model: mujoco.MjModel) -> None:
    ctrl = _controls(4, 500)
    clean = record_log(model, ctrl, n_substeps=2)
    # shoulder and elbow differ 10x in qpos; the slide is in metres, far below both
    sigma = {
        "qpos": np.array([1e-4, 1e-3, 1e-2]),
        "qvel": np.array([2e-3, 0.0, 5e-2]),
        "sensordata": np.array([1e-3, 0.0, 2e-3, 2e-3]),
    }
    noisy = record_log(model, ctrl, n_substeps=2, noise_std=sigma, rng=np.random.default_rng(7))
    for key, expected in sigma.items():
        _assert_std_per_column(getattr(noisy, key), getattr(clean, key), expected, key)
    # one shared sigma (the mean of the two hinges) fails the same check on both hinges
    with pytest.raises(AssertionError):
        _assert_std_per_column(noisy.qpos[:, 1:], clean.qpos[:, 1:], np.array([5.5e-3, 5.5e-3]), "qpos")
    assert noisy.meta["noise_std_per_entry"] == {k: v.tolist() for k, v in sigma.items()}
    assert noisy.meta["noise_std"]["qpos"] == [1e-4, 1e-3, 1e-2]


def test_record_log_float_and_uniform_arrays_draw_the_same_bits(model: mujoco.MjModel) -> None:
    ctrl = _controls(2, 100)
    one = record_log(model, ctrl, noise_std=0.01, rng=np.random.default_rng(3))
    arrays = {
        "qpos": np.full(model.nq, 0.01),
        "qvel": [0.01] * model.nv,
        "sensordata": np.full(model.nsensordata, 0.01),
    }
    per_entry = record_log(model, ctrl, noise_std=arrays, rng=np.random.default_rng(3))
    for key in ("qpos", "qvel", "sensordata"):
        assert np.array_equal(getattr(one, key), getattr(per_entry, key))
    assert one.meta["noise_std"] == {"qpos": 0.01, "qvel": 0.01, "sensordata": 0.01}  # what older logs held
    assert one.meta["noise_std_per_entry"] == {"qpos": [0.01] * 3, "qvel": [0.01] * 3, "sensordata": [0.01] * 4}


@pytest.mark.parametrize(
    ("noise_std", "message"),
    [
        (
            {"qpos": [1e-3, 1e-3]},
            "`noise_std` for 'qpos' must be a finite number >= 0 or a 1-D array of nq=3 finite numbers >= 0. "
            "Received shape (2,).",
        ),
        (
            {"qvel": [[1e-3, 1e-3, 1e-3]]},
            "`noise_std` for 'qvel' must be a finite number >= 0 or a 1-D array of nv=3 finite numbers >= 0. "
            "Received shape (1, 3).",
        ),
        (
            {"sensordata": [0.0, -1.0, 0.0, 0.0]},
            "`noise_std` for 'sensordata' must be a finite number >= 0 or a 1-D array of nsensordata=4 finite "
            "numbers >= 0. Received -1.0 at entry 1.",
        ),
        (
            {"qpos": [0.0, float("nan"), 0.0]},
            "`noise_std` for 'qpos' must be a finite number >= 0 or a 1-D array of nq=3 finite numbers >= 0. "
            "Received nan at entry 1.",
        ),
        (
            {"qpos": -0.1},
            "`noise_std` for 'qpos' must be a finite number >= 0 or a 1-D array of nq=3 finite numbers >= 0. "
            "Received -0.1.",
        ),
        (
            {"qpso": 0.1},
            "`noise_std` keys must be among 'qpos', 'qvel', 'sensordata'. Received 'qpso'.",
        ),
        (
            [0.1, 0.1, 0.1],
            "`noise_std` must be a finite number >= 0 or a mapping of 'qpos', 'qvel', 'sensordata' to sigmas. "
            "Received list.",
        ),
    ],
)
def test_record_log_refuses_bad_sigmas(model: mujoco.MjModel, noise_std: object, message: str) -> None:
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        record_log(model, _controls(1, 10), noise_std=noise_std, rng=np.random.default_rng(0))  # type: ignore[arg-type]


def _sigmas(spec: str, model: mujoco.MjModel) -> dict[str, list[float]]:
    resolved = parse_obs_noise(spec).resolve(model)
    assert isinstance(resolved, dict)
    return {k: v.tolist() for k, v in resolved.items()}


def test_later_entries_override_earlier_ones(model: mujoco.MjModel) -> None:
    assert _sigmas("qpos=0.001,qpos[lift]=0.0001", model)["qpos"] == [1e-4, 1e-3, 1e-3]
    assert _sigmas("qpos[lift]=0.0001,qpos=0.001", model)["qpos"] == [1e-3, 1e-3, 1e-3]
    assert _sigmas("0.01, qvel[*]=0, qvel[elbow]=0.2", model) == {
        "qpos": [0.01] * 3,
        "qvel": [0.0, 0.0, 0.2],
        "sensordata": [0.01] * 4,
    }
    assert _sigmas("qvel[*o*]=0.5", model)["qvel"] == [0.0, 0.5, 0.5]  # fnmatch: shoulder, elbow
    assert parse_obs_noise("0.01").resolve(model) == 0.01  # one number: drawn exactly as the float form


def test_record_spec_puts_each_sigma_on_its_joint(arm_file: Path) -> None:
    source = Source("model", str(arm_file))
    spec = "qpos=0.001,qpos[lift]=0.0001,qvel[shoulder]=0.002,qvel[elbow]=0.02"
    clean = record(source, episodes=3, steps=400, seed=4, progress=False)
    noisy = record(source, episodes=3, steps=400, seed=4, obs_noise=spec, progress=False)
    expected = {"qpos": [1e-4, 1e-3, 1e-3], "qvel": [0.0, 2e-3, 2e-2], "sensordata": [0.0] * 4}
    assert noisy.meta["noise_std_per_entry"] == expected
    assert np.array_equal(noisy.ctrl, clean.ctrl)
    for key, sigma in expected.items():
        _assert_std_per_column(getattr(noisy, key), getattr(clean, key), np.array(sigma), key)


def test_cli_float_form_is_record_log_with_that_float(arm_file: Path, tmp_path: Path) -> None:
    """`--obs-noise 0.01` logs what it logged before per-joint specs: record_log(noise_std=0.01) on the same
    controls and start states, with the recorder's noise stream; a spec giving every channel 0.01 is the same log."""
    source = Source("model", str(arm_file))
    clean = record(source, episodes=2, steps=60, seed=2, progress=False)
    model = mujoco.MjModel.from_xml_path(str(arm_file))
    starts = [a for a, _ in clean.episode_bounds()]
    direct = record_log(
        model,
        clean.ctrl.reshape(2, 60, -1),
        n_substeps=clean.n_substeps,
        initial_qpos=clean.qpos[starts],
        initial_qvel=clean.qvel[starts],
        noise_std=0.01,
        rng=np.random.default_rng([2, 0x10C]),
    )
    for spec, name in (("0.01", "a.npz"), ("qpos=0.01,qvel=0.01,sensordata=0.01", "b.npz")):
        out = tmp_path / name
        argv = ["record", "--model", str(arm_file), "--episodes", "2", "--steps", "60", "--seed", "2"]
        assert main([*argv, "--obs-noise", spec, "--out", str(out), "--quiet"]) == 0
        logged = sysid.load_log(out)
        for key in ("time", "qpos", "qvel", "ctrl", "sensordata"):
            assert np.array_equal(getattr(logged, key), getattr(direct, key)), (spec, key)
        assert logged.meta["noise_std"] == {"qpos": 0.01, "qvel": 0.01, "sensordata": 0.01}


def _forms(problem: str, received: str) -> str:
    return f"`--obs-noise` {problem}; it must be {OBS_NOISE_FORMS}. Received {received!r}."


REFUSALS = [
    ("qpso=0.1", _forms("entry 'qpso=0.1' names unknown channel 'qpso'", "qpso=0.1")),
    ("qpos=-1", _forms("entry 'qpos=-1' has standard deviation -1.0, not a finite number >= 0", "qpos=-1")),
    ("qvel=inf", _forms("entry 'qvel=inf' has standard deviation inf, not a finite number >= 0", "qvel=inf")),
    ("qpos=nan", _forms("entry 'qpos=nan' has standard deviation nan, not a finite number >= 0", "qpos=nan")),
    ("qpos[lift]", _forms("entry 'qpos[lift]' is not S, CHANNEL=S or CHANNEL[JOINT]=S", "qpos[lift]")),
    ("qpos[]=1", _forms("entry 'qpos[]=1' is not S, CHANNEL=S or CHANNEL[JOINT]=S", "qpos[]=1")),
    ("qpos=0.1,", _forms("entry '' is not S, CHANNEL=S or CHANNEL[JOINT]=S", "qpos=0.1,")),
    ("lots", _forms("entry 'lots' is not S, CHANNEL=S or CHANNEL[JOINT]=S", "lots")),
    ("", _forms("is empty", "")),
    (
        "sensordata[tip_pos]=0.1",
        _forms(
            "entry 'sensordata[tip_pos]=0.1' names joints, which only qpos and qvel entries take",
            "sensordata[tip_pos]=0.1",
        ),
    ),
]
NO_JOINT = (
    "`--obs-noise` pattern 'lfit' matches no joint in the model. Close matches: 'lift'. Known joints: 'lift', "
    f"'shoulder', 'elbow'. It must be {OBS_NOISE_FORMS}. Received 'qpos=0.001,qpos[lfit]=0.0001'."
)


@pytest.mark.parametrize(("spec", "message"), REFUSALS)
def test_parse_obs_noise_refusals(spec: str, message: str) -> None:
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        parse_obs_noise(spec)


def test_pattern_matching_no_joint_is_refused(model: mujoco.MjModel) -> None:
    with pytest.raises(ValueError, match=f"^{re.escape(NO_JOINT)}$"):
        parse_obs_noise("qpos=0.001,qpos[lfit]=0.0001").resolve(model)


def test_per_joint_entries_refuse_ball_and_free_joints() -> None:
    model = mujoco.MjModel.from_xml_string(FREE)
    message = _forms(
        "entry qpos[*] matches free joint 'box_free', whose qpos holds a quaternion (independent Gaussian noise on "
        "it is no rotation error): per-joint entries take hinge and slide joints only, so narrow the pattern or give "
        "the whole channel (qpos=S)",
        "qpos[*]=0.01",
    )
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        parse_obs_noise("qpos[*]=0.01").resolve(model)
    # the whole channel still reaches the quaternion (raw Gaussian noise, as the float form always did)
    assert _sigmas("qpos=0.01,qpos[lift]=0.001", model)["qpos"] == [0.001, 0.01, 0.01] + [0.01] * 7


@pytest.mark.parametrize(
    ("spec", "message"),
    [*REFUSALS[:3], ("qpos=0.001,qpos[lfit]=0.0001", NO_JOINT)],
)
def test_cli_refusals_exit_2_with_one_line(
    arm_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], spec: str, message: str
) -> None:
    out = tmp_path / "log.npz"
    argv = ["record", "--model", str(arm_file), "--episodes", "1", "--steps", "10", "--out", str(out), "--quiet"]
    assert main([*argv, "--obs-noise", spec]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"sim2real record: error: {message}\n"
    assert captured.out == "" and not out.exists()


def test_record_refuses_a_non_finite_float(arm_file: Path) -> None:
    with pytest.raises(ValueError, match=r"^`obs_noise` must be a finite number >= 0 or an --obs-noise spec string"):
        record(Source("model", str(arm_file)), obs_noise=float("inf"), steps=10, episodes=1, progress=False)


def test_fit_noise_estimates_follow_the_per_joint_truth(model: mujoco.MjModel) -> None:
    """sysid.fit estimates one noise level per logged column: on a log whose joints carry sigmas 10x apart, the
    estimates come out in the true order and within a factor of 1.5 of each truth (within 1.18 over 12 seeds)."""
    truth = {"qpos": [1e-4, 1e-3, 1e-2], "qvel": [1e-3, 3e-2, 3e-3]}
    log = record_log(
        model,
        _controls(2, 200),
        n_substeps=2,
        noise_std={**truth, "sensordata": 0.0},
        rng=np.random.default_rng(1),
    )
    result = sysid.fit(
        log,
        model,
        ["dof_damping[elbow]"],
        signals=["qpos", "qvel"],
        global_search=False,
        latency=None,
        profile=False,
        progress=False,
        nthread=1,
    )
    names = sysid.channel_names(model)
    for key, sigmas in truth.items():
        estimates = [result.noise_std[name] for name in names[key]]
        assert np.argsort(estimates).tolist() == np.argsort(sigmas).tolist(), (key, estimates)
        for estimate, sigma in zip(estimates, sigmas, strict=True):
            assert sigma / 1.5 < estimate < sigma * 1.5, (key, estimates)
    json.dumps(log.meta)  # the per-entry truth is plain JSON beside it
    assert log.meta["noise_std_per_entry"]["qvel"] == truth["qvel"]
