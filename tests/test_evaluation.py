"""Batched closed-loop evaluation: conditions, seeding, batching, measured returns and errors."""

from __future__ import annotations

import numpy as np
import pytest

import sim2real as s2r
from sim2real.agents import ReachController
from sim2real.evaluation import (
    Condition,
    Evaluation,
    episode_seed,
    evaluate,
    grid,
    measured,
    nominal,
    randomized,
    real,
    sweep,
)

TASK = "sim2real/arm-reach"


def _conditions() -> list[Condition]:
    return [
        nominal(),
        randomized([s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), s2r.ObservationNoise(s2r.Gaussian(std=0.01))]),
        real([s2r.ActionLatency(steps=2)], params={"dof_damping[shoulder_pitch]": 2.0}),
    ]


def _policies() -> dict[str, object]:
    return {"reach": ReachController(), "slow": ReachController(kp=0.3), "zero": lambda obs: np.zeros(3)}


@pytest.fixture(scope="module")
def result() -> Evaluation:
    return evaluate(_policies(), TASK, _conditions(), episodes=5, seed=3, max_steps=30, batch=2)


def test_shapes_and_metadata(result: Evaluation) -> None:
    assert result.policies == ("reach", "slow", "zero")
    assert [c.name for c in result.conditions] == ["sim", "randomized", "real"]
    for p in result.policies:
        for c in ("sim", "randomized", "real"):
            assert result.returns[p][c].shape == (5,)
            assert result.lengths[p][c].min() >= 1 and result.lengths[p][c].max() <= 30
            assert result.successes[p][c].dtype == bool
    assert result.env_steps == sum(int(result.lengths[p][c].sum()) for p in result.policies for c in result.returns[p])
    assert result.table("reach", ["sim", "real"]).shape == (5, 2)


def test_results_do_not_depend_on_batch_size(result: Evaluation) -> None:
    again = evaluate(_policies(), TASK, _conditions(), episodes=5, seed=3, max_steps=30, batch=5)
    assert again.to_json() == result.to_json()


def test_reproducible_and_seed_sensitive(result: Evaluation) -> None:
    again = evaluate(_policies(), TASK, _conditions(), episodes=5, seed=3, max_steps=30, batch=2)
    assert again.to_json() == result.to_json()
    other = evaluate(_policies(), TASK, _conditions(), episodes=5, seed=4, max_steps=30, batch=2)
    assert not np.array_equal(other.returns["reach"]["sim"], result.returns["reach"]["sim"])


def test_common_random_numbers(result: Evaluation) -> None:
    # The zero policy never moves: its return depends only on the initial state (target), which is the
    # same in every simulated condition because episode e is reset with episode_seed(seed, e) everywhere.
    zero = result.returns["zero"]
    np.testing.assert_array_equal(zero["sim"], zero["real"])
    # Draws are recorded per episode and match a single env replayed with the episode's seed.
    damping = result.draws["randomized"]["dof_damping[shoulder_pitch]"]
    env = s2r.wrap(s2r.make(TASK), *_conditions()[1].effects, seed=3)
    _, info = env.reset(seed=episode_seed(3, 4))
    assert info["sim2real"]["params"]["dof_damping[shoulder_pitch]"] == damping[4]


def test_single_episode_replay_matches(result: Evaluation) -> None:
    # Any (policy, condition, episode) can be replayed alone.
    env = s2r.wrap(s2r.make(TASK, params={"dof_damping[shoulder_pitch]": 2.0}), s2r.ActionLatency(steps=2), seed=3)
    obs, _ = env.reset(seed=episode_seed(3, 2))
    policy = ReachController()
    total = 0.0
    for _ in range(30):
        obs, reward, terminated, truncated, _ = env.step(policy(obs))
        total += float(reward)
        if terminated or truncated:
            break
    assert total == result.returns["reach"]["real"][2]


def test_the_gap_is_real(result: Evaluation) -> None:
    # 2 steps of action latency and doubled damping make the controller slower to close in.
    assert result.returns["reach"]["real"].mean() < result.returns["reach"]["sim"].mean()


