"""Names a robotics engineer reads: display labels of policies and conditions, sweep axes in words with units.

Policies and conditions often share names (a policy ``randomized`` trained in the condition ``randomized``), so the
report shows them apart: policies as ``"policy: <name>"`` and conditions by kind (``"sim: nominal"``,
``"sim: <name>"``, ``"real twin"``, ``"real: <name>"``) unless the caller names them. A sweep axis such as
``ObservationNoise.processes.0.std`` is shown in the observation's physical units when the caller knows them
(:func:`observation_unit` reads them from an env: ``"sensor noise std (rad (position), m (to_target), rad/s
(velocity))"``) and as ``"sensor noise std (observation units)"`` otherwise; latencies counted in control steps are
shown in milliseconds, converted by :func:`noise_models.timing.convert_time` (the one converter).

Example:
    >>> axis_label("ActionLatency.steps", control_timestep=0.02)
    AxisLabel(text='action latency (ms)', factor=20.0, unit='ms')
    >>> axis_label("ObservationNoise.processes.0.std").text
    'sensor noise std (observation units)'
    >>> axis_label("ObservationNoise.processes.0.std", observation_unit="rad").text
    'sensor noise std (rad)'
    >>> condition_label("sim", "nominal", simulated=True), condition_label("real", "real", simulated=True)
    ('sim: nominal', 'real twin')
    >>> channel_unit("qvel[shoulder]"), parameter_unit("dof_damping[elbow]")
    ('rad/s', 'N·m·s/rad')
    >>> parameter_unit("tendon_damping[cable]", tendons={"cable": "m"})  # a spatial tendon (see tendon_units)
    'N·s/m'
"""

from __future__ import annotations

import re
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from noise_models.timing import convert_time

__all__ = [
    "AxisLabel",
    "axis_label",
    "channel_unit",
    "condition_label",
    "linear_names",
    "model_units",
    "observation_unit",
    "parameter_unit",
    "policy_label",
    "tendon_units",
]


@dataclass(frozen=True)
class AxisLabel:
    """A sweep axis in words.

    Attributes:
        text: the axis label with its unit, e.g. ``"action latency (ms)"``.
        factor: multiply the sweep's values by this to get the label's unit (1 unless a unit was converted).
        unit: the unit a value on this axis is written with (``"ms"``, ``"rad"``; ``""`` for a factor of nominal
            or an unknown unit; ``"in each channel's unit"`` for noise on channels of different units).
    """

    text: str
    factor: float
    unit: str = ""


# effect type -> what it perturbs, in words (the field's unit follows from the field name)
_EFFECTS = {
    "Damping": "joint damping",
    "ActuatorGain": "actuator gain",
    "Mass": "body mass",
    "Friction": "friction",
    "Armature": "joint armature",
    "Gravity": "gravity",
    "TendonStiffness": "tendon stiffness",
    "TendonDamping": "tendon damping",
    "TendonFrictionLoss": "tendon friction loss",
    "ActionLatency": "action latency",
    "ObservationLatency": "observation latency",
    "ObservationNoise": "sensor noise",
    "ActionNoise": "actuator noise",
}
# ``steps`` of a timing model (ActionLatency, ObservationLatency, SampleAndHold) counts physics steps on a MuJoCo env
_TIME_FIELDS = {"steps": "physics_steps", "seconds": "seconds", "physics_steps": "physics_steps"}

