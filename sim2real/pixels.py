"""Image observations and live render contexts for texture uploads (contact sheets: :mod:`sim2real.sheets`).

* :class:`PixelObservation` renders the env's MuJoCo scene into ``uint8`` image observations
  (``sim2real.make(task, pixels=True, size=(84, 84), camera=...)`` uses it); it works on every task
  kind (dm-control suite and composer, gymnasium MuJoCo, ``sim2real/arm-reach``) and therefore
  with every effect, and under TorchRL through ``GymWrapper``.
* :func:`track_render_contexts` registers an env with :func:`randomizers.add_texture_uploader`, so a
  :class:`randomizers.Texture` resample reaches every live ``MjrContext`` inside it (gymnasium's
  ``MujocoRenderer`` viewers, dm-control physics contexts, ``mujoco.Renderer`` objects such as the
  arm-reach renderer and :class:`PixelObservation`'s own). ``sim2real.make`` tracks what it makes.

Example:
    >>> import sim2real as s2r
    >>> env = s2r.wrap(s2r.make("sim2real/arm-reach", pixels=True, size=(32, 32)),
    ...                s2r.GeomColor(set=s2r.Uniform(0, 1), geoms="*_link"), seed=0)
    >>> obs, info = env.reset(seed=0)
    >>> obs.shape, obs.dtype, "geom_rgba[upper_arm_link][0]" in info["sim2real"]["params"]
    ((32, 32, 3), dtype('uint8'), True)
    >>> env.close()
"""

from __future__ import annotations

import difflib
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from randomizers import add_texture_uploader
from sim2real._gl import require_rendering
from sim2real.physics import PhysicsHandle, find_physics

__all__ = ["PixelObservation", "check_size", "live_uploaders", "track_render_contexts"]

_CHILDREN = ("env", "_env", "dm_env", "base_env", "unwrapped", "physics", "mujoco_renderer", "_renderer", "renderer")


def check_size(size: object) -> tuple[int, int]:
    """``(height, width)`` of an image as two ints >= 1, or a ValueError naming ``size``."""
    ok = (
        isinstance(size, (tuple, list))
        and len(size) == 2
        and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0 for v in size)
    )
    if not ok:
        raise ValueError(f"`size` must be (height, width), two positive ints. Received {size!r}.")
    return int(size[0]), int(size[1])  # type: ignore[index]


def _camera_id(model: mujoco.MjModel, camera: int | str | None) -> int:
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) or f"#{i}" for i in range(model.ncam)]
    if camera is None:
        return 0 if model.ncam else -1
    if isinstance(camera, str):
        if camera in names:
            return names.index(camera)
        close = difflib.get_close_matches(camera, names, n=3, cutoff=0.5)
        hint = f" Close matches: {', '.join(repr(c) for c in close)}." if close else ""
        raise ValueError(
            f"`camera` must be a camera name of the model, an id in [-1, {model.ncam - 1}] (-1: free camera) or "
            f"None. Received {camera!r}.{hint} Known cameras: {', '.join(repr(n) for n in names) or 'none'}."
        )
    if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool) and -1 <= camera < model.ncam:
        return int(camera)
    raise ValueError(
        f"`camera` must be a camera name of the model, an id in [-1, {model.ncam - 1}] (-1: free camera) or None. "
        f"Received {camera!r}."
    )


# ----------------------------------------------------------------------------- render contexts

Upload = Callable[[mujoco.MjModel, Sequence[int]], None]


def _renderer_upload(renderer: mujoco.Renderer) -> Upload | None:
    context = getattr(renderer, "_mjr_context", None)
    gl = getattr(renderer, "_gl_context", None)
    if context is None or gl is None:
        return None

    def upload(model: mujoco.MjModel, ids: Sequence[int]) -> None:
        if renderer.model is model:
            gl.make_current()
            for texid in ids:
                mujoco.mjr_uploadTexture(model, context, int(texid))

    return upload


def _viewer_upload(viewer: Any) -> Upload | None:
    # gymnasium's OffScreenViewer: an MjrContext `con` made for `viewer.model` plus its GL context.
    context, gl = getattr(viewer, "con", None), getattr(viewer, "opengl_context", None)
    if not isinstance(context, mujoco.MjrContext) or gl is None:
        return None

    def upload(model: mujoco.MjModel, ids: Sequence[int]) -> None:
        if viewer.model is model:
            gl.make_current()
            for texid in ids:
                mujoco.mjr_uploadTexture(model, context, int(texid))

    return upload


def _dm_physics_upload(physics: Any) -> Upload | None:
    contexts = getattr(physics, "_contexts", None)  # created lazily by the first render
    if not contexts:
        return None

    def upload(model: mujoco.MjModel, ids: Sequence[int]) -> None:
        if physics._contexts is not contexts or physics.model.ptr is not model:
            return
        with contexts.gl.make_current() as ctx:
            for texid in ids:
                ctx.call(mujoco.mjr_uploadTexture, model, contexts.mujoco.ptr, int(texid))

    return upload


