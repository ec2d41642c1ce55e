"""Exciting a robot around its home pose: the home pose, gravity compensation and the joint-limit guard of ``record``.

``sim2real record --home keyframe|current|q0,q1,...`` chooses where each episode starts and what the excitation
swings around: position servos get their set point at the home pose (the actuator length there), torque motors
swing around zero or, with ``--gravity-comp``, around the torque that holds the arm against gravity at its
*current* pose (recomputed every control step from the simulated state, as a real controller's feed-forward
term would be). :func:`plan_excitation` then simulates the episodes and halves the amplitude until no limited
joint comes within 1% of its range's ends, and says so in its notes.

Example:
    >>> import mujoco
    >>> from sysid.synthetic import generate_arm
    >>> model = mujoco.MjModel.from_xml_string(generate_arm(dof=6, seed=0))
    >>> home = resolve_home("keyframe", model)
    >>> plan = plan_excitation(model, home, policy="multisine", amplitude=0.5, steps=100, episodes=1,
    ...                        substeps=10, seed=0, gravity_comp=True)
    >>> plan.ctrl.shape, plan.amplitude <= 0.5
    ((1, 100, 6), True)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from sim2real.mjcf_env import home_pose

__all__ = ["HOME_CHOICES", "ExcitationPlan", "GravityCompensation", "parse_home", "plan_excitation", "resolve_home"]

#: The named ``--home`` choices (besides an explicit ``q0,q1,...``).
HOME_CHOICES: tuple[str, ...] = ("keyframe", "current")
_HALVINGS = 6
_MARGIN = 0.01  # fraction of a joint's range kept clear of each end


def parse_home(text: str | Sequence[float] | None) -> str | tuple[float, ...] | None:
    """``--home``'s value: ``"keyframe"``, ``"current"``, a tuple of joint positions or None (the default).

    Example:
        >>> parse_home("0, 0.5,-1")
        (0.0, 0.5, -1.0)
        >>> parse_home("kyeframe")
        Traceback (most recent call last):
        ...
        ValueError: `--home` must be one of ['keyframe', 'current'] or comma-separated joint positions \
