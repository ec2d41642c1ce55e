"""``sim2real tasks``, ``demo`` and ``visualize``.

Example:
    >>> import contextlib, io
    >>> from sim2real.cli import main
    >>> err = io.StringIO()
    >>> with contextlib.redirect_stderr(err):
    ...     main(["visualize", "--n", "2"])
    2
    >>> err.getvalue()
    'sim2real visualize: error: give a task id (positional or --task), --model ROBOT.xml or --env MODULE:FACTORY.\\n'
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

import sim2real
from randomizers import Effect
from sim2real.cli._common import UsageError, check_outputs, source_inputs, source_of, writing
from sim2real.cli.parser import ARM_REACH

__all__ = ["ARM_REACH_POLICY", "cmd_demo", "cmd_tasks", "cmd_visualize", "default_effects"]

#: One-line description of the scripted arm-reach controller, printed by ``sim2real demo``.
ARM_REACH_POLICY = "scripted reach: action = clip(target - end_effector, -0.05, 0.05)"

Policy = Callable[[np.ndarray], np.ndarray]


def default_effects() -> list[Effect]:
    """The physics randomisation ``sim2real demo`` applies when no ``--config`` is given.

    The ranges are wide enough that the scripted arm-reach controller visibly suffers: slower
    servos (lower actuator gain), heavier links and more joint damping make it reach later or
    not at all within the 200-step episode.
    """
    return [
        sim2real.Mass(scale=sim2real.Uniform(0.5, 2.0)),
        sim2real.Damping(scale=sim2real.LogUniform(0.5, 4.0)),
        sim2real.ActuatorGain(scale=sim2real.Uniform(0.3, 1.0)),
        sim2real.Friction(scale=sim2real.Uniform(0.5, 1.5)),
    ]


# ---------------------------------------------------------------------------------- tasks


def cmd_tasks(out: TextIO) -> int:
    width = max(len(task_id) for task_id in sim2real.TASKS)
    for task_id, task in sim2real.TASKS.items():
        print(f"{task_id:<{width}}  {task.description}", file=out)
    print(f"\n{'gym/<id>':<{width}}  any gymnasium id works too, e.g. gym/Hopper-v5.", file=out)
    return 0


# ---------------------------------------------------------------------------------- demo


@dataclass(frozen=True)
class _Episode:
    ret: float
    length: int
    success: bool | None  # None when the task reports no "is_success"
    diverged: bool
    params: dict[str, float]


def _arm_reach_policy(obs: np.ndarray) -> np.ndarray:
    return np.clip(obs[3:6] - obs[0:3], -0.05, 0.05).astype(np.float32)


def _zero_policy(env: Any) -> Policy:
    zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    return lambda obs: zero


def _hold_policy(env: Any) -> Policy | None:
    """Position servos held at their set points of the env's start pose (other actuators at 0), or None when the
    model has no servo or the env's actions are not its actuators' controls: a zero action sends every servo to
    0 rad, far from the pose the arm starts in. The start pose: the model's home keyframe (named ``home``, else the
    first); without one a gymnasium MujocoEnv's ``init_qpos``; else ``qpos0``."""
    import gymnasium as gym
    import mujoco

    from sim2real.home import _servo_mask
    from sim2real.mjcf_env import MjcfEnv, home_key
    from sim2real.physics import find_physics

    handle = find_physics(env)
    space = env.action_space
    if handle is None or not isinstance(space, gym.spaces.Box):
        return None
    model = handle.model
    servo = _servo_mask(model)
    if not servo.any() or space.shape != (model.nu,):
        return None
    base = getattr(env, "unwrapped", env)
    if not isinstance(base, MjcfEnv) and not _actions_are_controls(model, space):
        return None
    data = mujoco.MjData(model)
    start = getattr(base, "init_qpos", None)
    if (key := home_key(model)) is not None:
        mujoco.mj_resetDataKeyframe(model, data, key)
    elif isinstance(start, np.ndarray) and start.shape == (model.nq,):
        data.qpos[:] = start
    mujoco.mj_forward(model, data)
    low, high = space.low, space.high
    hold = np.where(servo, np.clip(data.actuator_length, low, high), 0.0).astype(space.dtype)
    return lambda obs: hold


