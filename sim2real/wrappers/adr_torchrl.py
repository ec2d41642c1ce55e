"""TorchRL: :class:`AutoRandomizePhysicsTransform`, the physics transform with an ADR controller behind it.

The pinned value travels in ``"sim2real_params"`` like every draw. The episode's reward is summed from the
``"reward"`` the base env returns (before any reward transform appended later); a ``"success"`` (or ``"is_success"``)
entry, when the env has one, is the episode's success flag. The episode ends on ``"done"``.

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
        self.__dict__["_tally"] = _Tally()

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tally = self._tally
        tally.episode_return, tally.length, tally.running = 0.0, 0, True
        return super()._reset(tensordict, tensordict_reset)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict = super()._step(tensordict, next_tensordict)
        # One env per transform: reward and done hold one entry, and .item() is the cheapest read (~1 µs). The sums
        # live on a plain object: a Transform is an nn.Module, whose __setattr__ costs ~3 µs per attribute.
        tally = self._tally
        reward, done = next_tensordict.get("reward"), next_tensordict.get("done")
        tally.episode_return += reward.item() if reward.numel() == 1 else float(reward.sum())
        tally.length += 1
        if tally.running and (done.item() if done.numel() == 1 else bool(done.any())):
            tally.running = False
            success = next_tensordict.get("success", None)
            if success is None:
                success = next_tensordict.get("is_success", None)  # a gymnasium task's info["is_success"]
            flag = None if success is None else bool(success.any())
            randomizer: ADRRandomizer = self.randomizer  # type: ignore[assignment]
            randomizer.end_episode(Episode(tally.episode_return, tally.length, flag))
        return next_tensordict


class _Tally:
    """The running episode's reward sum and length, and whether it is still to be reported."""

    __slots__ = ("episode_return", "length", "running")

    def __init__(self) -> None:
        self.episode_return = 0.0
        self.length = 0
        self.running = False
