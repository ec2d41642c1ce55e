"""MuJoCo model-side randomisation: distributions, parameter addresses, physics and visual effects, schedules.

Operates on a compiled ``mujoco.MjModel`` and never on environments (``sim2real`` wraps those).
Depends only on numpy, scipy, mujoco and PyYAML; never imports ``sysid`` or ``sim2real``.

Example:
    >>> from randomizers import Friction, Mass, Uniform
    >>> effects = [Friction(scale=Uniform(0.5, 1.5)), Mass(scale=Uniform(0.8, 1.2), bodies="arm*")]
    >>> effects[1]
    Mass(scale=Uniform(low=0.8, high=1.2), bodies='arm*')
"""

from __future__ import annotations

from randomizers.addressing import Address, element_names, select
from randomizers.config import (
    EFFECT_TYPES,
    SIGNAL_TYPES,
    dump_config,
    dump_effects,
    effect_to_config,
    load_config,
    load_effects,
    load_signals,
)
from randomizers.distributions import (
    Choice,
    Constant,
    Distribution,
    LogUniform,
    Normal,
    Sampler,
    TruncatedNormal,
    Uniform,
    as_distribution,
    distribution_from_config,
)
from randomizers.effects import (
    ActuatorGain,
    Armature,
    Binding,
    Damping,
    Effect,
    Friction,
    FrictionLoss,
    Gravity,
    Interval,
    Mass,
    Push,
    Stiffness,
)
from randomizers.randomizer import PhysicsRandomizer
from randomizers.seeding import StreamFactory, stream
from randomizers.visual import (
    CameraFovy,
    CameraPose,
    GeomColor,
    Light,
    MaterialColor,
    Product,
    Texture,
    add_texture_uploader,
)

__all__ = [
    "EFFECT_TYPES",
    "SIGNAL_TYPES",
    "ActuatorGain",
    "Address",
    "Armature",
    "Binding",
    "CameraFovy",
    "CameraPose",
    "Choice",
    "Constant",
    "Damping",
    "Distribution",
    "Effect",
    "Friction",
    "FrictionLoss",
    "GeomColor",
    "Gravity",
    "Interval",
    "Light",
    "LogUniform",
    "Mass",
    "MaterialColor",
    "Normal",
    "PhysicsRandomizer",
    "Product",
    "Push",
    "Sampler",
    "Stiffness",
    "StreamFactory",
    "Texture",
    "TruncatedNormal",
    "Uniform",
    "add_texture_uploader",
    "as_distribution",
    "distribution_from_config",
    "dump_config",
    "dump_effects",
    "effect_to_config",
    "element_names",
    "load_config",
    "load_effects",
    "load_signals",
    "select",
    "stream",
]
