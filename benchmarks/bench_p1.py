"""P1 of issue 15: the single-env full stack over the raw env, before (two wrapper layers) and after (one fused layer).

Section [4] of ``bench_overhead.py`` (also runnable alone). Per task, these arms step side by side, in an order that
rotates and flips every repeat, timed in CPU time (``time.process_time``; the box is shared), resets untimed:

* ``raw``: ``s2r.make(task)``.
* ``two layers``: ``wrap(wrap(make(task), *physics, seed=0), *signals, seed=0)``, the stack as ``wrap`` built it
  before issue 15 (CorruptSignals around RandomizePhysics).
* ``fused``: ``wrap(make(task), *physics, *signals, seed=0)``, one RandomizeAndCorrupt layer (bitwise the same
  outputs as the two layers, tests/test_fused.py).
* ``fused, Python``: the same layer with its episodes stepping in Python (:class:`PythonPath`:
  ``SIM2REAL_PURE_PYTHON=1`` at its resets), where ``fused`` steps through the compiled hot step where it is built
  (``noise_models.compiled``): ``compiled/python`` is what the C extensions give.
* ``lean``: :class:`LeanFloor` around ``make(task)``, a minimal Python wrapper doing the fused layer's per-step
  arithmetic (action noise, clip, action delay, observation noise and delay, a fresh report of as many params) and
  nothing else: the floor any Python wrapper meets on this work (its draws are not the stack's; physics DR not
  included, which costs ~1% on either task). ``fused/lean`` >= 1 means the fused layer is at that floor.
* ``lean, keyed noise``: the same drawing a fresh block of Gaussian rows every 256 steps from a Philox generator
  (as the stack's keyed streams do: ``standard_normal(out=...)``, the bias added, the cast), instead of cycling one
  fixed block: the floor of a wrapper whose noise is noise. ``fused/lean keyed`` >= 1 means the fused layer is at it.
* ``lean, keyed, DR``: ``lean, keyed noise`` around an env whose model holds the stack's physics draws (a
  :class:`RandomizePhysics` layer draws and writes them at every reset; steps bypass it): the floor of a Python
  wrapper doing the whole stack's work, physics DR included (the randomised model's own dynamics cost ~1% on
  manipulator). ``fused/lean keyed DR`` >= 1 means the fused layer is at the floor of the full stack.
* ``lean, no report``: the same without the per-step report (``info["sim2real"]``: a fresh dict holding a fresh copy
  of the episode's params, as gymnasium's env checker demands of every step's info): what that contract costs.
* manipulator only, the env as it was before its fast path: ``dmc raw`` is the adapter around dm-control's own
  ``suite.load`` (observation and reward through the named indexer), ``dmc two layers`` the two-layer stack around
  it. ``before`` = dmc two layers / dmc raw is the figure of the issue (0.91-0.93).

The stack is section [3]'s: physics DR at reset plus obs noise, action noise, ``ObservationLatency(steps=3)`` and
``ActionLatency(seconds=0.02)``. Ratios are medians of per-repeat paired ratios (range in brackets).

With ``--chunk C`` the arms take turns every ``C`` steps (``steps // C`` rounds per repeat, order rotating and
flipping every round), so load changes slower than one round hit every arm alike: on a shared, loaded box this
pairs the arms far more tightly than one block per arm and repeat.

``--torchrl`` measures the TorchRL side instead: ``GymWrapper(make(task))`` raw, with ``Compose`` of the two
transforms, and with the one fused transform, ``env.rollout(chunk)`` in turns.

Usage:
    .venv/bin/python benchmarks/bench_p1.py [--steps N] [--repeats R] [--chunk C] [--tasks reacher-easy ...]
    .venv/bin/python benchmarks/bench_p1.py --torchrl --steps 3000 --chunk 100 --repeats 5 --tasks reacher-easy
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

import sim2real as s2r
from noise_models.fused import _clip

P1_GOALS = {"reacher-easy": 0.85, "manipulator-bring_ball": 0.97}
DEFAULT_TASKS = ("reacher-easy", "manipulator-bring_ball")


def _dm_control_env(name: str) -> Any:
    from dm_control import suite

    from sim2real.adapters import DmEnvToGym

    domain, task = name.split("-", 1)
    return DmEnvToGym(suite.load(domain, task))


class LeanFloor(gym.Wrapper):  # type: ignore[type-arg]
    """The cost floor of any Python wrapper doing the fused layer's per-step work, without its generality: the
    action plus a row of a preallocated Gaussian block, clipped to the bounds, delayed ``action_lag`` control steps
    on the action side; the observation plus a row of its block (noise and bias folded), delayed ``obs_lag`` steps
    through a ring of references; a fresh report (a template copy and a copy of ``n_params`` floats) every step.
    Nothing is checked, nothing is general, the draws are not the stack's: a reference for what the arithmetic and
    the fresh per-step dicts cost, not a feature (``lean`` arm)."""

    def __init__(
        self, env: Any, n_params: int, action_lag: int, obs_lag: int, report: bool = True, keyed: bool = False
    ) -> None:
        super().__init__(env)
        self.n_params, self.action_lag, self.obs_lag, self.report = n_params, action_lag, obs_lag, report
        self.keyed = keyed  # draw a fresh block every 256 steps (``lean, keyed noise``) instead of cycling one

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        rng = np.random.default_rng(0)
        space = self.env.action_space
        size = obs.shape[0]
        self._obs_rows = (rng.normal(0, 0.01, (256, size)) + rng.uniform(-0.02, 0.02, size)).astype(np.float32)
        self._act_rows = rng.normal(0, 0.05, (256, *space.shape)).astype(np.float32)
        self._low, self._high = space.low, space.high
        self._row = self._k = 0
        self._act_ring = [np.zeros(space.shape, np.float32)] * (self.action_lag + 1)
        self._obs_ring = [obs] * (self.obs_lag + 1)
        self._params = {f"p{j}": 0.1 * j for j in range(self.n_params)}
        self._template = {"params": None, "events": (), "episode": 0, "diverged": False, "reapplied": ()}
        if self.keyed:
            self._gen = np.random.Generator(np.random.Philox(key=np.arange(2, dtype=np.uint64)))
            self._bias = rng.uniform(-0.02, 0.02, size)
            self._obs64, self._act64 = np.empty((256, size)), np.empty((256, *space.shape))
            self._obs_list, self._act_list = list(self._obs_rows), list(self._act_rows)
            self._row = 255  # the first step draws the first block
        return obs, info

    def _draw(self) -> None:
        """The next block of both sides' rows: what a keyed refill does per block (normals, scale, bias, cast)."""
        gen, o, a = self._gen, self._obs64, self._act64
        gen.standard_normal(out=o)
        o *= 0.01
        np.add(o, self._bias, o)
        np.add(o, 0.0, out=self._obs_rows)
        gen.standard_normal(out=a)
        a *= 0.05
        np.add(a, 0.0, out=self._act_rows)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        r = self._row = (self._row + 1) % 256
        if r == 0 and self.keyed:
            self._draw()
        noisy = action + self._act_rows[r]
        _clip(noisy, self._low, self._high, noisy)  # the clip ufunc itself (np.clip's Python dispatch costs ~2 us)
        k = self._k = self._k + 1
        ring, size = self._act_ring, self.action_lag + 1
        ring[k % size] = noisy
        obs, reward, terminated, truncated, info = self.env.step(ring[(k - self.action_lag) % size])
        oring, osize = self._obs_ring, self.obs_lag + 1
        oring[k % osize] = obs + self._obs_rows[r]
        if self.report:
            report = self._template.copy()
            report["params"] = self._params.copy()
            info["sim2real"] = report
        return oring[(k - self.obs_lag) % osize], reward, terminated, truncated, info


