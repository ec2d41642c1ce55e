"""Soft actor-critic at the speed of its maths: one hand-written update on plain tensors, a preallocated replay
buffer and a direct env loop.

TorchRL's ``SACLoss`` spends most of an update in Python plumbing (TensorDict round trips, vmapped functional
parameter copies, distribution objects): about 13k Python calls per update against about 1.4k for the same tensor
maths written out. :class:`SACUpdate` is that maths, on the very modules :func:`~sim2real.agents.nets.build_actor`
and :func:`~sim2real.agents.nets.build_qvalue` make, so checkpoints (the actor's state dict) are unchanged.

The maths (Haarnoja et al. 2018, twin critics, learned temperature), with ``a = tanh(u)`` the action in the
normalised box ``[-1, 1]`` and ``u ~ N(loc, scale)``:

- critic: ``0.5 * sum_i mean((Q_i(o, a) - y)^2)``, ``y = r + gamma^m (1 - terminated) (min_i Q'_i(o2, a2) -
  alpha log pi(a2 | o2))`` with ``a2 ~ pi(. | o2)`` and the target critics ``Q'``; ``m`` is the number of env steps
  the transition spans (1, or up to ``n`` for an n-step return ``r = sum_k gamma^k r_k`` ending at ``o2``);
- actor: ``mean(alpha log pi(a | o) - min_i Q_i(o, a))`` through the critics' weights detached;
- temperature: ``-log_alpha * mean(log pi(a | o) + target_entropy)``, ``target_entropy = -act_dim``;
- one Adam step on the sum, then Polyak averaging of the target critics with rate ``tau``.

Log-probabilities and the critics' action input are in the normalised box (the affine map to the env's bounds is a
constant of the policy), so the entropy target ``-act_dim`` means the same on an arm whose bounds are +-0.05 as on
one with +-1. Which transitions are used: ``terminated`` stops bootstrapping, a time-limit truncation does not.

Example:
    >>> import torch
    >>> from sim2real.agents.nets import build_actor, build_qvalue, actor_normalizer
    >>> _ = torch.manual_seed(0)
    >>> actor = build_actor("sac", 4, [-1.0, -1.0], [1.0, 1.0], (16,), "relu")
    >>> norm = actor_normalizer(actor)
    >>> qnets = [build_qvalue(4, 2, (16,), "relu", norm) for _ in range(2)]
    >>> update = SACUpdate(actor, qnets, lr=1e-3, gamma=0.99, tau=0.005, alpha_init=1.0)
    >>> buffer = ReplayBuffer(100, 4, 2, seed=0)
    >>> for _ in range(50):
    ...     buffer.add(torch.randn(4).numpy(), torch.rand(2).numpy(), 1.0, torch.randn(4).numpy(), False)
    >>> losses = update.step(*buffer.sample(32))
    >>> losses.shape, bool(torch.isfinite(losses).all())
    (torch.Size([4]), True)
"""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["LOSS_KEYS", "NStepWriter", "ReplayBuffer", "SACUpdate"]

#: Names of the four values :meth:`SACUpdate.step` returns, in order.
LOSS_KEYS: tuple[str, ...] = ("loss_actor", "loss_qvalue", "loss_alpha", "alpha")

_LOG2 = math.log(2.0)
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def _actor_parts(actor: Any) -> tuple[nn.Module, nn.Module, nn.Module]:
    """``(normalize, mlp, param_extractor)`` of a SAC actor made by ``build_actor``."""
    from sim2real.agents.nets import Normalize

    try:
        net = actor.module[0].module
        norm, mlp, extractor = net[0], net[1], net[2]
    except (AttributeError, IndexError, TypeError):
        norm = None
    if norm is None or not isinstance(norm, Normalize) or len(net) != 3:
        raise TypeError(f"`actor` must be a SAC actor made by build_actor. Received {type(actor).__name__}.")
    return norm, mlp, extractor


def _qnet(qvalue: Any) -> Any:
    net = getattr(qvalue, "module", qvalue)
    if not isinstance(getattr(net, "mlp", None), nn.Module) or not hasattr(net, "norm"):
        raise TypeError(f"`qvalues` must be made by build_qvalue. Received {type(qvalue).__name__}.")
    return net