# address field prefix -> SI unit of the model field (hinge joints; slides would be m / N·s/m)
_PARAMETER_UNITS = (
    ("dof_damping", "N·m·s/rad"),
    ("dof_frictionloss", "N·m"),
    ("dof_armature", "kg·m²"),
    ("actuator_gain", "N·m per ctrl unit"),
    ("actuator_gear", "N·m per ctrl unit"),
    ("body_mass", "kg"),
    ("geom_friction", "1"),
    ("obs_latency", "s"),
    ("action_latency", "s"),
)
_CHANNEL_UNITS = (("qpos", "rad"), ("qvel", "rad/s"), ("qacc", "rad/s²"), ("ctrl", "ctrl units"))
# the same fields on a slide joint (or an actuator that pushes along one): lengths, not angles
_LINEAR_UNITS = {
    "dof_damping": "N·s/m",
    "dof_frictionloss": "N",
    "dof_armature": "kg",
    "actuator_gain": "N per ctrl unit",
    "actuator_gear": "N per ctrl unit",
    "qpos": "m",
    "qvel": "m/s",
    "qacc": "m/s²",
}


# tendon field -> (unit when the tendon's length is in m, unit when it is in rad): a tendon's force, stiffness,
# damping and armature follow the unit of its length, which :func:`tendon_units` reads from the model
_TENDON_UNITS = {
    "tendon_stiffness": ("N/m", "N·m/rad"),
    "tendon_damping": ("N·s/m", "N·m·s/rad"),
    "tendon_frictionloss": ("N", "N·m"),
    "tendon_lengthspring": ("m", "rad"),
    "tendon_armature": ("kg", "kg·m²"),
}
#: the unit :func:`parameter_unit` gives a tendon field of a fixed tendon over both hinges and slides
MIXED = "mixed units (tendon over hinge and slide joints)"


def tendon_units(model: Any) -> tuple[tuple[str, str], ...]:
    """``(tendon, unit of its length)`` for every tendon of a MuJoCo model, in id order: ``"m"`` for a spatial
    tendon and for a fixed tendon over slide joints only, ``"rad"`` for a fixed tendon over hinges only,
    ``"mixed"`` for a fixed tendon over both (its length adds angles and lengths; the coefficients carry the
    conversion, which the model does not state). Unnamed tendons are ``#<id>``, as addresses name them.

    :func:`parameter_unit` gives each tendon field (``tendon_damping``, ``tendon_stiffness``, ...) its unit from
    this; pass it as ``tendons=`` there and to :meth:`sim2real.report.GapReport.build`.

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body><joint name="a" type="slide"/><geom size=".1"/></body>'
        ...     '<body><joint name="b"/><geom size=".1"/></body></worldbody><tendon>'
        ...     '<fixed name="rail"><joint joint="a" coef="1"/></fixed>'
        ...     '<fixed><joint joint="a" coef="1"/><joint joint="b" coef="0.1"/></fixed></tendon></mujoco>')
        >>> tendon_units(model)
        (('rail', 'm'), ('#1', 'mixed'))
    """
    import mujoco

    from randomizers.addressing import element_names

    units = []
    for t, name in enumerate(element_names(model, "tendon")):
        start = int(model.tendon_adr[t])
        wraps = range(start, start + int(model.tendon_num[t]))
        if any(int(model.wrap_type[w]) != int(mujoco.mjtWrap.mjWRAP_JOINT) for w in wraps):
            units.append((name, "m"))  # a spatial tendon: a path through sites and around geoms, in metres
            continue
        kinds = {int(model.jnt_type[int(model.wrap_objid[w])]) for w in wraps}
        units.append((name, "rad" if kinds == {_HINGE} else "m" if kinds == {_SLIDE} else "mixed"))
    return tuple(units)


def linear_names(model: Any) -> tuple[str, ...]:
    """Names of the model's slide joints and of the actuators that push along slides only (directly or through a
    fixed tendon of slides): their parameters and channels are lengths and forces, not angles and torques; pass it
    as ``linear=`` to :func:`parameter_unit`, :func:`channel_unit` and :meth:`sim2real.report.GapReport.build`."""
    import mujoco

    obj = mujoco.mjtObj
    slide = {j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE}
    names = [mujoco.mj_id2name(model, obj.mjOBJ_JOINT, j) for j in sorted(slide)]
    for a in range(model.nu):
        target, kind = int(model.actuator_trnid[a, 0]), model.actuator_trntype[a]
        if kind == mujoco.mjtTrn.mjTRN_JOINT:
            pushes = target in slide
        elif kind == mujoco.mjtTrn.mjTRN_TENDON:
            wraps = range(int(model.tendon_adr[target]), int(model.tendon_adr[target] + model.tendon_num[target]))
            pushes = all(
                model.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT and int(model.wrap_objid[w]) in slide for w in wraps
            )
        else:
            pushes = False
        if pushes:
            names.append(mujoco.mj_id2name(model, obj.mjOBJ_ACTUATOR, a))
    return tuple(n for n in names if n)