class DrawsOnly(gym.Wrapper):  # type: ignore[type-arg]
    """The raw env under a physics layer's draws: ``reset`` goes through ``layer`` (a RandomizePhysics around the
    env), which draws and writes the episode's physics; ``step`` calls the env itself (no wrapper on the step path,
    nothing reported): what the randomised model's own dynamics cost, for the ``lean, keyed, DR`` arm."""

    def __init__(self, layer: Any) -> None:
        super().__init__(layer.env)
        self.layer = layer

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        return self.layer.reset(**kwargs)  # type: ignore[no-any-return]

    def close(self) -> None:
        self.layer.close()


class PythonPath:
    """A fused layer whose episodes step in Python (``SIM2REAL_PURE_PYTHON=1`` while it resets): the ``fused,
    Python`` arm, what the ``fused`` arm does without the compiled hot step (noise_models.compiled). Its ``step`` is
    the layer's own, looked up on every call as the other arms' (a one-shot first-step check replaces itself), so
    that the arm times no extra Python call."""

    def __init__(self, layer: Any) -> None:
        self.layer = layer
        self.action_space = layer.action_space

    @property
    def step(self) -> Any:
        return self.layer.step

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        from noise_models import compiled

        before = os.environ.get(compiled.ENV)
        os.environ[compiled.ENV] = "1"
        try:
            out = self.layer.reset(**kwargs)
        finally:
            if before is None:
                del os.environ[compiled.ENV]
            else:
                os.environ[compiled.ENV] = before
        return out  # type: ignore[no-any-return]

    def close(self) -> None:
        self.layer.close()


