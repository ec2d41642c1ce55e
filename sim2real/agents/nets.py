"""Actor and critic networks shared by training, checkpoints and the policy adapter.

One builder per network so a checkpoint can rebuild exactly the module it was saved from: the
architecture is a function of ``(algo, obs_dim, action bounds, hidden_sizes, activation)`` only.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> actor = build_actor("ppo", 16, [-0.05] * 3, [0.05] * 3, (32,), "tanh")
    >>> td = actor(TensorDict({"observation": torch.zeros(4, 16)}, batch_size=[4]))
    >>> td["action"].shape
    torch.Size([4, 3])
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

__all__ = ["OBS_KEY", "Normalize", "actor_dims", "actor_normalizer", "build_actor", "build_critic", "build_qvalue"]

#: The observation entry every network reads.
OBS_KEY = "observation"

_ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


class Normalize(nn.Module):
    """Fixed affine input normalisation ``(x - loc) / scale``; ``loc`` and ``scale`` are buffers, so they
    travel in the state dict (and checkpoints) with the weights. Identity until :meth:`set_stats`.

    Entries listed in ``angles`` (joint angles in radians) are not normalised: entry ``i`` becomes ``sin(x_i)``
    and ``cos(x_i)`` is appended after the ``dim`` entries, in the order of ``angles`` (``out_dim = dim +
    len(angles)``). A hinge that has turned once more then looks as it did before the turn, where the raw angle
    would be a value the network never saw. The state dict is the same with or without ``angles`` (they are
    rebuilt from the config).

    Args:
        dim: observation size.
        angles: indices of the angle entries, each ``< dim``.

    Raises:
        ValueError: an index outside ``[0, dim)`` or repeated.

    Example:
        >>> import math
        >>> norm = Normalize(3, angles=(0,))
        >>> norm.out_dim
        4
        >>> a = norm(torch.tensor([0.5, 2.0, 3.0]))
        >>> b = norm(torch.tensor([0.5 + 2 * math.pi, 2.0, 3.0]))
        >>> bool(torch.allclose(a, b, atol=1e-6)), [round(v, 3) for v in a.tolist()]
        (True, [0.479, 2.0, 3.0, 0.878])
    """

    # Registered as buffers in __init__; declared so the type checker sees tensors, not Module.__getattr__.
    loc: torch.Tensor
    scale: torch.Tensor
    angle_index: torch.Tensor

    def __init__(self, dim: int, angles: Sequence[int] = ()) -> None:
        super().__init__()
        angles = tuple(angles)
        if len(set(angles)) != len(angles) or not all(
            isinstance(i, int) and not isinstance(i, bool) and 0 <= i < dim for i in angles
        ):
            raise ValueError(
                f"`angle_obs` must hold distinct observation indices in [0, {dim}) (the observation has {dim} "
                f"entries). Received {list(angles)}."
            )
        self.angles = angles
        self.out_dim = dim + len(angles)
        self.register_buffer("loc", torch.zeros(dim))
        self.register_buffer("scale", torch.ones(dim))
        # Not persistent: a checkpoint's state dict keeps the keys it had before angle features existed.
        self.register_buffer("angle_index", torch.tensor(angles, dtype=torch.long), persistent=False)

    def set_stats(self, loc: torch.Tensor, scale: torch.Tensor) -> None:
        """Sets the statistics in place (every module sharing this normaliser sees them)."""
        self.loc.copy_(loc)
        self.scale.copy_(scale)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised ``x`` (with the angle entries as sines and their cosines appended)."""
        out = (x - self.loc) / self.scale
        if not self.angles:
            return out
        raw = x.index_select(-1, self.angle_index)
        return torch.cat((out.index_copy(-1, self.angle_index, torch.sin(raw)), torch.cos(raw)), -1)


class _QNet(nn.Module):
    def __init__(self, norm: Normalize, mlp: nn.Module) -> None:
        super().__init__()
        self.norm = norm
        self.mlp = mlp

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.mlp(torch.cat((self.norm(obs), action), dim=-1))


def _mlp(in_features: int, out_features: int, hidden: Sequence[int], activation: str) -> MLP:
    return MLP(
        in_features=in_features,
        out_features=out_features,
        num_cells=list(hidden),
        activation_class=_ACTIVATIONS[activation],
    )


