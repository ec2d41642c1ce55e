"""Visual effects (issue #4): the #2 effect contract, rendering, textures on live contexts, pixels, CLI."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import assert_restored, model_arrays

import sim2real as s2r
from randomizers import PhysicsRandomizer, dump_effects, load_effects, stream
from randomizers.visual import (
    _TextureGeometry,
    add_texture_uploader,
    hsv_to_rgb,
    render_texture,
    renderer_uploader,
    rgb_to_hsv,
    texture_uploaders,
)
from sim2real._gl import PACKAGES, RenderingUnavailable, require_rendering

U = s2r.Uniform
TASK = "sim2real/arm-reach"
SIZE = (32, 32)
# One instance of each visual effect (and light flavour), valid on sim2real/arm-reach.
EFFECTS = {
    "GeomColor": s2r.GeomColor(add=(U(-0.1, 0.1), U(-0.2, 0.2), U(-0.2, 0.2)), geoms=["*_link", "palm"], space="hsv"),
    "MaterialColor": s2r.MaterialColor(scale=U(0.5, 1.0), materials=["link", "joint"]),
    "Texture": s2r.Texture(textures=["grid", "sky"], pattern=["checker", "gradient", "noise", "flat"]),
    "Light": s2r.Light(scale=U(0.3, 1.2)),
    "LightDir": s2r.Light(add=U(-0.3, 0.3), attribute="dir", lights="key"),
    "LightFlag": s2r.Light(set=s2r.Choice((0.0, 1.0)), attribute="active"),
    "CameraPose": s2r.CameraPose(add=U(-0.1, 0.1), roll=U(-0.1, 0.1), cameras="overview"),
    "CameraFovy": s2r.CameraFovy(scale=U(0.8, 1.2)),
}
IDS = list(EFFECTS)
ACTIONS = np.random.default_rng(7).uniform(-0.05, 0.05, size=(10, 3)).astype(np.float32)


def _texels(model: mujoco.MjModel, name: str) -> np.ndarray:
    t = model.texture(name).id
    adr, n = int(model.tex_adr[t]), int(model.tex_width[t] * model.tex_height[t] * model.tex_nchannel[t])
    return model.tex_data[adr : adr + n]


def _check_written(effect: s2r.Texture, model: mujoco.MjModel, params: dict[str, float]) -> None:
    """The model holds exactly what the reported values describe."""
    if isinstance(effect, s2r.Texture):
        for name in ("grid", "sky"):
            p = [params[f"tex_pattern[{name}]"], params[f"tex_seed[{name}]"]]
            rgb1 = [params[f"tex_rgb1[{name}][{c}]"] for c in range(3)]
            rgb2 = [params[f"tex_rgb2[{name}][{c}]"] for c in range(3)]
            geometry = _TextureGeometry(model, model.texture(name).id)
            expected = render_texture(geometry, effect.patterns_drawn[int(p[0])], rgb1, rgb2, int(p[1]))
            np.testing.assert_array_equal(_texels(model, name).reshape(-1, 3), expected)
        return
    live = effect.bind(model)  # a second binding reads the live (perturbed) values
    assert list(params) == list(live.addresses)
    np.testing.assert_array_equal(live.nominal, np.array(list(params.values())))


# ------------------------------------------------------------------------------ the #2 contract


@pytest.mark.parametrize("name", IDS)
def test_single_env_reports_and_writes_values(name: str) -> None:
    effect = EFFECTS[name]
    env = s2r.wrap(s2r.make(TASK), effect, seed=0)
    model = env.unwrapped.model
    _, info = env.reset(seed=3)
    params = info["sim2real"]["params"]
    assert params and all(np.isfinite(v) for v in params.values())
    _check_written(effect, model, params)
    seen = [params] + [env.reset(seed=seed)[1]["sim2real"]["params"] for seed in (4, 5, 6)]
    assert any(p != env.randomizer.nominal_params() for p in seen)
    assert len({tuple(p.values()) for p in seen}) > 1, "new episodes draw new values"
    env.close()


@pytest.mark.parametrize("name", IDS)
def test_seed_twin_matches_bare_generator(name: str) -> None:
    """Values in use equal binding.values(distribution.sample(stream(seed, key, episode)))."""
    effect = EFFECTS[name]
    env = s2r.wrap(s2r.make(TASK), effect, seed=7)
    nominal = effect.bind(env.unwrapped.model)
    for episode in range(3):
        _, info = env.reset()
        gen = stream(env.randomizer.root_seed, env.randomizer.stream_names[0], episode)
        expected = nominal.values(np.asarray(effect.distribution.sample(gen, nominal.draw_count())))
        np.testing.assert_array_equal(np.array(list(info["sim2real"]["params"].values())), expected)
    env.close()


def test_composed_with_physics_effects_draws_do_not_shift() -> None:
    physics = [s2r.Mass(scale=U(0.8, 1.2)), s2r.Damping(scale=U(0.5, 2.0))]
    env_all = s2r.wrap(s2r.make(TASK), *EFFECTS.values(), *physics, seed=11)
    _, info_all = env_all.reset(seed=4)
    for effect in [*EFFECTS.values(), *physics]:
        _, info_one = s2r.wrap(s2r.make(TASK), effect, seed=11).reset(seed=4)
        for key, value in info_one["sim2real"]["params"].items():
            assert info_all["sim2real"]["params"][key] == value, (effect, key)


@pytest.mark.parametrize("name", ["GeomColor", "Texture", "CameraPose"])
def test_vector_env_gives_independent_reproducible_draws(name: str) -> None:
    envs = s2r.make_vec(TASK, 3, EFFECTS[name], seed=0)
    _, info = envs.reset(seed=0)
    last = [k for k in info["sim2real"]["params"] if not k.startswith("_")][-1]  # "_k": gymnasium's masks
    first = np.array(info["sim2real"]["params"][last])
    assert len(set(first.tolist())) == 3, "each sub-env draws its own values"
    again = s2r.make_vec(TASK, 3, EFFECTS[name], seed=0)
    _, info2 = again.reset(seed=0)
    for key, values in info["sim2real"]["params"].items():
        np.testing.assert_array_equal(values, info2["sim2real"]["params"][key])
    envs.close()
    again.close()


def test_restore_is_bitwise_after_resets_steps_and_intervals() -> None:
    effects = [*EFFECTS.values(), s2r.GeomColor(set=U(0, 1), geoms="floor", schedule=s2r.Interval(steps=2))]
    env = s2r.wrap(s2r.make(TASK), *effects, seed=0)
    twin = s2r.make(TASK)
    model = env.unwrapped.model
    before = model_arrays(model)
    for target in (env, twin):
        for seed in (0, 5, 9):
            target.reset(seed=seed)
            for action in ACTIONS[:5]:
                target.step(action)
    env.close()
    assert_restored(before, model, twin.unwrapped.model)


def test_startup_schedule_keeps_the_texture() -> None:
    effect = s2r.Texture(textures="grid", pattern="noise", schedule="startup")
    env = s2r.wrap(s2r.make(TASK), effect, seed=0)
    _, a = env.reset()
    first = _texels(env.unwrapped.model, "grid").copy()
    _, b = env.reset()
    assert a["sim2real"]["params"] == b["sim2real"]["params"]
    np.testing.assert_array_equal(_texels(env.unwrapped.model, "grid"), first)


@pytest.mark.parametrize("name", IDS)
def test_gymnasium_check_env(name: str) -> None:
    from gymnasium.utils.env_checker import check_env

    check_env(s2r.wrap(s2r.make(TASK), EFFECTS[name], seed=0), skip_render_check=True)


@pytest.mark.parametrize("name", ["GeomColor", "Texture", "Light", "CameraPose"])
def test_torchrl_check_env_specs(name: str) -> None:
    from torchrl.envs import GymWrapper
    from torchrl.envs.utils import check_env_specs

    env = s2r.wrap(GymWrapper(s2r.make(TASK)), EFFECTS[name], seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(3)
    transform = env.transform[-1] if hasattr(env.transform, "__len__") else env.transform
    assert td["sim2real_params"].shape == (3, len(transform.param_names))


def _dm_env_tests() -> type:
    import unittest

    from dm_control import suite
    from dm_env import test_utils

    class WrappedReacherVisualTest(test_utils.EnvironmentTestMixin, unittest.TestCase):
        def make_object_under_test(self):  # type: ignore[no-untyped-def]
            return s2r.wrap(
                suite.load("reacher", "easy"),
                s2r.GeomColor(set=U(0, 1), geoms="arm"),
                s2r.Light(scale=U(0.5, 1.5)),
                s2r.CameraFovy(add=U(-5, 5), cameras="fixed"),
                s2r.Texture(textures="grid", pattern="checker"),
                seed=0,
            )

    return WrappedReacherVisualTest


TestDmEnvVisualContract = _dm_env_tests()


def test_engine_on_a_bare_model_and_layering() -> None:
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><light name="top"/><geom name="g" size=".1" rgba="1 0 0 1"/></worldbody></mujoco>'
    )
    r = PhysicsRandomizer([s2r.GeomColor(set=U(0, 1)), s2r.Light(set=0.0, attribute="active")], seed=0)
    r.bind(model, mujoco.MjData(model))
    r.begin_episode(seed=2)
    r.apply()
    assert r.current_params["light_active[top]"] == 0.0 and not model.light_active[0]
    r.restore_nominal()
    assert model.light_active[0] and model.geom_rgba[0].tolist() == [1, 0, 0, 1]
    code = "import sys, randomizers.visual; sys.exit('sim2real' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


# ------------------------------------------------------------------------------ semantics


def test_hsv_round_trip_and_hue_wraps() -> None:
    rgb = np.random.default_rng(0).random((500, 3))
    np.testing.assert_allclose(hsv_to_rgb(rgb_to_hsv(rgb)), rgb, atol=1e-12)
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom name="g" size=".1" rgba="1 0 0 1"/></worldbody></mujoco>'
    )
    binding = s2r.GeomColor(add=(0.5, 0.0, 0.0), space="hsv").bind(model)
    np.testing.assert_allclose(binding.values(np.array([0.5, 0.0, 0.0])), [0, 1, 1], atol=1e-7)  # red + half turn
    binding = s2r.GeomColor(add=(0.75, 0.0, 0.0), space="hsv").bind(model)
    np.testing.assert_allclose(rgb_to_hsv(binding.values(np.array([0.75, 0.0, 0.0])))[0], 0.75, atol=1e-6)


def test_geom_color_starts_from_the_material_colour_it_shows() -> None:
    model = s2r.make(TASK).unwrapped.model
    binding = s2r.GeomColor(scale=1.0, geoms="palm").bind(model)  # palm shows material "link"
    np.testing.assert_array_equal(
        binding.values(np.ones(3)), model.mat_rgba[model.material("link").id, :3].astype(np.float64)
    )
    shared = s2r.GeomColor(set=U(0, 1), geoms="*_link", shared=True).bind(model)
    values = shared.values(np.array([0.1, 0.2, 0.3])).reshape(-1, 3)
    assert shared.draw_count() == 3 and (values == values[0]).all()


def test_light_direction_is_renormalised_and_camera_still_looks_at_the_target() -> None:
    model = s2r.make(TASK).unwrapped.model
    d = s2r.Light(add=U(-0.5, 0.5), attribute="dir").bind(model)
    v = d.values(np.full(d.size, 0.4)).reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, rtol=1e-6)
    pose = s2r.CameraPose(add=U(-0.2, 0.2), roll=0.0).bind(model)
    target = pose.targets[0]
    values = pose.values(np.array([0.2, -0.1, 0.15, 0.0]))
    pos, quat = values[:3], values[3:]
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, quat)
    forward = -mat.reshape(3, 3)[:, 2]
    np.testing.assert_allclose(forward, (target - pos) / np.linalg.norm(target - pos), atol=1e-12)
    # zero offset and roll reproduce the nominal orientation
    np.testing.assert_allclose(pose.values(np.zeros(4))[3:], model.cam_quat[0], atol=1e-12)


def test_yaml_round_trip_of_every_visual_effect() -> None:
    effects = list(EFFECTS.values())
    assert load_effects(dump_effects(effects)) == effects
    text = """