def live_uploaders(env: Any) -> list[Upload]:
    """One upload function per live render context found inside ``env`` (wrappers, adapters,
    TorchRL envs): ``mujoco.Renderer`` objects, gymnasium offscreen viewers, dm-control physics."""
    found: list[Upload] = []
    queue, seen = [env], set()
    while queue:
        obj = queue.pop(0)
        if obj is None or id(obj) in seen or isinstance(obj, (str, int, float, np.ndarray)):
            continue
        seen.add(id(obj))
        upload: Upload | None = None
        if isinstance(obj, mujoco.Renderer):
            upload = _renderer_upload(obj)
        elif type(obj).__name__ == "OffScreenViewer":
            upload = _viewer_upload(obj)
        elif hasattr(obj, "_contexts") and any(c.__module__.startswith("dm_control") for c in type(obj).__mro__):
            upload = _dm_physics_upload(obj)
        if upload is not None:
            found.append(upload)
            continue
        viewers = getattr(obj, "_viewers", None) if type(obj).__name__ == "MujocoRenderer" else None
        if isinstance(viewers, dict):
            queue.extend(viewers.values())
        for name in _CHILDREN:
            try:
                child = getattr(obj, name, None)
            except Exception:  # properties of half-closed envs may raise
                continue
            if child is not None and child is not obj:
                queue.append(child)
    return found


def track_render_contexts(env: Any) -> Callable[[], None]:
    """Makes texture resamples reach every live render context inside ``env``; returns an untrack
    function. The registration holds ``env`` weakly and ends by itself when ``env`` is collected.

    ``sim2real.make`` calls it on every env it creates; call it yourself for envs built elsewhere
    (e.g. a TorchRL ``DMControlEnv(..., from_pixels=True)``) before wrapping them with textures.
    """
    remove: Callable[[], None] = lambda: None  # noqa: E731 - replaced right below

    def gone(_: Any) -> None:
        remove()

    try:
        ref: Callable[[], Any] = weakref.ref(env, gone)
    except TypeError:  # objects without weakref support stay registered until untracked
        ref = lambda: env  # noqa: E731

    def upload(model: mujoco.MjModel, ids: Sequence[int]) -> None:
        target = ref()
        if target is None:
            remove()
            return
        handle = find_physics(target)
        if handle is None or handle.model is not model:
            return
        for push in live_uploaders(target):
            push(model, ids)

    remove = add_texture_uploader(upload)
    return remove


# ----------------------------------------------------------------------------- pixel observations


class PixelObservation(gym.ObservationWrapper):
    """Replaces (or extends) observations with an RGB image of the env's MuJoCo scene.

    The frame is rendered after every ``reset`` and ``step`` with a ``mujoco.Renderer`` of its own,
    from ``camera``, at ``size``; so it shows every visual effect applied to the model (colours,
    textures, lights, camera pose and field of view). Composer envs recompile their model on
    reset; the renderer follows the new model.

    Args:
        env: a gymnasium env with MuJoCo inside (any ``sim2real.make`` task).
        size: ``(height, width)`` in pixels.
        camera: camera name or id (-1: MuJoCo's free camera); default the model's first camera,
            or the free camera when it has none.
        pixels_only: observations are the image (``Box(0, 255, (h, w, 3), uint8)``); with False a
            ``Dict`` of ``"state"`` (the original observation) and ``"pixels"``.

    Raises:
        ValueError: bad ``size`` or unknown ``camera`` (known cameras listed).
        sim2real._gl.RenderingUnavailable: no headless OpenGL backend works (names the packages).

    Example:
        >>> import sim2real as s2r
        >>> env = PixelObservation(s2r.make("dmc/reacher-easy"), size=(24, 32), camera="fixed")
        >>> obs, _ = env.reset(seed=0)
        >>> obs.shape, env.observation_space.dtype
        ((24, 32, 3), dtype('uint8'))
        >>> PixelObservation(s2r.make("dmc/reacher-easy"), camera="fixd")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: `camera` must be a camera name ... Received 'fixd'. Close matches: 'fixed'. Known cameras: ...
    """

    def __init__(
        self,
        env: gym.Env,
        size: tuple[int, int] = (84, 84),
        camera: int | str | None = None,
        pixels_only: bool = True,
    ) -> None:
        super().__init__(env)
        self.size = check_size(size)
        if not isinstance(pixels_only, bool):
            raise TypeError(f"`pixels_only` must be a bool. Received {pixels_only!r}.")
        handle = find_physics(env)
        if handle is None:
            raise TypeError(
                f"`env` of type {type(env).__module__}.{type(env).__qualname__} has no MuJoCo model to render."
            )
        self._handle: PhysicsHandle = handle
        self.camera = camera
        self._camera_id = _camera_id(handle.model, camera)
        self.pixels_only = pixels_only
        h, w = self.size
        image = spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8)
        self.observation_space = (
            image if pixels_only else spaces.Dict({"state": env.observation_space, "pixels": image})
        )
        self._renderer: mujoco.Renderer | None = None
        self._untrack = track_render_contexts(self)

    def _current(self) -> PhysicsHandle:
        if self._handle.recompiles:  # composer: a new model every episode
            handle = find_physics(self.env)
            if handle is not None:
                self._handle = handle
        return self._handle

    def render_frame(self) -> np.ndarray:
        """The current scene as a fresh ``(height, width, 3)`` uint8 array."""
        handle = self._current()
        model = handle.model
        if self._renderer is None or self._renderer.model is not model:
            require_rendering()
            if self._renderer is not None:
                self._renderer.close()
            h, w = self.size
            # The offscreen buffer bounds the frame size; grow it instead of refusing.
            glob = model.vis.global_
            glob.offwidth, glob.offheight = max(glob.offwidth, w), max(glob.offheight, h)
            self._renderer = mujoco.Renderer(model, height=h, width=w)
        self._renderer.update_scene(handle.data, camera=self._camera_id)
        return self._renderer.render()

    def observation(self, observation: Any) -> Any:
        frame = self.render_frame()
        if self.pixels_only:
            return frame
        return {"state": observation, "pixels": frame}

    def close(self) -> None:
        self._untrack()
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()
