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

    .venv/bin/python benchmarks/bench_eval.py --torchrl             # issue 6 (goal: batched / rollout >= 10)
    .venv/bin/python benchmarks/bench_eval.py --torchrl --quick     # smoke test
    .venv/bin/python benchmarks/bench_eval.py [--quick]             # issue 15's P4 (below)
    .venv/bin/python benchmarks/bench_eval.py --make [--before DIR] # issue 15: make x 64, before/after
    .venv/bin/python benchmarks/bench_eval.py --make-vec            # issue 15: make_vec / SyncVectorEnv
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


#: Signal models P4's --action-latency adds to every sim2real arm's effects (not to the SyncVectorEnv or limit arms).
_EXTRA: list[Any] = []
_LATENCY: float | None = None  # its ActionLatency's seconds (passed on to the fresh processes of --before)


def effects() -> list[Any]:
    return [
        s2r.Mass(scale=s2r.Uniform(0.7, 1.3)),
        s2r.Damping(scale=s2r.Uniform(0.5, 2.0)),
        s2r.ActuatorGain(scale=s2r.Uniform(0.8, 1.2)),
        *_EXTRA,
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


def main_torchrl(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64, help="parameter samples of the batched arm")
    parser.add_argument("--rollout-episodes", type=int, default=4, help="episodes of the rollout arm")
    parser.add_argument("--steps", type=int, default=1000, help="control steps per episode (reacher: 1000)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="smoke test: 8 samples, 100 steps, 1 repeat")
    args = parser.parse_args(argv)
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


# ------------------------------------------------------------------------------------------ issue 15: P4
#
# The batched engine (sim2real.batched) against today's batched evaluation (evaluate(engine="per-env")),
# a plain gymnasium SyncVectorEnv with hand-written reset-time DR, and the closed-loop mujoco.rollout limit
# (one Rollout call per control step over N model copies, policy on the state, no observation or reward code).
# Every arm runs the same numpy MLP policy (64-64 tanh) on N parameter samples; figures are control steps/s,
# arms alternate order in each repeat, medians over repeats.

P4_TASKS = {"dmc/reacher-easy": ("reacher", "easy"), "dmc/manipulator-bring_ball": ("manipulator", "bring_ball")}
P4_GOALS = {"limit": 0.5, "sync": 4.0, "today": 7.0}

#: The P4 arms' clock: wall time, or with --cpu-time this process's CPU time (all its threads), which a box shared
#: with other jobs disturbs far less (run-to-run spread of wall figures was 2-3x under load).
_clock = time.perf_counter


class NumpyMLP:
    """A fixed random 64-64 tanh MLP in numpy: the same policy cost in every arm."""

    batched = True  # sim2real.agents.as_policy: takes a (B, obs_dim) batch

    def __init__(self, obs_dim: int, act_dim: int, seed: int = 0) -> None:
        import numpy as np

        rng = np.random.default_rng(seed)
        self.w = [rng.normal(0, 1 / np.sqrt(i), (i, o)) for i, o in ((obs_dim, 64), (64, 64), (64, act_dim))]

    def __call__(self, obs: Any) -> Any:
        import numpy as np

        h = np.tanh(np.asarray(obs, dtype=np.float64) @ self.w[0])
        h = np.tanh(h @ self.w[1])
        return np.tanh(h @ self.w[2]).astype(np.float32)


def _hand_dr_env(task: str, index: int, seed: int) -> Any:
    """The task with reset-time DR written by hand: the same three effects as :func:`effects`, scaled on the model."""
    import gymnasium as gym
    import numpy as np

    class HandDR(gym.Wrapper):
        def __init__(self, env: Any) -> None:
            super().__init__(env)
            physics = env.unwrapped.physics
            self.model, self.data = physics.model.ptr, physics.data.ptr
            self.nominal = (self.model.body_mass.copy(), self.model.body_inertia.copy(),
                            self.model.dof_damping.copy(), self.model.actuator_gear.copy())  # fmt: skip
            self.rng = np.random.default_rng((seed, index))

        def reset(self, **kwargs: Any) -> Any:
            mass, inertia, damping, gear = self.nominal
            m = self.model
            s = self.rng.uniform(0.7, 1.3, m.nbody)
            m.body_mass[:] = mass * s
            m.body_inertia[:] = inertia * s[:, None]
            m.dof_damping[:] = damping * self.rng.uniform(0.5, 2.0, m.nv)
            m.actuator_gear[:, 0] = gear[:, 0] * self.rng.uniform(0.8, 1.2, m.nu)
            mujoco.mj_setConst(m, self.data)
            return self.env.reset(**kwargs)

    return HandDR(s2r.make(task))


def stack() -> list[Any]:
    """The full stack: the physics effects plus observation/action noise and observation latency."""
    return [
        *effects(),
        s2r.ObservationNoise(s2r.Gaussian(std=0.01), s2r.Bias(s2r.Uniform(-0.02, 0.02))),
        s2r.ActionNoise(s2r.Gaussian(std=0.05)),
        s2r.ObservationLatency(steps=2),
    ]


def _p4_engine(task: str, num: int, steps: int, threads: int = 1, chosen: Any = None) -> tuple[float, float]:
    """The batched engine stepped directly: (control steps/s stepping only, seconds to build the N worlds)."""
    from sim2real.batched import make_batched

    start = _clock()
    worlds = make_batched(task, num, *(effects() if chosen is None else chosen), seed=0, threads=threads)
    build = _clock() - start
    policy = NumpyMLP(worlds.observation_dim, worlds.action_dim)
    obs, _ = worlds.reset(seed=0)
    start = _clock()
    for _ in range(steps):
        obs, *_ = worlds.step(policy(obs))
    rate = num * steps / (_clock() - start)
    worlds.close()
    return rate, build


def _p4_interleaved(task: str, num: int, steps: int, chunk: int = 25) -> float:
    """Full stack over raw on the engine with the load drift cancelled: both sets of ``num`` worlds built in this
    process and stepped in alternating chunks of ``chunk`` control steps (the order flips every chunk), each arm's
    clock summed over its own chunks. Returns raw time / stack time (the stack's rate over raw's)."""
    from sim2real.batched import make_batched

    arms = {
        "raw": make_batched(task, num, seed=0, threads=1),
        "stack": make_batched(task, num, *stack(), seed=0, threads=1),
    }
    policy = NumpyMLP(arms["raw"].observation_dim, arms["raw"].action_dim)
    obs = {arm: worlds.reset(seed=0)[0] for arm, worlds in arms.items()}
    spent = dict.fromkeys(arms, 0.0)
    for c, first in enumerate(range(0, steps, chunk)):
        for arm in list(arms) if c % 2 == 0 else list(arms)[::-1]:
            worlds, o = arms[arm], obs[arm]
            start = _clock()
            for _ in range(min(chunk, steps - first)):
                o, *_ = worlds.step(policy(o))
            spent[arm] += _clock() - start
            obs[arm] = o
    for worlds in arms.values():
        worlds.close()
    return spent["raw"] / spent["stack"]


_ENGINE_SNIPPET = """
import importlib.util, os, sys, time
sys.path.insert(0, sys.argv[1])
os.environ.setdefault("MUJOCO_GL", "egl")
import sim2real
assert sim2real.__file__.startswith(sys.argv[1]), sim2real.__file__
spec = importlib.util.spec_from_file_location("bench_eval_p4", sys.argv[2])
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)
if sys.argv[7] == "cpu":
    bench._clock = time.process_time
if sys.argv[9] != "none":  # --action-latency of the calling run
    bench._EXTRA[:] = [bench.s2r.ActionLatency(seconds=float(sys.argv[9]))]
if sys.argv[8] == "interleaved":
    print(bench._p4_interleaved(sys.argv[3], int(sys.argv[4]), int(sys.argv[5])))
    sys.exit(0)
chosen = {"effects": None, "raw": [], "stack": bench.stack()}[sys.argv[8]]
print(bench._p4_engine(sys.argv[3], int(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6]), chosen=chosen)[0])
"""


def _p4_engine_at(path: str, task: str, num: int, steps: int, threads: int, chosen: str = "effects") -> float:
    """:func:`_p4_engine` in a fresh process importing sim2real from ``path`` (a checkout's root), timed by this
    run's clock: the engine of another commit side by side with this one's (``--before``). ``chosen``: the
    effects, ``"effects"`` (:func:`effects`), ``"raw"`` (none) or ``"stack"`` (:func:`stack`); ``"interleaved"``:
    :func:`_p4_interleaved`'s ratio instead of a rate."""
    import subprocess
    import sys

    clock = "cpu" if _clock is time.process_time else "wall"
    argv = [sys.executable, "-c", _ENGINE_SNIPPET, path, os.path.abspath(__file__), task, str(num), str(steps),
            str(threads), clock, chosen, "none" if _LATENCY is None else repr(_LATENCY)]  # fmt: skip
    out = subprocess.run(argv, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def _p4_evaluate(task: str, num: int, steps: int, engine: str) -> tuple[float, str]:
    """``evaluate`` end to end (env construction included): (env steps/s, engine that ran)."""
    env = s2r.make(task)
    policy = NumpyMLP(env.observation_space.shape[0], env.action_space.shape[0])
    start = _clock()
    result = evaluate({"mlp": policy}, task, [randomized(effects())], episodes=num, batch=num, seed=0,
                      max_steps=steps, engine=engine)  # fmt: skip
    return result.env_steps / (_clock() - start), result.engines["randomized"]


def _p4_sync(task: str, num: int, steps: int) -> float:
    """A plain gymnasium SyncVectorEnv of hand-DR envs (construction excluded)."""
    import gymnasium as gym

    envs = gym.vector.SyncVectorEnv([lambda i=i: _hand_dr_env(task, i, 0) for i in range(num)])
    policy = NumpyMLP(envs.single_observation_space.shape[0], envs.single_action_space.shape[0])
    obs, _ = envs.reset(seed=0)
    start = _clock()
    for _ in range(steps):
        obs, *_ = envs.step(policy(obs))
    rate = num * steps / (_clock() - start)
    envs.close()
    return rate


def _p4_limit(domain: str, name: str, num: int, steps: int) -> float:
    """Closed loop, one ``Rollout.rollout`` call per control step over ``num`` model copies (policy on qpos/qvel)."""
    import copy

    import numpy as np
    from dm_control import suite
    from mujoco import rollout as mj_rollout

    env = suite.load(domain, name)
    n_sub = env._n_sub_steps
    m0 = env.physics.model.ptr
    models = [copy.copy(m0) for _ in range(num)]
    rng = np.random.default_rng(0)
    for m in models:
        m.body_mass[:] *= rng.uniform(0.7, 1.3, m.nbody)
        m.dof_damping[:] *= rng.uniform(0.5, 2.0, m.nv)
    threads = os.cpu_count() or 1
    datas = [mujoco.MjData(m0) for _ in range(threads)]
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    nstate = mujoco.mj_stateSize(m0, spec)
    state = np.zeros((num, nstate))
    d0 = mujoco.MjData(m0)
    mujoco.mj_getState(m0, d0, state[0], spec)
    state[:] = state[0]
    out = np.empty((num, n_sub, nstate))
    sens = np.empty((num, n_sub, m0.nsensordata))
    control = np.empty((num, n_sub, m0.nu))
    policy = NumpyMLP(m0.nq + m0.nv, m0.nu)
    qslice = slice(1, 1 + m0.nq + m0.nv)  # state = [time, qpos, qvel, ...]
    pool = mj_rollout.Rollout(nthread=threads)
    start = _clock()
    for _ in range(steps):
        control[:] = policy(state[:, qslice])[:, None, :]
        pool.rollout(models, datas, state, control, skip_checks=True, nstep=n_sub, state=out, sensordata=sens)
        state[:] = out[:, -1]
    rate = num * steps / (_clock() - start)
    pool.close()
    return rate


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="P4 (issue 15): batched engine vs evaluate, SyncVectorEnv, limit")
    parser.add_argument("--samples", type=int, default=64, help="parameter samples (worlds) per arm")
    parser.add_argument("--steps", type=int, nargs=2, default=[1000, 200], help="control steps: reacher, manipulator")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="smoke test: 8 samples, 50 steps, 1 repeat")
    parser.add_argument("--cpu-time", action="store_true", help="time every arm by this process's CPU time")
    parser.add_argument("--tasks", nargs="+", default=list(P4_TASKS), choices=list(P4_TASKS))
    parser.add_argument(
        "--before",
        default=None,
        metavar="DIR",
        help="also step the engine of an older checkout (DIR: e.g. `git archive <commit> | tar -x "
        "-C DIR`) and of this one, each in a fresh process, at 1 thread and at os.cpu_count()",
    )
    parser.add_argument("--action-latency", type=float, default=None, metavar="SECONDS",
                        help="add ActionLatency(seconds=SECONDS) to the sim2real arms' effects (issue 15: "
                             "'today' is then the per-env fallback evaluate(engine='auto') took before it was batched)")  # fmt: skip
    args = parser.parse_args(argv)
    if args.quick:
        args.samples, args.steps, args.repeats = 8, [50, 20], 1
    if args.action_latency is not None:
        global _LATENCY
        _LATENCY = args.action_latency
        _EXTRA[:] = [s2r.ActionLatency(seconds=args.action_latency)]
        print(f"# extra effects on the sim2real arms (not sync/limit): {_EXTRA}")
    if args.cpu_time:
        global _clock
        _clock = time.process_time
    import numpy as np

    from sim2real.batched import supports

    n = args.samples
    print(f"# bench_eval P4  python {platform.python_version()}  mujoco {mujoco.__version__}  numpy {np.__version__}  "
          f"{os.cpu_count()} CPUs; {n} samples, {args.repeats} repeats, numpy 64-64 MLP policy; clock: "
          f"{'process CPU time' if args.cpu_time else 'wall'}")  # fmt: skip
    for (task, (domain, name)), steps in zip(P4_TASKS.items(), args.steps, strict=True):
        if task not in args.tasks:
            continue
        batched = supports(task, *effects()) is None
        arms: dict[str, Any] = {
            "today": lambda t=task, s=steps: _p4_evaluate(t, n, s, "per-env")[0],
            "sync": lambda t=task, s=steps: _p4_sync(t, n, s),
            "limit": lambda d=domain, m=name, s=steps: _p4_limit(d, m, n, s),
        }
        if batched:
            threads = os.cpu_count() or 1
            arms["engine"] = lambda t=task, s=steps: _p4_engine(t, n, s)[0]
            arms["threads"] = lambda t=task, s=steps, k=threads: _p4_engine(t, n, s, k)[0]
            arms["raw"] = lambda t=task, s=steps: _p4_engine(t, n, s, chosen=[])[0]
            arms["stack"] = lambda t=task, s=steps: _p4_engine(t, n, s, chosen=stack())[0]
            arms["evaluate"] = lambda t=task, s=steps: _p4_evaluate(t, n, s, "auto")[0]
            if args.before:
                here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
                for arm, path in (("now", here), ("before", os.path.abspath(args.before))):
                    arms[arm] = lambda t=task, s=steps, p=path: _p4_engine_at(p, t, n, s, 1)
                    arms[f"{arm}_threads"] = lambda t=task, s=steps, p=path, k=threads: _p4_engine_at(p, t, n, s, k)
                    for which in ("raw", "stack"):  # the full stack over raw of each checkout, threads=1
                        arms[f"{arm}_{which}"] = lambda t=task, s=steps, p=path, c=which: _p4_engine_at(
                            p, t, n, s, 1, c
                        )
        rates: dict[str, list[float]] = {k: [] for k in arms}
        for r in range(args.repeats):
            order = list(arms) if r % 2 == 0 else list(arms)[::-1]
            for arm in order:
                rates[arm].append(arms[arm]())
        med = {k: statistics.median(v) for k, v in rates.items()}
        paired = [_p4_interleaved(task, n, steps) for _ in range(args.repeats)] if batched else []
        checkouts: dict[str, list[float]] = {}
        if batched and args.before:  # the interleaved ratio of each checkout, in fresh processes, alternating
            here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
            checkouts = {"now": [], "before": []}
            for r in range(args.repeats):
                for arm in ("now", "before") if r % 2 == 0 else ("before", "now"):
                    path = here if arm == "now" else os.path.abspath(args.before)
                    checkouts[arm].append(_p4_engine_at(path, task, n, steps, 1, "interleaved"))
        print(f"\n## {task}: {n} worlds x {steps} control steps")
        for arm, label in (("engine", "batched engine (stepping; make_batched)"),
                           ("threads", f"batched engine, threads={os.cpu_count()}"),
                           ("raw", "batched engine, no effects (raw)"),
                           ("stack", "batched engine, full stack (DR+noise+latency)"),
                           ("evaluate", "evaluate(engine='auto') end to end"),
                           ("today", "evaluate(engine='per-env') end to end (today)"),
                           ("sync", "SyncVectorEnv + hand-written reset DR"),
                           ("limit", "closed-loop mujoco.rollout limit"),
                           ("now", "engine, this checkout, fresh process, threads=1"),
                           ("now_threads", f"engine, this checkout, fresh process, threads={os.cpu_count()}"),
                           ("before", f"engine, {args.before}, fresh process, threads=1"),
                           ("before_threads", f"engine, {args.before}, fresh process, threads={os.cpu_count()}"),
                           ("now_raw", "engine raw, this checkout, fresh process"),
                           ("now_stack", "engine full stack, this checkout, fresh process"),
                           ("before_raw", f"engine raw, {args.before}, fresh process"),
                           ("before_stack", f"engine full stack, {args.before}, fresh process")):  # fmt: skip
            if arm in med:
                runs = ", ".join(f"{x:.0f}" for x in rates[arm])
                print(f"{label:48s} {med[arm]:10.0f} control steps/s  (runs: {runs})")
        if not batched:
            print(f"batched engine: not available ({supports(task, *effects())}); evaluate falls back to per-env")
            continue
        build = _p4_engine(task, n, 1)[1]
        e = max(med["engine"], med["threads"])
        print(f"building {n} worlds: {build:.2f} s (not in the engine figure)")
        print(
            f"RESULT {task} (engine = the faster of 1 and {os.cpu_count()} threads): "
            f"batched full stack / batched raw = {med['stack'] / med['raw']:.2f} (each repeat's adjacent pair: "
            f"{', '.join(f'{s / r:.3f}' for s, r in zip(rates['stack'], rates['raw'], strict=True))}; goal >= 0.95); "
            f"engine/limit = {e / med['limit']:.2f} (goal >= {P4_GOALS['limit']}), "
            f"engine/sync = {e / med['sync']:.1f}x (goal >= {P4_GOALS['sync']:.0f}x), "
            f"evaluate auto/per-env (both end to end, builds included) = {med['evaluate'] / med['today']:.1f}x "
            f"(goal >= {P4_GOALS['today']:.0f}x); engine stepping / today end to end = {e / med['today']:.1f}x"
        )
        print(f"RESULT {task} full stack / raw, interleaved in chunks of 25 steps (one process, threads=1): "
              f"{statistics.median(paired):.3f} (runs: {', '.join(f'{x:.3f}' for x in paired)}; goal >= 0.95)")  # fmt: skip
        if args.before:
            print(f"RESULT {task} engine now / before (fresh processes): threads=1 {med['now'] / med['before']:.2f}x, "
                  f"threads={os.cpu_count()} {med['now_threads'] / med['before_threads']:.2f}x; "
                  f"threads={os.cpu_count()} / threads=1: now {med['now_threads'] / med['now']:.2f}, "
                  f"before {med['before_threads'] / med['before']:.2f}")  # fmt: skip
            print(f"RESULT {task} full stack / raw interleaved (fresh processes): now "
                  f"{statistics.median(checkouts['now']):.3f} (runs: {', '.join(f'{x:.3f}' for x in checkouts['now'])}), "
                  f"before {statistics.median(checkouts['before']):.3f} "
                  f"(runs: {', '.join(f'{x:.3f}' for x in checkouts['before'])})")  # fmt: skip
            print(f"RESULT {task} full stack / raw (fresh processes, threads=1): now "
                  f"{med['now_stack'] / med['now_raw']:.2f}, before {med['before_stack'] / med['before_raw']:.2f} "
                  f"(goal >= 0.95)")  # fmt: skip


# ------------------------------------------------------------------------------------------ issue 15: make x N
#
# Building N envs with sim2real.make, each arm in a fresh process (so each pays its own first compile), arms
# alternating: this checkout with textures (make's default), this checkout headless (textures=False: what the
# batched engine and evaluate use), and optionally an older checkout (--before DIR: a directory holding its
# sim2real/randomizers/noise_models/sysid packages, e.g. from `git archive <commit> | tar -x -C DIR`).

_MAKE_SNIPPET = """
import os, sys, time
os.environ.setdefault("MUJOCO_GL", "egl")
import sim2real as s2r
task, n, kw = sys.argv[1], int(sys.argv[2]), eval(sys.argv[3])
start = time.perf_counter()
first = s2r.make(task, **kw)
one = time.perf_counter() - start
start = time.perf_counter()
envs = [s2r.make(task, **kw) for _ in range(n)]
print(one, time.perf_counter() - start)
"""


def _make_arm(task: str, n: int, textures: bool, path: str) -> tuple[float, float]:
    """(seconds for the first env, seconds for ``n`` more) in a fresh process importing sim2real from ``path``."""
    import subprocess
    import sys

    kw = "{}" if textures else "{'textures': False}"
    env = {**os.environ, "PYTHONPATH": path}
    out = subprocess.run([sys.executable, "-c", _MAKE_SNIPPET, task, str(n), kw], env=env, check=True,
                         capture_output=True, text=True, cwd=path).stdout.split()  # fmt: skip
    return float(out[-2]), float(out[-1])


def main_make(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="issue 15: sim2real.make x N, before/after side by side")
    parser.add_argument("--samples", type=int, default=64, help="envs built after the first")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--before", default=None, help="directory with an older checkout's packages")
    args = parser.parse_args(argv)
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    arms: dict[str, tuple[bool, str]] = {"textures": (True, here), "headless": (False, here)}
    if args.before:
        arms = {"before": (True, os.path.abspath(args.before)), **arms}
    print(f"# bench_eval --make  python {platform.python_version()}  mujoco {mujoco.__version__}  {os.cpu_count()} "
          f"CPUs; {args.samples} envs after the first, {args.repeats} repeats, fresh process per arm")  # fmt: skip
    for task in ("dmc/reacher-easy", "dmc/manipulator-bring_ball", "sim2real/arm-reach"):
        firsts: dict[str, list[float]] = {k: [] for k in arms}
        totals: dict[str, list[float]] = {k: [] for k in arms}
        for r in range(args.repeats):
            for arm in list(arms) if r % 2 == 0 else list(arms)[::-1]:
                textures, path = arms[arm]
                if arm == "before" or textures or task in _HEADLESS:
                    one, many = _make_arm(task, args.samples, textures, path)
                    firsts[arm].append(one)
                    totals[arm].append(many)
        print(f"\n## {task}: make x {args.samples}")
        med = {k: statistics.median(v) for k, v in totals.items() if v}
        for arm, seconds in med.items():
            runs = ", ".join(f"{x:.2f}" for x in totals[arm])
            print(f"{arm:9s} {seconds:7.2f} s ({1e3 * seconds / args.samples:6.1f} ms/env; first env "
                  f"{statistics.median(firsts[arm]):.2f} s)  runs: {runs}")  # fmt: skip
        ref = med.get("before", med["textures"])
        print("RESULT " + task + ": " + ", ".join(f"{k} {ref / v:.1f}x" for k, v in med.items() if k != "before")
              + (" faster than before" if "before" in med else " faster than with textures"))  # fmt: skip


_HEADLESS = ("dmc/reacher-easy", "dmc/manipulator-bring_ball", "sim2real/arm-reach")


# ------------------------------------------------------------------------------------------ issue 15: make_vec
#
# make_vec against plain gymnasium SyncVectorEnvs, stepping only (construction excluded), arms alternating:
# with the three physics effects vs a SyncVectorEnv of make(task) envs with the same DR written by hand
# (_hand_dr_env) and vs a SyncVectorEnv of the same sim2real-wrapped envs reporting on every step (make_vec
# before draws were reported at reset only); without effects vs a SyncVectorEnv of bare make(task) envs.


def _vec_rate(envs: Any, steps: int) -> float:
    import numpy as np

    actions = np.random.default_rng(0).uniform(-1, 1, (steps, *envs.action_space.shape)).astype(np.float32)
    envs.reset(seed=0)
    start = _clock()
    for t in range(steps):
        envs.step(actions[t])
    rate = envs.num_envs * steps / (_clock() - start)
    envs.close()
    return rate


def main_make_vec(argv: list[str] | None = None) -> None:
    import gymnasium as gym

    from sim2real.wrapping import _ReportAtReset

    parser = argparse.ArgumentParser(description="issue 15: make_vec over plain SyncVectorEnvs")
    parser.add_argument("--samples", type=int, default=64, help="sub-envs")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--task", default="dmc/reacher-easy")
    parser.add_argument("--cpu-time", action="store_true", help="time every arm by this process's CPU time")
    args = parser.parse_args(argv)
    n, task = args.samples, args.task
    if args.cpu_time:
        global _clock
        _clock = time.process_time
    arms: dict[str, Any] = {
        "make_vec": lambda: s2r.make_vec(task, n, *effects(), seed=0),
        "hand": lambda: gym.vector.SyncVectorEnv([lambda i=i: _hand_dr_env(task, i, 0) for i in range(n)]),
        "every_step": lambda: gym.vector.SyncVectorEnv(
            [lambda i=i: s2r.wrap(s2r.make(task), *effects(), seed=(0, i)) for i in range(n)]
        ),
        "make_vec_raw": lambda: s2r.make_vec(task, n, seed=0),
        "bare": lambda: gym.vector.SyncVectorEnv([lambda: s2r.make(task) for _ in range(n)]),
        # make_vec without effects before its sub-envs were one layer: RandomizePhysics inside _ReportAtReset.
        "two_layers": lambda: gym.vector.SyncVectorEnv(
            [lambda i=i: _ReportAtReset(s2r.wrap(s2r.make(task), seed=(0, i))) for i in range(n)]
        ),
    }
    print(f"# bench_eval --make-vec  python {platform.python_version()}  gymnasium {gym.__version__}  "
          f"{os.cpu_count()} CPUs; {task}, {n} sub-envs x {args.steps} steps, {args.repeats} repeats; clock: "
          f"{'process CPU time' if args.cpu_time else 'wall'}")  # fmt: skip
    rates: dict[str, list[float]] = {k: [] for k in arms}
    for r in range(args.repeats):
        for arm in list(arms) if r % 2 == 0 else list(arms)[::-1]:
            rates[arm].append(_vec_rate(arms[arm](), args.steps))
    med = {k: statistics.median(v) for k, v in rates.items()}
    for arm, label in (("make_vec", "make_vec, 3 physics effects"),
                       ("hand", "SyncVectorEnv, make(task) + hand-written DR"),
                       ("every_step", "SyncVectorEnv, same wrapped envs, report every step"),
                       ("make_vec_raw", "make_vec, no effects"),
                       ("bare", "SyncVectorEnv, bare make(task)"),
                       ("two_layers", "no effects, _ReportAtReset(RandomizePhysics) (before)")):  # fmt: skip
        runs = ", ".join(f"{x:.0f}" for x in rates[arm])
        print(f"{label:52s} {med[arm]:9.0f} steps/s  (runs: {runs})")
    print(f"RESULT make_vec / SyncVectorEnv+hand DR = {med['make_vec'] / med['hand']:.2f}; make_vec (no effects) / "
          f"bare SyncVectorEnv = {med['make_vec_raw'] / med['bare']:.2f} (goal >= 0.95; the two layers before: "
          f"{med['two_layers'] / med['bare']:.2f}); make_vec / the same wrapped envs reporting every step = "
          f"{med['make_vec'] / med['every_step']:.2f}")  # fmt: skip


if __name__ == "__main__":
    import sys

    if "--torchrl" in sys.argv:
        main_torchrl([a for a in sys.argv[1:] if a != "--torchrl"])
    elif "--make-vec" in sys.argv:
        main_make_vec([a for a in sys.argv[1:] if a != "--make-vec"])
    elif "--make" in sys.argv:
        main_make([a for a in sys.argv[1:] if a != "--make"])
    else:
        main()
