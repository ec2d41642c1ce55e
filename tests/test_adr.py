"""Automatic domain randomisation (issue 13): the controller, its streams, its state and the env APIs."""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real
from randomizers import (
    ADR,
    ADRRandomizer,
    Damping,
    Episode,
    Friction,
    LogUniform,
    Mass,
    Normal,
    Pin,
    Uniform,
)
from randomizers.adr_randomizer import BOUNDARY_STREAM
from randomizers.seeding import stream

SLIDER = """<mujoco><option timestep="0.01"/><worldbody>
<body name="cart"><joint name="slide" type="slide" axis="1 0 0" damping="1"/>
<geom name="block" type="box" size=".1 .1 .1" mass="1" contype="0" conaffinity="0"/></body></worldbody>
<actuator><motor name="push" joint="slide" gear="1" ctrlrange="-1 1"/></actuator></mujoco>"""

DAMPING = "Damping[joints=slide]"
FRICTION = "Friction[geoms=block]"


class Slider(gym.Env):
    """A 1-D slider pushed with a constant force for 20 control steps; success when it ends past ``goal``.

    More damping means less distance, so success holds exactly for damping below a threshold; the block's
    friction never matters (the geom has no contacts).
    """

    def __init__(self, goal: float = 0.0) -> None:
        self.model = mujoco.MjModel.from_xml_string(SLIDER)
        self.data = mujoco.MjData(self.model)
        self.goal = goal
        self.t = 0
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def _obs(self) -> np.ndarray:
        return np.array([self.data.qpos[0], self.data.qvel[0]])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self.t = 0
        return self._obs(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        self.data.ctrl[:] = action
        mujoco.mj_step(self.model, self.data, nstep=5)
        self.t += 1
        x = float(self.data.qpos[0])
        done = self.t >= 20
        return self._obs(), x if done else 0.0, False, done, ({"success": x >= self.goal} if done else {})


def distance(damping_scale: float) -> float:
    """How far the scripted policy pushes the slider in one episode at this damping."""
    env = Slider()
    env.model.dof_damping[0] *= damping_scale
    env.reset()
    for _ in range(20):
        env.step(np.ones(1))
    return float(env.data.qpos[0])


THRESHOLD = 3.1  # success holds for damping scale <= 3.1 (distance is monotone in damping)


def slider_adr(**kwargs: Any) -> ADR:
    args: dict[str, Any] = dict(delta=0.25, m=3, t_low=0.2, t_high=0.6, p_boundary=1.0)
    args.update(kwargs)
    return ADR(
        [Damping(scale=Uniform(0.0, 10.0), joints="slide"), Friction(scale=Uniform(0.5, 2.0), geoms="block")], **args
    )


def drive(env: Any, episodes: int) -> list[np.ndarray]:
    """The scripted policy (full push) for ``episodes`` episodes; returns every observation."""
    seen = []
    for _ in range(episodes):
        obs, _ = env.reset()
        seen.append(obs)
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(np.ones(1, np.float32))
            seen.append(obs)
            done = terminated or truncated
    return seen


# -- the toy task: ranges grow to the solvable interval and stop -----------------------------------------------
def test_range_grows_to_the_threshold_and_irrelevant_parameter_to_its_limit() -> None:
    assert distance(3.0) > distance(THRESHOLD) > distance(3.25)
    adr = slider_adr()
    env = sim2real.wrap(Slider(goal=distance(THRESHOLD)), adr=adr, seed=0)
    drive(env, 400)
    low, high = adr.ranges[DAMPING]
    assert low == 0.0  # less damping always succeeds: down to the hard limit
    assert abs(high - THRESHOLD) <= 0.25  # the upper bound stops at the threshold, within one delta
    assert adr.ranges[FRICTION] == (0.5, 2.0)  # irrelevant: both boundaries at their hard limits
    hist = adr.history
    uppers = [row[0] for row in hist.high]
    assert max(uppers) == pytest.approx(3.25)  # never one step beyond the first failing value
    assert hist.frames[0] == 0 and hist.frames[-1] <= adr.frames == 400 * 20
    assert list(hist.frames) == sorted(hist.frames)
    assert hist.entropy[0] == -math.inf and hist.entropy[-1] == pytest.approx(adr.entropy())
    assert adr.entropy() == pytest.approx((math.log(high - low) + math.log(1.5)) / 2)


def test_toy_run_is_deterministic_with_the_seed() -> None:
    runs = []
    for seed in (0, 0, 1):
        adr = slider_adr()
        env = sim2real.wrap(Slider(goal=distance(THRESHOLD)), adr=adr, seed=seed)
        obs = drive(env, 60)
        runs.append((adr.state(), np.array(obs)))
    assert runs[0][0] == runs[1][0]
    assert runs[0][1].tobytes() == runs[1][1].tobytes()  # bitwise-identical trajectories
    assert runs[0][0]["history"] != runs[2][0]["history"]  # another seed pins other boundaries


# -- the algorithm, step by step ------------------------------------------------------------------------------
def test_buffer_mean_moves_one_boundary_and_clears() -> None:
    adr = ADR([Damping(scale=Uniform(0.0, 2.0))], delta=0.5, m=2, t_low=0.2, t_high=0.8)
    up = Pin("Damping[joints=*]", "high", 1.0)
    assert adr.record(up, 1.0, 10) is False
    assert adr.buffers[("Damping[joints=*]", "high")] == [1.0]
    assert adr.record(up, 0.5, 10) is False  # mean 0.75: between the thresholds, nothing moves, buffer cleared
    assert adr.buffers[("Damping[joints=*]", "high")] == []
    adr.record(up, 1.0)
    assert adr.record(up, 0.8) is True
    assert adr.ranges["Damping[joints=*]"] == (1.0, 1.5)
    assert adr.record(up, 1.0) is False and adr.stale == 1  # the boundary moved: a result at 1.0 is stale
    top = Pin("Damping[joints=*]", "high", 1.5)
    adr.record(top, 1.0), adr.record(top, 1.0)
    assert adr.ranges["Damping[joints=*]"] == (1.0, 2.0)
    adr.record(Pin("Damping[joints=*]", "high", 2.0), 1.0), adr.record(Pin("Damping[joints=*]", "high", 2.0), 1.0)
    assert adr.ranges["Damping[joints=*]"] == (1.0, 2.0)  # the hard limit holds
    down = Pin("Damping[joints=*]", "low", 1.0)
    adr.record(down, 0.0), adr.record(down, 0.1)
    assert adr.ranges["Damping[joints=*]"] == (1.0, 2.0)  # narrowing stops at the initial range (the point 1.0)
    adr.record(top := Pin("Damping[joints=*]", "high", 2.0), 0.2), adr.record(top, 0.0)
    assert adr.ranges["Damping[joints=*]"] == (1.0, 1.5)
    assert adr.frames == 20
    assert len(adr.history.frames) == 4  # start + three moves


def test_loguniform_moves_in_log_space_and_entropy_is_its_own() -> None:
    adr = ADR([Mass(scale=LogUniform(0.25, 4.0))], delta=math.log(2.0), m=1, t_low=0.2, t_high=0.8)
    adr.record(Pin("Mass[bodies=*]", "high", 1.0), 1.0)
    adr.record(Pin("Mass[bodies=*]", "low", 1.0), 1.0)
    lo, hi = adr.ranges["Mass[bodies=*]"]
    assert lo == pytest.approx(0.5) and hi == pytest.approx(2.0)
    # differential entropy of a log-uniform value on [a, b]: log(log(b/a)) + (log a + log b)/2
    assert adr.entropy() == pytest.approx(math.log(math.log(4.0)))


def test_metric_auto_success_return_and_callable() -> None:
    episode = Episode(episode_return=3.5, length=10, success=True)
    assert slider_adr().score(episode) == 1.0
    assert slider_adr().score(Episode(3.5, 10)) == 3.5
    assert slider_adr(metric="return").score(episode) == 3.5
    assert slider_adr(metric=lambda e: e.length / 100).score(episode) == 0.1
    with pytest.raises(ValueError, match="no success flag"):
        slider_adr(metric="success").score(Episode(3.5, 10))


# -- bad input ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"t_low": 0.8, "t_high": 0.5}, "`t_low` of ADR must be < `t_high`. Received t_low=0.8, t_high=0.5."),
        ({"t_low": 0.5, "t_high": 0.5}, "`t_low` of ADR must be < `t_high`. Received t_low=0.5, t_high=0.5."),
        ({"p_boundary": 1.5}, "`p_boundary` of ADR must be in [0, 1]. Received 1.5."),
        ({"p_boundary": -0.1}, "`p_boundary` of ADR must be in [0, 1]. Received -0.1."),
        ({"m": 0}, "`m` of ADR must be an int >= 1. Received 0."),
        ({"delta": 0.0}, "`delta` of ADR must be > 0 (for 'Damping[joints=slide]'). Received 0.0."),
        (
            {"initial": {DAMPING: (2.0, 1.0)}},
            "`initial['Damping[joints=slide]']` of ADR must be a point or a range (low, high) with low <= high "
            "inside the effect's limits [0.0, 10.0]. Received (2.0, 1.0).",
        ),
        (
            {"initial": {FRICTION: (0.4, 1.0)}},
            "`initial['Friction[geoms=block]']` of ADR must be a point or a range (low, high) with low <= high "
            "inside the effect's limits [0.5, 2.0]. Received (0.4, 1.0).",
        ),
        ({"initial": {"Mass[bodies=*]": 1.0}}, "`initial` of ADR names no ADR effect: ['Mass[bodies=*]']."),
        ({"metric": "reward"}, "`metric` of ADR must be one of ['auto', 'return', 'success'] or a callable."),
    ],
)
def test_bad_arguments_are_named(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises((ValueError, TypeError)) as err:
        slider_adr(**kwargs)
    assert str(err.value).startswith(message)


def test_distributions_adr_cannot_move_and_other_bad_effects() -> None:
    with pytest.raises(ValueError) as err:
        ADR([Mass(add=Normal(0.0, 0.1), bodies="cart")], delta=0.1, t_low=0.1, t_high=0.9)
    assert str(err.value) == (
        "`effects[0]` of ADR must draw from Uniform or LogUniform (ADR moves their bounds), or be a Correlated "
        "effect (ADR scales its covariance). Received Mass(add=Normal(mean=0.0, std=0.1), bodies='cart')."
    )
    with pytest.raises(ValueError, match="a `set` effect has no nominal point"):
        ADR([Damping(set=Uniform(0.0, 2.0))], delta=0.1, t_low=0.1, t_high=0.9)
    with pytest.raises(ValueError, match="Received schedule='startup'"):
        ADR([Damping(scale=Uniform(0.0, 2.0), schedule="startup")], delta=0.1, t_low=0.1, t_high=0.9)
    with pytest.raises(ValueError, match="share the key 'Damping\\[joints=\\*\\]'"):
        ADR([Damping(scale=Uniform(0.0, 2.0)), Damping(scale=Uniform(0.0, 3.0))], delta=0.1, t_low=0.1, t_high=0.9)
    with pytest.raises(ValueError, match="inside the effect's limits"):
        ADR([Damping(scale=Uniform(1.5, 2.0))], delta=0.1, t_low=0.1, t_high=0.9)  # nominal point outside
    with pytest.raises(ValueError, match="`adr` must be one ADR controller"):
        sim2real.wrap(Slider(), slider_adr(), adr=slider_adr())


# -- keyed streams --------------------------------------------------------------------------------------------
def params_over(env: Any, episodes: int) -> list[dict[str, float]]:
    out = []
    for _ in range(episodes):
        _, info = env.reset()
        out.append(info["sim2real"]["params"])
    return out


def test_enabling_adr_never_shifts_another_effects_draws() -> None:
    mass = Mass(scale=Uniform(0.5, 1.5), bodies="cart")
    plain = params_over(sim2real.wrap(Slider(), mass, seed=3), 20)
    with_adr = params_over(sim2real.wrap(Slider(), mass, adr=slider_adr(), seed=3), 20)
    assert [p["body_mass[cart]"] for p in plain] == [p["body_mass[cart]"] for p in with_adr]


def test_unmoved_range_draws_what_the_plain_effect_draws() -> None:
    damping = Damping(scale=Uniform(0.5, 2.0), joints="slide")
    adr = ADR([damping], delta=0.1, t_low=0.1, t_high=0.9, p_boundary=0.0, initial={DAMPING: (0.5, 2.0)})
    plain = params_over(sim2real.wrap(Slider(), damping, seed=5), 10)
    driven = params_over(sim2real.wrap(Slider(), adr=adr, seed=5), 10)
    assert plain == driven


def test_effects_at_ranges_draw_what_unpinned_adr_episodes_draw() -> None:
    from randomizers import Correlated, MultivariateNormal

    joint = Correlated(["actuator_gain[push]"], MultivariateNormal((1.0,), ((0.04,),), low=(0.1,)))
    effects = [
        Damping(scale=Uniform(0.0, 4.0), joints="slide"),
        Mass(scale=LogUniform(0.25, 4.0), bodies="cart"),
        joint,
    ]
    adr = ADR(effects, delta=0.5, m=1, t_low=0.2, t_high=0.8, p_boundary=0.0)
    for key, side in ((DAMPING, "high"), (DAMPING, "low"), ("Mass[bodies=cart]", "high"), (joint.key, "high")):
        adr.record(Pin(key, side, adr.ranges[key][side == "high"]), 1.0)  # type: ignore[arg-type]
    final = adr.effects_at_ranges()
    assert [e.key for e in final] == list(adr.keys)
    assert final[0] == Damping(scale=Uniform(0.5, 1.5), joints="slide")
    assert final[1].distribution == LogUniform(1.0, math.exp(0.5))  # type: ignore[attr-defined]
    assert final[2].distribution == MultivariateNormal((1.0,), ((0.01,),), low=(0.1,))  # scale 0.5: cov x 0.25
    # Same keys, same streams: the plain effects draw exactly what ADR's unpinned episodes draw.
    driven = params_over(sim2real.wrap(Slider(), adr=adr, seed=4), 8)
    plain = params_over(sim2real.wrap(Slider(), *final, seed=4), 8)
    assert driven == plain and len({p["dof_damping[slide]"] for p in plain}) == 8


def test_pins_come_from_their_own_keyed_stream_and_are_reported() -> None:
    adr = slider_adr(p_boundary=0.5)
    env = sim2real.wrap(Slider(), adr=adr, seed=7)
    for episode in range(12):
        _, info = env.reset()
        rng = stream((7,), BOUNDARY_STREAM, episode)
        u, i, s = rng.random(), int(rng.integers(2)), int(rng.integers(2))
        pin = info["sim2real"]["adr"]["pin"]
        if u >= 0.5:
            assert pin is None
            continue
        key, side = adr.keys[i], ("low", "high")[s]
        assert pin == (key, side, 1.0)  # nothing recorded yet: every range is the nominal point
        address = "dof_damping[slide]" if key == DAMPING else "geom_friction[block][0]"
        nominal = 1.0
        assert info["sim2real"]["params"][address] == nominal * pin[2]


def test_reset_seed_reproduces_pins_and_draws() -> None:
    env = sim2real.wrap(Slider(), Mass(scale=Uniform(0.5, 1.5)), adr=slider_adr(p_boundary=0.5), seed=1)
    first = [env.reset(seed=9)[1]["sim2real"] for _ in range(1)] + [env.reset()[1]["sim2real"] for _ in range(4)]
    again = [env.reset(seed=9)[1]["sim2real"] for _ in range(1)] + [env.reset()[1]["sim2real"] for _ in range(4)]
    assert [(r["params"], r["adr"]) for r in first] == [(r["params"], r["adr"]) for r in again]


# -- explicit state -------------------------------------------------------------------------------------------
def test_state_round_trips_through_json_and_resumes_identically() -> None:
    goal = distance(THRESHOLD)
    adr = slider_adr()
    env = sim2real.wrap(Slider(goal=goal), adr=adr, seed=0)
    drive(env, 50)
    text = adr.to_json()
    copy = ADR.from_state(json.loads(text))
    assert copy.state() == adr.state() and copy.ranges == adr.ranges and copy.history == adr.history
    assert ADR.from_config(adr.config()).ranges == slider_adr().ranges
    # Continuing the original and the copy on equal envs gives the same controller.
    drive(env, 30)
    twin = sim2real.wrap(Slider(goal=goal), adr=copy, seed=0)
    twin_rand: ADRRandomizer = twin.randomizer
    twin_rand.episode = env.randomizer.episode - 30  # resume the episode counter where the state was taken
    drive(twin, 30)
    assert copy.state() == adr.state()
    with pytest.raises(ValueError, match=r"must be ADR\.state\(\) data of version 1"):
        ADR.from_state({"version": 99})


# -- the other env APIs ---------------------------------------------------------------------------------------
def test_make_vec_shares_one_controller_with_per_env_pins() -> None:
    adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, m=1, t_low=-1e9, t_high=-1e8, p_boundary=1.0)
    envs = sim2real.make_vec("dmc/reacher-easy", 3, adr=adr, seed=0)
    _, info = envs.reset()
    pins = [tuple(p) for p in info["sim2real"]["adr"]["pin"]]
    assert len(set(pins)) > 1  # each sub-env draws its own pin (streams rooted at (seed, i))
    for i, pin in enumerate(pins):
        assert pin[2] == 1.0
        rng = stream((0, i), BOUNDARY_STREAM, 0)
        rng.random()
        rng.integers(1)
        assert pin[1] == ("low", "high")[int(rng.integers(2))]
    zero = np.zeros((3, 2), np.float32)
    for _ in range(1000):
        envs.step(zero)
    # Three episodes ended on the same step, reported in sub-env order: the first result for a boundary widens
    # it; a later one for the same boundary measured the old value and is dropped as stale.
    assert adr.frames == 3000
    sides = {pin[1] for pin in pins}
    low, high = adr.ranges["Damping[joints=*]"]
    assert (low, high) == (0.5 if "low" in sides else 1.0, 1.5 if "high" in sides else 1.0)
    assert adr.stale == 3 - len(sides)
    envs.close()
    with pytest.raises(ValueError, match="`vectorization` must be 'sync' with `adr`"):
        sim2real.make_vec("dmc/reacher-easy", 2, adr=adr, vectorization="async")