def model_units(model: Any) -> dict[str, Any]:
    """What :meth:`sim2real.report.GapReport.build` reads a model's units from: ``linear`` (:func:`linear_names`) and
    ``tendons`` (:func:`tendon_units`), as keyword arguments.

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body><joint name="rail" type="slide"/><geom size=".1"/></body></worldbody>'
        ...     '<actuator><motor name="push" joint="rail"/></actuator></mujoco>')
        >>> model_units(model)
        {'linear': ('rail', 'push'), 'tendons': ()}
    """
    return {"linear": linear_names(model), "tendons": tendon_units(model)}


def _tendon(field: str, address: str, tendons: Mapping[str, str]) -> str | None:
    """The unit of the tendon field ``field`` of the tendon ``address`` names, when ``tendons`` knows that tendon."""
    pair = _TENDON_UNITS.get(field)
    named = re.match(r"[^\[]*\[([^\]]*)\]", address)
    if pair is None or named is None or named.group(1) not in tendons:
        return None
    length = tendons[named.group(1)]
    return pair[0] if length == "m" else pair[1] if length == "rad" else MIXED


def _linear(field: str, address: str, linear: Collection[str]) -> str | None:
    """The linear unit of ``field`` when the element ``address`` names is in ``linear``, else None."""
    named = re.match(r"[^\[]*\[([^\]]*)\]", address)
    if named is None or named.group(1) not in linear:
        return None
    return _LINEAR_UNITS.get(field)


def axis_label(
    axis: str,
    control_timestep: float | None = None,
    *,
    observation_unit: str | None = None,
    substeps: int | None = None,
) -> AxisLabel:
    """The human label of a sweep axis ``"<Effect>.<field path>"`` (``Condition.axes``).

    Args:
        axis: the axis as the conditions name it, e.g. ``"Damping.scale"``.
        control_timestep: seconds per control step; latencies in steps are then shown in ms (a step is a control
            step divided by ``substeps``; without ``substeps``, a control step, as on a one-substep task).
        observation_unit: the unit of the observation channels (:func:`observation_unit`), for sensor noise; None
            says "observation units".
        substeps: physics steps per control step of the env. A timing model's ``steps`` are physics steps; without
            ``control_timestep`` they are shown as such.

    Returns:
        An :class:`AxisLabel`; an unknown axis keeps its name (with ``factor`` 1).

    Example:
        >>> axis_label("Damping.scale").text, axis_label("ActionLatency.steps").text
        ('joint damping (× nominal)', 'action latency (physics steps)')
        >>> axis_label("ActionLatency.steps", 0.01, substeps=4)  # a MujocoEnv with frame_skip=4 at 100 Hz
        AxisLabel(text='action latency (ms)', factor=2.5, unit='ms')
    """
    effect, _, field = axis.partition(".")
    what = _EFFECTS.get(effect)
    if what is None or not field:
        return AxisLabel(axis, 1.0)
    last = field.rsplit(".", 1)[-1]
    if last in ("scale", "gain"):
        return AxisLabel(f"{what} (× nominal)", 1.0)
    if last in _TIME_FIELDS:
        unit = _TIME_FIELDS[last]
        # a bare ``steps`` with a control timestep but no substeps keeps the one-substep reading of a suite task
        if unit == "physics_steps" and (control_timestep is None or (substeps is None and last == "physics_steps")):
            return AxisLabel(f"{what} (physics steps)", 1.0, "physics steps")
        per = 1 if substeps is None else substeps
        step = (control_timestep or 1.0) / per
        seconds = convert_time(1.0, unit, "seconds", timestep=step, substeps=per)
        return AxisLabel(f"{what} (ms)", round(1000.0 * seconds, 12), "ms")
    if last == "std" and "sensor" in what:
        if not observation_unit:
            return AxisLabel(f"{what} std (observation units)", 1.0, "observation units")
        single = "(" not in observation_unit  # one unit for every channel, e.g. "rad"
        return AxisLabel(
            f"{what} std ({observation_unit})", 1.0, observation_unit if single else "in each channel's unit"
        )
    if last == "std":
        return AxisLabel(f"{what} std (ctrl units)", 1.0, "ctrl units")
    if last in ("offset", "add"):
        return AxisLabel(f"{what} offset", 1.0)
    return AxisLabel(f"{what} {last}", 1.0)


