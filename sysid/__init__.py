"""System identification from logged trajectories (issue #5).

Fits the same parameter addresses that :mod:`randomizers` perturbs, from trajectory logs that this
package owns (:mod:`sysid.logs`). Depends on randomizers, noise_models, numpy, scipy and mujoco; never on
``sim2real``.

Example:
    >>> import sysid
    >>> "TrajectoryLog" in sysid.__all__
    True
"""

from __future__ import annotations

from sysid.csv_import import UNITS, CsvWarning, load_column_map, load_csv, log_format
from sysid.design import DesignResult, candidate_grid, design_experiment, fisher_information, parameter_space
from sysid.excitation import (
    EXCITATIONS,
    PRBS,
    ActuatorLimits,
    Chirp,
    ExcitationPolicy,
    Multisine,
    RandomSteps,
    as_limits,
    make_excitation,
)
from sysid.fit import DEFAULT_LATENCY_RANGE, fit
from sysid.logs import (
    OPTIONAL_KEYS,
    REQUIRED_KEYS,
    LogError,
    TrajectoryLog,
    channel_names,
    check_log_path,
    load_log,
    save_log,
    validate_log,
)
from sysid.online import OnlineEstimator, OnlineResult, estimate_noise_std, estimate_online
from sysid.params import EFFECT_FIELDS, ParameterSpace
from sysid.quality import FitQuality, NotOkError
from sysid.record import record_log
from sysid.result import FitResult

__all__ = [
    "DEFAULT_LATENCY_RANGE",
    "EFFECT_FIELDS",
    "EXCITATIONS",
    "OPTIONAL_KEYS",
    "PRBS",
    "REQUIRED_KEYS",
    "UNITS",
    "ActuatorLimits",
    "Chirp",
    "CsvWarning",
    "DesignResult",
    "ExcitationPolicy",
    "FitQuality",
    "FitResult",
    "LogError",
    "Multisine",
    "NotOkError",
    "OnlineEstimator",
    "OnlineResult",
    "ParameterSpace",
    "RandomSteps",
    "TrajectoryLog",
    "as_limits",
    "candidate_grid",
    "channel_names",
    "check_log_path",
    "design_experiment",
    "estimate_noise_std",
    "estimate_online",
    "fisher_information",
    "fit",
    "load_column_map",
    "load_csv",
    "load_log",
    "log_format",
    "make_excitation",
    "parameter_space",
    "record_log",
    "save_log",
    "validate_log",
]
