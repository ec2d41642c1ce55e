"""Fast env construction (issue 15): compiled-model cache, own model copies, headless envs, lazy named indexers."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest

import sim2real as s2r
from sim2real.tasks import headless_options
from sim2real.tasks.models import compiled_model

TASKS = ["dmc/reacher-easy", "dmc/manipulator-bring_peg", "sim2real/arm-reach"]


def _model(env: object) -> object:
    return s2r.find_physics(env).model  # type: ignore[union-attr]


@pytest.mark.parametrize("task", TASKS)
def test_headless_env_steps_bitwise_like_the_textured_one(task: str) -> None:
    effects = [s2r.Mass(scale=s2r.Uniform(0.7, 1.3)), s2r.Damping(scale=s2r.Uniform(0.5, 2.0))]
    textured = s2r.wrap(s2r.make(task), *effects, seed=3)
    headless = s2r.wrap(s2r.make(task, textures=False), *effects, seed=3)
    assert _model(headless).ntex == 0 and _model(textured).ntex > 0  # type: ignore[attr-defined]
    for field in ("body_mass", "body_inertia", "geom_size", "geom_friction", "dof_damping", "actuator_gear"):
        assert np.array_equal(getattr(_model(headless), field), getattr(_model(textured), field)), field
    rng = np.random.default_rng(0)
    scale = 0.08 if task == "sim2real/arm-reach" else 1.0
    for episode in range(2):
        a, ia = textured.reset(seed=10 + episode)
        b, ib = headless.reset(seed=10 + episode)
        assert np.array_equal(a, b)
        assert ia["sim2real"]["params"] == ib["sim2real"]["params"]
        for _ in range(40):
            action = rng.uniform(-scale, scale, textured.action_space.shape).astype(np.float32)
            a, ra, ta, ua, _ = textured.step(action)
            b, rb, tb, ub, _ = headless.step(action)
            assert np.array_equal(a, b) and ra == rb and ta == tb and ua == ub


@pytest.mark.parametrize("textures", [True, False])
def test_every_env_owns_its_model_copy(textures: bool) -> None:
    first = s2r.make("dmc/reacher-easy", textures=textures)
    second = s2r.make("dmc/reacher-easy", textures=textures)
    m1, m2 = _model(first), _model(second)
    nominal = m2.body_mass.copy()  # type: ignore[attr-defined]
    m1.body_mass[:] *= 3.0  # type: ignore[attr-defined]
    m1.geom_size[:] *= 2.0  # type: ignore[attr-defined]
    assert np.array_equal(m2.body_mass, nominal)  # type: ignore[attr-defined]
    third = s2r.make("dmc/reacher-easy", textures=textures)  # the cached template was not written either
    assert np.array_equal(_model(third).body_mass, nominal)  # type: ignore[attr-defined]
    arms = [s2r.make("sim2real/arm-reach") for _ in range(2)]
    arms[0].unwrapped.model.dof_damping[:] = 7.0
    assert not np.array_equal(arms[1].unwrapped.model.dof_damping, arms[0].unwrapped.model.dof_damping)
    assert compiled_model("<mujoco/>") is not compiled_model("<mujoco/>")


def test_lazy_named_indexers_match_dm_control() -> None:
    from dm_control import suite
    from dm_control.mujoco import index

    env = s2r.make("dmc/manipulator-bring_ball", textures=False)
    physics = env.unwrapped.physics
    loaded = suite.load("manipulator", "bring_ball").physics
    axes = index.make_axis_indexers(loaded.model)
    for ours, struct, name in (
        (physics.named.model, loaded.model, "mjmodel"),
        (physics.named.data, loaded.data, "mjdata"),
    ):
        theirs = index.struct_indexer(struct, name, axes)._asdict()
        if name == "mjmodel":  # the headless model has no texture elements; every other field is indexed alike
            theirs = {k: v for k, v in theirs.items() if not k.startswith("tex")}
            assert sorted(k for k in ours._asdict() if not k.startswith("tex")) == sorted(theirs)
        else:
            assert sorted(ours._asdict()) == sorted(theirs)
    for field, key in (("body_mass", "ball"), ("geom_size", "ball"), ("jnt_range", "arm_shoulder"), ("xpos", "hand")):
        part = physics.named.model if hasattr(physics.model, field) else physics.named.data
        struct = loaded.named.model if hasattr(loaded.model, field) else loaded.named.data
        np.testing.assert_array_equal(getattr(part, field)[key], getattr(struct, field)[key])
    physics.named.model.body_mass["ball"] = 2.5  # writes through the named view reach the model
    assert physics.model.body_mass[physics.model.name2id("ball", "body")] == 2.5
    with pytest.raises(AttributeError, match="no attribute 'not_a_field'"):
        physics.named.model.not_a_field  # noqa: B018
    copied = physics.copy(share_model=False)  # a copy of a copy stays lazy and correct
    assert copied.named.model.body_mass["ball"] == 2.5


def test_textures_option_errors_name_the_argument() -> None:
    with pytest.raises(TypeError, match=r"`textures` must be a bool\. Received 'no'\."):
        s2r.make("dmc/reacher-easy", textures="no")
    with pytest.raises(ValueError, match=r"`textures` must be True when the env renders \(render_mode='rgb_array'\)"):
        s2r.make("sim2real/arm-reach", render_mode="rgb_array", textures=False)
    with pytest.raises(ValueError, match=r"`textures` must be True with pixels=True\. Received False\."):
        s2r.make("dmc/reacher-easy", pixels=True, textures=False)
    with pytest.raises(TypeError, match=r"Received unknown \['textures'\]"):
        s2r.make("dmc/jaco-reach_site", textures=False)


def test_headless_options_keep_textures_where_they_matter() -> None:
    assert headless_options("sim2real/arm-reach", {}) == {"textures": False}
    assert headless_options("dmc/reacher-easy", {"render_mode": "rgb_array"}) == {"render_mode": "rgb_array"}
    assert headless_options("dmc/reacher-easy", {"textures": True}) == {"textures": True}
    texture = s2r.Texture(textures="grid", pattern="checker")
    assert headless_options("dmc/reacher-easy", {}, [[s2r.Damping(scale=1.0)], [texture]]) == {}
    assert headless_options("model:arm.xml", {}) == {}