# dm-control observation key -> (unit on hinge joints, unit on slide joints); keys that name a distance are metres
_OBSERVATION_KEYS = {
    "position": ("rad", "m"),
    "joint_angles": ("rad", "m"),
    "velocity": ("rad/s", "m/s"),
    "joint_velocities": ("rad/s", "m/s"),
    "to_target": ("m", "m"),
    "finger_to_target": ("m", "m"),
    "target_position": ("m", "m"),
    "height": ("m", "m"),
}


def observation_unit(keys: object, *, angular: bool = True) -> str | None:
    """The unit of a flat observation made of dm-control keys, or None when one of the keys is unknown.

    Args:
        keys: the observation's keys in order (e.g. ``("position", "to_target", "velocity")``), or an env whose
            unwrapped adapter has an ``observation_layout`` (``(key, slice, shape)`` triples) and a MuJoCo model
            (``angular`` is then True when every joint of the model is a hinge).
        angular: joint positions and velocities are angles (rad, rad/s), not lengths (m, m/s).

    Returns:
        One unit when every channel has it (``"rad"``), else each key's unit in order, e.g.
        ``"rad (position), m (to_target), rad/s (velocity)"``; None when a key's unit is not known (the caller
        then says "observation units" rather than guess).

    Example:
        >>> observation_unit(("position", "to_target", "velocity"))
        'rad (position), m (to_target), rad/s (velocity)'
        >>> observation_unit(("position",)), observation_unit(("position", "pixels")) is None
        ('rad', True)
        >>> import sim2real
        >>> from sysid.synthetic import generate_arm
        >>> from sim2real.mjcf_env import MjcfEnv
        >>> observation_unit(MjcfEnv(xml=generate_arm(dof=6, seed=0)))  # what `--model robot.xml` observes
        'rad (qpos), rad/s (qvel)'
    """
    names: tuple[str, ...]
    if isinstance(keys, (list, tuple)):
        names = tuple(str(k) for k in keys)
    elif _is_mjcf_env(keys):  # a bare MJCF env (--model): qpos then qvel
        base: Any = getattr(keys, "unwrapped", keys)
        kinds = {int(t) for t in base.model.jnt_type}
        if len(kinds) != 1 or not kinds <= {_HINGE, _SLIDE}:
            return None  # hinges beside slides (an arm with a gripper): one unit per channel is not one per key
        return "rad (qpos), rad/s (qvel)" if kinds == {_HINGE} else "m (qpos), m/s (qvel)"
    else:
        layout = getattr(getattr(keys, "unwrapped", keys), "observation_layout", None)
        if not layout:
            return None
        names = tuple(str(item[0]) for item in layout)
        angular = _all_hinges(keys)
    if not names or any(n not in _OBSERVATION_KEYS for n in names):
        return None
    units = [_OBSERVATION_KEYS[n][0 if angular else 1] for n in names]
    if len(set(units)) == 1:
        return units[0]
    return ", ".join(f"{u} ({n})" for u, n in zip(units, names, strict=True))