def build_actor(
    algo: str,
    obs_dim: int,
    low: Sequence[float],
    high: Sequence[float],
    hidden_sizes: Sequence[int],
    activation: str,
    init_log_std: float = 0.0,
    angle_obs: Sequence[int] = (),
) -> ProbabilisticActor:
    """A tanh-Gaussian policy ``observation -> action`` bounded to ``[low, high]``.

    PPO uses a state-independent learned log standard deviation (the usual choice for on-policy
    continuous control); SAC a state-dependent one (its entropy tuning needs it).

    Args:
        algo: ``"ppo"`` or ``"sac"``.
        obs_dim: observation size.
        low: lower action bounds (its length is the action size).
        high: upper action bounds.
        hidden_sizes: hidden layer widths.
        activation: ``"tanh"``, ``"relu"`` or ``"elu"``.
        init_log_std: initial log standard deviation before the tanh.
        angle_obs: observation entries that are angles in radians, fed as sine and cosine (see
            :class:`Normalize`).

    Returns:
        A ``ProbabilisticActor`` reading ``"observation"`` and writing ``"action"`` (and
        ``"action_log_prob"`` when sampling). Its first layer is a :class:`Normalize` (see
        :func:`actor_normalizer`).
    """
    low_t = torch.as_tensor(list(low), dtype=torch.float32)
    high_t = torch.as_tensor(list(high), dtype=torch.float32)
    act_dim = int(low_t.numel())
    norm = Normalize(obs_dim, angle_obs)
    if algo == "ppo":
        net = nn.Sequential(
            norm,
            _mlp(norm.out_dim, act_dim, hidden_sizes, activation),
            AddStateIndependentNormalScale(act_dim, init_value=float(init_log_std)),
        )
    else:
        mlp = _mlp(norm.out_dim, 2 * act_dim, hidden_sizes, activation)
        with torch.no_grad():  # start the scale near exp(init_log_std) through the biased softplus
            mlp[-1].bias[act_dim:].fill_(float(init_log_std))
        net = nn.Sequential(norm, mlp, NormalParamExtractor(scale_mapping="biased_softplus_1.0"))
    module = TensorDictModule(net, in_keys=[OBS_KEY], out_keys=["loc", "scale"])
    spec = Bounded(low=low_t, high=high_t, shape=(act_dim,), dtype=torch.float32)
    return ProbabilisticActor(
        module,
        in_keys=["loc", "scale"],
        spec=spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": low_t, "high": high_t},
        return_log_prob=True,
    )


def actor_dims(actor: nn.Module) -> tuple[int, list[float], list[float]]:
    """``(obs_dim, low, high)`` of an actor made by :func:`build_actor`.

    Raises:
        TypeError: ``actor`` was not made by :func:`build_actor`.
    """
    spec: Any = getattr(actor, "spec", None)  # a TorchRL Composite when made by build_actor; checked below
    linear = next((m for m in actor.modules() if isinstance(m, nn.Linear)), None)
    norm = next((m for m in actor.modules() if isinstance(m, Normalize)), None)
    try:
        action = spec["action"]
        low, high = action.space.low, action.space.high
    except Exception:
        low = high = None
    if linear is None or low is None or high is None:
        raise TypeError(
            "`policy` must be an actor built by sim2real.agents (the `policy` of a TrainResult or of a "
            f"loaded checkpoint). Received {type(actor).__name__}."
        )
    obs_dim = int(norm.loc.numel()) if norm is not None else int(linear.in_features)  # angle features widen the MLP
    return obs_dim, [float(v) for v in low.flatten()], [float(v) for v in high.flatten()]


def actor_normalizer(actor: nn.Module) -> Normalize:
    """The :class:`Normalize` input layer of an actor made by :func:`build_actor`."""
    norm = next((m for m in actor.modules() if isinstance(m, Normalize)), None)
    if norm is None:
        raise TypeError(f"`actor` must be built by build_actor. Received {type(actor).__name__}.")
    return norm


def build_critic(obs_dim: int, hidden_sizes: Sequence[int], activation: str, norm: Normalize) -> ValueOperator:
    """State-value network ``observation -> state_value`` (PPO), sharing the actor's normaliser ``norm``."""
    return ValueOperator(nn.Sequential(norm, _mlp(norm.out_dim, 1, hidden_sizes, activation)), in_keys=[OBS_KEY])


def build_qvalue(
    obs_dim: int, act_dim: int, hidden_sizes: Sequence[int], activation: str, norm: Normalize
) -> ValueOperator:
    """Action-value network ``(observation, action) -> state_action_value`` (SAC), normalising the observation
    with the actor's ``norm`` (its angle features included)."""
    return ValueOperator(
        _QNet(norm, _mlp(norm.out_dim + act_dim, 1, hidden_sizes, activation)),
        in_keys=[OBS_KEY, "action"],
        out_keys=["state_action_value"],
    )
