"""A fit's sensor noise is exported per signal group (positions, velocities) when the target env's observation
layout is known; one level for the whole observation otherwise (what every export did before)."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

import sim2real as s2r
import sysid
from randomizers import Uniform, load_config
from sim2real.calibration import noise_select
from sim2real.mjcf_env import MjcfEnv

# A 5-joint arm and a free puck (held up by gravity compensation, so the log has no contacts).
ARM = """<mujoco>
  <option timestep="0.005"/>
  <default><joint damping="0.2" axis="0 1 0" range="-2 2"/><geom type="capsule" size="0.03"/></default>
  <worldbody>
    <body name="l1"><joint name="j1" axis="0 0 1"/><geom fromto="0 0 0 0.2 0 0" mass="1.0"/>
      <body name="l2" pos="0.2 0 0"><joint name="j2"/><geom fromto="0 0 0 0.2 0 0" mass="0.8"/>
        <body name="l3" pos="0.2 0 0"><joint name="j3"/><geom fromto="0 0 0 0.15 0 0" mass="0.5"/>
          <body name="l4" pos="0.15 0 0"><joint name="j4" axis="1 0 0"/><geom fromto="0 0 0 0.1 0 0" mass="0.3"/>
            <body name="l5" pos="0.1 0 0"><joint name="j5"/><geom fromto="0 0 0 0.08 0 0" mass="0.2"/></body>
          </body>
        </body>
      </body>
    </body>
    <body name="puck" pos="0.6 0.4 0.3" gravcomp="1">
      <freejoint name="puck"/><geom type="cylinder" size="0.04 0.01" mass="0.1"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="j1" gear="3"/><motor joint="j2" gear="3"/><motor joint="j3" gear="2"/>
    <motor joint="j4"/><motor joint="j5"/>
  </actuator>