'q0,q1,...'. Received 'kyeframe'.
    """
    if text is None:
        return None
    if not isinstance(text, str):
        values = tuple(float(v) for v in text)
    elif text in HOME_CHOICES:
        return text
    else:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise ValueError(
                f"`--home` must be one of {list(HOME_CHOICES)} or comma-separated joint positions 'q0,q1,...'. "
                f"Received {text!r}."
            ) from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"`--home` joint positions must be finite. Received {values!r}.")
    return values


def resolve_home(home: str | Sequence[float], model: mujoco.MjModel) -> np.ndarray:
    """The home ``qpos`` (shape ``(nq,)``) for ``"keyframe"`` (keyframe ``home``, else the first, else ``qpos0``)
    or explicit positions (``nq`` of them).

    Raises:
        ValueError: explicit positions of the wrong length, or ``"current"`` (which depends on the env's reset).
    """
    if isinstance(home, str):
        if home != "keyframe":
            raise ValueError(f"`--home` {home!r} has no fixed pose; only 'keyframe' or explicit positions do.")
        return home_pose(model)
    q = np.asarray(home, dtype=np.float64)
    if q.shape != (model.nq,):
        width = {int(mujoco.mjtJoint.mjJNT_FREE): 7, int(mujoco.mjtJoint.mjJNT_BALL): 4}
        order = [
            (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}")
            + (f" x{width[int(model.jnt_type[j])]}" if int(model.jnt_type[j]) in width else "")
            for j in range(model.njnt)
        ]
        raise ValueError(  # a gripper's fingers or a free object count too: name them, in qpos order
            f"`--home` must give {model.nq} joint positions (the model's nq, in qpos order: {', '.join(order)}). "
            f"Received {q.shape[0] if q.ndim else 1}."
        )
    return q


def _servo_mask(model: mujoco.MjModel) -> np.ndarray:
    from sysid.actuator_limits import _is_position_servo

    return np.asarray(_is_position_servo(model), dtype=bool)


class GravityCompensation:
    """The controls of the torque actuators that hold the arm still against gravity at a pose.

    The actuator map (joint torque per unit control, around the pose of ``calibrate_at``) is probed once; each
    call solves it in the least-squares sense for the gravity torque ``qfrc_bias(q, qvel=0)``.

    Args:
        model: the model (not modified).
        qpos: the pose the actuator map is probed at (the home pose).

    Raises:
        ValueError: the model has no torque actuators (only position servos).
    """

    def __init__(self, model: mujoco.MjModel, qpos: np.ndarray) -> None:
        self.model = model
        self.motors = ~_servo_mask(model)
        if not self.motors.any():
            raise ValueError(
                "`--gravity-comp` applies to torque-driven actuators; every actuator of this model is a position "
                "servo. Received a servo-only model."
            )
        self._data = mujoco.MjData(model)
        data = self._data
        data.qpos[:] = qpos
        columns = []
        for i in np.flatnonzero(self.motors):
            data.ctrl[:] = 0.0
            mujoco.mj_forward(model, data)
            base = data.qfrc_actuator.copy()
            data.ctrl[i] = 1.0
            mujoco.mj_forward(model, data)
            columns.append(data.qfrc_actuator - base)
        self._pinv = np.linalg.pinv(np.stack(columns, axis=1))
        self._bias = np.zeros(model.nv)
        self._out = np.zeros(model.nu)

    def __call__(self, qpos: np.ndarray) -> np.ndarray:
        """Controls ``(nu,)``: the gravity-holding command on the torque actuators, 0 on the servos."""
        data = self._data
        data.qpos[:] = qpos
        data.qvel[:] = 0.0
        # Gravity alone needs kinematics and the recursive Newton-Euler pass, not a full mj_forward (no
        # collision or constraint solve): at zero velocity the bias force is the gravity torque.
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)
        mujoco.mj_rne(self.model, data, 0, self._bias)
        self._out[self.motors] = self._pinv @ self._bias
        return self._out.copy()


@dataclass(frozen=True)
class ExcitationPlan:
    """The commands ``record`` sends and why.

    Attributes:
        ctrl: ``(episodes, steps, nu)`` commands, as sent (gravity compensation included).
        home: ``(nq,)`` the pose every episode starts from.
        amplitude: the amplitude used (a fraction of each actuator's half-range around its centre).
        requested: the amplitude asked for.
        notes: what the plan changed or could not guarantee, one sentence each.
    """

    ctrl: np.ndarray
    home: np.ndarray
    amplitude: float
    requested: float
    notes: tuple[str, ...]


def _limited_joint_ids(model: mujoco.MjModel) -> np.ndarray:
    scalar = np.isin(model.jnt_type, (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE))
    return np.flatnonzero(scalar & model.jnt_limited.astype(bool))


def _limited_joints(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    joints = _limited_joint_ids(model)
    ranges = model.jnt_range[joints]
    margin = np.maximum(_MARGIN * (ranges[:, 1] - ranges[:, 0]), 1e-6)
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, int(j)) or f"#{j}" for j in joints]
    low = ranges[:, 0] + margin
    high = ranges[:, 1] - margin
    return model.jnt_qposadr[joints], low, high, names


def _simulate(
    model: mujoco.MjModel,
    home: np.ndarray,
    deviation: np.ndarray,
    center: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    substeps: int,
    latency: int,
    gravity: GravityCompensation | None,
    stop_early: bool = False,
    tick: Callable[[], None] | None = None,
) -> tuple[np.ndarray, str | None]:
    """Runs the episodes; returns the commands sent and the first joint that left its range (or None). With
    ``stop_early`` a trial ends at the first joint out of range (its commands are then incomplete). ``tick`` is
    called after each episode (a progress bar)."""
    adr, low, high, names = _limited_joints(model)
    data = mujoco.MjData(model)
    episodes, steps, nu = deviation.shape
    ctrl = np.empty((episodes, steps, nu))
    outside: str | None = None
    for e in range(episodes):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = home
        mujoco.mj_forward(model, data)
        for t in range(steps):
            base = center if gravity is None else np.where(gravity.motors, gravity(data.qpos), center)
            ctrl[e, t] = np.clip(base + deviation[e, t], bounds[0], bounds[1])
            # Zeros until the first delayed command arrives: what record_log (initial_ctrl's default) will simulate.
            data.ctrl[:] = ctrl[e, t - latency] if t >= latency else 0.0
            mujoco.mj_step(model, data, nstep=substeps)
            q = data.qpos[adr]
            bad = np.flatnonzero((q < low) | (q > high))
            if outside is None and bad.size:
                outside = names[int(bad[0])]
                if stop_early:
                    return ctrl, outside
        if tick is not None:
            tick()
    return ctrl, outside


def plan_excitation(
    model: mujoco.MjModel,
    home: np.ndarray,
    *,
    policy: str,
    amplitude: float,
    steps: int,
    episodes: int,
    substeps: int,
    seed: int,
    gravity_comp: bool = False,
    latency: int = 0,
    tick: Callable[[], None] | None = None,
) -> ExcitationPlan:
    """The commands of ``episodes`` excitation episodes around ``home`` that keep every limited joint in range.

    Servos swing around their set point at ``home``; torque motors around the middle of their range, or around
    the gravity-holding torque when ``gravity_comp``. The episodes are simulated (``latency`` control steps of
    action delay included) and the amplitude is halved, up to 6 times, until no limited joint comes within 1% of
    an end of its range; the notes say when that happened or when even no excitation leaves the range.

    Args:
        model: the model the log is recorded on (perturbed already).
        home: ``(nq,)`` start pose of every episode (zero velocity).
        policy: a name of :data:`sysid.EXCITATIONS`.
        amplitude: requested fraction of each actuator's half-range, in (0, 1].
        steps: control steps per episode.
        episodes: episodes (episode ``e`` continues the signal at ``t0 = e * steps * dt``).
        substeps: physics steps per control step.
        seed: the excitation's seed.
        gravity_comp: add the gravity-holding torque of the current pose to the torque motors' commands.
        latency: action latency in control steps (zeros are sent until the first command arrives, as the log
            ``record`` makes of the plan will).
        tick: called after each simulated episode (trials included), e.g. to move a progress bar.

    Raises:
        ValueError: bad amplitude, a model without usable actuator limits, ``gravity_comp`` on a servo-only model.
    """
    import sysid

    if isinstance(amplitude, bool) or not isinstance(amplitude, (int, float)) or not 0 < amplitude <= 1:
        raise ValueError(f"`amplitude` must be in (0, 1]. Received {amplitude!r}.")
    data = mujoco.MjData(model)
    data.qpos[:] = home
    mujoco.mj_forward(model, data)
    limits = sysid.as_limits(model)
    servo = _servo_mask(model)
    span = limits.high - limits.low
    inside = np.clip(data.actuator_length, limits.low + 1e-3 * span, limits.high - 1e-3 * span)
    center = np.where(servo, inside, limits.center)
    limits = sysid.as_limits(limits, center)
    gravity = GravityCompensation(model, home) if gravity_comp else None
    dt = float(model.opt.timestep) * substeps
    unit = sysid.make_excitation(policy, limits, amplitude=1.0, seed=seed)
    full = np.stack([unit.signal(steps, dt, t0=e * steps * dt) for e in range(episodes)]) - center
    bounds = (limits.low, limits.high)
    notes: list[str] = []
    adr, _, _, names = _limited_joints(model)
    off_range = [
        f"{names[k]!r} (home {home[a]:.4g}, range [{model.jnt_range[j, 0]:.4g}, {model.jnt_range[j, 1]:.4g}])"
        for k, (a, j) in enumerate(zip(adr, _limited_joint_ids(model), strict=True))
        if not model.jnt_range[j, 0] <= home[a] <= model.jnt_range[j, 1]
    ]
    if off_range:  # the usual cause: MJCF ranges are in degrees unless <compiler angle="radian"/>
        notes.append(
            f"the home pose lies outside the range of joint(s) {', '.join(off_range)}; if the MJCF's ranges are meant "
            'in radians, add <compiler angle="radian"/> (MuJoCo reads them in degrees by default).'
        )
    _, still = _simulate(model, home, 0.0 * full, center, bounds, substeps, latency, gravity, True, tick=tick)
    if still is not None:
        _, low, high, _ = _limited_joints(model)
        k = names.index(still)
        j, q = int(_limited_joint_ids(model)[k]), float(home[adr[k]])
        if not model.jnt_range[j, 0] <= q <= model.jnt_range[j, 1]:
            notes.append(f"joint {still!r} starts outside its range; the amplitude was not reduced.")
        elif not low[k] <= q <= high[k]:  # it starts there: no excitation can keep it clear
            notes.append(
                f"joint {still!r} starts within {_MARGIN:.0%} of an end of its range (home {q:.4g}, range "
                f"[{model.jnt_range[j, 0]:.4g}, {model.jnt_range[j, 1]:.4g}]), so the check that keeps joints clear "
                "of their limits cannot pass; the amplitude was not reduced."
            )
        else:
            hint = "" if gravity_comp or servo.all() else "; try --gravity-comp"
            notes.append(
                f"joint {still!r} leaves its range even without excitation (the arm is not at rest at the home pose"
                f"{hint}); the amplitude was not reduced."
            )
        ctrl, _ = _simulate(model, home, amplitude * full, center, bounds, substeps, latency, gravity, tick=tick)
        return ExcitationPlan(ctrl, home.copy(), float(amplitude), float(amplitude), tuple(notes))
    used = float(amplitude)
    for _ in range(_HALVINGS + 1):
        ctrl, outside = _simulate(model, home, used * full, center, bounds, substeps, latency, gravity, True, tick=tick)
        if outside is None:
            break
        first = outside
        used /= 2
    else:
        used *= 2
        ctrl, _ = _simulate(model, home, used * full, center, bounds, substeps, latency, gravity, tick=tick)
        notes.append(f"joint {first!r} reaches its limit even at amplitude {used:g}; the log touches the limit.")
        return ExcitationPlan(ctrl, home.copy(), used, float(amplitude), tuple(notes))
    if used < amplitude:
        notes.append(
            f"amplitude clipped from {amplitude:g} to {used:g} so every limited joint stays inside its range "
            f"(joint {first!r} reached its limit at {2 * used:g})."
        )
    return ExcitationPlan(ctrl, home.copy(), used, float(amplitude), tuple(notes))
