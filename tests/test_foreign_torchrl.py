"""TorchRL envs written the way other people write them: nested Composite observations, an action entry of their
own, TorchRL's own action repeat, batched envs, and what the TensorDicts report (substeps, pushes)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real as s2r
from noise_models import ActionLatency, ActionNoise, Bias, ControlJitter, Gaussian, ObservationLatency, ObservationNoise
from randomizers import Choice, Uniform
from tests.test_foreign_envs import ARM_XML, MOCAP_XML, RebuiltScene, _user_mujoco_env

pytest.importorskip("torchrl")


def _handle(env: Any) -> Any:
    handle = s2r.find_physics(env)
    assert handle is not None
    return handle


def _nested_torchrl_arm() -> Any:
    """A TorchRL env as users write one: ``EnvBase`` around MuJoCo, joint state nested under ``"robot"``."""
    import torch
    from tensordict import TensorDict
    from torchrl.data import Bounded, Composite, Unbounded
    from torchrl.envs import EnvBase

    class NestedArm(EnvBase):
        n_substeps = 4

        def __init__(self) -> None:
            super().__init__(device="cpu")
            self.model = mujoco.MjModel.from_xml_string(ARM_XML)
            self.data = mujoco.MjData(self.model)
            f64 = torch.float64
            self.observation_spec = Composite(
                robot=Composite(qpos=Unbounded((2,), dtype=f64), qvel=Unbounded((2,), dtype=f64)),
                tip=Unbounded((3,), dtype=torch.float32),
            )
            self.action_spec = Bounded(-1.0, 1.0, (2,), dtype=f64)
            self.reward_spec = Unbounded((1,))

        def _obs(self) -> dict[str, Any]:
            d = self.data
            robot = {"qpos": torch.tensor(d.qpos.copy()), "qvel": torch.tensor(d.qvel.copy())}
            return {"robot": robot, "tip": torch.tensor(d.xpos[2].astype(np.float32))}

        def _reset(self, td: Any) -> Any:
            mujoco.mj_resetData(self.model, self.data)
            mujoco.mj_forward(self.model, self.data)
            done = torch.zeros(1, dtype=torch.bool)
            return TensorDict({**self._obs(), "done": done, "terminated": done.clone()}, [])

        def _simulate(self, nstep: int) -> None:
            mujoco.mj_step(self.model, self.data, nstep=nstep)

        def _step(self, td: Any) -> Any:
            self.data.ctrl[:] = td["action"].numpy()
            self._simulate(self.n_substeps)
            done = torch.zeros(1, dtype=torch.bool)
            return TensorDict({**self._obs(), "reward": torch.zeros(1), "done": done, "terminated": done.clone()}, [])

        def _set_seed(self, seed: int | None) -> None:
            pass

    return NestedArm()


@pytest.mark.parametrize("physics", [False, True], ids=["signals", "fused"])
def test_noise_reaches_nested_torchrl_observations(physics: bool) -> None:
    from torchrl.envs.utils import check_env_specs

    effects = (s2r.Mass(scale=1.0),) if physics else ()
    env = s2r.wrap(_nested_torchrl_arm(), *effects, ObservationNoise(Bias(0.5)), seed=0)
    check_env_specs(env, seed=0)
    td = env.reset()
    bare = _nested_torchrl_arm().reset()
    for key in (("robot", "qpos"), ("robot", "qvel"), "tip"):  # the nested entries were left untouched before
        np.testing.assert_allclose(td[key].numpy(), bare[key].numpy() + 0.5)
        assert td[key].dtype == bare[key].dtype
    td = env.rand_step(td)
    assert td["next", "robot", "qvel"].dtype == bare["robot", "qvel"].dtype


def test_nested_torchrl_entries_are_selected_by_dotted_name_or_tuple_key() -> None:
    from torchrl.envs import TransformedEnv

    from sim2real.wrappers import CorruptSignalsTransform

    env = s2r.wrap(_nested_torchrl_arm(), ObservationNoise(Bias(0.5), select="robot.qv*"), seed=0)
    td = env.reset()
    np.testing.assert_array_equal(td["robot", "qpos"].numpy(), [0.0, 0.0])
    np.testing.assert_array_equal(td["robot", "qvel"].numpy(), [0.5, 0.5])
    transform = CorruptSignalsTransform([ObservationNoise(Bias(0.5))], seed=0, observation_keys=[("robot", "qpos")])
    td = TransformedEnv(_nested_torchrl_arm(), transform).reset()
    np.testing.assert_array_equal(td["robot", "qpos"].numpy(), [0.5, 0.5])
    np.testing.assert_array_equal(td["robot", "qvel"].numpy(), [0.0, 0.0])
    bad = CorruptSignalsTransform([ObservationNoise(Bias(0.5))], seed=0, observation_keys=[("robot", "x")])
    with pytest.raises(ValueError, match=r"^`observation_keys` names \[\('robot', 'x'\)\], which the env does not"):
        TransformedEnv(_nested_torchrl_arm(), bad).reset()


@pytest.mark.parametrize("physics", [False, True])
def test_torchrl_selects_the_parts_of_a_flat_dm_control_observation_as_gymnasium_does(physics: bool) -> None:
    # GymWrapper(DmEnvToGym(...)) has one flat "observation" entry; its parts (position, to_target, velocity on
    # reacher) are named by the gym env's observation_layout, so select="position" works on the TorchRL side too,
    # with the gym side's report names, and only the position entries are noisy. (It raised: "`select` names key
    # 'position', which the signal does not have. Known keys: 'observation'.")
    import torch
    from torchrl.envs import GymWrapper

    effects = (s2r.Damping(scale=Uniform(0.5, 2.0)),) if physics else ()
    models = (ObservationNoise(Gaussian(std=Uniform(0.05, 0.1)), select="position"),)
    adapter = s2r.make("dmc/reacher-easy")
    torch_env = s2r.wrap(GymWrapper(adapter), *effects, *models, seed=3)
    gym_env = s2r.wrap(s2r.make("dmc/reacher-easy"), *effects, *models, seed=3)
    td = torch_env.reset()
    _, info = gym_env.reset(seed=1)
    transform = torch_env.transform[-1] if hasattr(torch_env.transform, "__getitem__") else torch_env.transform
    names = [k for k in transform.current_params if k.startswith("obs_")]
    assert (
        names
        == [k for k in info["sim2real"]["params"] if k.startswith("obs_")]
        == [
            "obs_noise_std[0]",
            "obs_noise_std[1]",
        ]
    )
    for _ in range(3):
        td = torch_env.step(td.set("action", torch.zeros(2)))["next"]
        noisy, exact = td["observation"].numpy(), adapter.observe()  # observe(): the physics' own, again
        assert (noisy[:2] != exact[:2]).all() and (noisy[2:] == exact[2:]).all()
    torch_env.close()
    gym_env.close()


@pytest.mark.parametrize("native", [False, True])
def test_torchrl_repeating_an_env_that_steps_frame_skip_itself_is_warned_about(native: bool) -> None:
    # An EnvBase with a `frame_skip` instance attribute gets a FrameSkipTransform from TorchRL itself, which repeats
    # the whole step; sim2real reads the attribute as the env's physics steps per step (gymnasium's meaning), so a
    # latency counts frame_skip ** 2 physics steps per TorchRL step (HC's journey 3: 25 for 5). Said once at wrap
    # time; not when the class says it implements frame_skip itself (`_has_frame_skip = True`: no transform added).
    import warnings

    from torchrl.envs import TransformedEnv

    arm = type(_nested_torchrl_arm())  # (no frame_skip attribute: TorchRL leaves it alone)

    class Skipping(arm):  # type: ignore[misc, valid-type]
        _has_frame_skip = native

        def __init__(self) -> None:
            super().__init__()
            self.frame_skip = 4

        def _step(self, td: Any) -> Any:
            self.n_substeps = self.frame_skip
            return super()._step(td)

    env = Skipping()
    assert isinstance(env, TransformedEnv) != native  # TorchRL's own FrameSkipTransform(4) unless native
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        wrapped = s2r.wrap(env, ActionLatency(steps=8), seed=0)
        wrapped.reset()
    said = [str(w.message) for w in caught if "FrameSkipTransform(4)" in str(w.message)]
    if native:
        assert said == []
    else:
        assert said == [
            "TorchRL repeats each step of Skipping 4 times (it appends FrameSkipTransform(4) to an EnvBase with a "
            "`frame_skip` attribute), and sim2real reads that attribute as the env's physics steps per step: latency "
            "and jitter count 16 physics steps per TorchRL step. If the env's _step already runs `frame_skip` physics "
            "steps, set `_has_frame_skip = True` on its class so TorchRL does not repeat it; if it runs one, name the "
            "attribute otherwise."
        ]
    wrapped.close()


# -- TorchRL's own action repeat (GymWrapper(..., frame_skip=k)) -------------------------------------------------


def _torchrl_path(env: Any, actions: np.ndarray) -> tuple[dict[str, float], np.ndarray]:
    import torch

    td = env.reset()
    out = []
    for a in actions:
        td["action"] = torch.as_tensor(a, dtype=env.action_spec.dtype)
        td = env.step(td)["next"]
        out.append(td["observation"].numpy().copy())
    return dict(zip(env.transform.param_names, td["sim2real_signal_params"].tolist(), strict=True)), np.array(out)


def _reference(env: Any, actions: np.ndarray, repeat: int, action_lag: int = 0, obs_lag: int = 0) -> np.ndarray:
    """The bare env stepped by hand: ctrl applied ``action_lag`` physics steps late; an observation taken at
    physics step t arrives at t + ``obs_lag`` (the reset one at once) and the newest arrived one is seen."""
    env.reset(seed=0)
    model, data = env.unwrapped.model, env.unwrapped.data
    per_step = repeat * env.unwrapped.frame_skip
    taken, seen, t = [(0, env.unwrapped._get_obs())], [], 0
    for _ in actions:
        for _ in range(repeat):
            for _ in range(env.unwrapped.frame_skip):
                source = t - action_lag
                data.ctrl[:] = actions[source // per_step] if source >= 0 else 0.0
                mujoco.mj_step(model, data)
                t += 1
            mujoco.mj_rnePostConstraint(model, data)
        taken.append((t, env.unwrapped._get_obs()))
        seen.append([obs for stamp, obs in taken if stamp == 0 or stamp + obs_lag <= t][-1])
    return np.array(seen)


@pytest.mark.parametrize("repeat", [1, 2])
@pytest.mark.parametrize(
    ("model", "lags"),
    [(ActionLatency(steps=8), (8, 0)), (ActionLatency(steps=6), (6, 0)), (ObservationLatency(steps=6), (0, 6))],
    ids=["action-whole-steps", "action-mid-step", "observation"],
)
def test_physics_rate_latency_under_torchrl_frame_skip_is_what_is_reported(
    tmp_path: Any, repeat: int, model: Any, lags: tuple[int, int]
) -> None:
    from torchrl.envs import GymWrapper

    path = str(tmp_path / "arm.xml")
    with open(path, "w") as f:
        f.write(ARM_XML)
    env = s2r.wrap(GymWrapper(_user_mujoco_env(path, 4), frame_skip=repeat), model, seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (10, 2)).astype(np.float32)  # the env's action dtype
    params, seen = _torchrl_path(env, actions)
    side = "action" if isinstance(model, ActionLatency) else "obs"
    assert params[f"{side}_latency_steps"] == max(lags)
    # With frame_skip=2, a latency of whole control steps delayed the command by 2 TorchRL steps for the first half of
    # each step and not at all for the second, and the observation by 2 TorchRL steps (16 physics steps, not 6).
    np.testing.assert_array_equal(seen, _reference(_user_mujoco_env(path, 4), actions, repeat, *lags))


def test_mocap_action_latency_under_torchrl_frame_skip_counts_torchrl_steps(tmp_path: Any) -> None:
    from torchrl.envs import GymWrapper

    path = str(tmp_path / "mocap.xml")
    with open(path, "w") as f:
        f.write(MOCAP_XML)
    actions = np.random.default_rng(1).uniform(-1, 1, (6, 3)).astype(np.float32)
    env = s2r.wrap(
        GymWrapper(_user_mujoco_env(path, 20, mocap=True), frame_skip=2), ActionLatency(seconds=0.08), seed=0
    )
    params, seen = _torchrl_path(env, actions)
    assert env.transform.action_latency_path == "action"
    # 0.08 s is one TorchRL step of 2 x 20 physics steps (it was applied as 2 steps, 0.16 s, and reported as 0.08 s)
    assert (params["action_latency"], params["action_latency_steps"], params["action_latency_control_steps"]) == (
        0.08,
        40.0,
        1.0,
    )
    late = GymWrapper(_user_mujoco_env(path, 20, mocap=True), frame_skip=2)
    _, expected = _torchrl_path_bare(late, np.vstack([np.zeros((1, 3), np.float32), actions[:-1]]))
    np.testing.assert_array_equal(seen, expected)


def _torchrl_path_bare(env: Any, actions: np.ndarray) -> tuple[None, np.ndarray]:
    import torch

    td = env.reset()
    out = []
    for a in actions:
        td["action"] = torch.as_tensor(a)
        td = env.step(td)["next"]
        out.append(td["observation"].numpy().copy())
    return None, np.array(out)


# -- TorchRL envs whose action entry is not "action" -----------------------------------------------------------


def _keyed_torchrl_arm() -> Any:
    """A TorchRL env whose action is ``("arm", "torque")``."""
    import torch
    from tensordict import TensorDict
    from torchrl.data import Bounded, Composite, Unbounded
    from torchrl.envs import EnvBase

    class KeyedArm(EnvBase):
        def __init__(self) -> None:
            super().__init__(device="cpu")
            self.model = mujoco.MjModel.from_xml_string(ARM_XML)
            self.data = mujoco.MjData(self.model)
            self.n_substeps = 4
            self.observation_spec = Composite(qpos=Unbounded((2,), dtype=torch.float64))
            self.action_spec = Composite(arm=Composite(torque=Bounded(-1.0, 1.0, (2,), dtype=torch.float64)))
            self.reward_spec = Unbounded((1,))

        def _out(self, **extra: Any) -> Any:
            done = torch.zeros(1, dtype=torch.bool)
            qpos = torch.tensor(self.data.qpos.copy())
            return TensorDict({"qpos": qpos, "done": done, "terminated": done.clone(), **extra}, [])

        def _reset(self, td: Any) -> Any:
            mujoco.mj_resetData(self.model, self.data)
            return self._out()

        def _simulate(self, nstep: int) -> None:
            mujoco.mj_step(self.model, self.data, nstep=nstep)

        def _step(self, td: Any) -> Any:
            self.data.ctrl[:] = td["arm", "torque"].numpy()
            self._simulate(self.n_substeps)
            return self._out(reward=torch.zeros(1))

        def _set_seed(self, seed: int | None) -> None:
            pass

    return KeyedArm()


def test_signal_models_use_a_torchrl_envs_own_action_key() -> None:
    import torch
    from torchrl.envs.utils import check_env_specs

    for models in ((ObservationNoise(Gaussian(std=0.1)),), (ActionNoise(Bias(0.25)), ActionLatency(steps=4))):
        env = s2r.wrap(_keyed_torchrl_arm(), *models, seed=0)  # KeyError: 'action' before, whatever the models
        check_env_specs(env, seed=0)
    data = _handle(env).data
    td = env.reset()
    td["arm", "torque"] = torch.tensor([0.1, -0.2], dtype=torch.float64)
    env.step(td)
    env.step(td)
    np.testing.assert_allclose(data.ctrl, [0.35, 0.05])  # the noisy command, one control step (4 physics steps) late


# -- batched envs, rebuilt models and what the TensorDicts report ----------------------------------------------


def test_torchrl_draws_reach_a_rebuilt_model() -> None:
    from torchrl.envs import GymWrapper

    env = s2r.wrap(GymWrapper(RebuiltScene()), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=0)
    for _ in range(2):
        td = env.reset()
        (mass,) = td["sim2real_params"].tolist()
        assert mass == _handle(env).model.body_mass[1] != 1.0


def test_a_batched_torchrl_env_is_refused_with_the_per_worker_recipe() -> None:
    from torchrl.envs import GymEnv, SerialEnv

    for effects in ((ObservationNoise(Gaussian(std=0.1)),), (s2r.Mass(scale=Uniform(0.5, 2.0)),)):
        # Before: a RecursionError (signals: TorchRL's batched __getattr__) or "has no MuJoCo model" (physics).
        with pytest.raises(TypeError, match=r"^`env` is a batched TorchRL env \(SerialEnv, batch_size \[2\]\): wrap"):
            s2r.wrap(SerialEnv(2, lambda: GymEnv("InvertedPendulum-v5")), *effects, seed=0)
    recipe = SerialEnv(
        2,
        [
            lambda i=i: s2r.wrap(GymEnv("InvertedPendulum-v5"), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=(0, i))
            for i in range(2)
        ],
    )
    first, second = recipe.reset()["sim2real_params"].tolist()
    assert first != second
    recipe.close()


@pytest.mark.parametrize("repeat", [1, 2])
def test_torchrl_reports_the_substeps_control_jitter_applied(repeat: int) -> None:
    from torchrl.envs import GymWrapper
    from torchrl.envs.utils import check_env_specs

    jitter = ControlJitter(Choice((-2.0, 0.0, 3.0)))
    env = s2r.wrap(GymWrapper(gym.make("InvertedPendulum-v5"), frame_skip=repeat), jitter, seed=0)
    check_env_specs(env, seed=0)  # the per-step draw was in no TensorDict key before
    data = _handle(env).data
    td = env.reset()
    applied, reported = [], []
    for _ in range(12):
        start = data.time
        td = env.rand_step(td)["next"]
        applied.append(round((data.time - start) / 0.02))  # InvertedPendulum-v5: 0.02 s per physics step
        reported.append(int(td["sim2real_substeps"]))
    assert reported == applied and len(set(applied)) > 1


@pytest.mark.parametrize("signals", [False, True], ids=["physics", "fused"])
def test_torchrl_reports_the_pushes_each_step_applied(signals: bool) -> None:
    from torchrl.envs import GymEnv
    from torchrl.envs.utils import check_env_specs

    push = s2r.Push(force=Uniform(1.0, 2.0), interval=Uniform(2.0, 3.0), bodies="object")
    models = (ObservationNoise(Gaussian(std=0.01)),) if signals else ()
    env = s2r.wrap(GymEnv("Pusher-v5"), push, *models, seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(12)
    rows = td["next", "sim2real_pushes"][:, 0].numpy()  # the pushes were in no TensorDict key before
    physics = env.transform.physics if signals else env.transform
    events = physics.randomizer.events
    body = _handle(env).model.body("object").id
    assert len(events) >= 3
    for event in events:
        np.testing.assert_array_equal(rows[event.step - 1], [body, *event.force])
    started = {event.step - 1 for event in events}
    assert all(rows[k, 0] == -1.0 for k in range(12) if k not in started)


def test_a_second_physics_or_signal_layer_on_a_torchrl_env_is_refused() -> None:
    from torchrl.envs import GymEnv
    from torchrl.envs.utils import check_env_specs

    inner = s2r.wrap(GymEnv("InvertedPendulum-v5"), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=0)
    # Before: the second transform's "sim2real_params" replaced the first's (the masses' draws were in no key).
    with pytest.raises(ValueError) as err:
        s2r.wrap(inner, s2r.Damping(scale=Uniform(0.5, 2.0)), seed=1)
    assert str(err.value) == (
        "`env` already has a sim2real physics transform (RandomizePhysicsTransform) writing 'sim2real_params': give "
        "every physics effect to one sim2real.wrap call (a second transform would overwrite its draws)."
    )
    signals = s2r.wrap(GymEnv("InvertedPendulum-v5"), ObservationNoise(Gaussian(std=0.1)), seed=0)
    with pytest.raises(ValueError, match=r"^`env` already has a sim2real signal transform \(CorruptSignalsTransform\)"):
        s2r.wrap(signals, ActionLatency(steps=1), seed=1)
    # The documented composition, physics first and signals around it, still stacks.
    layered = s2r.wrap(
        s2r.wrap(GymEnv("InvertedPendulum-v5"), s2r.Mass(scale=Uniform(0.5, 2.0)), seed=0),
        ObservationNoise(Gaussian(std=0.1)),
        seed=0,
    )
    check_env_specs(layered, seed=0)
