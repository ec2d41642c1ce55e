"""SAC update throughput: sim2real's :class:`~sim2real.agents.sac.SACUpdate` against a minimal plain-PyTorch
update and TorchRL's ``SACLoss`` (run through ``bench_train.py --algo sac``; see its docstring)."""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable

import torch
from bench_overhead import cpu_model
from sac_reference import PlainSAC

from sim2real.agents.nets import actor_normalizer, build_actor, build_qvalue
from sim2real.agents.sac import ReplayBuffer, SACUpdate

RATIO_GOAL = 0.8
OBS_DIM, ACT_DIM, HIDDEN, BATCH, CAPACITY = 6, 2, (256, 256), 256, 20_000  # dmc/reacher-easy's sizes


def _data(seed: int) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(CAPACITY, OBS_DIM, generator=g)
    act = torch.rand(CAPACITY, ACT_DIM, generator=g) * 2 - 1
    rew = torch.rand(CAPACITY, generator=g)
    nxt = torch.randn(CAPACITY, OBS_DIM, generator=g)
    term = torch.zeros(CAPACITY)
    return obs, act, rew, nxt, term


def sim2real_arm(data: tuple[torch.Tensor, ...]) -> Callable[[], object]:
    actor = build_actor("sac", OBS_DIM, [-1.0] * ACT_DIM, [1.0] * ACT_DIM, HIDDEN, "relu")
    norm = actor_normalizer(actor)
    qvalues = [build_qvalue(OBS_DIM, ACT_DIM, HIDDEN, "relu", norm) for _ in range(2)]
    update = SACUpdate(actor, qvalues, lr=3e-4, gamma=0.99, tau=0.005, alpha_init=1.0)
    buffer = ReplayBuffer(CAPACITY, OBS_DIM, ACT_DIM, seed=0)
    for row in zip(*(t.numpy() for t in data), strict=True):
        buffer.add(*row)
    return lambda: update.step(*buffer.sample(BATCH))


def plain_arm(data: tuple[torch.Tensor, ...]) -> Callable[[], object]:
    sac = PlainSAC(OBS_DIM, ACT_DIM, HIDDEN)
    g = torch.Generator().manual_seed(0)

    def step() -> None:
        idx = torch.randint(0, CAPACITY, (BATCH,), generator=g)
        sac.update(*(t[idx] for t in data))

    return step


def torchrl_arm(data: tuple[torch.Tensor, ...]) -> Callable[[], object]:
    from tensordict import TensorDict
    from torchrl.data import Bounded, LazyTensorStorage, RandomSampler
    from torchrl.data import ReplayBuffer as TRB
    from torchrl.objectives import SACLoss, SoftUpdate

    actor = build_actor("sac", OBS_DIM, [-1.0] * ACT_DIM, [1.0] * ACT_DIM, HIDDEN, "relu")
    qvalue = build_qvalue(OBS_DIM, ACT_DIM, HIDDEN, "relu", actor_normalizer(actor))
    spec = Bounded(low=-torch.ones(ACT_DIM), high=torch.ones(ACT_DIM), shape=(ACT_DIM,))
    loss = SACLoss(actor, qvalue, num_qvalue_nets=2, loss_function="l2", alpha_init=1.0, action_spec=spec)
    loss.make_value_estimator(gamma=0.99)
    target = SoftUpdate(loss, tau=0.005)
    optim = torch.optim.Adam(loss.parameters(), lr=3e-4)
    obs, act, rew, nxt, term = data
    done = term.bool().unsqueeze(-1)
    td = TensorDict(
        {"observation": obs, "action": act,
         "next": {"observation": nxt, "reward": rew.unsqueeze(-1), "done": done, "terminated": done}},
        batch_size=[CAPACITY],
    )  # fmt: skip
    buffer = TRB(storage=LazyTensorStorage(CAPACITY), sampler=RandomSampler(), batch_size=BATCH,
                 generator=torch.Generator().manual_seed(0))  # fmt: skip
    buffer.extend(td)

    def step() -> None:
        out = loss(buffer.sample())
        total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
        optim.zero_grad()
        total.backward()
        optim.step()
        target.step()

    return step


def main(repeats: int = 7, updates: int = 60, threads: int = 1) -> None:
    if threads > 0:
        torch.set_num_threads(threads)
    torch.manual_seed(0)
    data = _data(0)
    arms = {"sim2real": sim2real_arm(data), "plain": plain_arm(data), "torchrl": torchrl_arm(data)}
    print(f"bench_train --algo sac: python {platform.python_version()}, torch {torch.__version__} "
          f"({torch.get_num_threads()} thread(s)); {os.cpu_count()} CPUs, {cpu_model()}, "
          f"load {' '.join(f'{x:.2f}' for x in os.getloadavg())}")  # fmt: skip
    print(f"networks {HIDDEN}, batch {BATCH}, obs {OBS_DIM}, act {ACT_DIM}; {repeats} x {updates} updates per arm, "
          "blocks alternate; updates/s over CPU time")  # fmt: skip
    for step in arms.values():
        for _ in range(max(3, updates // 5)):
            step()  # warm-up: allocator, autograd caches
    rates: dict[str, list[float]] = {name: [] for name in arms}
    for rep in range(repeats):
        for name, step in arms.items():
            start = time.process_time()
            for _ in range(updates):
                step()
            rates[name].append(updates / (time.process_time() - start))
        print(f"  repeat {rep + 1}: " + "  ".join(f"{n} {r[-1]:6.1f}" for n, r in rates.items()), flush=True)
    ratio = {n: statistics.median(a / b for a, b in zip(rates[n], rates["plain"], strict=True)) for n in arms}
    print(f"\n{'arm':<10}{'updates/s':>11}{'/plain':>9}")
    for name in arms:
        print(f"{name:<10}{statistics.median(rates[name]):>11.1f}{ratio[name]:>9.3f}")
    verdict = "MET" if ratio["sim2real"] >= RATIO_GOAL else "MISSED"
    print(
        f"RESULT sac_updates_over_plain={ratio['sim2real']:.3f} torchrl_over_plain={ratio['torchrl']:.3f} "
        f"(goal: sim2real >= {RATIO_GOAL}) {verdict}"
    )
