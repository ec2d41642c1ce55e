"""Sensor and actuator imperfections: noise processes, quantisation, dropout, latency at physics rate.

numpy only: this package knows nothing of MuJoCo or of environment APIs (see DESIGN.md);
``sim2real.wrap`` applies these models to gymnasium, dm_env and TorchRL environments. Parameters take
a number or anything with ``sample(rng, size)`` (the ``randomizers`` distributions work).

Example:
    >>> from noise_models import ActionLatency, Bias, Gaussian, ObservationLatency, ObservationNoise
    >>> models = [ObservationNoise(Gaussian(std=0.01), Bias(0.02)), ObservationLatency(steps=3),
    ...           ActionLatency(seconds=0.02)]
    >>> models[1]
    ObservationLatency(steps=3.0)
"""

from __future__ import annotations

from noise_models.corruptor import ActionNoise, ObservationNoise, SignalCorruptor, SignalModel
from noise_models.processes import (
    BLOCK,
    PROCESS_TYPES,
    Bias,
    Deadzone,
    Drift,
    Dropout,
    Gaussian,
    Outlier,
    Process,
    Quantize,
    Saturate,
    Scale,
    Sticky,
    Stuck,
    UniformNoise,
)
from noise_models.seeding import StreamFactory, normalize_seed, stream
from noise_models.timing import ActionLatency, ControlJitter, ObservationLatency, SampleAndHold
from noise_models.values import Layout

__all__ = [
    "BLOCK",
    "PROCESS_TYPES",
    "ActionLatency",
    "ActionNoise",
    "Bias",
    "ControlJitter",
    "Deadzone",
    "Drift",
    "Dropout",
    "Gaussian",
    "Layout",
    "ObservationLatency",
    "ObservationNoise",
    "Outlier",
    "Process",
    "Quantize",
    "SampleAndHold",
    "Saturate",
    "Scale",
    "SignalCorruptor",
    "SignalModel",
    "Sticky",
    "StreamFactory",
    "Stuck",
    "UniformNoise",
    "normalize_seed",
    "stream",
]
