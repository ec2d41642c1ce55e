"""TorchRL: :class:`AutoRandomizePhysicsTransform`, the physics transform with an ADR controller behind it.

The pinned value travels in ``"sim2real_params"`` like every draw. The episode's reward is summed from the
``"reward"`` the base env returns (before any reward transform appended later); a ``"success"`` entry, when the env
has one, is the episode's success flag. The episode ends on ``"done"``.

Example:
    >>> from torchrl.envs import DMControlEnv, TransformedEnv
    >>> from randomizers import ADR, Damping, Uniform
    >>> adr = ADR([Damping(scale=Uniform(0.0, 4.0))], delta=0.5, t_low=0.2, t_high=0.8)
    >>> env = TransformedEnv(DMControlEnv("reacher", "easy"), AutoRandomizePhysicsTransform([], adr, seed=0))
    >>> td = env.rollout(3)
    >>> td["next", "sim2real_params"].shape
    torch.Size([3, 2])
"""

from __future__ import annotations

from collections.abc import Sequence

from tensordict import TensorDictBase

from randomizers import ADR, Effect, Episode
from randomizers.adr_randomizer import ADRRandomizer
from randomizers.seeding import SeedLike
from sim2real.wrappers.torchrl import RandomizePhysicsTransform

__all__ = ["AutoRandomizePhysicsTransform"]


class AutoRandomizePhysicsTransform(RandomizePhysicsTransform):
    """:class:`~sim2real.wrappers.RandomizePhysicsTransform` whose ADR effects draw from ``adr``'s ranges.

    Args:
        effects: physics effects outside ADR.
        adr: the controller (shared by every transform of the process that gets it).
        seed: root seed of every stream, the boundary choice included.
    """

    def __init__(self, effects: Sequence[Effect], adr: ADR, seed: SeedLike = None) -> None:
        super().__init__((), seed)
        self.randomizer = ADRRandomizer(effects, adr, seed)  # not bound yet: the parent env binds it
        self.adr = adr
        self._return = 0.0
        self._length = 0
        self._running = False

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        self._return, self._length, self._running = 0.0, 0, True
        return super()._reset(tensordict, tensordict_reset)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict = super()._step(tensordict, next_tensordict)
        # One env per transform: reward and done hold one entry, and .item() is the cheapest read (~1 µs).
        reward, done = next_tensordict.get("reward"), next_tensordict.get("done")
        self._return += reward.item() if reward.numel() == 1 else float(reward.sum())
        self._length += 1
        if self._running and (done.item() if done.numel() == 1 else bool(done.any())):
            self._running = False
            success = next_tensordict.get("success", None)
            flag = None if success is None else bool(success.any())
            randomizer: ADRRandomizer = self.randomizer  # type: ignore[assignment]
            randomizer.end_episode(Episode(self._return, self._length, flag))
        return next_tensordict