def _actions_are_controls(model: Any, space: Any) -> bool:
    """Whether an action space is the actuators' control range (as gymnasium's MujocoEnv and a dm_env built on
    ``ctrlrange`` declare it): then an action entry is that actuator's command."""
    limited = np.asarray(model.actuator_ctrllimited, dtype=bool)
    if not limited.any():
        return False
    ranges = np.asarray(model.actuator_ctrlrange, dtype=np.float64)
    low, high = np.asarray(space.low, dtype=np.float64), np.asarray(space.high, dtype=np.float64)
    return bool(
        np.allclose(low[limited], ranges[limited, 0], rtol=1e-6, atol=1e-6)
        and np.allclose(high[limited], ranges[limited, 1], rtol=1e-6, atol=1e-6)
    )


def _run_episode(env: Any, policy: Policy, seed: int) -> _Episode:
    obs, info = env.reset(seed=seed)
    params = dict(info.get("sim2real", {}).get("params", {}))
    total, length, done = 0.0, 0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        total += float(reward)
        length += 1
        done = bool(terminated or truncated)
    success = bool(info["is_success"]) if "is_success" in info else None
    diverged = bool(info.get("sim2real", {}).get("diverged", False) or info.get("diverged", False))
    return _Episode(total, length, success, diverged, params)


def _load_demo_effects(config: str | None, *, signals: bool = False) -> list[Any]:
    """The effects of ``--config`` (with ``signals``, its noise and latency models too: a fit's ``--export``
    holds both, and a demo that dropped them would show a randomised sim without the latency it calls for)."""
    if config is None:
        return default_effects()
    try:
        # A Path makes the loader read the file whatever its suffix (a str could be taken for YAML text).
        loaded = sim2real.load_config(Path(config)) if signals else sim2real.load_effects(Path(config))
        return list(loaded)
    except (OSError, ValueError) as err:
        raise UsageError(f"--config: {err}") from err


def _make_envs(task: str, effects: Sequence[Any], seed: int) -> tuple[Any, Any]:
    try:
        nominal = sim2real.make(task)
    except ValueError as err:
        raise UsageError(str(err)) from err
    try:
        randomised = sim2real.wrap(sim2real.make(task), *effects, seed=seed)
    except (TypeError, ValueError) as err:
        nominal.close()
        raise UsageError(f"the effects do not fit task {task!r}: {err}") from err
    return nominal, randomised


def _summary_row(name: str, episodes: list[_Episode]) -> str:
    returns = np.array([e.ret for e in episodes])
    successes = [e.success for e in episodes if e.success is not None]
    success = f"{100.0 * np.mean(successes):6.1f}%" if successes else f"{'n/a':>7}"
    length = np.mean([e.length for e in episodes])
    diverged = sum(e.diverged for e in episodes)
    return (
        f"{name:<12}{returns.mean():>12.2f}{returns.std():>10.2f}{success:>10}{length:>10.1f}"
        f"{diverged:>7d}/{len(episodes)}"
    )


def _print_params(episodes: list[_Episode], nominal: dict[str, float], seed: int, out: TextIO) -> None:
    shown = episodes[:3]
    addresses = sorted({a for e in shown for a in e.params})
    if not addresses:
        print("(the effects sampled no parameters)", file=out)
        return
    width = max(len(a) for a in addresses)
    heads = f"{'nominal':>14}" + "".join(f"{f'ep {i} (seed {seed + i})':>18}" for i in range(len(shown)))
    print(f"{'parameter':<{width}}{heads}", file=out)

    def cell(values: dict[str, float], address: str, size: int) -> str:
        return f"{values[address]:>{size}.6g}" if address in values else f"{'-':>{size}}"

    for address in addresses:
        cells = cell(nominal, address, 14) + "".join(cell(e.params, address, 18) for e in shown)
        print(f"{address:<{width}}{cells}", file=out)