effects:
  - {type: GeomColor, add: [[-0.1, 0.1], 0, {type: Normal, mean: 0, std: 0.01}], space: hsv, geoms: "*_link"}
  - {type: Texture, textures: grid, pattern: [checker, noise], rgb1: [0.2, 0.8]}
"""
    color, texture = load_effects(text)
    assert color.channels == (U(-0.1, 0.1), s2r.Constant(0.0), s2r.Normal(0.0, 0.01))
    assert texture.rgb1 == (U(0.2, 0.8),) * 3 and texture.patterns_drawn == ("checker", "noise")


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: s2r.GeomColor(scale=U(-1, 1)), "`scale` of GeomColor must not go below 0"),
        (lambda: s2r.GeomColor(add=(0.1, 0.1)), "`add` of GeomColor must be one distribution or a sequence of 3"),
        (
            lambda: s2r.GeomColor(add=0.1, space="lab"),
            "`space` of GeomColor must be one of ['rgb', 'hsv']. Received 'lab'.",
        ),
        (lambda: s2r.MaterialColor(set=(U(0, 1), U(0, 1.5), 0)), "`set` of MaterialColor must stay within [0, 1]"),
        (lambda: s2r.Light(scale=1.0, attribute="colour"), "`attribute` of Light must be one of ['pos', 'dir'"),
        (
            lambda: s2r.Light(add=1.0, attribute="castshadow"),
            "takes `set` only (a draw >= 0.5 means on). Received add.",
        ),
        (lambda: s2r.Texture(rgb1=U(0, 2)), "`rgb1` of Texture must stay within [0, 1]"),
        (lambda: s2r.Texture(pattern=[]), "`pattern` of Texture must be one of ['flat', 'checker'"),
        (lambda: s2r.CameraFovy(set=0.0), "`set` of CameraFovy must stay in (0, 180) degrees. Received Constant"),
        (lambda: s2r.CameraPose(add=0.1, scale=1.0), "CameraPose needs exactly one of `scale`, `add` or `set`"),
    ],
)
def test_bad_arguments_are_rejected_with_clear_messages(build, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises((ValueError, TypeError)) as err:
        build()
    assert message in str(err.value)


def test_bad_selection_names_close_matches() -> None:
    model = s2r.make(TASK).unwrapped.model
    with pytest.raises(
        ValueError, match=r"`lights` pattern 'kee' matches no light in the model\. Close matches: 'key'"
    ):
        s2r.Light(scale=1.0, lights="kee").bind(model)
    with pytest.raises(ValueError, match=r"Known textures: 'sky', 'grid'"):
        s2r.Texture(textures="floor").bind(model)
    with pytest.raises(ValueError, match=r"would take cam_fovy\[overview\] \(nominal 45.0\) outside \(0, 180\)"):
        s2r.CameraFovy(scale=U(1.0, 5.0)).bind(model)


def test_pixel_options_are_validated() -> None:
    with pytest.raises(TypeError, match=r"`size` and `pixels_only` apply with pixels=True only"):
        s2r.make(TASK, size=(8, 8))
    with pytest.raises(ValueError, match=r"`size` must be \(height, width\), two positive ints. Received \(0, 8\)"):
        s2r.make(TASK, pixels=True, size=(0, 8))
    with pytest.raises(ValueError, match=r"Received 'overveiw'. Close matches: 'overview'"):
        s2r.make(TASK, pixels=True, camera="overveiw")


def test_missing_backend_error_names_the_debian_packages() -> None:
    def broken() -> None:
        raise RuntimeError("eglInitialize failed")

    with pytest.raises(RenderingUnavailable) as err:
        require_rendering(broken)
    text = str(err.value)
    assert "eglInitialize failed" in text and PACKAGES["egl"] in text and PACKAGES["osmesa"] in text
    assert PACKAGES == {"egl": "libegl1 libegl-mesa0 libgl1-mesa-dri", "osmesa": "libosmesa6"}


# ------------------------------------------------------------------------------ rendering


def _pixel_env(*effects: object, seed: int = 0, task: str = TASK) -> object:
    return s2r.wrap(s2r.make(task, pixels=True, size=SIZE), *effects, seed=seed)


@pytest.mark.render
def test_frames_differ_between_draws_and_repeat_bitwise_for_a_seed() -> None:
    effects = list(EFFECTS.values())
    a, b = _pixel_env(*effects), _pixel_env(*effects)
    frames_a = [a.reset(seed=s)[0] for s in (0, 1, 0)]
    frames_b = [b.reset(seed=s)[0] for s in (0, 1)]
    assert frames_a[0].shape == (*SIZE, 3) and frames_a[0].dtype == np.uint8
    assert (frames_a[0] != frames_a[1]).mean() > 0.2, "different draws must look different"
    assert frames_a[0].tobytes() == frames_a[2].tobytes() == frames_b[0].tobytes()
    assert frames_a[1].tobytes() == frames_b[1].tobytes()
    a.close()
    b.close()


@pytest.mark.render
@pytest.mark.parametrize("name", IDS)
def test_each_effect_changes_the_rendered_frame(name: str) -> None:
    nominal = s2r.make(TASK, pixels=True, size=(48, 48))
    frame0, _ = nominal.reset(seed=0)
    frames = []
    for wrap_seed in (1, 2, 3):  # same arm pose and target (reset seed 0), new visual draws
        env = s2r.wrap(s2r.make(TASK, pixels=True, size=(48, 48)), EFFECTS[name], seed=wrap_seed)
        frames.append(env.reset(seed=0)[0])
        env.close()
    assert any(f.tobytes() != frame0.tobytes() for f in frames), name
    assert len({f.tobytes() for f in frames}) > 1, name


@pytest.mark.render
def test_texture_change_reaches_a_live_renderer_only_through_the_upload() -> None:
    model = s2r.make(TASK).unwrapped.model
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    renderer = mujoco.Renderer(model, *SIZE)

    def frame() -> np.ndarray:
        renderer.update_scene(data, camera="overview")
        return renderer.render()

    before = frame()
    red_floor = s2r.Texture(textures="grid", pattern="flat", rgb1=(1.0, 0.0, 0.0))
    r = PhysicsRandomizer([red_floor], seed=0)
    r.bind(model, data)
    r.begin_episode()
    r.apply()
    assert frame().tobytes() == before.tobytes(), "without an upload the GPU keeps the old texture"
    remove = add_texture_uploader(renderer_uploader(renderer))
    try:
        r.begin_episode()
        r.apply()
        after = frame()
        floor = after[-4:, :, :].astype(int)  # the bottom rows show the floor
        assert (floor[..., 0] > floor[..., 1] + 40).all(), "the floor turned red"
        fresh = mujoco.Renderer(model, *SIZE)
        fresh.update_scene(data, camera="overview")
        assert fresh.render().tobytes() == after.tobytes(), "live upload == a context made from the new data"
        fresh.close()
        r.restore_nominal()
        assert frame().tobytes() == before.tobytes(), "restore uploads the nominal texels back"
    finally:
        remove()
        renderer.close()


@pytest.mark.render
def test_restore_gives_the_nominal_frame_bitwise() -> None:
    env = s2r.make(TASK, pixels=True, size=SIZE)
    nominal, _ = env.reset(seed=0)
    before = model_arrays(env.unwrapped.model)
    wrapped = s2r.wrap(env, *EFFECTS.values(), seed=3)
    for seed in (0, 1):
        frame, _ = wrapped.reset(seed=seed)
        assert frame.tobytes() != nominal.tobytes()
    wrapped.restore_nominal()  # the pixel renderer (a live context) stays open
    again, _ = env.reset(seed=0)
    assert again.tobytes() == nominal.tobytes()
    twin = s2r.make(TASK)
    for seed in (0, 0, 1, 0):
        twin.reset(seed=seed)
    assert_restored(before, env.unwrapped.model, twin.unwrapped.model)


@pytest.mark.render
@pytest.mark.parametrize("task", ["gym/Hopper-v5", "dmc/reacher-easy"])
def test_textures_reach_the_envs_own_render_contexts(task: str) -> None:
    """gymnasium's MujocoRenderer viewer and dm-control's physics contexts get the new texels."""
    env = s2r.wrap(s2r.make(task, render_mode="rgb_array", width=32, height=32), s2r.Texture(pattern="noise"), seed=0)
    env.reset(seed=0)
    env.render()  # the env's own context now exists and holds draw 0's texels
    stale = s2r.find_physics(env).model.tex_data.copy()
    env.reset(seed=1)  # draws new textures: they must reach the live context
    live = env.render()
    fresh = s2r.make(task, render_mode="rgb_array", width=32, height=32)
    model = s2r.find_physics(fresh).model
    model.tex_data[:] = stale
    fresh.reset(seed=1)
    assert fresh.render().tobytes() != live.tobytes(), "the texture draw is visible"
    fresh.close()
    fresh = s2r.make(task, render_mode="rgb_array", width=32, height=32)
    s2r.find_physics(fresh).model.tex_data[:] = s2r.find_physics(env).model.tex_data
    fresh.reset(seed=1)
    assert fresh.render().tobytes() == live.tobytes(), "live context == a fresh one made from the new texels"
    env.close()
    fresh.close()


@pytest.mark.render
def test_pixels_only_false_and_gymnasium_checker() -> None:
    from gymnasium.utils.env_checker import check_env

    env = s2r.make(TASK, pixels=True, size=SIZE, pixels_only=False, camera=-1)
    obs, _ = env.reset(seed=0)
    assert obs["state"].shape == (16,) and obs["pixels"].shape == (*SIZE, 3)
    check_env(s2r.wrap(s2r.make(TASK, pixels=True, size=SIZE), EFFECTS["GeomColor"], seed=0), skip_render_check=True)


@pytest.mark.render
def test_torchrl_pixel_envs_with_visual_effects() -> None:
    from torchrl.envs import DMControlEnv, GymWrapper
    from torchrl.envs.utils import check_env_specs

    env = s2r.wrap(GymWrapper(s2r.make(TASK, pixels=True, size=SIZE)), EFFECTS["Texture"], EFFECTS["Light"], seed=0)
    check_env_specs(env, seed=0)
    a, b = env.reset()["pixels"].clone(), env.reset()["pixels"].clone()
    assert a.shape == (*SIZE, 3) and not (a == b).all()
    # TorchRL's own dm-control pixel env: track its contexts, then textures reach its renders.
    dm = DMControlEnv("reacher", "easy", from_pixels=True, pixels_only=True)
    s2r.track_render_contexts(dm)
    dm = s2r.wrap(dm, s2r.Texture(textures="grid", pattern="noise"), seed=0)
    p1, p2 = dm.reset()["pixels"].clone(), dm.reset()["pixels"].clone()
    assert not (p1 == p2).all()


@pytest.mark.render
def test_composer_jaco_recompiles_and_keeps_its_visual_draws() -> None:
    effects = [
        s2r.GeomColor(set=U(0, 1), geoms="jaco_arm/*", shared=True),
        s2r.Texture(textures="groundplane", pattern="checker"),
        s2r.Light(scale=U(0.3, 1.0)),
        s2r.CameraFovy(scale=U(0.8, 1.2)),
    ]
    env = _pixel_env(*effects, task="dmc/jaco-reach_site")
    frame_a, info_a = env.reset(seed=0)
    frame_b, info_b = env.reset(seed=1)
    assert info_a["sim2real"]["params"] != info_b["sim2real"]["params"]
    assert frame_a.tobytes() != frame_b.tobytes()
    model = s2r.find_physics(env).model  # this episode's freshly compiled model holds the draws
    fovy = info_b["sim2real"]["params"]["cam_fovy[front_close]"]
    assert float(model.cam_fovy[0]) == fovy
    env.close()


@pytest.mark.render
def test_contact_sheet_and_cli_write_atomically(tmp_path: Path) -> None:
    from sim2real.cli import main

    config = tmp_path / "effects.yaml"
    config.write_text(dump_effects([EFFECTS["GeomColor"], EFFECTS["Texture"]]))
    out = tmp_path / "sheet.png"
    assert main(["visualize", TASK, "--config", str(config), "--n", "3", "--size", "24", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["effects.yaml", "sheet.png"], "no temp file left"
    sheet = s2r.contact_sheet(TASK, config, n=3, size=(24, 24))
    again = s2r.contact_sheet(TASK, config, n=3, size=(24, 24))
    assert sheet.frames.tobytes() == again.frames.tobytes() and sheet.path is None
    assert len({f.tobytes() for f in sheet.frames}) == 3
    assert main(["visualize", "no/such-task", "--n", "1", "--out", str(out)]) == 2
    # A missing folder is created, as for every other command's output (it was checked before any rendering).
    assert main(["visualize", TASK, "--n", "1", "--size", "8", "--out", str(tmp_path / "new ü" / "x.png")]) == 0
    assert (tmp_path / "new ü" / "x.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["visualize", TASK, "--n", "1", "--out", str(config / "x.png")]) == 2  # a file on the way


def test_uploaders_are_dropped_with_their_envs() -> None:
    import gc

    gc.collect()  # envs of earlier tests must not vanish in the middle of the count
    count = len(texture_uploaders())
    env = s2r.make(TASK)
    assert len(texture_uploaders()) == count + 1
    del env
    gc.collect()
    assert len(texture_uploaders()) == count


def test_texture_patterns_look_as_documented() -> None:
    model = s2r.make(TASK).unwrapped.model
    grid = _TextureGeometry(model, model.texture("grid").id)  # 2D, 256 x 256
    sky = _TextureGeometry(model, model.texture("sky").id)  # skybox: 6 faces of 256 x 256
    red, blue = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    flat = render_texture(grid, "flat", red, blue, 0)
    assert (flat == [255, 0, 0]).all()
    checker = render_texture(grid, "checker", red, blue, 0).reshape(256, 256, 3)
    assert (checker[:128, :128] == [255, 0, 0]).all() and (checker[:128, 128:] == [0, 0, 255]).all()
    assert (checker[128:, :128] == [0, 0, 255]).all() and (checker[128:, 128:] == [255, 0, 0]).all()
    gradient = render_texture(grid, "gradient", red, blue, 0).reshape(256, 256, 3)
    assert (np.diff(gradient[:, 0, 2].astype(int)) >= 0).all() and gradient[0, 0, 0] > 250 and gradient[-1, 0, 2] > 250
    faces = render_texture(sky, "gradient", red, blue, 0).reshape(6, 256, 256, 3).astype(int)
    assert faces[2, 128, 128, 0] == 255 and faces[3, 128, 128, 2] == 255, "+y face is the zenith, -y the nadir"
    assert abs(faces[0, 128, 128, 0] - 128) <= 1, "the horizon is half way"
    a, b = render_texture(grid, "noise", red, blue, 1), render_texture(grid, "noise", red, blue, 1)
    assert a.tobytes() == b.tobytes() != render_texture(grid, "noise", red, blue, 2).tobytes()
    a = a.reshape(256, 256, 3).astype(int)
    assert a[..., 1].max() == 0 and (a[..., 0] + a[..., 2] - 255).__abs__().max() <= 1, "a mix of rgb1 and rgb2"
    assert np.abs(np.diff(a[..., 0], axis=1)).max() <= 32, "smooth (per-texel noise would jump by up to 255)"
    assert np.abs(a[:, 0, 0] - a[:, -1, 0]).max() <= 32, "tiles seamlessly"