</mujoco>"""
TRUTH = {"qpos": 1e-3, "qvel": 5e-3}  # velocities 5x noisier than positions


@pytest.fixture(scope="module")
def fit() -> sysid.FitResult:
    model = mujoco.MjModel.from_xml_string(ARM)
    t = np.arange(300)
    ctrl = np.stack([0.5 * np.sin(0.05 * t * (k + 1) + k) for k in range(5)], axis=1)
    log = sysid.record_log(model, ctrl, n_substeps=4, noise_std=TRUTH, rng=np.random.default_rng(0))
    result = sysid.fit(log, model, ["dof_damping[j2]", "dof_damping[j3]"], progress=False, global_search=False)
    assert result.ok
    return result


def _gaussians(effects: list[Any]) -> list[Any]:
    (noise,) = [e for e in effects if type(e).__name__ == "ObservationNoise"]
    return list(noise.processes)


def test_without_a_layout_the_export_keeps_one_level(fit: sysid.FitResult) -> None:
    (gaussian,) = _gaussians(fit.to_effects())
    assert gaussian.std == 0.003 and gaussian.select is None  # the mean of 1e-3 and 5e-3: neither truth


@pytest.mark.parametrize("min_relative_width", [0.1, 0.0])
def test_with_the_layout_of_an_mjcf_env_each_group_keeps_its_level_and_brackets_its_truth(
    fit: sysid.FitResult, min_relative_width: float
) -> None:
    env = MjcfEnv(xml=ARM)
    nq, nv = env.model.nq, env.model.nv
    where = noise_select(env)
    assert where == {"qpos": list(range(nq)), "qvel": list(range(nq, nq + nv))}
    effects = fit.to_effects(min_relative_width=min_relative_width, noise_select=where)  # width=2: 2 stderr
    positions, velocities = _gaussians(effects)
    for gaussian, signal, select in ((positions, "qpos", range(nq)), (velocities, "qvel", range(nq, nq + nv))):
        sigma, stderr = fit.noise_level(signal)
        assert gaussian.select == tuple(select)
        assert isinstance(gaussian.std, Uniform)
        assert gaussian.std.low <= TRUTH[signal] <= gaussian.std.high, (signal, gaussian.std)
        half = max(min_relative_width * sigma, 2 * stderr)
        assert (gaussian.std.low, gaussian.std.high) == (round(sigma - half, 12), round(sigma + half, 12))
    assert velocities.std.low > 3 * positions.std.high  # two levels, not one


def test_the_exported_config_loads_into_wrap_and_the_demo(fit: sysid.FitResult, tmp_path: Path) -> None:
    from sim2real.cli import main

    env = MjcfEnv(xml=ARM)
    text = fit.to_randomizers(noise_select=noise_select(env))
    loaded = load_config(text)
    wrapped = s2r.wrap(env, *loaded, seed=0)
    _, info = wrapped.reset(seed=0)
    drawn = info["sim2real"]["params"]
    nq = env.model.nq
    (positions, velocities) = _gaussians(loaded)
    for i in range(nq + env.model.nv):
        std = drawn[f"obs_noise_std[{i}]"]
        box = positions.std if i < nq else velocities.std
        assert box.low <= std <= box.high
    arm = tmp_path / "arm.xml"
    arm.write_text(ARM)
    config = tmp_path / "exported.yaml"
    config.write_text(text)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["demo", "--model", str(arm), "--config", str(config), "--episodes", "1", "--quiet"])
    assert (code, err.getvalue()) == (0, "")
    assert "ObservationNoise(Gaussian(std=Uniform(" in out.getvalue()


def test_noise_levels_and_their_degrees_of_freedom_survive_json(fit: sysid.FitResult) -> None:
    again = sysid.FitResult.from_json(fit.to_json())
    assert again == fit and again.noise_dof == fit.noise_dof
    assert set(fit.noise_dof) == set(fit.noise_std) and all(d > 100 for d in fit.noise_dof.values())
    older = fit.to_dict()
    del older["noise_dof"]  # a document written before the degrees of freedom were stored
    sigma, stderr = sysid.FitResult.from_dict(older).noise_level("qvel")
    assert sigma == pytest.approx(fit.noise_level("qvel")[0], rel=0.01) and np.isnan(stderr)
    with pytest.raises(ValueError, match=r"`signal` must be a fitted channel .* Received 'qacc'\."):
        fit.noise_level("qacc")


def test_named_observation_parts_are_found_only_where_they_hold_qpos_and_qvel() -> None:
    assert noise_select(s2r.make("dmc/reacher-easy")) == {"qpos": "position", "qvel": "velocity"}
    assert noise_select(s2r.make("dmc/manipulator-bring_ball")) is None
    assert noise_select(s2r.make("sim2real/arm-reach")) is None


def test_an_empty_noise_select_is_refused_not_an_export_without_sensor_noise(fit: sysid.FitResult) -> None:
    """``noise_select={}`` exported no ObservationNoise at all, silently: the calibrated sim lost its sensor noise."""
    message = (
        r"`noise_select` must map at least one signal \('qpos', 'qvel', a sensor\) to where it sits in the "
        r"observation, or be None \(one level for the whole observation\). Received \{\}\."
    )
    with pytest.raises(ValueError, match=message):
        fit.to_effects(noise_select={})
    with pytest.raises(ValueError, match=message):
        fit.to_randomizers(noise_select={})


def test_a_noise_select_slice_is_written_by_the_yaml_export_and_reloads_equal(fit: sysid.FitResult) -> None:
    """A slice is a valid ``select`` for to_effects: to_randomizers raised yaml's RepresenterError ('cannot represent
    an object'), then (090a454) refused it; it is now written as '0:12' and reloads to the same slice (its list of
    indices would name another noise stream and draw other values: tests/test_loose_ends11_select.py)."""
    where = {"qpos": slice(0, 12), "qvel": slice(12, 23)}
    effects = fit.to_effects(noise_select=where)
    assert len(_gaussians(effects)) == 2
    text = fit.to_randomizers(noise_select=where)
    assert "select: 0:12\n" in text and "select: '12:23'\n" in text, text  # yaml quotes what YAML 1.1 reads as base 60
    assert [g.select for g in _gaussians(load_config(text))] == [slice(0, 12), slice(12, 23)]
    assert _gaussians(load_config(text)) == _gaussians(effects)
    from noise_models import Gaussian, ObservationNoise
    from randomizers import dump_config

    assert "select: range(0, 2)\n" in dump_config([ObservationNoise(Gaussian(std=0.1), select=range(2))])
    assert "select:\n    - 0\n    - 1\n" in dump_config([ObservationNoise(Gaussian(std=0.1, select=[0, 1]))])