def cmd_demo(args: argparse.Namespace, out: TextIO) -> int:
    from tqdm import tqdm

    source = source_of(args)
    effects = _load_demo_effects(args.config, signals=True)
    nominal, randomised = _make_envs(source.id, effects, args.seed)
    policy: Policy
    if source.id == ARM_REACH:
        policy_name, policy = ARM_REACH_POLICY, _arm_reach_policy
    elif (hold := _hold_policy(nominal)) is not None:
        policy_name = (
            f"hold the home pose (position servos at their home set points; no scripted controller for {source.label})"
        )
        policy = hold
    else:
        policy_name = f"zero action (no scripted controller for {source.label}; only {ARM_REACH} has one)"
        policy = _zero_policy(nominal)

    # Read before close(): the wrapper knows the nominal value of every address it perturbs.
    randomizer = getattr(randomised, "randomizer", None)
    nominal_params = randomizer.nominal_params() if randomizer is not None else {}
    n = args.episodes
    results: dict[str, list[_Episode]] = {}
    show_bar = not args.quiet and sys.stderr.isatty()
    try:
        with tqdm(total=2 * n, desc="demo", unit="ep", file=sys.stderr, disable=not show_bar) as bar:
            for name, env in (("nominal", nominal), ("randomised", randomised)):
                bar.set_postfix_str(name)
                episodes = []
                for i in range(n):
                    episodes.append(_run_episode(env, policy, args.seed + i))
                    bar.update(1)
                results[name] = episodes
    finally:
        nominal.close()
        randomised.close()

    print(
        f"sim2real demo: {source.label}, {n} episode(s) per condition, reset seeds {args.seed}..{args.seed + n - 1}",
        file=out,
    )
    print(f"policy: {policy_name}", file=out)
    origin = args.config if args.config is not None else "defaults"
    print(
        f"randomised condition: sim2real.wrap(make({source.id!r}), *effects, seed={args.seed}), effects from {origin}:",
        file=out,
    )
    for effect in effects:
        print(f"  {effect!r}", file=out)
    print(file=out)
    print(f"{'condition':<12}{'mean return':>12}{'std':>10}{'success':>10}{'mean len':>10}{'diverged':>10}", file=out)
    for name, episodes in results.items():
        print(_summary_row(name, episodes), file=out)
    gap = np.mean([e.ret for e in results["randomised"]]) - np.mean([e.ret for e in results["nominal"]])
    print(f"return gap (randomised - nominal): {gap:+.2f}", file=out)
    if results["nominal"][0].success is None:
        print("(this task reports no success flag; compare returns)", file=out)
    print(file=out)
    print(f"sampled parameters of the randomised condition, first {min(3, n)} episode(s):", file=out)
    _print_params(results["randomised"], nominal_params, args.seed, out)
    return 0


# ---------------------------------------------------------------------------------- visualize


def cmd_visualize(args: argparse.Namespace, out: TextIO) -> int:
    check_outputs({"--out": args.out}, inputs={**source_inputs(args), "--config": args.config})
    effects = _load_demo_effects(args.config) if args.config is not None else []
    camera: int | str | None = args.camera
    if isinstance(camera, str) and camera.lstrip("-").isdigit():
        camera = int(camera)
    if args.task_positional is None and args.task is None and args.model is None and args.env is None:
        raise UsageError("give a task id (positional or --task), --model ROBOT.xml or --env MODULE:FACTORY.")
    source = source_of(args, task=args.task_positional)
    try:
        sheet = writing(
            args.out,
            lambda: sim2real.contact_sheet(
                source.id,
                effects,
                n=args.n,
                seed=args.seed,
                size=(args.size, args.size),
                camera=camera,
                out=args.out,
                title=f"{source.label}: {len(effects)} effect(s), seed {args.seed}",
            ),
        )
    except (TypeError, ValueError, FileNotFoundError) as err:
        raise UsageError(str(err)) from err
    h, w = sheet.image.shape[:2]
    print(f"wrote {sheet.path} ({args.n} frames of {source.label}, {len(effects)} effect(s), {w}x{h} px)", file=out)
    return 0