def test_dm_env_and_torchrl_report_episodes() -> None:
    from dm_control import suite

    adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, m=1, t_low=-1e9, t_high=-1e8, p_boundary=1.0)
    env = sim2real.wrap(suite.load("reacher", "easy", task_kwargs={"time_limit": 0.2}), adr=adr, seed=0)
    timestep = env.reset()
    pin = env.pin
    assert env.current_params["dof_damping[shoulder]"] == 0.01 and pin is not None  # the nominal point
    while not timestep.last():
        timestep = env.step(np.zeros(2))
    assert adr.frames == 10 and adr.ranges["Damping[joints=*]"] != (1.0, 1.0)
    env.close()

    from torchrl.envs import DMControlWrapper

    adr2 = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, m=1, t_low=-1e9, t_high=-1e8, p_boundary=1.0)
    short = suite.load("reacher", "easy", task_kwargs={"time_limit": 0.2})  # 10 control steps
    tenv = sim2real.wrap(DMControlWrapper(short), adr=adr2, seed=0)
    td = tenv.rollout(50, break_when_any_done=True)
    assert td.shape[0] == 10 and bool(td["next", "done"][-1])
    assert adr2.frames == 10 and adr2.ranges["Damping[joints=*]"] != (1.0, 1.0)
    tenv.close()