def _squash_log_prob(u: torch.Tensor, loc: torch.Tensor, scale: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
    """``log pi(tanh(u))`` summed over the action: Gaussian log-density minus ``log(1 - tanh(u)^2)``, the latter in
    the overflow-free form ``2 (log 2 - u - softplus(-2u))``."""
    gauss = -0.5 * eps.pow(2) - scale.log() - _HALF_LOG_2PI
    return (gauss - 2.0 * (_LOG2 - u - F.softplus(-2.0 * u))).sum(-1)


class SACUpdate:
    """The SAC gradient step on a batch of tensors (see the module docstring for the maths).

    Args:
        actor: a SAC actor from :func:`~sim2real.agents.nets.build_actor` (trained in place).
        qvalues: two (or more) critics from :func:`~sim2real.agents.nets.build_qvalue`, each with its own
            weights, sharing the actor's normaliser; their action input is the normalised action.
        lr: Adam learning rate of actor, critics and temperature (one optimiser, as TorchRL's recipe).
        gamma: discount.
        tau: Polyak rate of the target critics.
        alpha_init: initial temperature.
        target_entropy: entropy target in the normalised action box; default ``-act_dim``.

    Raises:
        TypeError: ``actor`` or ``qvalues`` were not made by the builders.
        ValueError: fewer than two critics.
    """

    def __init__(
        self,
        actor: Any,
        qvalues: Sequence[Any],
        *,
        lr: float,
        gamma: float,
        tau: float,
        alpha_init: float,
        target_entropy: float | None = None,
    ) -> None:
        self.norm, self.mlp, self.extractor = _actor_parts(actor)
        self.qnets = [_qnet(q) for q in qvalues]
        if len(self.qnets) < 2:
            raise ValueError(f"`qvalues` must hold at least 2 critics. Received {len(self.qnets)}.")
        self.q_mlps: list[nn.Module] = [q.mlp for q in self.qnets]
        self.targets: list[nn.Module] = [copy.deepcopy(m) for m in self.q_mlps]
        for target in self.targets:
            target.requires_grad_(False)
        last = next(m for m in reversed(list(self.mlp.modules())) if isinstance(m, nn.Linear))
        self.act_dim = int(last.out_features) // 2
        self.gamma = float(gamma)
        self.tau = float(tau)
        self.target_entropy = float(-self.act_dim if target_entropy is None else target_entropy)
        self.log_alpha = nn.Parameter(torch.tensor(math.log(alpha_init), dtype=torch.float32))
        self.actor_params = [p for p in self.mlp.parameters() if p.requires_grad]
        self._sources: list[torch.Tensor] = [p for m in self.q_mlps for p in m.parameters()]
        self._target_params: list[torch.Tensor] = [p for t in self.targets for p in t.parameters()]
        params = [*self.actor_params, *self._sources, self.log_alpha]
        self.optim = torch.optim.Adam(params, lr=lr)

    def _policy(self, obs_n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised sample ``tanh(u)`` and its log-probability, from normalised observations."""
        loc, scale = self.extractor(self.mlp(obs_n))
        eps = torch.randn_like(loc)
        u = loc + scale * eps
        return torch.tanh(u), _squash_log_prob(u, loc, scale, eps)

    def step(
        self,
        obs: torch.Tensor,
        action: torch.Tensor,
        reward: torch.Tensor,
        next_obs: torch.Tensor,
        terminated: torch.Tensor,
        steps: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """One gradient step on a batch.

        Args:
            obs: ``(B, obs_dim)`` observations.
            action: ``(B, act_dim)`` actions in the normalised box ``[-1, 1]``.
            reward: ``(B,)`` rewards (already scaled).
            next_obs: ``(B, obs_dim)`` next observations.
            terminated: ``(B,)`` 1.0 where the episode ended in a terminal state (no bootstrap), else 0.0.
            steps: ``(B,)`` env steps each transition spans (its bootstrap is discounted by ``gamma ** steps``);
                None means 1 for all (one-step transitions).

        Returns:
            ``(4,)`` tensor of :data:`LOSS_KEYS` values (detached).
        """
        norm = self.norm
        obs_n = norm(obs)
        next_n = norm(next_obs)
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            next_a, next_logp = self._policy(next_n)
            next_in = torch.cat((next_n, next_a), -1)
            next_q = torch.min(torch.stack([t(next_in) for t in self.targets]), 0).values.squeeze(-1)
            discount = self.gamma if steps is None else torch.pow(self.gamma, steps)
            target = reward + discount * (1.0 - terminated) * (next_q - alpha * next_logp)
        q_in = torch.cat((obs_n, action), -1)
        loss_q = 0.5 * torch.stack([F.mse_loss(m(q_in).squeeze(-1), target) for m in self.q_mlps]).sum()
        new_a, logp = self._policy(obs_n)
        pi_in = torch.cat((obs_n, new_a), -1)
        q_pi = torch.min(torch.stack([_detached(m, pi_in) for m in self.q_mlps]), 0).values.squeeze(-1)
        loss_actor = (alpha * logp - q_pi).mean()
        loss_alpha = -self.log_alpha * (logp.detach() + self.target_entropy).mean()
        total = loss_actor + loss_q + loss_alpha
        self.optim.zero_grad(set_to_none=True)
        total.backward()
        self.optim.step()
        with torch.no_grad():
            torch._foreach_lerp_(self._target_params, self._sources, self.tau)
        return torch.stack((loss_actor.detach(), loss_q.detach(), loss_alpha.detach(), alpha))


def _detached(mlp: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """``mlp(x)`` with the weights detached: the actor's loss moves the actor, not the critic."""
    for layer in mlp:  # type: ignore[attr-defined]  # a TorchRL MLP is an nn.Sequential
        x = F.linear(x, layer.weight.detach(), layer.bias.detach()) if isinstance(layer, nn.Linear) else layer(x)
    return x


class ReplayBuffer:
    """A uniform replay buffer of preallocated float32 arrays (a ring once full), sampled with its own seeded
    ``torch.Generator``. Rows are written through numpy views of the same memory the sampled tensors index.
    Each row also keeps the number of env steps it spans (1, or up to ``n`` for an n-step transition).

    Args:
        capacity: transitions kept.
        obs_dim: observation size.
        act_dim: action size.
        seed: seeds the sampling generator.
    """

    def __init__(self, capacity: int, obs_dim: int, act_dim: int, seed: int) -> None:
        self.capacity = int(capacity)
        self.obs = torch.zeros(self.capacity, obs_dim)
        self.next_obs = torch.zeros(self.capacity, obs_dim)
        self.action = torch.zeros(self.capacity, act_dim)
        self.reward = torch.zeros(self.capacity)
        self.terminated = torch.zeros(self.capacity)
        self.steps = torch.ones(self.capacity)
        self._np = [
            t.numpy() for t in (self.obs, self.action, self.reward, self.next_obs, self.terminated, self.steps)
        ]
        self.generator = torch.Generator().manual_seed(int(seed))
        self._next = 0
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def add(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
        steps: int = 1,
    ) -> None:
        """Stores one transition (overwriting the oldest once full); ``steps`` env steps lead from ``obs`` to
        ``next_obs`` and ``reward`` is their discounted sum."""
        i = self._next
        o, a, r, n, t, m = self._np
        o[i] = obs
        a[i] = action
        r[i] = reward
        n[i] = next_obs
        t[i] = float(terminated)
        m[i] = steps
        self._next = (i + 1) % self.capacity
        self._size = min(self._size + 1, self.capacity)

    def sample(
        self, batch_size: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(obs, action, reward, next_obs, terminated, steps)`` of ``batch_size`` transitions drawn uniformly
        with replacement (the arguments of :meth:`SACUpdate.step`, in order)."""
        idx = torch.randint(0, self._size, (batch_size,), generator=self.generator)
        return (
            self.obs.index_select(0, idx),
            self.action.index_select(0, idx),
            self.reward.index_select(0, idx),
            self.next_obs.index_select(0, idx),
            self.terminated.index_select(0, idx),
            self.steps.index_select(0, idx),
        )


class NStepWriter:
    """Turns one-step transitions into n-step ones on their way into a :class:`ReplayBuffer`.

    The transition stored for the step taken in ``o_t`` carries ``R = sum_{k<m} gamma^k r_{t+k}``, the observation
    ``o_{t+m}`` it bootstraps from and ``m`` (the buffer's ``steps``): ``m = n`` inside an episode; at an episode's
    end every pending step is written with the steps left (``m < n``), ``terminated`` if the episode ended in a
    terminal state. With ``n = 1`` it stores each transition as it comes.

    Args:
        buffer: where transitions go.
        n: steps per return (>= 1).
        gamma: discount.

    Raises:
        ValueError: ``n`` is not a positive int.

    Example:
        >>> import numpy as np
        >>> buffer = ReplayBuffer(10, 1, 1, seed=0)
        >>> writer = NStepWriter(buffer, n=2, gamma=0.5)
        >>> o, a = np.zeros(1), np.zeros(1)
        >>> for t, r in enumerate([1.0, 2.0, 4.0]):
        ...     writer.add(o + t, a, r, o + t + 1, terminated=t == 2, truncated=False)
        >>> buffer.reward[:3].tolist(), buffer.next_obs[:3, 0].tolist(), buffer.steps[:3].tolist()
        ([2.0, 4.0, 4.0], [2.0, 3.0, 3.0], [2.0, 2.0, 1.0])
        >>> buffer.terminated[:3].tolist()
        [0.0, 1.0, 1.0]
    """

    def __init__(self, buffer: ReplayBuffer, n: int, gamma: float) -> None:
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"`n` must be a positive int. Received {n!r}.")
        self.buffer = buffer
        self.n = n
        self._powers = [float(gamma) ** k for k in range(n)]
        self._pending: deque[tuple[np.ndarray, np.ndarray, float]] = deque()

    def add(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
        truncated: bool,
    ) -> None:
        """Takes the step ``obs --action--> (reward, next_obs)``; writes the transitions it completes."""
        if self.n == 1:
            self.buffer.add(obs, action, reward, next_obs, terminated)
            return
        pending = self._pending
        pending.append((obs.copy(), action, reward))  # an env may hand out one reused array
        if terminated or truncated:
            while pending:
                self._write(next_obs, terminated)
        elif len(pending) == self.n:
            self._write(next_obs, False)

    def _write(self, next_obs: np.ndarray, terminated: bool) -> None:
        pending = self._pending
        ret = 0.0
        for power, (_, _, r) in zip(self._powers, pending, strict=False):
            ret += power * r
        obs, action, _ = pending.popleft()
        self.buffer.add(obs, action, ret, next_obs, terminated, len(pending) + 1)
