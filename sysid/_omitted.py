"""Score test for physics the fitted model leaves out (internal): the evidence behind ``FitQuality.omitted``.

A fit that leaves out a term the log has (joint friction, a heavier link, a servo gain 20% low) is biased, and its
fitted parameters soak up what they can: with joint damping free, a missing Coulomb friction ``f·sign(q̇)`` is mostly
absorbed as extra damping. What is left in the residuals is small next to the measurement noise on every row (the
held-out error barely grows, the residuals look white), but it is the same small shape row after row, so it adds
up along the one direction the missing term would move the trajectory. The Lagrange-multiplier (score) test looks
exactly there: for every *candidate* parameter the model has but the fit holds fixed — each measured joint's
damping, friction loss and armature, each moving body's mass, each actuator's gain — it takes that parameter's
Jacobian column at the estimate, removes what the fitted parameters and the fitted initial states can already
explain, and asks whether the residual has a component along what is left:

    z_c = (j_c⊥ · r) / (‖j_c⊥‖ · s)

With the right model the weighted residual ``r`` is white measurement noise, so every ``z_c`` is standard normal
(a linearised fact, not a fitted threshold) and the largest ``|z|`` over the candidates is judged with a
Bonferroni level; with a term left out, ``r`` lines up with that term's column and ``|z|`` grows like the square
root of the log length. The test needs no refit: one batched rollout per candidate at the estimate.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from sysid._problem import Problem
from sysid._statistics import profile_states
from sysid.params import ParameterSpace

__all__ = ["candidate_addresses", "omitted_scores"]

_DOF_FIELDS = ("dof_damping", "dof_frictionloss", "dof_armature")
_REL_STEP = 1e-3  # forward-difference step relative to the value (these terms act linearly or nearly so)


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, i: int) -> str | None:
    name = mujoco.mj_id2name(model, kind, i)
    return name or None


def candidate_addresses(problem: Problem, fitted: tuple[str, ...]) -> list[str]:
    """Addresses the score test checks: the physics of the measured joints that the fit holds fixed.

    Hinge and slide joints whose position or velocity is in the residual give their damping, friction loss and
    armature; bodies that such a joint moves give their mass; actuators on such joints (or on a tendon) give their
    gain. Unnamed elements have no address and are skipped.
    """
    model = problem.model
    channels = set(problem.channels)
    joints: list[int] = []
    for j in range(model.njnt):
        if int(model.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            continue
        name = _name(model, mujoco.mjtObj.mjOBJ_JOINT, j)
        if name is not None and (f"qvel[{name}]" in channels or f"qpos[{name}]" in channels):
            joints.append(j)
    out = [f"{f}[{_name(model, mujoco.mjtObj.mjOBJ_JOINT, j)}]" for j in joints for f in _DOF_FIELDS]
    bodies = sorted({int(model.jnt_bodyid[j]) for j in joints})
    out += [f"body_mass[{n}]" for b in bodies if (n := _name(model, mujoco.mjtObj.mjOBJ_BODY, b)) is not None]
    moved = set(joints)
    for a in range(model.nu):
        name = _name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a)
        trn = int(model.actuator_trntype[a])
        on_joint = trn == int(mujoco.mjtTrn.mjTRN_JOINT) and int(model.actuator_trnid[a, 0]) in moved
        if name is not None and (on_joint or trn == int(mujoco.mjtTrn.mjTRN_TENDON)):
            out.append(f"actuator_gain[{name}]")
    taken = set(fitted)
    return [a for a in out if a not in taken]


def omitted_scores(
    problem: Problem,
    estimated: mujoco.MjModel,
    signals: tuple[str, ...],
    obs_margin: int,
    state_mask: np.ndarray | None,
    delay: int,
    obs_delay: int,
    x0: np.ndarray,
    r: np.ndarray,
    jac: np.ndarray,
    fitted_x0: bool,
    s2: float,
) -> dict[str, float]:
    """``{address: z}`` score of every candidate parameter the fit held fixed (NaN: the fit already spans it).

    Args:
        problem: the fit's final problem (its weights, segments and channels).
        estimated: the model with the fitted values written in.
        signals, obs_margin, state_mask: the settings the fit built ``problem`` with.
        delay: fitted action delay (physics steps); ``obs_delay``: fitted sensor delay (control steps).
        x0: (S, nx) fitted (or logged) segment initial states.
        r: (N,) weighted residual at the estimate; ``jac``: (N, P [+ S*nxa]) its Jacobian.
        fitted_x0: whether ``jac`` carries initial-state columns.
        s2: residual variance per degree of freedom.
    """
    p = problem.space.size
    addresses = candidate_addresses(problem, problem.space.addresses)
    if not addresses or r.size == 0:
        return {}
    base = estimated  # only read: every rollout runs on copies
    values = ParameterSpace(base, addresses, [(-1.0, 1.0)] * len(addresses)).nominal
    space = ParameterSpace(base, addresses, [(v - 1.0, v + 1.0) for v in values])
    # A term at zero (friction the model leaves out) is stepped from zero: by a thousandth of the typical size
    # of that field over the other candidates, or of 1 (the terms act linearly, so the size barely matters).
    fields = [a.split("[", 1)[0] for a in addresses]
    typical = {f: float(np.mean([abs(v) for v, g in zip(values, fields, strict=True) if g == f])) for f in set(fields)}
    steps = np.array(
        [_REL_STEP * (abs(v) if v != 0 else (typical[f] or 1.0)) for v, f in zip(values, fields, strict=True)]
    )
    cand = Problem(
        problem.log,
        base,
        space,
        problem.seg,
        signals,
        problem.fitted_anchor,
        obs_margin,
        problem.nthread,
        None,
        state_mask,
    )
    cand.weights = problem.weights
    # A few model copies rewritten chunk after chunk: a copy of a large model costs as much as its rollout.
    k = len(addresses)
    chunk = max(4, 2 * problem.nthread)
    table = values[None] + np.diag(steps)
    r0 = cand.residuals(values[None], delay, obs_delay, x0)[0]
    jc = (
        np.concatenate(
            [(cand.residuals(table[i : i + chunk], delay, obs_delay, x0) - r0).T for i in range(0, k, chunk)], axis=1
        )
        / steps[None, :]
    )
    usable = np.all(np.isfinite(jc), axis=0)  # a candidate whose step diverged says nothing
    jc = np.where(usable[None, :], jc, 0.0)
    joined = np.hstack([jac[:, :p], jc, jac[:, p:]])
    prof = profile_states(problem, joined, p + k) if fitted_x0 and jac.shape[1] > p else joined[:, : p + k]
    a, c = prof[:, :p], prof[:, p:]
    if p:
        c = c - a @ np.linalg.lstsq(a, c, rcond=None)[0]
    scale = math.sqrt(max(s2, 1e-300))
    out: dict[str, float] = {}
    for i, address in enumerate(addresses):
        norm = float(np.linalg.norm(c[:, i]))
        raw = float(np.linalg.norm(jc[:, i]))
        # A column the fitted parameters and states already span carries no evidence of its own.
        spanned = not usable[i] or raw == 0 or norm <= 1e-6 * raw
        out[address] = math.nan if spanned else float(c[:, i] @ r) / (norm * scale)
    return out