# -- local / Ray backends: synchronous rounds -----------------------------------------------------------------
def slider_worker(adr: ADR, item: tuple[int, int, float]) -> int:
    """One round's work for one worker: ``episodes`` scripted episodes on a slider seeded ``seed``."""
    seed, episodes, goal = item
    env = sim2real.wrap(Slider(goal=goal), adr=adr, seed=seed)
    drive(env, episodes)
    return len(adr.collected or ())


def test_rounds_are_deterministic_in_item_order_on_every_backend() -> None:
    from sim2real.adr_rounds import run_adr_round

    goal = distance(THRESHOLD)
    # Round 1 on a spawned local pool, round 2 (from the moved ranges) on Ray: each equals the serial rounds.
    # (One process start per backend: Ray's start-up alone takes 15-30 s on the shared 2-core box.)
    backends = ("local", "ray") if _ray_available() else ("local", "local")
    states = {}
    for name, plan in (("serial", ("serial", "serial")), ("distributed", backends)):
        adr = slider_adr()
        for r, backend in enumerate(plan):
            items = [((r, w), 15, goal) for w in range(2)]
            with _ray_session(backend):
                rnd = run_adr_round(
                    slider_worker, adr, items, backend=backend, workers=None if backend == "serial" else 1
                )
            assert rnd.outputs == (15, 15) and [len(x) for x in rnd.results] == [15, 15]
            if r == 0:
                assert adr.ranges[DAMPING] != (1.0, 1.0)  # round 2 starts from moved ranges
        states[name] = adr.state()
    assert states["serial"] == states["distributed"]
    assert states["serial"]["frames"] == 2 * 2 * 15 * 20
    assert states["serial"]["history"][-1][2][0] > 1.0  # the damping range grew

    # Order is item order: replaying one round's results in another order may end elsewhere.
    first = slider_adr()
    rnd = run_adr_round(slider_worker, first, [((0, w), 15, goal) for w in range(3)], backend="serial")
    replay = slider_adr()
    replay.apply_results([r for results in rnd.results for r in results])
    assert replay.state() == first.state()


