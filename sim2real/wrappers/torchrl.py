"""TorchRL transform that randomises physics: :class:`RandomizePhysicsTransform`.

The draws of the episode travel in every TensorDict under ``"sim2real_params"`` (float64, one
entry per address in :attr:`RandomizePhysicsTransform.param_names`), and a physics divergence sets
``"sim2real_diverged"`` together with ``"truncated"``/``"done"``.

Example:
    >>> from torchrl.envs import DMControlEnv, TransformedEnv
    >>> from randomizers import Friction, Uniform
    >>> env = TransformedEnv(DMControlEnv("reacher", "easy"),
    ...                      RandomizePhysicsTransform([Friction(scale=Uniform(0.5, 1.5))], seed=0))
    >>> td = env.reset()
    >>> td["sim2real_params"].shape
    torch.Size([10])
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import Binary, Composite, Unbounded
from torchrl.envs.transforms import Transform

from randomizers import Effect, PhysicsRandomizer
from randomizers.seeding import SeedLike
from sim2real.physics import PhysicsHandle
from sim2real.wrappers.gym import require_physics

__all__ = ["RandomizePhysicsTransform"]

PARAMS_KEY = "sim2real_params"
DIVERGED_KEY = "sim2real_diverged"


def _no_exceptions(physics: Any) -> None:
    # A transform cannot catch an exception raised inside the base env's step, so let MuJoCo's
    # auto-reset happen and detect the divergence from the warning counters instead.
    if hasattr(physics, "_warnings_cause_exception"):
        physics._warnings_cause_exception = False


class RandomizePhysicsTransform(Transform):
    """Applies physics effects on every reset of the TorchRL env it is appended to.

    Args:
        effects: physics effects from :mod:`randomizers`.
        seed: root seed of the effect streams.
    """

    def __init__(self, effects: Sequence[Effect], seed: SeedLike = None) -> None:
        super().__init__(in_keys=[], out_keys=[PARAMS_KEY, DIVERGED_KEY])
        self.randomizer = PhysicsRandomizer(effects, seed)
        self._handle: PhysicsHandle | None = None
        self._hook: Any = None
        self._names: tuple[str, ...] = ()

    # -- binding ---------------------------------------------------------------------------------
    def _bound(self) -> PhysicsHandle:
        if self._handle is None:
            parent = self.parent
            if parent is None:
                raise RuntimeError("RandomizePhysicsTransform must be appended to a TransformedEnv before use.")
            base = parent.base_env
            handle = require_physics(base, self.randomizer.effects)
            self.randomizer.bind(handle.model, handle.data)
            if handle.source.startswith("dm_control"):
                _no_exceptions(handle.owner.physics)
            if handle.recompiles:
                self._hook = handle.on_recompile(self._recompiled)
            self._handle = handle
            # Addresses come from a throwaway draw so the spec is known before the first reset.
            self._names = tuple(self.randomizer.nominal_params())
        return self._handle

    def _recompiled(self, model: Any, data: Any) -> None:
        self.randomizer.bind(model, data)
        self.randomizer.apply()
        _no_exceptions(self._handle.owner.physics)  # type: ignore[union-attr]

    @property
    def param_names(self) -> tuple[str, ...]:
        """The address of each entry of ``"sim2real_params"``."""
        self._bound()
        return self._names

    @property
    def current_params(self) -> dict[str, float]:
        """Address -> value in use this episode."""
        return self.randomizer.current_params

    def _params_tensor(self, batch: torch.Size) -> torch.Tensor:
        params = self.randomizer.current_params
        values = [params.get(name, float("nan")) for name in self._names]
        return torch.tensor(values, dtype=torch.float64).expand(*batch, len(values)).clone()

    # -- TorchRL hooks ---------------------------------------------------------------------------
    def _reset_env_preprocess(self, tensordict: TensorDictBase | None) -> TensorDictBase | None:
        handle = self._bound()
        self.randomizer.begin_episode()
        if not handle.recompiles:
            self.randomizer.apply()
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset.set(PARAMS_KEY, self._params_tensor(tensordict_reset.batch_size))
        tensordict_reset.set(DIVERGED_KEY, torch.zeros(*tensordict_reset.batch_size, 1, dtype=torch.bool))
        return tensordict_reset

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.randomizer.has_step_effects:
            self.randomizer.step()
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        handle = self._bound()
        batch = next_tensordict.batch_size
        diverged = handle.diverged()
        next_tensordict.set(PARAMS_KEY, self._params_tensor(batch))
        next_tensordict.set(DIVERGED_KEY, torch.full((*batch, 1), diverged, dtype=torch.bool))
        if diverged:
            for key in ("truncated", "done"):
                if key in next_tensordict:
                    next_tensordict.set(key, torch.ones_like(next_tensordict.get(key)))
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        self._bound()
        batch = observation_spec.shape
        observation_spec[PARAMS_KEY] = Unbounded(
            shape=(*batch, len(self._names)), dtype=torch.float64, device=observation_spec.device
        )
        observation_spec[DIVERGED_KEY] = Binary(
            n=1, shape=(*batch, 1), dtype=torch.bool, device=observation_spec.device
        )
        return observation_spec

    def restore_nominal(self) -> None:
        """Writes every touched model field back to its nominal value (bitwise)."""
        self.randomizer.restore_nominal()

    def close(self) -> None:
        self.restore_nominal()
        if self._hook is not None and self._handle is not None:
            self._handle.remove_hook(self._hook)
            self._hook = None
        super().close() if hasattr(super(), "close") else None
