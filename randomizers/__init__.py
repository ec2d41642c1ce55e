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

from randomizers.addressing import element_names, select
from randomizers.adr import ADR, ADRHistory, Episode, EpisodeResult, Pin
from randomizers.adr_randomizer import ADRRandomizer
from randomizers.com import BodyComOffset
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
from randomizers.correlated import Correlated
from randomizers.distributions import (
    Choice,
    Constant,
    Distribution,
    LogUniform,
    MultivariateNormal,
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
from randomizers.parameters import (
    EFFECT_FIELDS,
    FIELD_EFFECTS,
    Address,
    ParameterBinding,
    ParameterSet,
    effect_for,
    parse_assignment,
)
from randomizers.randomizer import PhysicsRandomizer
from randomizers.seeding import StreamFactory, stream
from randomizers.tendons import TendonDamping, TendonFrictionLoss, TendonStiffness
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
    "ADR",
    "EFFECT_FIELDS",
    "EFFECT_TYPES",
    "FIELD_EFFECTS",
    "SIGNAL_TYPES",
    "ADRHistory",
    "ADRRandomizer",
    "ActuatorGain",
    "Address",
    "Armature",
    "Binding",
    "BodyComOffset",
    "CameraFovy",
    "CameraPose",
    "Choice",
    "Constant",
    "Correlated",
    "Damping",
    "Distribution",
    "Effect",
    "Episode",
    "EpisodeResult",
    "Friction",
    "FrictionLoss",
    "GeomColor",
    "Gravity",
    "Interval",
    "Light",
    "LogUniform",
    "Mass",
    "MaterialColor",
    "MultivariateNormal",
    "Normal",
    "ParameterBinding",
    "ParameterSet",
    "PhysicsRandomizer",
    "Pin",
    "Product",
    "Push",
    "Sampler",
    "Stiffness",
    "StreamFactory",
    "TendonDamping",
    "TendonFrictionLoss",
    "TendonStiffness",
    "Texture",
    "TruncatedNormal",
    "Uniform",
    "add_texture_uploader",
    "as_distribution",
    "distribution_from_config",
    "dump_config",
    "dump_effects",
    "effect_for",
    "effect_to_config",
    "element_names",
    "load_config",
    "load_effects",
    "load_signals",
    "parse_assignment",
    "select",
    "stream",
]