_HINGE, _SLIDE = 3, 2  # mujoco.mjtJoint.mjJNT_HINGE / mjJNT_SLIDE


def _is_mjcf_env(env: object) -> bool:
    from sim2real.mjcf_env import MjcfEnv

    return isinstance(getattr(env, "unwrapped", env), MjcfEnv)


def _all_hinges(env: object) -> bool:
    """True when every joint of the MuJoCo model inside ``env`` is a hinge (and it has one)."""
    import mujoco

    from sim2real.physics import find_physics

    handle = find_physics(env)
    if handle is None or handle.model.njnt == 0:
        return False
    return bool((handle.model.jnt_type == int(mujoco.mjtJoint.mjJNT_HINGE)).all())


def policy_label(name: str) -> str:
    """``"policy: <name>"``: a policy's default display name, apart from any condition of the same name."""
    return f"policy: {name}"


def condition_label(name: str, kind: str, *, simulated: bool) -> str:
    """A condition's default display name, by kind: ``"sim: nominal"`` for the nominal sim named ``sim``,
    ``"sim: <name>"`` for other simulators, ``"real twin"`` for a simulated ``real`` target, ``"real: <name>"``
    for measured returns; sweep points keep their name."""
    if kind == "nominal":
        return "sim: nominal" if name == "sim" else f"sim: {name}"
    if kind == "randomized":
        return f"sim: {name}"
    if kind == "real":
        return ("real twin" if name == "real" else f"real twin: {name}") if simulated else f"real: {name}"
    if kind == "measured":
        return f"real: {name}"
    return name


def parameter_unit(
    address: str, linear: Collection[str] = (), tendons: Mapping[str, str] | Iterable[tuple[str, str]] = ()
) -> str:
    """The SI unit of an addressed parameter's field (``""`` when unknown), e.g. ``N·m·s/rad`` for
    ``dof_damping[...]``; ``N·s/m`` when the element is among ``linear`` (slide joints, and actuators that push
    along them).

    A tendon field (``tendon_stiffness``, ``tendon_damping``, ``tendon_frictionloss``, ``tendon_lengthspring``,
    ``tendon_armature``) takes its unit from its tendon's length unit in ``tendons`` (:func:`tendon_units`: ``"m"``,
    ``"rad"`` or ``"mixed"``, which is said so); a tendon ``tendons`` does not list has no unit (``""``).

    Example:
        >>> parameter_unit("dof_damping[elbow]"), parameter_unit("dof_damping[finger]", linear=("finger",))
        ('N·m·s/rad', 'N·s/m')
        >>> units = {"coupling": "rad", "grip": "m", "#2": "mixed"}
        >>> [parameter_unit(f"tendon_stiffness[{t}]", tendons=units) for t in ("coupling", "grip", "#2", "other")]
        ['N·m/rad', 'N/m', 'mixed units (tendon over hinge and slide joints)', '']
        >>> parameter_unit("tendon_lengthspring[grip][1]", tendons=units)
        'm'
    """
    field = address.split("[", 1)[0]
    if field in _TENDON_UNITS:
        return _tendon(field, address, dict(tendons)) or ""
    found = _linear(field, address, linear)
    if found is not None:
        return found
    for prefix, unit in _PARAMETER_UNITS:
        if address.startswith(prefix):
            return unit
    return ""


def channel_unit(channel: str, linear: Collection[str] = ()) -> str:
    """The unit of a logged channel (``qpos[...]`` rad, ``qvel[...]`` rad/s, ...; m and m/s for a joint among
    ``linear``); ``""`` when unknown."""
    head = re.split(r"[\[.]", channel, maxsplit=1)[0]
    found = _linear(head, channel, linear)
    if found is not None:
        return found
    for prefix, unit in _CHANNEL_UNITS:
        if head == prefix:
            return unit
    return ""
