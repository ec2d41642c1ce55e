"""sim2real: make robot policies survive the jump from MuJoCo simulation to the real world.

``import sim2real as s2r`` reaches everything: tasks (:func:`make`), wrapping any env
(:func:`wrap`), the effects of :mod:`randomizers` and the noise and latency models of :mod:`noise_models`.

Example:
    >>> import sim2real as s2r
    >>> env = s2r.wrap(s2r.make("sim2real/arm-reach"), s2r.Damping(scale=s2r.Uniform(0.5, 2.0)), seed=0)
    >>> obs, info = env.reset(seed=0)
    >>> obs.shape, sorted(info["sim2real"]["params"])[0]
    ((16,), 'dof_damping[base_yaw]')
"""

from __future__ import annotations

from sim2real._gl import select_backend

select_backend()

from noise_models import (  # noqa: E402
    ActionLatency,
    ActionNoise,
    Bias,
    ControlJitter,
    Deadzone,
    Drift,
    Dropout,
    Gaussian,
    ObservationLatency,
    ObservationNoise,
    Outlier,
    Quantize,
    SampleAndHold,
    Saturate,
    Scale,
    Sticky,
    Stuck,
    UniformNoise,
)
from randomizers import (  # noqa: E402 - the GL backend must be chosen before mujoco loads
    ADR,
    ActuatorGain,
    ADRHistory,
    Armature,
    BodyComOffset,
    CameraFovy,
    CameraPose,
    Choice,
    Constant,
    Correlated,
    Damping,
    Friction,
    FrictionLoss,
    GeomColor,
    Gravity,
    Interval,
    Light,
    LogUniform,
    Mass,
    MaterialColor,
    MultivariateNormal,
    Normal,
    Push,
    Stiffness,
    TendonDamping,
    TendonFrictionLoss,
    TendonStiffness,
    Texture,
    TruncatedNormal,
    Uniform,
    dump_config,
    load_config,
    load_effects,
)
from sim2real import metrics  # noqa: E402
from sim2real.adapters import DmEnvToGym  # noqa: E402
from sim2real.batched import make_batched  # noqa: E402
from sim2real.metrics import Estimate, FewSamplesWarning, Gap, RobustnessRadius  # noqa: E402
from sim2real.physics import PhysicsHandle, find_physics  # noqa: E402
from sim2real.pixels import PixelObservation, track_render_contexts  # noqa: E402
from sim2real.sheets import ContactSheet, contact_sheet  # noqa: E402
from sim2real.tasks import TASKS, make, task_ids  # noqa: E402
from sim2real.wrapping import make_vec, wrap  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "ADR",
    "TASKS",
    "ADRHistory",
    "ActionLatency",
    "ActionNoise",
    "ActuatorGain",
    "Armature",
    "Bias",
    "BodyComOffset",
    "CameraFovy",
    "CameraPose",
    "Choice",
    "Constant",
    "ContactSheet",
    "ControlJitter",
    "Correlated",
    "Damping",
    "Deadzone",
    "DmEnvToGym",
    "Drift",
    "Dropout",
    "Estimate",
    "FewSamplesWarning",
    "Friction",
    "FrictionLoss",
    "Gap",
    "Gaussian",
    "GeomColor",
    "Gravity",
    "Interval",
    "Light",
    "LogUniform",
    "Mass",
    "MaterialColor",
    "MultivariateNormal",
    "Normal",
    "ObservationLatency",
    "ObservationNoise",
    "Outlier",
    "PhysicsHandle",
    "PixelObservation",
    "Push",
    "Quantize",
    "RobustnessRadius",
    "SampleAndHold",
    "Saturate",
    "Scale",
    "Sticky",
    "Stiffness",
    "Stuck",
    "TendonDamping",
    "TendonFrictionLoss",
    "TendonStiffness",
    "Texture",
    "TruncatedNormal",
    "Uniform",
    "UniformNoise",
    "contact_sheet",
    "dump_config",
    "find_physics",
    "load_config",
    "load_effects",
    "make",
    "make_batched",
    "make_vec",
    "metrics",
    "task_ids",
    "track_render_contexts",
    "wrap",
]
