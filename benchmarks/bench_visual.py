"""Cost of visual randomisation at reset against the cost of one rendered frame (issue #4).

Measures in one run, side by side, on each task's compiled model with a live 84x84
``mujoco.Renderer`` (the frame a pixel policy sees):

1. ``render``: one frame, ``update_scene(data, camera); render()``.
2. ``colour+light+camera``: one resample of a ``PhysicsRandomizer`` holding GeomColor (HSV jitter,
   every geom), MaterialColor, Light (diffuse and direction), CameraPose and CameraFovy (all
   cameras): ``begin_episode(); apply()``. Goal: <= 0.10 of a render.
3. ``texture``: one resample of ``Texture`` over every texture of the model (pattern drawn from
   flat/checker/gradient/noise), including ``mjr_uploadTexture`` to the live renderer through
   the registered uploader. Goal: <= 2 renders. Per-pattern costs and the upload alone are shown for context.

The arms run one after the other inside every repeat, in an order that rotates each repeat, so
machine noise hits them alike; figures are medians over repeats of the mean time per call, ratios
the medians of the per-repeat ratios.

Usage:
    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_visual.py            # full run
    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_visual.py --quick    # smoke test

The last line printed is ``RESULT ...`` with both ratios against their goals.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable

import mujoco
import numpy as np

import sim2real as s2r
from randomizers import PhysicsRandomizer, add_texture_uploader
from randomizers.visual import PATTERNS, renderer_uploader

CCL_GOAL = 0.10
TEXTURE_GOAL = 2.0
DEFAULT_TASKS = ("sim2real/arm-reach", "dmc/reacher-easy")


def ccl_effects(model: mujoco.MjModel) -> list[s2r.Effect]:  # type: ignore[name-defined]
    """Colour + light + camera effects touching every geom, material, light and camera of ``model``."""
    u = s2r.Uniform
    effects: list[s2r.Effect] = [  # type: ignore[name-defined]
        s2r.GeomColor(add=(u(-0.05, 0.05), u(-0.2, 0.2), u(-0.2, 0.2)), space="hsv"),
        s2r.Light(scale=u(0.5, 1.5)),
        s2r.Light(add=u(-0.2, 0.2), attribute="dir"),
        s2r.CameraPose(add=u(-0.05, 0.05), roll=u(-0.05, 0.05)),
        s2r.CameraFovy(scale=u(0.9, 1.1)),
    ]
    if model.nmat:
        effects.insert(1, s2r.MaterialColor(scale=u(0.7, 1.3)))
    return effects


def time_per_call(fn: Callable[[], object], calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - start) / calls


def bench_task(task: str, repeats: int, renders: int, resamples: int, textures: int) -> dict[str, float]:
    env = s2r.make(task)
    handle = s2r.find_physics(env)
    model, data = handle.model, handle.data
    env.reset(seed=0)
    mujoco.mj_forward(model, data)
    renderer = mujoco.Renderer(model, 84, 84)
    camera = 0 if model.ncam else -1

    def render() -> None:
        renderer.update_scene(data, camera=camera)
        renderer.render()

    ccl = PhysicsRandomizer(ccl_effects(model), seed=0)
    ccl.bind(model, data)
    tex = PhysicsRandomizer([s2r.Texture(pattern=PATTERNS)], seed=0)
    tex.bind(model, data)
    per_pattern = {p: PhysicsRandomizer([s2r.Texture(pattern=p)], seed=0) for p in PATTERNS}
    flat_ids = [t for t in range(model.ntex) if model.tex_type[t] == mujoco.mjtTexture.mjTEXTURE_2D]
    flat_names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_TEXTURE, t) for t in flat_ids]
    per_pattern["2d"] = PhysicsRandomizer([s2r.Texture(textures=flat_names, pattern=PATTERNS)], seed=0)
    for r in per_pattern.values():
        r.bind(model, data)
    remove = add_texture_uploader(renderer_uploader(renderer))
    texids = list(range(model.ntex))

    def resample(r: PhysicsRandomizer) -> Callable[[], None]:
        def run() -> None:
            r.begin_episode()
            r.apply()

        return run

    def upload() -> None:
        renderer._gl_context.make_current()  # type: ignore[attr-defined]
        for t in texids:
            mujoco.mjr_uploadTexture(model, renderer._mjr_context, t)  # type: ignore[attr-defined]

    arms: dict[str, tuple[Callable[[], None], int]] = {
        "render": (render, renders),
        "ccl": (resample(ccl), resamples),
        "texture": (resample(tex), textures),
        "upload": (upload, textures),
        **{f"texture:{p}": (resample(r), textures) for p, r in per_pattern.items()},
    }
    for fn, _ in arms.values():  # warm up: contexts, caches, lazy imports
        fn()
    results: dict[str, list[float]] = {k: [] for k in arms}
    names = list(arms)
    for rep in range(repeats):
        order = names[rep % len(names) :] + names[: rep % len(names)]
        for name in order:
            fn, calls = arms[name]
            results[name].append(time_per_call(fn, calls))
    remove()
    ccl.restore_nominal()
    tex.restore_nominal()
    renderer.close()
    env.close()
    out = {k: statistics.median(v) for k, v in results.items()}
    out["ccl_ratio"] = statistics.median(c / r for c, r in zip(results["ccl"], results["render"], strict=True))
    out["texture_ratio"] = statistics.median(t / r for t, r in zip(results["texture"], results["render"], strict=True))
    out["texels"] = float(sum(int(model.tex_width[t] * model.tex_height[t]) for t in texids))
    out["ntex"] = float(model.ntex)
    out["ccl_params"] = float(len(ccl.current_params))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(DEFAULT_TASKS))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--renders", type=int, default=40, help="renders per repeat")
    parser.add_argument("--resamples", type=int, default=400, help="colour+light+camera resamples per repeat")
    parser.add_argument("--textures", type=int, default=10, help="texture resamples per repeat and pattern")
    parser.add_argument("--quick", action="store_true", help="smoke test: tiny counts")
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.renders, args.resamples, args.textures = 2, 5, 20, 2

    print(
        f"bench_visual: MUJOCO_GL={os.environ.get('MUJOCO_GL')} python {platform.python_version()} "
        f"mujoco {mujoco.__version__} numpy {np.__version__} nproc {os.cpu_count()}"
    )
    print(
        f"repeats={args.repeats} renders={args.renders} resamples={args.resamples} textures={args.textures}, "
        "frame 84x84, medians over repeats"
    )
    summary = []
    worst_ccl, worst_tex = 0.0, 0.0
    for task in args.tasks:
        r = bench_task(task, args.repeats, args.renders, args.resamples, args.textures)
        ms = {k: v * 1e3 for k, v in r.items() if isinstance(v, float) and not k.endswith(("ratio", "texels", "ntex"))}
        print(
            f"\n{task}: {int(r['ntex'])} textures, {int(r['texels'])} texels; {int(r['ccl_params'])} colour/light/camera values"
        )
        print(f"  render 84x84                  {ms['render']:9.3f} ms")
        print(
            f"  colour+light+camera resample  {r['ccl'] * 1e6:9.1f} us   ratio to render {r['ccl_ratio']:.4f} (goal <= {CCL_GOAL})"
        )
        print(
            f"  texture resample (+upload)    {ms['texture']:9.3f} ms   ratio to render {r['texture_ratio']:.3f} (goal <= {TEXTURE_GOAL})"
        )
        for p in PATTERNS:
            print(f"    pattern {p:<9}             {ms[f'texture:{p}']:9.3f} ms")
        print(f"    2D textures only (no skybox) {ms['texture:2d']:9.3f} ms")
        print(f"    upload alone                {ms['upload']:9.3f} ms")
        worst_ccl, worst_tex = max(worst_ccl, r["ccl_ratio"]), max(worst_tex, r["texture_ratio"])
        summary.append(f"{task}:ccl={r['ccl_ratio']:.4f},texture={r['texture_ratio']:.3f},render_ms={ms['render']:.2f}")
    ccl_ok = "met" if worst_ccl <= CCL_GOAL else "missed"
    tex_ok = "met" if worst_tex <= TEXTURE_GOAL else "missed"
    print(
        f"\nRESULT color_light_camera_over_render={worst_ccl:.4f} (goal <= {CCL_GOAL}: {ccl_ok}) "
        f"texture_over_render={worst_tex:.3f} (goal <= {TEXTURE_GOAL}: {tex_ok}) [{' '.join(summary)}]"
    )


if __name__ == "__main__":
    main()
