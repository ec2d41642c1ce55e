"""sysid.fit's rollout savings keep its numbers: a reused base rollout is bitwise, a re-weighted Jacobian equals a
recomputed one, and the statistics from the Jacobian one iterate back match those from a fresh one."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sysid import ParameterSpace, fit, record_log
from sysid._problem import Problem, make_segments
from sysid._solver import COST_ATOL, Progress, State, fd_steps, lm
from sysid._statistics import estimate_statistics
from sysid.params import ModelPool

ARM = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" axis="0 1 0" damping="0.2" armature="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body name="lower" pos="0.3 0 0">
        <joint name="elbow" axis="0 1 0" damping="0.1" armature="0.005"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.025"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor name="shoulder" joint="shoulder" gear="2"/><motor name="elbow" joint="elbow"/></actuator>
</mujoco>
"""
PARAMS = ["dof_damping[*]"]


@pytest.fixture(scope="module")
def setup() -> tuple[mujoco.MjModel, Problem, np.ndarray]:
    model = mujoco.MjModel.from_xml_string(ARM)
    rng = np.random.default_rng(3)
    t = np.arange(150) * 0.01
    ctrl = np.stack([0.2 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (0.7, 1.9)], axis=1)
    truth = mujoco.MjModel.from_xml_string(ARM.replace('damping="0.2"', 'damping="0.25"'))
    log = record_log(truth, ctrl, n_substeps=2, noise_std={"qpos": 1e-3, "qvel": 1e-2}, rng=rng)
    space = ParameterSpace(model, PARAMS)
    seg = make_segments([(0, 150, 0, 150)], 50, True)
    problem = Problem(log, model, space, seg, ("qpos", "qvel"), True, 0, 2, ModelPool(model, space))
    problem.weights = np.array([1e3, 1e3, 1e2, 1e2])
    return model, problem, space.nominal


def _count_rows(problem: Problem, monkeypatch: pytest.MonkeyPatch) -> list[int]:
    rows: list[int] = []
    original = Problem.rollout

    def counting(self: Problem, models: list, states: np.ndarray, controls: np.ndarray, segs=None):  # type: ignore[no-untyped-def]
        rows.append(states.shape[0])
        return original(self, models, states, controls, segs)

    monkeypatch.setattr(Problem, "rollout", counting)
    return rows


def test_jacobian_reuses_the_rollout_just_done_bitwise(setup, monkeypatch) -> None:
    _, problem, theta = setup
    x0 = problem.anchors() + 1e-4
    steps = fd_steps(theta, theta / 10, theta * 10, 1e-6)
    problem._last = None
    fresh_r, fresh_jac = problem.jacobian(theta, 0, 0, x0, steps, True)
    rows = _count_rows(problem, monkeypatch)
    problem.residuals(theta, 0, 0, x0)
    r, jac = problem.jacobian(theta, 0, 0, x0, steps, True)
    segments, p = problem.seg.count, theta.size
    # The residual call rolled out the S base rows; the Jacobian only the perturbed ones.
    assert rows == [segments, p * segments + segments * problem.nxa]
    assert np.array_equal(r, fresh_r) and np.array_equal(jac, fresh_jac)
    # Anything else (another delay, other initial states) is rolled out again.
    problem.jacobian(theta, 0, 0, x0 + 1e-5, steps, True)
    assert rows[-1] == (p + 1) * segments + segments * problem.nxa


def test_reweighting_rescales_the_jacobian_like_a_recomputation(setup) -> None:
    _, problem, theta = setup
    x0 = problem.anchors()
    steps = fd_steps(theta, theta / 10, theta * 10, 1e-6)
    old = problem.weights.copy()
    r, jac = problem.jacobian(theta, 0, 0, x0, steps, True)
    new = old * np.array([0.5, 2.0, 1.3, 0.9])
    factor = (new / old)[problem.channel_of_residual()]
    problem.weights = new
    try:
        r2, jac2 = problem.jacobian(theta, 0, 0, x0 + 0.0, steps, True)
    finally:
        problem.weights = old
    np.testing.assert_allclose(r * factor, r2, rtol=1e-12, atol=0)
    np.testing.assert_allclose(jac * factor[:, None], jac2, rtol=1e-9, atol=1e-9 * np.abs(jac2).max())


def _solve(problem: Problem, st: State, theta: np.ndarray, atol: float = COST_ATOL) -> State:
    return lm(
        problem,
        st,
        theta / 10,
        theta * 10,
        fit_x0=True,
        max_iter=50,
        fd_step=1e-6,
        progress=Progress(False),
        stage="test",
        atol=atol,
    )


@pytest.fixture(scope="module")
def optimum(setup) -> tuple[State, np.ndarray]:
    """The solved problem and its standard errors."""
    _, problem, theta = setup
    st = _solve(problem, State(theta * 1.3, problem.anchors(), 0, 0), theta)
    r, jac = problem.jacobian(st.theta, 0, 0, st.x0, fd_steps(st.theta, theta / 10, theta * 10, 1e-6), True)
    unknowns = theta.size + problem.seg.count * problem.nxa
    stats = estimate_statistics(problem, st.theta, r, jac, theta / 10, theta * 10, True, unknowns)
    return st, stats.stderr


def test_statistics_from_the_prior_jacobian_match_a_fresh_one(setup, optimum) -> None:
    _, problem, theta = setup
    best, se = optimum
    lower, upper = theta / 10, theta * 10
    # 0.05 SE off the optimum: one step lowers ½χ² by ~0.003 < COST_ATOL, so the solve stops on that step.
    st = _solve(problem, State(best.theta + 0.05 * se, best.x0.copy(), 0, 0), theta)
    assert st.prior_jac is not None and st.last_r is not None and st.r is None and st.iterations == 1
    unknowns = theta.size + problem.seg.count * problem.nxa
    near = estimate_statistics(problem, st.theta, st.last_r, st.prior_jac, lower, upper, True, unknowns)
    r, jac = problem.jacobian(st.theta, 0, 0, st.x0, fd_steps(st.theta, lower, upper, 1e-6), True)
    fresh = estimate_statistics(problem, st.theta, r, jac, lower, upper, True, unknowns)
    assert np.array_equal(st.last_r, r)
    np.testing.assert_allclose(near.stderr, fresh.stderr, rtol=1e-3)
    np.testing.assert_allclose(near.crlb, fresh.crlb, rtol=1e-3)


def test_a_last_step_that_mattered_leaves_no_prior_jacobian(setup, optimum) -> None:
    _, problem, theta = setup
    best, se = optimum
    # 1.5 SE off with a loose solve: the one step lowers ½χ² by ~1 (> COST_ATOL) and the solve stops there.
    st = _solve(problem, State(best.theta + 1.5 * se, best.x0.copy(), 0, 0), theta, atol=5.0)
    assert st.iterations == 1 and st.r is None
    assert st.prior_jac is None and st.last_r is None


def test_fit_results_do_not_depend_on_the_reuse(setup, monkeypatch) -> None:
    """The whole fit with the rollout cache disabled gives bitwise the same estimates."""
    model, problem, _ = setup
    log = problem.log
    with_cache = fit(log, model, PARAMS, progress=False, n_starts=4)
    monkeypatch.setattr(Problem, "_cached", lambda self, values, delay, x0: None)
    without = fit(log, model, PARAMS, progress=False, n_starts=4)
    assert np.array_equal(with_cache.estimates, without.estimates)
    assert np.array_equal(with_cache.stderr, without.stderr)