def _ray_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("ray") is not None


@contextlib.contextmanager
def _ray_session(backend: str) -> Iterator[None]:
    """A one-CPU Ray for a ``ray`` round (stopped afterwards unless it was already up) that can unpickle this
    module's functions by value (Ray workers do not have tests/ on their path)."""
    if backend != "ray":
        yield
        return
    import sys

    import ray
    from ray import cloudpickle

    module = sys.modules[__name__]
    cloudpickle.register_pickle_by_value(module)
    ours = not ray.is_initialized()
    if ours:
        ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        if ours:
            ray.shutdown()
        cloudpickle.unregister_pickle_by_value(module)


# -- training ------------------------------------------------------------------------------------------------
ADR_YAML = """
effects:
  - {type: Damping, scale: [0.2, 5.0]}
  - {type: Mass, scale: [0.5, 2.0], bodies: '*'}
delta: 0.1
t_low: -1e9
t_high: -1e8
m: 1
p_boundary: 1.0
metric: return
"""


def test_config_adr_round_trips_and_bad_adr_is_named() -> None:
    from sim2real.agents import PPOConfig, SACConfig

    for cls in (PPOConfig, SACConfig):
        cfg = cls(frames=1000, adr=ADR_YAML)
        assert cls.from_yaml(cfg.to_yaml()) == cfg
        assert ADR.from_config(__import__("yaml").safe_load(cfg.adr)).keys == ("Damping[joints=*]", "Mass[bodies=*]")
    with pytest.raises(ValueError) as err:
        PPOConfig(adr=ADR_YAML.replace("t_low: -1e9", "t_low: 0.0"))
    assert str(err.value) == "`adr`: `t_low` of ADR must be < `t_high`. Received t_low=0.0, t_high=-100000000.0."


