"""One fused layer (issue 15): ``wrap(env, *physics, *signals)`` returns one wrapper / transform that is bitwise the
two layers it replaces (``wrap(wrap(env, *physics), *signals)``) for gymnasium, dm_env and TorchRL: observations,
rewards, ends, infos and draws, over several seeds and resets, with noise and latency, on a task we ship and on an
arm generated here."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from conftest import GENERATED_ARM, PHYSICS  # the fused layer's arm nobody designed for, and its effects

import sim2real as s2r
from noise_models import (
    ActionLatency,
    ActionNoise,
    Bias,
    ControlJitter,
    Gaussian,
    ObservationLatency,
    ObservationNoise,
    SampleAndHold,
)
from randomizers import Uniform
from sim2real.mjcf_env import MjcfEnv
from sim2real.wrappers import CorruptSignals, RandomizeAndCorrupt, RandomizePhysics

STACKS: dict[str, tuple[Any, ...]] = {
    "noise+latency": (
        ObservationNoise(Gaussian(std=0.01), Bias(Uniform(-0.02, 0.02))),
        ActionNoise(Gaussian(std=0.05)),
        ObservationLatency(steps=3),
        ActionLatency(seconds=0.02),
    ),
    "mid-step latency+hold": (
        ObservationNoise(Gaussian(std=0.02)),
        ActionLatency(steps=3),
        SampleAndHold(steps=4),
    ),
    "jitter": (ObservationNoise(Gaussian(std=0.01)), ActionLatency(steps=2), ControlJitter(delta=Uniform(-1.0, 1.0))),
}


def _arm() -> MjcfEnv:
    return MjcfEnv(xml=GENERATED_ARM, control_timestep=0.02, max_episode_steps=12)


def _make(task: str) -> Any:
    return _arm() if task == "generated" else s2r.make(task)


def _assert_same_info(a: Any, b: Any) -> None:
    assert a == b  # nested dicts of floats, tuples and bools compare exactly
    assert list(a.get("sim2real", {}).get("params", {})) == list(b.get("sim2real", {}).get("params", {}))


def _run_gym(env: Any, actions: np.ndarray, seeds: list[int | None]) -> list[Any]:
    out: list[Any] = []
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        out.append(("reset", obs.copy(), info))
        for a in actions:
            obs, reward, terminated, truncated, info = env.step(a)
            out.append(("step", obs.copy(), reward, terminated, truncated, info))
            if terminated or truncated:
                break
    return out


@pytest.mark.parametrize("task", ["dmc/reacher-easy", "generated"])
@pytest.mark.parametrize("stack", list(STACKS))
def test_gym_fused_is_bitwise_the_two_layers(task: str, stack: str) -> None:
    signals = STACKS[stack]
    fused = s2r.wrap(_make(task), *PHYSICS, *signals, seed=7)
    layered = s2r.wrap(s2r.wrap(_make(task), *PHYSICS, seed=7), *signals, seed=7)
    assert type(fused) is RandomizeAndCorrupt and fused.env is fused.unwrapped
    assert type(layered) is CorruptSignals and type(layered.env) is RandomizePhysics
    rng = np.random.default_rng(0)
    space = fused.action_space
    actions = rng.uniform(space.low, space.high, size=(15, *space.shape)).astype(space.dtype)
    seeds: list[int | None] = [3, None, 11, None]
    a, b = _run_gym(fused, actions, seeds), _run_gym(layered, actions, seeds)
    assert len(a) == len(b) > 30
    for x, y in zip(a, b, strict=True):
        assert x[0] == y[0]
        np.testing.assert_array_equal(x[1], y[1], strict=True)
        assert x[2:-1] == y[2:-1]
        _assert_same_info(x[-1], y[-1])
    assert fused.current_params == {**layered.env.current_params, **layered.current_params}
    model = s2r.find_physics(fused).model  # type: ignore[union-attr]
    nominal = s2r.find_physics(_make(task)).model  # type: ignore[union-attr]
    base = fused.release()
    assert base is fused.env
    np.testing.assert_array_equal(model.body_mass, nominal.body_mass)  # the nominal model, bitwise
    np.testing.assert_array_equal(model.dof_damping, nominal.dof_damping)
    layered.close()


def _finger() -> Any:
    from dm_control import suite

    from sim2real.adapters import DmEnvToGym

    return DmEnvToGym(suite.load("finger", "spin", task_kwargs={"random": 0}))


@pytest.mark.parametrize("noise", [True, False])
def test_gym_fused_delays_a_suite_env_actions_itself_as_the_hook_would(noise: bool) -> None:
    # finger-spin: 2 physics substeps per control step, 2 actuators. A whole-control-step latency on a suite env
    # is delayed by the fused layer itself (a ring of actions; SignalClock.ring_actions): the same commands reach
    # the same physics steps as through the physics-step hook the two layers use. Without action noise the caller's
    # action is copied into the ring: this caller writes its buffer again after every step.
    signals = (ObservationNoise(Gaussian(std=0.01)), ActionLatency(seconds=0.04))
    signals += (ActionNoise(Gaussian(std=0.05)),) if noise else ()
    fused = s2r.wrap(_finger(), *PHYSICS, *signals, seed=5)
    layered = s2r.wrap(s2r.wrap(_finger(), *PHYSICS, seed=5), *signals, seed=5)
    space = fused.action_space
    actions = np.random.default_rng(1).uniform(space.low, space.high, (40, *space.shape)).astype(space.dtype)
    buffer = np.zeros(space.shape, space.dtype)
    ctrl_a, ctrl_b = s2r.find_physics(fused).data.ctrl, s2r.find_physics(layered).data.ctrl  # type: ignore[union-attr]
    for seed in (2, None, 9):
        (oa, ia), (ob, ib) = fused.reset(seed=seed), layered.reset(seed=seed)
        assert fused._action_ring is not None and len(fused._action_ring) == 3  # 40 ms = 2 control steps
        assert layered.clock._ring is not None  # the two layers: the hook's ring of ctrl rows
        np.testing.assert_array_equal(oa, ob, strict=True)
        _assert_same_info(ia, ib)
        for a in actions:
            buffer[:] = a
            ra, rb = fused.step(buffer), layered.step(buffer.copy())
            np.testing.assert_array_equal(ra[0], rb[0], strict=True)
            assert ra[1:4] == rb[1:4]
            _assert_same_info(ra[4], rb[4])
            np.testing.assert_array_equal(ctrl_a, ctrl_b, strict=True)  # the delayed command, bitwise
            buffer[:] = 0.5  # the caller reuses its buffer
    assert ia["sim2real"]["params"]["action_latency_steps"] == 4  # physics steps
    fused.close()
    layered.close()


def test_gym_fused_leaves_the_delay_to_the_hook_where_the_action_is_not_the_command() -> None:
    # A task whose before_step scales the action, and a recorder hooked on the physics step after the fused layer
    # (it reads the command the env wrote, before the delay): the hook's ring of ctrl rows applies the latency.
    from sim2real.recording import RecordTrajectory

    env = s2r.make("dmc/reacher-easy")
    task = env.dm_env.task
    task.before_step = lambda action, physics: physics.set_control(2.0 * np.asarray(action))
    fused = s2r.wrap(env, *PHYSICS, ActionLatency(seconds=0.04), seed=1)
    fused.reset(seed=0)
    assert fused._action_ring is None and fused.clock._ring is not None
    ctrl = s2r.find_physics(fused).data.ctrl  # type: ignore[union-attr]
    sent = [np.array([0.3, -0.2]), np.array([0.1, 0.4]), np.array([-0.5, 0.5])]
    for k, a in enumerate(sent):
        fused.step(a)
        np.testing.assert_array_equal(ctrl, 2.0 * sent[k - 2] if k >= 2 else np.zeros(2), strict=True)
    fused.close()
    recorded = RecordTrajectory(s2r.wrap(s2r.make("dmc/reacher-easy"), *PHYSICS, ActionLatency(seconds=0.04), seed=1))
    recorded.reset(seed=0)
    assert recorded.env._action_ring is None
    recorded.close()


def test_gym_fused_hook_leaves_the_physics_step_for_a_ring_episode_and_comes_back_below_a_later_recorder() -> None:
    # While the fused layer delays the actions itself, its physics-step hook has nothing to do and leaves dm-control's
    # Physics.step (the class's step runs, no pass-through call). A recorder wrapped around it later (installed while
    # the hook is out) must still read the command the env wrote: at the next reset the hook comes back in its place,
    # below the recorder, and applies the delay there; once the recorder's hook is gone the hook may leave again.
    from sim2real.physics import _DmStepChain
    from sim2real.recording import RecordTrajectory

    fused = s2r.wrap(s2r.make("dmc/reacher-easy"), *PHYSICS, ActionLatency(seconds=0.04), seed=1)
    physics = fused.env.dm_env.physics
    fused.reset(seed=0)
    assert fused._action_ring is not None and "step" not in vars(physics)
    fused.step(np.array([0.2, 0.2]))
    recorded = RecordTrajectory(fused)  # hooked on the physics step while the fused layer's hook is out
    assert "step" in vars(physics)
    recorded.reset(seed=0)
    assert fused._action_ring is None and fused.clock._ring is not None  # the hook's ring of ctrl rows again
    chain = vars(physics)[_DmStepChain.ATTRIBUTE]
    assert [link.stepper for link in chain.links if not link.out] == [fused.clock._stepper, recorded._capture]
    ctrl = s2r.find_physics(fused).data.ctrl  # type: ignore[union-attr]
    sent = [np.array([0.3, -0.2]), np.array([0.1, 0.4]), np.array([-0.5, 0.5]), np.array([0.7, -0.1])]
    for k, a in enumerate(sent):
        recorded.step(a)
        np.testing.assert_array_equal(ctrl, sent[k - 2] if k >= 2 else np.zeros(2), strict=True)  # delayed below
    np.testing.assert_array_equal(recorded.to_log().ctrl[-4:], np.array(sent), strict=True)  # as the env wrote it
    recorded._remove()  # the recorder's hook alone (close() would close the fused layer too)
    assert [link.stepper for link in chain.links] == [fused.clock._stepper]
    fused.reset(seed=1)
    assert fused._action_ring is not None and "step" not in vars(physics)  # out again
    fused.close()
    assert "step" not in vars(physics) and chain.links == []


def test_physics_step_chain_leaves_someone_elses_step_alone() -> None:
    # Code outside sim2real that replaced Physics.step over the hook freezes the chain: the hook stays in (the
    # fused layer does not delay the actions itself), and closing the layer does not delete the other code's step.
    fused = s2r.wrap(s2r.make("dmc/reacher-easy"), *PHYSICS, ActionLatency(seconds=0.04), seed=1)
    physics = fused.env.dm_env.physics
    fused.reset(seed=0)
    fused.reset(seed=0)  # (the hook back in; then out again for this ring episode)
    assert fused._action_ring is not None
    fused.clock._remove.bypass(False)
    below = physics.step
    calls: list[int] = []

    def theirs(nstep: int = 1) -> None:
        calls.append(nstep)
        below(nstep)

    physics.step = theirs
    fused.reset(seed=1)
    assert fused._action_ring is None and physics.step is theirs  # frozen: the hook stays in, under theirs
    ctrl = s2r.find_physics(fused).data.ctrl  # type: ignore[union-attr]
    for k in range(3):
        fused.step(np.full(2, 0.1 * (k + 1)))
    np.testing.assert_array_equal(ctrl, np.full(2, 0.1), strict=True)  # the command of two steps before
    assert calls == [1, 1, 1]
    fused.close()
    assert physics.step is theirs


def test_gym_fused_keeps_the_reports_of_a_diverged_reset_and_step() -> None:
    """A reset that diverges under an extreme draw: the next step ends the episode, in both, identically."""
    physics = (s2r.Stiffness(set=1e12),)
    signals = (ObservationNoise(Gaussian(std=0.01)), ActionLatency(steps=2))
    fused = s2r.wrap(_arm(), *physics, *signals, seed=1)
    layered = s2r.wrap(s2r.wrap(_arm(), *physics, seed=1), *signals, seed=1)
    actions = np.ones((6, 3), np.float32)
    a, b = _run_gym(fused, actions, [0, 1]), _run_gym(layered, actions, [0, 1])
    assert any(x[-1]["sim2real"]["diverged"] for x in a)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x[1], y[1], strict=True)
        assert x[2:-1] == y[2:-1]
        _assert_same_info(x[-1], y[-1])


def test_gym_fused_spec_make_and_errors() -> None:
    signals = (ObservationNoise(Bias(0.25)), ActionNoise(Gaussian(std=0.1)))
    env = s2r.wrap(s2r.make("gym/Reacher-v5"), *PHYSICS[:2], *signals, seed=3)
    assert isinstance(env, RandomizeAndCorrupt)
    twin = env.spec.make()  # type: ignore[union-attr]
    assert type(twin) is RandomizeAndCorrupt and twin.randomizer.effects == env.randomizer.effects
    o1, i1 = env.reset(seed=2)
    o2, i2 = twin.reset(seed=2)
    np.testing.assert_array_equal(o1, o2)
    assert i1 == i2
    with pytest.raises(ValueError, match=r"`action` must have the shape of the env's action space, \(2,\)"):
        env.step(np.zeros(3, np.float32))
    env.close()
    twin.close()


# -- dm_env ---------------------------------------------------------------------------------------------------


def _dm(task: str) -> Any:
    from sim2real.tasks.suite import suite_env

    domain, name = task.split("-")
    return suite_env(domain, name, textures=False)


@pytest.mark.parametrize("task", ["reacher-easy", "manipulator-bring_ball"])
def test_dm_env_fused_is_bitwise_the_two_layers(task: str) -> None:
    from sim2real.wrappers import CorruptSignalsDmEnv, RandomizeAndCorruptDmEnv, RandomizePhysicsDmEnv

    signals = STACKS["noise+latency"]
    fused = s2r.wrap(_dm(task), *PHYSICS, *signals, seed=5)
    layered = CorruptSignalsDmEnv(RandomizePhysicsDmEnv(_dm(task), PHYSICS, seed=5), signals, seed=5)
    assert type(fused) is RandomizeAndCorruptDmEnv
    assert fused.physics is fused._env.physics
    for env in (fused, layered):  # the same initial states (the tasks' own RandomState)
        env.task.random.seed(42)
    spec = fused.action_spec()
    actions = np.random.default_rng(1).uniform(spec.minimum, spec.maximum, size=(40, *spec.shape))
    n_steps = 0
    for episode in range(3):
        ta, tb = fused.reset(), layered.reset()
        assert fused.current_params == layered.current_params and fused.diverged == layered.diverged
        for k in range(len(actions) if episode < 2 else 5):
            for key in ta.observation:
                np.testing.assert_array_equal(ta.observation[key], tb.observation[key], strict=True)
            assert (ta.step_type, ta.reward, ta.discount) == (tb.step_type, tb.reward, tb.discount)
            ta, tb = fused.step(actions[k]), layered.step(actions[k])
            n_steps += 1
    assert n_steps == 85
    fused.close()
    layered.close()


# -- TorchRL --------------------------------------------------------------------------------------------------


def _torchrl_env(task: str) -> Any:
    from torchrl.envs import GymWrapper

    return GymWrapper(_make(task))


@pytest.mark.parametrize("task", ["dmc/reacher-easy", "generated"])
def test_torchrl_fused_is_bitwise_the_compose_of_two(task: str) -> None:
    import torch
    from torchrl.envs import Compose, TransformedEnv
    from torchrl.envs.utils import check_env_specs

    from sim2real.wrappers import CorruptSignalsTransform, RandomizeAndCorruptTransform, RandomizePhysicsTransform

    signals = STACKS["noise+latency"]
    fused = s2r.wrap(_torchrl_env(task), *PHYSICS, *signals, seed=9)
    layered = TransformedEnv(
        _torchrl_env(task), Compose(RandomizePhysicsTransform(PHYSICS, 9), CorruptSignalsTransform(signals, 9))
    )
    assert type(fused.transform) is RandomizeAndCorruptTransform
    twin = fused.transform.clone()  # its physics half answers to the clone, not to the original
    assert twin.physics is not fused.transform.physics and twin.physics.__dict__["_owner"] is twin
    for env in (fused, layered):  # on both: it resets them, and the episode counters must stay level
        check_env_specs(env, seed=0)
    assert fused.full_observation_spec == layered.full_observation_spec
    assert fused.transform.param_names == layered.transform[0].param_names
    assert fused.transform.signal_param_names == layered.transform[1].param_names
    torch.manual_seed(0)
    actions = fused.full_action_spec["action"].rand((25,))

    def policy_of(env: Any) -> Any:
        steps = iter(actions)

        def policy(td: Any) -> Any:
            td.set("action", next(steps).clone())
            return td

        return policy

    for seed in (1, 2):
        fused.set_seed(seed)
        layered.set_seed(seed)
        ta = fused.rollout(25, policy_of(fused), break_when_any_done=False)
        tb = layered.rollout(25, policy_of(layered), break_when_any_done=False)
        assert set(ta.keys(True, True)) == set(tb.keys(True, True))
        for key in ta.keys(True, True):
            assert ta.get(key).dtype == tb.get(key).dtype
            assert torch.equal(ta.get(key), tb.get(key)), key
    assert fused.transform.current_params == {
        **layered.transform[0].current_params,
        **layered.transform[1].current_params,
    }
    fused.close()
    layered.close()


def test_gym_fused_hot_step_reports_draws_changed_mid_episode() -> None:
    # The hot step binds the episode's merged draws once; a change of the draws mid-episode (restore_nominal, or
    # the randomizer applied again) replaces the physics dict, and the next step's report follows it.
    env = s2r.wrap(s2r.make("dmc/reacher-easy"), *PHYSICS, *STACKS["noise+latency"], seed=4)
    _, info = env.reset(seed=1)
    assert env._hot
    action = np.zeros(env.action_space.shape, env.action_space.dtype)
    drawn = env.step(action)[4]["sim2real"]["params"]
    assert drawn == info["sim2real"]["params"]
    env.restore_nominal()
    nominal = env.step(action)[4]["sim2real"]["params"]
    assert nominal == {**env.randomizer.nominal_params(), **env.signal_params} != drawn
    env.close()