def test_sweep_includes_bounds_and_nominal() -> None:
    points = sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", {"low": 0.5, "high": 0.9, "num": 3})
    assert [c.value for c in points] == [(0.5,), (0.7,), (0.9,), (1.0,)]
    assert {c.sweep for c in points} == {"ActuatorGain.scale"}
    assert points[0].nominal == (1.0,)
    assert type(points[0].effects[-1]).__name__ == "ActuatorGain"
    noise = sweep(s2r.ObservationNoise(s2r.Gaussian(std=0.0)), "processes.0.std", [0.0, 0.05])
    assert [c.name for c in noise] == ["ObservationNoise.processes.0.std=0", "ObservationNoise.processes.0.std=0.05"]
    assert noise[1].effects[0] == s2r.ObservationNoise(s2r.Gaussian(std=0.05))


def test_grid_is_x_major() -> None:
    points = grid(
        {"effect": {"type": "Damping", "scale": 1.0}, "field": "scale", "values": [1.0, 2.0]},
        {"type": "ObservationLatency", "steps": 0, "field": "steps", "values": [0, 1]},
    )
    assert [c.value for c in points] == [(1.0, 0.0), (1.0, 1.0), (2.0, 0.0), (2.0, 1.0)]
    assert points[0].axes == ("Damping.scale", "ObservationLatency.steps")
    assert all(c.kind == "grid" for c in points)


def test_sweep_errors() -> None:
    with pytest.raises(ValueError, match=r"`values` must be at least 2 finite, strictly increasing values"):
        sweep({"type": "Damping", "scale": 1.0}, "scale", [2.0, 1.0])
    with pytest.raises(ValueError, match=r"`values.num` must be an int >= 2. Received 1."):
        sweep({"type": "Damping", "scale": 1.0}, "scale", {"low": 0, "high": 1, "num": 1})
    with pytest.raises(TypeError, match=r"`effect` must be an effect from `randomizers`"):
        sweep(3.0, "scale", [0.5, 1.0])


def test_measured_csv(tmp_path) -> None:
    path = tmp_path / "real.csv"
    path.write_text("policy,return,success\nreach,-10.5,1\nreach,-12,0\nreach,-11,true\nother,1,0\n")
    cond = measured(path)
    assert cond.kind == "measured" and cond.returns["reach"] == (-10.5, -12.0, -11.0)
    assert cond.successes["reach"] == (True, False, True)
    out = evaluate({"reach": ReachController()}, TASK, [nominal(), cond], episodes=2, max_steps=5)
    assert out.returns["reach"]["real"].tolist() == [-10.5, -12.0, -11.0]
    assert out.returns["reach"]["sim"].shape == (2,)
    with pytest.raises(ValueError, match=r"different numbers of runs: \[2, 3\]"):
        out.table("reach", ["sim", "real"])
    bad = tmp_path / "bad.csv"
    bad.write_text("policy,return\nreach,nan\n")
    with pytest.raises(ValueError, match=r"bad.csv:2: `return` must be a finite number. Received 'nan'."):
        measured(bad)
    with pytest.raises(ValueError, match=r"must have columns `policy` and `return`. Received \['name', 'r'\]"):
        (tmp_path / "cols.csv").write_text("name,r\na,1\n")
        measured(tmp_path / "cols.csv")


def test_argument_errors() -> None:
    with pytest.raises(ValueError, match=r"`episodes` must be an int >= 1. Received 0."):
        evaluate([ReachController()], TASK, [nominal()], episodes=0)
    with pytest.raises(ValueError, match=r"`conditions` must have unique names. Received duplicates \['sim'\]."):
        evaluate([ReachController()], TASK, [nominal(), nominal()])
    with pytest.raises(TypeError, match=r"`conditions` must be a non-empty list of Condition"):
        evaluate([ReachController()], TASK, ["sim"])
    with pytest.raises(ValueError, match=r"`kind` must be one of"):
        Condition("x", "simulated")
    with pytest.raises(ValueError, match=r"`policies` must have unique names"):
        evaluate([ReachController(), ReachController()], TASK, [nominal()])