def test_cli_train_adr_logs_ranges_checkpoints_the_state_and_errors_exit_2(tmp_path: Any, capsys: Any) -> None:
    from sim2real.agents import PPOConfig, load_checkpoint
    from sim2real.cli import main

    bad = tmp_path / "adr.yaml"
    bad.write_text(ADR_YAML.replace("p_boundary: 1.0", "p_boundary: 2.0"))
    code = main(["train", "--task", "sim2real/arm-reach", "--adr", str(bad), "--out", str(tmp_path / "p.pt")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err == "sim2real train: error: --adr: `p_boundary` of ADR must be in [0, 1]. Received 2.0."
    code = main(["train", "--task", "sim2real/arm-reach", "--adr", str(tmp_path / "no.yaml"), "--out", "p.pt"])
    assert code == 2 and "--adr: cannot read" in capsys.readouterr().err

    # One training run (sim2real train -> agents.train) checks the logger, the checkpoint and the summary.
    good = tmp_path / "good.yaml"
    good.write_text(ADR_YAML)
    agent = tmp_path / "ppo.yaml"
    agent.write_text(
        "algo: ppo\nframes: 600\nframes_per_batch: 300\nminibatch_size: 150\nepochs: 1\nobs_norm_frames: 0\n"
        "num_envs: 3\n"  # 3 batched worlds x 200 steps: each ends one episode
    )
    out = tmp_path / "policy.pt"
    argv = ["train", "--task", "sim2real/arm-reach", "--adr", str(good), "--agent-config", str(agent)]
    assert main([*argv, "--out", str(out), "--log-dir", str(tmp_path / "runs"), "--quiet"]) == 0
    summary = capsys.readouterr().out
    checkpoint = load_checkpoint(out)
    assert checkpoint.adr is not None and checkpoint.effects is None
    assert checkpoint.config == PPOConfig(
        frames=600, frames_per_batch=300, minibatch_size=150, epochs=1, obs_norm_frames=0, adr=ADR_YAML, num_envs=3
    )
    adr = ADR.from_state(checkpoint.adr)
    assert adr.frames == 600  # three 200-step episodes, one per world, ending on the same step
    # Every finished episode was pinned (p_boundary 1) and widened its boundary (m 1), unless an earlier world's
    # result of the same step had already moved that boundary (a stale result, dropped).
    assert len(adr.history.frames) == 1 + 3 - adr.stale
    ranges = ", ".join(f"{key} [{lo:g}, {hi:g}]" for key, (lo, hi) in adr.ranges.items())
    assert f"adr: entropy {adr.entropy():.3f} nats/dim; {ranges}" in summary
    (run,) = (tmp_path / "runs").iterdir()
    logged = {p.relative_to(run / "scalars").as_posix() for p in (run / "scalars").rglob("*.csv")}
    assert {"adr/Damping[joints=*]/low.csv", "adr/Mass[bodies=*]/high.csv"} <= logged
    assert f"log: {run}" in summary


def test_api_checkers_pass_with_adr() -> None:
    from gymnasium.utils.env_checker import check_env
    from torchrl.envs import DMControlEnv
    from torchrl.envs.utils import check_env_specs

    env = sim2real.wrap(Slider(goal=distance(THRESHOLD)), Mass(scale=Uniform(0.5, 1.5)), adr=slider_adr(), seed=0)
    check_env(env, skip_render_check=True)
    tenv = sim2real.wrap(DMControlEnv("reacher", "easy"), adr=slider_adr_reacher(), seed=0)
    check_env_specs(tenv)
    tenv.close()


def slider_adr_reacher() -> ADR:
    return ADR([Damping(scale=Uniform(0.0, 4.0)), Mass(scale=LogUniform(0.5, 2.0))], delta=0.1, t_low=0.1, t_high=0.9)


def test_correlated_scales_its_covariance() -> None:
    from randomizers import Correlated, MultivariateNormal

    cov = ((0.04, 0.03), (0.03, 0.09))
    mean = (1.0, 1.0)
    joint = Correlated(["dof_damping[slide]", "actuator_gain[push]"], MultivariateNormal(mean, cov, low=(0.0, 0.0)))
    key = joint.key
    adr = ADR([joint], delta=0.5, m=1, t_low=-1e9, t_high=-1e8, metric="return", p_boundary=1.0)
    assert adr.ranges[key] == (0.0, 0.0) and adr.entropy() == -math.inf
    env = sim2real.wrap(Slider(), adr=adr, seed=0)
    _, info = env.reset()
    assert info["sim2real"]["adr"]["pin"] == (key, "high", 0.0)  # only the scale's upper end moves
    assert [info["sim2real"]["params"][a] for a in ("dof_damping[slide]", "actuator_gain[push]")] == [1.0, 1.0]
    drive(env, 1)
    assert adr.ranges[key] == (0.0, 0.5)
    inverse = np.linalg.inv(np.array(cov))
    _, info = env.reset()
    x = np.array([info["sim2real"]["params"][a] for a in ("dof_damping[slide]", "actuator_gain[push]")]) - mean
    assert float(x @ inverse @ x) == pytest.approx(0.25)  # pinned: on the 0.5-sigma ellipse
    expected = 0.5 * math.log(2 * math.pi * math.e) + math.log(0.5) + 0.5 * math.log(np.linalg.det(cov)) / 2
    assert adr.entropy() == pytest.approx(expected)
    assert ADR.from_state(adr.to_json()).state() == adr.state()


def test_interval_resamples_draw_from_the_range_and_keep_the_pin() -> None:
    from randomizers import Interval

    damping = Damping(scale=Uniform(0.0, 4.0), joints="slide", schedule=Interval(steps=5))
    free = ADR([damping], delta=0.1, t_low=0.1, t_high=0.9, p_boundary=0.0, initial={DAMPING: (0.5, 2.0)})
    env = sim2real.wrap(Slider(), adr=free, seed=0)
    env.reset()
    seen = {env.step(np.ones(1, np.float32))[4]["sim2real"]["params"]["dof_damping[slide]"] for _ in range(20)}
    assert len(seen) == 5 and all(0.5 <= v < 2.0 for v in seen)  # the reset draw + one every 5 steps, in the range
    pinned = ADR([damping], delta=0.1, t_low=0.1, t_high=0.9, p_boundary=1.0, initial={DAMPING: (0.5, 2.0)})
    env = sim2real.wrap(Slider(), adr=pinned, seed=0)
    _, info = env.reset()
    value = info["sim2real"]["adr"]["pin"][2]
    seen = {env.step(np.ones(1, np.float32))[4]["sim2real"]["params"]["dof_damping[slide]"] for _ in range(20)}
    assert seen == {value} and value in (0.5, 2.0)


def _dm_env_tests() -> type:
    import unittest

    from dm_control import suite
    from dm_env import test_utils

    class ADRReacherTest(test_utils.EnvironmentTestMixin, unittest.TestCase):
        def make_object_under_test(self) -> Any:
            adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, m=1, t_low=-1e9, t_high=-1e8, p_boundary=1.0)
            env = suite.load("reacher", "easy", task_kwargs={"time_limit": 0.2})
            return sim2real.wrap(env, Mass(scale=Uniform(0.8, 1.2)), adr=adr, seed=0)

    return ADRReacherTest


TestDmEnvADRContract = _dm_env_tests()


# -- the study's "adr" policy ---------------------------------------------------------------------------------
def test_study_profile_adr_section_is_checked_and_gives_the_adr_role(tmp_path: Any, monkeypatch: Any) -> None:
    import shutil

    import sim2real.study.profile as profile_module
    from sim2real.study import load_profile
    from sim2real.study.policies import role_agent, study_roles

    shipped = load_profile()
    folder = tmp_path / "dmc-reacher-easy"
    shutil.copytree(shipped.folder, folder, ignore=shutil.ignore_patterns("*.pt"))
    monkeypatch.setattr(profile_module, "PROFILES", tmp_path)
    text = (folder / "study.yaml").read_text()
    if "\nadr:\n" in text:
        text = text[: text.index("\nadr:\n")] + text[text.index("\n# System identification") :]
    (folder / "study.yaml").write_text(text)
    assert load_profile().adr is None and study_roles(load_profile())[-1] == "calibrated"
    with pytest.raises(ValueError, match=r"`role` 'adr' needs an `adr` section in .*study.yaml"):
        role_agent(load_profile(), "adr")

    section = """
adr:
  ranges:
    effects:
      - {type: Damping, scale: [0.0, 5.0]}
      - {type: ActuatorGain, scale: [0.25, 2.0]}
      - {type: Mass, scale: [0.25, 4.0]}
    delta: 0.1
    t_low: 500
    t_high: 800
  signals:
    - {type: ActionLatency, steps: 1}
"""
    (folder / "study.yaml").write_text(text + section)
    profile = load_profile()
    assert profile.adr is not None and study_roles(profile) == ("nominal", "randomized", "calibrated", "adr")
    adr = ADR.from_config(__import__("yaml").safe_load(profile.adr))
    assert set(adr.ranges.values()) == {(1.0, 1.0)}  # started at the nominal point: no range picked by hand
    assert adr.keys == tuple(e.key for e in profile.randomized if hasattr(e, "operation"))  # the same parameters
    assert [type(e).__name__ for e in profile.adr_signals] == ["ActionLatency"]
    assert role_agent(profile, "adr").adr == profile.adr and role_agent(profile, "nominal") == profile.agent
    with pytest.raises(ValueError, match=r"`role` must be one of \['nominal', 'randomized', 'calibrated', 'adr'\]"):
        role_agent(profile, "dr")
    (folder / "study.yaml").write_text(text + section.replace("t_low: 500", "t_low: 900"))
    with pytest.raises(ValueError) as err:
        load_profile()
    assert str(err.value) == (
        f"{folder / 'study.yaml'}: adr.ranges: `t_low` of ADR must be < `t_high`. Received t_low=900.0, t_high=800.0."
    )
    (folder / "study.yaml").write_text(text + "adr: {signals: []}\n")
    with pytest.raises(ValueError, match=r"study.yaml: `adr` must have `ranges` \(an ADR config\). Received keys"):
        load_profile()
