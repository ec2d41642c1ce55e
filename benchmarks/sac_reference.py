"""A minimal plain-PyTorch SAC update: the speed floor ``bench_train.py --algo sac`` compares against.

Actor MLP ``obs -> (loc, pre-scale)``, twin critic MLPs ``(obs, action) -> q``, their Polyak targets and a learned
temperature, one Adam over all; tanh-squashed Gaussian, the same losses as :class:`sim2real.agents.sac.SACUpdate`
written the way a tutorial writes them (no normaliser, no TensorDict).
"""

from __future__ import annotations

import copy
import math

import torch
import torch.nn.functional as F
from torch import nn


def mlp(inp: int, out: int, hidden: tuple[int, ...]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(inp, width), nn.ReLU()]
        inp = width
    return nn.Sequential(*layers, nn.Linear(inp, out))


class PlainSAC:
    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...] = (256, 256), lr: float = 3e-4) -> None:
        self.actor = mlp(obs_dim, 2 * act_dim, hidden)
        self.q1, self.q2 = mlp(obs_dim + act_dim, 1, hidden), mlp(obs_dim + act_dim, 1, hidden)
        self.t1, self.t2 = copy.deepcopy(self.q1), copy.deepcopy(self.q2)
        self.log_alpha = nn.Parameter(torch.zeros(()))
        self.q_params = [*self.q1.parameters(), *self.q2.parameters()]
        self.t_params = [*self.t1.parameters(), *self.t2.parameters()]
        self.optim = torch.optim.Adam([*self.actor.parameters(), *self.q_params, self.log_alpha], lr=lr)
        self.gamma, self.tau, self.target_entropy = 0.99, 0.005, -float(act_dim)

    def sample(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc, pre = self.actor(obs).chunk(2, -1)
        std = F.softplus(pre) + 1e-4
        dist = torch.distributions.Normal(loc, std)
        u = dist.rsample()
        a = torch.tanh(u)
        logp = (dist.log_prob(u) - 2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(-1)
        return a, logp

    def update(self, obs, act, rew, next_obs, term) -> None:  # type: ignore[no-untyped-def]
        alpha = self.log_alpha.exp().detach()
        with torch.no_grad():
            a2, logp2 = self.sample(next_obs)
            x2 = torch.cat([next_obs, a2], -1)
            q_next = torch.min(self.t1(x2), self.t2(x2)).squeeze(-1) - alpha * logp2
            y = rew + self.gamma * (1 - term) * q_next
        x = torch.cat([obs, act], -1)
        loss_q = 0.5 * (F.mse_loss(self.q1(x).squeeze(-1), y) + F.mse_loss(self.q2(x).squeeze(-1), y))
        a, logp = self.sample(obs)
        xa = torch.cat([obs, a], -1)
        for p in self.q_params:
            p.requires_grad_(False)
        q_pi = torch.min(self.q1(xa), self.q2(xa)).squeeze(-1)
        for p in self.q_params:
            p.requires_grad_(True)
        loss_pi = (alpha * logp - q_pi).mean()
        loss_alpha = -(self.log_alpha * (logp.detach() + self.target_entropy)).mean()
        self.optim.zero_grad()
        (loss_q + loss_pi + loss_alpha).backward()
        self.optim.step()
        with torch.no_grad():
            torch._foreach_lerp_(self.t_params, self.q_params, self.tau)