def test_evaluation_is_frozen(result: Evaluation) -> None:
    with pytest.raises(ValueError):
        result.returns["reach"]["sim"][0] = 0.0
    with pytest.raises(TypeError):
        result.returns["reach"]["x"] = np.zeros(1)  # type: ignore[index]


def _replay(env, seed: int, episode: int, steps: int) -> float:
    obs, _ = env.reset(seed=episode_seed(seed, episode))
    policy = ReachController()
    total = 0.0
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(policy(obs))
        total += float(reward)
        if terminated or truncated:
            break
    return total


def test_shared_envs_leave_no_trace_between_conditions() -> None:
    # One job reuses its envs for every condition with the same calibration: wrappers are released and
    # the nominal model restored, so each condition matches a freshly built env.
    gain = sweep({"type": "ActuatorGain", "scale": 1.0}, "scale", [0.5, 1.0])
    latency = s2r.ObservationLatency(steps=2)
    conds = [randomized([s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), latency]), *gain, nominal()]
    out = evaluate({"reach": ReachController()}, TASK, conds, episodes=3, seed=7, max_steps=25, batch=3)
    for cond in conds:
        for e in range(3):
            fresh = s2r.wrap(s2r.make(TASK), *cond.effects, seed=7) if cond.effects else s2r.make(TASK)
            assert _replay(fresh, 7, e, 25) == out.returns["reach"][cond.name][e], (cond.name, e)


def test_suite_copies_step_like_suite_load() -> None:
    from dm_control import suite

    from sim2real.adapters import DmEnvToGym

    copied, loaded = s2r.make("dmc/reacher-easy"), DmEnvToGym(suite.load("reacher", "easy"))
    a, _ = copied.reset(seed=11)
    b, _ = loaded.reset(seed=11)
    np.testing.assert_array_equal(a, b)
    rng = np.random.default_rng(0)
    for _ in range(50):
        action = rng.uniform(-1, 1, 2).astype(np.float32)
        a, ra, *_ = copied.step(action)
        b, rb, *_ = loaded.step(action)
        np.testing.assert_array_equal(a, b)
        assert ra == rb
    # Rewards while the finger is inside the target too (the fast task reads the radii by index).
    from sim2real.agents import ReacherPD

    pd, total = ReacherPD(), 0.0
    a, _ = copied.reset(seed=3)
    b, _ = loaded.reset(seed=3)
    for _ in range(300):
        a, ra, *_ = copied.step(pd(a))
        b, rb, *_ = loaded.step(pd(b))
        assert ra == rb
        total += ra
    assert total > 50
    # Without a seed, every env draws fresh entropy (as suite.load does).
    x, _ = s2r.make("dmc/reacher-easy").reset()
    y, _ = s2r.make("dmc/reacher-easy").reset()
    assert not np.array_equal(x, y)


def test_release_restores_the_base_env() -> None:
    base = s2r.make(TASK)
    model = base.unwrapped.model
    nominal_damping = model.dof_damping.copy()
    env = s2r.wrap(base, s2r.Damping(scale=s2r.Uniform(2.0, 3.0)), s2r.ObservationLatency(steps=1), seed=0)
    env.reset(seed=0)
    assert not np.array_equal(model.dof_damping, nominal_damping)
    assert env.release() is base  # one fused layer (physics and signals) since issue 15: one release
    np.testing.assert_array_equal(model.dof_damping, nominal_damping)
    obs, _ = base.reset(seed=0)
    assert base.step(np.zeros(3, dtype=np.float32))[0].shape == obs.shape


@pytest.mark.parametrize("backend", ["local", "ray"])
def test_backends_give_the_same_results(backend: str) -> None:
    policies = {"reach": ReachController(), "slow": ReachController(kp=0.3)}
    kwargs = {"episodes": 4, "seed": 5, "max_steps": 20, "batch": 2}
    serial = evaluate(policies, TASK, _conditions(), **kwargs)
    started = False
    if backend == "ray":
        ray = pytest.importorskip("ray")
        if not ray.is_initialized():
            ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
            started = True
    try:
        other = evaluate(policies, TASK, _conditions(), backend=backend, workers=2, **kwargs)
    finally:
        if started:
            ray.shutdown()
    assert other.to_json() == serial.to_json()