def arms_for(name: str) -> dict[str, Any]:
    """The arms of one task (see the module docstring)."""
    from bench_overhead import make_signal_models, make_stack_physics, task_id

    tid = task_id(name)
    fused = s2r.wrap(s2r.make(tid), *make_stack_physics(), *make_signal_models(), seed=0)
    _, info = fused.reset(seed=0)
    params = info["sim2real"]["params"]
    # The action lag in control steps (the report's action_latency_steps counts physics steps).
    lags = (len(params), int(params["action_latency_steps"]) // fused.clock.nominal, int(params["obs_latency_steps"]))
    arms: dict[str, Any] = {
        "raw": s2r.make(tid),
        "two layers": s2r.wrap(s2r.wrap(s2r.make(tid), *make_stack_physics(), seed=0), *make_signal_models(), seed=0),
        "fused": fused,
        "fused, Python": PythonPath(s2r.wrap(s2r.make(tid), *make_stack_physics(), *make_signal_models(), seed=0)),
        "lean": LeanFloor(s2r.make(tid), *lags),
        "lean, keyed noise": LeanFloor(s2r.make(tid), *lags, keyed=True),
        "lean, keyed, DR": LeanFloor(
            DrawsOnly(s2r.wrap(s2r.make(tid), *make_stack_physics(), seed=0)), *lags, keyed=True
        ),
        "lean, no report": LeanFloor(s2r.make(tid), *lags, report=False),
    }
    if name.startswith("manipulator-"):
        arms["dmc raw"] = _dm_control_env(name)
        arms["dmc two layers"] = s2r.wrap(
            s2r.wrap(_dm_control_env(name), *make_stack_physics(), seed=0), *make_signal_models(), seed=0
        )
    return arms


class _Stepper:
    """One arm stepping its own episodes across calls: :meth:`run` times ``n`` steps in CPU time, resets untimed
    (episode ``k`` starts with ``reset(seed=k)``, as in ``time_steps``)."""

    def __init__(self, env: Any, actions: np.ndarray) -> None:
        self.env, self.actions = env, actions
        self.episode = 0
        self.k = 0
        env.reset(seed=0)

    def run(self, n: int) -> float:
        env, actions, clock = self.env, self.actions, time.process_time
        elapsed = 0.0
        done = 0
        while done < n:
            start = clock()
            ended = False
            while done < n:
                _, _, terminated, truncated, _ = env.step(actions[self.k % len(actions)])
                self.k += 1
                done += 1
                if terminated or truncated:
                    ended = True
                    break
            elapsed += clock() - start
            if ended:
                self.episode += 1
                env.reset(seed=self.episode)
        return elapsed


def _rotation(names: list[str], r: int) -> list[str]:
    """The arms' order in round ``r``: rotated by one each round and reversed every other, so no arm always
    follows the same one."""
    order = names[r % len(names) :] + names[: r % len(names)]
    return order[::-1] if r % 2 else order


def _interleaved(
    arms: dict[str, Any], actions: np.ndarray, chunk: int, rounds: int, repeats: int
) -> dict[str, list[float]]:
    """Steps/s per arm and repeat, each repeat ``rounds`` rounds of ``chunk`` steps per arm in rotating order: load
    changes slower than one round hit every arm alike."""
    steppers = {arm: _Stepper(env, actions) for arm, env in arms.items()}
    names = list(arms)
    rates: dict[str, list[float]] = {arm: [] for arm in names}
    for rep in range(repeats):
        spent = dict.fromkeys(names, 0.0)
        for r in range(rounds):
            for arm in _rotation(names, r):
                spent[arm] += steppers[arm].run(chunk)
        for arm in names:
            rates[arm].append(chunk * rounds / spent[arm])
        print(
            f"  repeat {rep + 1}/{repeats}: "
            + "  ".join(f"{arm} {1e6 / rates[arm][-1]:6.1f} µs" for arm in names)
            + f"  two/raw {rates['two layers'][-1] / rates['raw'][-1]:.3f}"
            + f"  fused/raw {rates['fused'][-1] / rates['raw'][-1]:.3f}",
            flush=True,
        )
    return rates


def _ratio(rates: dict[str, list[float]], num: str, den: str) -> tuple[float, float, float]:
    pairs = [a / b for a, b in zip(rates[num], rates[den], strict=True)]
    return statistics.median(pairs), min(pairs), max(pairs)


def bench_p1(tasks: list[str], steps: int, repeats: int, warmup: int, chunk: int = 0) -> dict[str, dict[str, Any]]:
    """CPU-time step rates of every arm, interleaved, and the ratios P1 asks for; ``chunk`` > 0 interleaves the arms
    every ``chunk`` steps (``steps // chunk`` rounds per repeat) instead of every ``steps``."""
    from bench_overhead import time_steps

    out: dict[str, dict[str, Any]] = {}
    for name in tasks:
        arms = arms_for(name)
        space = arms["raw"].action_space
        actions = np.random.default_rng(12345).uniform(space.low, space.high, (4096, *space.shape)).astype(space.dtype)
        for env in arms.values():
            time_steps(env, actions, warmup, clock=time.process_time)
        names = list(arms)
        if chunk > 0:
            print(
                f"  {name}: {len(names)} arms interleaved every {chunk} steps, {max(1, steps // chunk)} rounds/repeat"
            )
            rates = _interleaved(arms, actions, chunk, max(1, steps // chunk), repeats)
            out[name] = _summary(rates)
            for env in arms.values():
                env.close()
            continue
        rates: dict[str, list[float]] = {arm: [] for arm in names}
        for rep in range(repeats):
            order = names[rep % len(names) :] + names[: rep % len(names)]
            if rep % 2:
                order.reverse()
            for arm in order:
                rates[arm].append(time_steps(arms[arm], actions, steps, clock=time.process_time))
            print(
                f"  {name:<24} repeat {rep + 1}/{repeats}: "
                + "  ".join(f"{arm} {1e6 / rates[arm][-1]:6.1f} µs" for arm in names)
                + f"  two/raw {rates['two layers'][-1] / rates['raw'][-1]:.3f}"
                + f"  fused/raw {rates['fused'][-1] / rates['raw'][-1]:.3f}",
                flush=True,
            )
        out[name] = _summary(rates)
        for env in arms.values():
            env.close()
    return out


def _summary(rates: dict[str, list[float]]) -> dict[str, Any]:
    result: dict[str, Any] = {"us": {arm: 1e6 / statistics.median(v) for arm, v in rates.items()}}
    result["two/raw"] = _ratio(rates, "two layers", "raw")
    result["fused/raw"] = _ratio(rates, "fused", "raw")
    result["fused/two"] = _ratio(rates, "fused", "two layers")
    result["python/raw"] = _ratio(rates, "fused, Python", "raw")
    result["fused/python"] = _ratio(rates, "fused", "fused, Python")
    result["lean/raw"] = _ratio(rates, "lean", "raw")
    result["fused/lean"] = _ratio(rates, "fused", "lean")
    result["lean no report/raw"] = _ratio(rates, "lean, no report", "raw")
    result["lean keyed/raw"] = _ratio(rates, "lean, keyed noise", "raw")
    result["fused/lean keyed"] = _ratio(rates, "fused", "lean, keyed noise")
    result["lean keyed DR/raw"] = _ratio(rates, "lean, keyed, DR", "raw")
    result["fused/lean keyed DR"] = _ratio(rates, "fused", "lean, keyed, DR")
    if "dmc raw" in rates:
        result["before"] = _ratio(rates, "dmc two layers", "dmc raw")
        result["fast raw/dmc raw"] = _ratio(rates, "raw", "dmc raw")
        result["fused/dmc raw"] = _ratio(rates, "fused", "dmc raw")
    return result


def _fmt(r: tuple[float, float, float]) -> str:
    return f"{r[0]:.3f} [{r[1]:.3f}-{r[2]:.3f}]"


def report(results: dict[str, dict[str, Any]]) -> None:
    """Prints the P1 table and the ``RESULT_P1`` line."""
    print(f"\n{'task':<26}{'arm':<16}{'µs/step (CPU, median)':>22}")
    for name, r in results.items():
        for arm, us in r["us"].items():
            print(f"{name:<26}{arm:<16}{us:>22.1f}")
    print(f"\n{'task':<26}{'before: two/raw':>24}{'after: fused/raw':>24}{'fused/two':>24}{'goal':>6}")
    verdicts = []
    for name, r in results.items():
        goal = P1_GOALS.get(name, 0.97)
        print(f"{name:<26}{_fmt(r['two/raw']):>24}{_fmt(r['fused/raw']):>24}{_fmt(r['fused/two']):>24}{goal:>6.2f}")
        verdicts.append(
            f"{name} fused/raw={r['fused/raw'][0]:.3f} two/raw={r['two/raw'][0]:.3f} python/raw={r['python/raw'][0]:.3f}"
        )
        print(
            f"  the fused layer stepping in Python (SIM2REAL_PURE_PYTHON=1): python/raw {_fmt(r['python/raw'])}; "
            f"compiled/python {_fmt(r['fused/python'])}"
        )
        print(
            f"{'  floor: a lean Python wrapper doing the same arithmetic (LeanFloor)':<26}\n"
            f"    lean/raw {_fmt(r['lean/raw'])}; fused/lean {_fmt(r['fused/lean'])}; "
            f"lean without the per-step report / raw {_fmt(r['lean no report/raw'])}\n"
            f"    lean drawing fresh noise blocks / raw {_fmt(r['lean keyed/raw'])}; "
            f"fused/lean keyed {_fmt(r['fused/lean keyed'])}\n"
            f"    the same over the stack's physics draws (the full stack's floor) / raw {_fmt(r['lean keyed DR/raw'])}; "
            f"fused/lean keyed DR {_fmt(r['fused/lean keyed DR'])}"
        )
        verdicts.append(
            f"{name} lean/raw={r['lean/raw'][0]:.3f} lean_keyed/raw={r['lean keyed/raw'][0]:.3f} "
            f"lean_keyed_dr/raw={r['lean keyed DR/raw'][0]:.3f}"
        )
        if "before" in r:
            print(
                f"{'  (manipulator, dm-control named-indexer task)':<26}\n"
                f"    before its fast path: dmc two layers / dmc raw {_fmt(r['before'])}; "
                f"fast raw / dmc raw {_fmt(r['fast raw/dmc raw'])} (speed-up of the raw step); "
                f"fused / dmc raw {_fmt(r['fused/dmc raw'])}"
            )
            verdicts.append(f"{name} fused/dmc_raw={r['fused/dmc raw'][0]:.3f} before={r['before'][0]:.3f}")
    met = all(r["fused/raw"][0] >= P1_GOALS.get(n, 0.97) for n, r in results.items())
    print(
        "(ratios: median of per-repeat paired ratios of steps/s, [min-max]; before = two layers, after = one fused "
        "layer; goal on fused/raw)"
    )
    goals = ", ".join(f"{n}>={g}" for n, g in P1_GOALS.items())
    print(f"RESULT_P1 {' '.join(verdicts)} (goals fused/raw: {goals}) {'PASS' if met else 'MISS'}")


def bench_torchrl(name: str, chunk: int, rounds: int, repeats: int) -> dict[str, tuple[float, float, float]]:
    """TorchRL: ``GymWrapper(make(task))`` raw, with the two transforms (``Compose``) and with the fused one, each
    stepping ``env.rollout(chunk)`` in turns (random actions from the spec), CPU time; returns the paired ratios."""
    import torch
    from bench_overhead import make_signal_models, make_stack_physics, task_id
    from torchrl.envs import Compose, GymWrapper, TransformedEnv

    from sim2real.wrappers import CorruptSignalsTransform, RandomizePhysicsTransform

    tid = task_id(name)
    arms: dict[str, Any] = {
        "raw": GymWrapper(s2r.make(tid)),
        "two layers": TransformedEnv(
            GymWrapper(s2r.make(tid)),
            Compose(
                RandomizePhysicsTransform(make_stack_physics(), 0), CorruptSignalsTransform(make_signal_models(), 0)
            ),
        ),
        "fused": s2r.wrap(GymWrapper(s2r.make(tid)), *make_stack_physics(), *make_signal_models(), seed=0),
    }
    torch.manual_seed(0)
    names = list(arms)
    for env in arms.values():
        env.rollout(chunk, break_when_any_done=False)
    rates: dict[str, list[float]] = {arm: [] for arm in names}
    for rep in range(repeats):
        spent = dict.fromkeys(names, 0.0)
        for r in range(rounds):
            for arm in _rotation(names, r):
                start = time.process_time()
                arms[arm].rollout(chunk, break_when_any_done=False)
                spent[arm] += time.process_time() - start
        for arm in names:
            rates[arm].append(chunk * rounds / spent[arm])
        print(
            f"  torchrl {name} repeat {rep + 1}/{repeats}: "
            + "  ".join(f"{arm} {1e6 / rates[arm][-1]:6.1f} µs" for arm in names),
            flush=True,
        )
    for env in arms.values():
        env.close()
    out = {
        "two/raw": _ratio(rates, "two layers", "raw"),
        "fused/raw": _ratio(rates, "fused", "raw"),
        "fused/two": _ratio(rates, "fused", "two layers"),
    }
    us = "  ".join(f"{arm} {1e6 / statistics.median(v):.1f} µs" for arm, v in rates.items())
    print(f"torchrl {name}: {us}")
    print(f"RESULT_P1_TORCHRL {name} " + " ".join(f"{k}={_fmt(v)}" for k, v in out.items()))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=10000, help="timed steps per arm per repeat")
    parser.add_argument("--repeats", type=int, default=6, help="repeats (medians of paired ratios are reported)")
    parser.add_argument("--tasks", nargs="+", default=list(DEFAULT_TASKS), help="dm-control suite tasks")
    parser.add_argument("--chunk", type=int, default=0, help="interleave the arms every CHUNK steps (0: per repeat)")
    parser.add_argument("--quick", action="store_true", help="tiny run to check the script works")
    parser.add_argument("--torchrl", action="store_true", help="the TorchRL transforms instead (rollout, CPU time)")
    args = parser.parse_args()
    steps, repeats, warmup = (500, 2, 100) if args.quick else (args.steps, args.repeats, 1000)
    print(f"bench_p1: python {platform.python_version()}, mujoco {mujoco.__version__}, numpy {np.__version__}")
    print(f"steps={steps} repeats={repeats} chunk={args.chunk} tasks={args.tasks} clock=process_time (CPU)")
    print("\n[4] P1 (issue 15): full stack over raw, two layers (before) vs one fused layer (after)")
    if args.torchrl:
        chunk = args.chunk or 100
        for name in args.tasks:
            bench_torchrl(name, chunk, max(1, steps // chunk), repeats)
        return
    report(bench_p1(args.tasks, steps, repeats, warmup, args.chunk))


if __name__ == "__main__":
    main()
