"""TorchRL: :class:`RandomizeAndCorruptTransform`, physics randomisation and signal models in one transform.

:func:`sim2real.wrap` appends it to a TorchRL env given both physics effects and signal models. It does what
``Compose(RandomizePhysicsTransform(effects), CorruptSignalsTransform(models))`` does, in the same order (the
signal models act on the action first and the physics effects' step schedule after; at reset the signal models
draw first, as ``Compose`` runs its reset preprocessing backwards; on the way out physics writes
``"sim2real_params"``/``"sim2real_diverged"`` first, then the signal models change the observation and write
``"sim2real_signal_params"``): the same TensorDicts, bitwise (tested), with one transform on the path instead of a
``Compose`` of two.

Example:
    >>> import sim2real
    >>> from torchrl.envs import DMControlEnv
    >>> from noise_models import Gaussian, ObservationNoise
    >>> from randomizers import Damping, Uniform
    >>> env = sim2real.wrap(DMControlEnv("reacher", "easy"), Damping(scale=Uniform(0.5, 2.0)),
    ...                     ObservationNoise(Gaussian(std=0.01)), seed=0)
    >>> type(env.transform).__name__
    'RandomizeAndCorruptTransform'
    >>> td = env.rollout(3)
    >>> td["sim2real_params"].shape, td["sim2real_signal_params"].shape
    (torch.Size([3, 2]), torch.Size([3, 1]))
    >>> env.transform.param_names, env.transform.signal_param_names
    (('dof_damping[shoulder]', 'dof_damping[wrist]'), ('obs_noise_std',))
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from tensordict import NestedKey, TensorDictBase
from torchrl.data import Composite

from randomizers import Effect
from randomizers.seeding import SeedLike
from sim2real.wrappers.torchrl import CorruptSignalsTransform, RandomizePhysicsTransform

__all__ = ["RandomizeAndCorruptTransform"]


class _PhysicsPart(RandomizePhysicsTransform):
    """The physics half of a :class:`RandomizeAndCorruptTransform`: its parent env is its owner's."""

    def __init__(self, effects: Sequence[Effect], seed: SeedLike, owner: RandomizeAndCorruptTransform) -> None:
        super().__init__(effects, seed)
        self.__dict__["_owner"] = owner  # in __dict__, not a registered submodule (no cycle in .modules())

    @property
    def parent(self) -> Any:
        return self.__dict__["_owner"].parent


class RandomizeAndCorruptTransform(CorruptSignalsTransform):
    """Physics effects on every reset and noise and timing models on observations and actions, in one transform.

    TensorDicts carry what the two transforms write: ``"sim2real_params"`` (float64, one entry per
    :attr:`param_names`), ``"sim2real_diverged"`` (with ``"truncated"``/``"done"`` set on a divergence) and
    ``"sim2real_signal_params"`` (one entry per :attr:`signal_param_names`).

    The signal models compute in numpy (:mod:`noise_models` is numpy only): on the CPU each observation entry and
    the action reach them as zero-copy views of the tensors' memory, and their results go back as tensors sharing
    the arrays' memory; one copy remains where several observation entries are concatenated into one signal, or
    where a latency or sample-and-hold buffer would otherwise keep a view of a tensor TorchRL may reuse.

    Args:
        effects: physics effects from :mod:`randomizers`.
        models: ObservationNoise, ActionNoise, ObservationLatency, ActionLatency, SampleAndHold, ControlJitter.
        seed: root seed of every stream.
        observation_keys: the entries treated as the observation (see
            :class:`~sim2real.wrappers.CorruptSignalsTransform`).
    """

    def __init__(
        self,
        effects: Sequence[Effect],
        models: Sequence[Any],
        seed: SeedLike = None,
        observation_keys: Sequence[NestedKey] | None = None,
    ) -> None:
        physics = _PhysicsPart(effects, seed, self)  # built first, as RandomizePhysicsTransform comes first
        super().__init__(models, seed, observation_keys)
        self.__dict__["_physics"] = physics

    @property
    def physics(self) -> RandomizePhysicsTransform:
        """The physics half (what a ``RandomizePhysicsTransform`` would be)."""
        physics: RandomizePhysicsTransform = self.__dict__["_physics"]
        return physics

    @property
    def randomizer(self) -> Any:
        """The :class:`randomizers.PhysicsRandomizer` behind ``"sim2real_params"``."""
        return self.physics.randomizer

    @property
    def param_names(self) -> tuple[str, ...]:
        """The address of each entry of ``"sim2real_params"``."""
        return self.physics.param_names

    @property
    def signal_param_names(self) -> tuple[str, ...]:
        """The name of each entry of ``"sim2real_signal_params"``."""
        self._bound()
        return self._names

    @property
    def current_params(self) -> dict[str, float]:
        """Address or name -> value in use this episode: the physics draws, then the signal models'."""
        merged = dict(self.physics.current_params)
        merged.update(self.corruptor.current_params)
        return merged

    @property
    def reapplied(self) -> tuple[str, ...]:
        """Addresses whose draws the task's own reset overwrote and that were written again (this episode)."""
        return self.physics.reapplied

    # -- TorchRL hooks, in Compose's order ---------------------------------------------------------
    def _reset_env_preprocess(self, tensordict: TensorDictBase | None) -> TensorDictBase | None:
        tensordict = super()._reset_env_preprocess(tensordict)
        return self.physics._reset_env_preprocess(tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset = self.physics._reset(tensordict, tensordict_reset)
        return super()._reset(tensordict, tensordict_reset)

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict = super()._inv_call(tensordict)
        return self.physics._inv_call(tensordict)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict = self.physics._step(tensordict, next_tensordict)
        return super()._step(tensordict, next_tensordict)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec = self.physics.transform_observation_spec(observation_spec)
        return super().transform_observation_spec(observation_spec)

    def clone(self) -> RandomizeAndCorruptTransform:
        # Transform.clone copies __dict__ shallowly: the clone's physics half must answer to the clone.
        other = super().clone()
        part = self.physics.clone()
        part.__dict__["_owner"] = other
        other.__dict__["_physics"] = part
        return other

    def restore_nominal(self) -> None:
        """Writes every touched model field back to its nominal value (bitwise)."""
        self.physics.restore_nominal()

    def close(self) -> None:
        self.physics.close()
        super().close()
