"""Throughput of batched closed-loop evaluation (issue #6) against TorchRL's ``env.rollout``.

One policy (a TorchRL MLP actor, the kind ``sim2real train`` produces) is evaluated over 64 parameter
samples of a randomised ``dmc/reacher-easy`` (Mass, Damping and ActuatorGain scales drawn per episode):

* **batched**: :func:`sim2real.evaluation.evaluate` with one condition of 64 episodes, all 64 envs stepped
  together with one batched policy call per control step (``backend="serial"``: one process);
* **rollout**: TorchRL's ``DMControlEnv("reacher", "easy")`` with the same effects through
  ``sim2real.wrap`` (a ``RandomizePhysicsTransform``), one ``env.rollout(max_steps, policy)`` per sample;
* **raw mj_step**: the limit, ``mujoco.mj_step`` on reacher's model with the same substeps per control
  step and no Python env code (a control step = ``n_sub_steps`` physics steps).

Both evaluation arms run in the same process one after the other in every repeat (order alternating), so
machine noise hits them alike; the figure is env steps (control steps) per second and the ratio of medians.
The batched figure includes building its 64 envs (each copies reacher's compiled model, 11 MB of skybox
texture included); the rollout arm builds its one env before its timer starts. The construction time is printed
separately, with the stepping-only rate it implies.
The rollout arm runs fewer episodes (``--rollout-episodes``) since its throughput does not depend on the
count. Usage::

    .venv/bin/python benchmarks/bench_eval.py             # full run (goal: batched / rollout >= 10)
    .venv/bin/python benchmarks/bench_eval.py --quick     # smoke test
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco

import sim2real as s2r
from sim2real.evaluation import evaluate, randomized

GOAL = 10.0


def effects() -> list[Any]:
    return [
        s2r.Mass(scale=s2r.Uniform(0.7, 1.3)),
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
        s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2)),
    ]


def make_actor(obs_dim: int, act_dim: int) -> Any:
    import torch
    from tensordict.nn import TensorDictModule

    torch.manual_seed(0)
    net = torch.nn.Sequential(
        torch.nn.Linear(obs_dim, 64), torch.nn.Tanh(), torch.nn.Linear(64, 64), torch.nn.Tanh(),
        torch.nn.Linear(64, act_dim), torch.nn.Tanh(),
    )  # fmt: skip
    return TensorDictModule(net, in_keys=["observation"], out_keys=["action"])


def batched(actor: Any, episodes: int, steps: int) -> float:
    start = time.perf_counter()
    result = evaluate({"mlp": actor}, "dmc/reacher-easy", [randomized(effects())], episodes=episodes,
                      batch=episodes, seed=0, max_steps=steps)  # fmt: skip
    return result.env_steps / (time.perf_counter() - start)


def rollout(actor: Any, episodes: int, steps: int) -> float:
    import torch
    from tensordict.nn import TensorDictModule
    from torchrl.envs import CatTensors, DMControlEnv, DoubleToFloat, TransformedEnv

    env = s2r.wrap(DMControlEnv("reacher", "easy"), *effects(), seed=0)
    keys = ["position", "to_target", "velocity"]
    env = TransformedEnv(env, DoubleToFloat())
    env.append_transform(CatTensors(in_keys=keys, out_key="observation", del_keys=False))
    policy = TensorDictModule(actor.module, in_keys=["observation"], out_keys=["action"])
    total = 0
    start = time.perf_counter()
    with torch.no_grad():
        for e in range(episodes):
            env.set_seed(e)
            data = env.rollout(steps, policy)
            total += data.numel()
    env.close()
    return total / (time.perf_counter() - start)


def construction(episodes: int) -> float:
    """Seconds to build the batched arm's envs (``make`` + ``wrap``), which its figure includes."""
    start = time.perf_counter()
    envs = [s2r.wrap(s2r.make("dmc/reacher-easy"), *effects(), seed=0) for _ in range(episodes)]
    seconds = time.perf_counter() - start
    for env in envs:
        env.close()
    return seconds


def raw_limit(steps: int) -> float:
    from dm_control import suite

    env = suite.load("reacher", "easy")
    n_sub = env._n_sub_steps
    model, data = env.physics.model.ptr, env.physics.data.ptr
    mujoco.mj_resetData(model, data)
    start = time.perf_counter()
    for _ in range(steps * n_sub):
        mujoco.mj_step(model, data)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64, help="parameter samples of the batched arm")
    parser.add_argument("--rollout-episodes", type=int, default=4, help="episodes of the rollout arm")
    parser.add_argument("--steps", type=int, default=1000, help="control steps per episode (reacher: 1000)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="smoke test: 8 samples, 100 steps, 1 repeat")
    args = parser.parse_args()
    if args.quick:
        args.episodes, args.rollout_episodes, args.steps, args.repeats = 8, 2, 100, 1
    import torch

    torch.set_num_threads(1)
    env = s2r.make("dmc/reacher-easy")
    actor = make_actor(env.observation_space.shape[0], env.action_space.shape[0])
    print(f"# bench_eval  python {platform.python_version()}  mujoco {mujoco.__version__}  torch {torch.__version__}")
    print(f"# dmc/reacher-easy, {args.episodes} parameter samples x {args.steps} steps (batched), "
          f"{args.rollout_episodes} x {args.steps} (rollout), {args.repeats} repeats, torch threads 1")  # fmt: skip
    fast: list[float] = []
    slow: list[float] = []
    for r in range(args.repeats):
        arms = [("batched", fast, batched, args.episodes), ("rollout", slow, rollout, args.rollout_episodes)]
        for name, sink, fn, episodes in arms if r % 2 == 0 else arms[::-1]:
            rate = fn(actor, episodes, args.steps)
            sink.append(rate)
            print(f"repeat {r}  {name:8s} {rate:10.0f} env steps/s")
    limit = raw_limit(args.steps * 4)
    ratio = statistics.median(fast) / statistics.median(slow)
    build = construction(args.episodes)
    steps = args.episodes * args.steps
    stepping = steps / (steps / statistics.median(fast) - build)
    print(f"batched env construction {build:.2f} s for {args.episodes} envs (in the batched figure; the rollout "
          f"arm's one env is built outside its timer)")  # fmt: skip
    print(f"batched stepping only   ~{stepping:10.0f} env steps/s ({stepping / statistics.median(slow):.1f}x rollout)")
    print(f"batched  median {statistics.median(fast):10.0f} env steps/s")
    print(f"rollout  median {statistics.median(slow):10.0f} env steps/s")
    print(f"raw mj_step limit {limit:10.0f} control steps/s (no env code, one process)")
    print(f"RESULT batched/rollout = {ratio:.1f}x (goal >= {GOAL:.0f}x: {'met' if ratio >= GOAL else 'missed'}); "
          f"batched reaches {statistics.median(fast) / limit:.2f} of the raw mj_step limit")  # fmt: skip


if __name__ == "__main__":
    main()
