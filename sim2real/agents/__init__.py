"""Agents: PPO and SAC training with TorchRL, checkpoints, scripted baselines and the policy adapter.

Configs and baselines need numpy and PyYAML only; everything touching torch is imported on first use,
so ``import sim2real.agents`` stays light.

Example:
    >>> import sim2real.agents as agents
    >>> agents.PPOConfig(frames=1_000).frames
    1000
    >>> agents.as_policy(agents.ReachController()).name
    'ReachController(kp=1.0, max_delta=0.05)'
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from sim2real.agents.baselines import BASELINES, ReachController, ReacherPD, baseline_for
from sim2real.agents.config import ACTIVATIONS, PPOConfig, SACConfig, load_agent_config
from sim2real.agents.policy import BatchedPolicy, as_policy
from sim2real.agents.run_status import RunStatus, read_run_status

if TYPE_CHECKING:
    from sim2real.agents.checkpoint import Checkpoint, CheckpointError, load_checkpoint, save_checkpoint
    from sim2real.agents.cli import cli_train
    from sim2real.agents.collect import make_train_env
    from sim2real.agents.training import TrainResult, train

__all__ = [
    "ACTIVATIONS",
    "BASELINES",
    "BatchedPolicy",
    "Checkpoint",
    "CheckpointError",
    "PPOConfig",
    "ReachController",
    "ReacherPD",
    "RunStatus",
    "SACConfig",
    "TrainResult",
    "as_policy",
    "baseline_for",
    "cli_train",
    "load_agent_config",
    "load_checkpoint",
    "make_train_env",
    "read_run_status",
    "save_checkpoint",
    "train",
]

_LAZY = {
    "Checkpoint": "sim2real.agents.checkpoint",
    "CheckpointError": "sim2real.agents.checkpoint",
    "load_checkpoint": "sim2real.agents.checkpoint",
    "save_checkpoint": "sim2real.agents.checkpoint",
    "TrainResult": "sim2real.agents.training",
    "make_train_env": "sim2real.agents.collect",
    "train": "sim2real.agents.training",
    "cli_train": "sim2real.agents.cli",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'sim2real.agents' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
