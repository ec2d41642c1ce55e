"""Headless OpenGL selection: must run before mujoco or dm_control is imported."""

from __future__ import annotations

import ctypes.util
import os
from collections.abc import Callable
from typing import Any

#: Debian packages that provide each headless backend.
PACKAGES: dict[str, str] = {"egl": "libegl1 libegl-mesa0 libgl1-mesa-dri", "osmesa": "libosmesa6"}

_working: str | None = None


class RenderingUnavailable(RuntimeError):
    """No headless OpenGL backend works; the message names the Debian packages to install."""


def select_backend() -> str | None:
    """Sets ``MUJOCO_GL`` to ``egl`` (else ``osmesa``) when unset and the library is installed.

    Returns the backend in effect (None when nothing headless was found: rendering then raises
    :class:`RenderingUnavailable` naming the Debian packages to install).
    """
    current = os.environ.get("MUJOCO_GL")
    if current:
        return current
    for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(library):
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
    return None


def unavailable_message(backend: str | None, error: object) -> str:
    """The error text when rendering cannot start with ``backend`` (None: none was found).

    Example:
        >>> print(unavailable_message(None, "no library"))  # doctest: +NORMALIZE_WHITESPACE
        Headless rendering is unavailable: neither EGL nor OSMesa was found (no library). Install the
        Debian packages for EGL: `sudo apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri`, or for
        OSMesa: `sudo apt-get install -y libosmesa6`, then set MUJOCO_GL=egl (or osmesa) before
        importing sim2real.
    """
    where = "neither EGL nor OSMesa was found" if backend is None else f"MUJOCO_GL={backend!r} failed"
    return (
        f"Headless rendering is unavailable: {where} ({error}). Install the Debian packages for EGL: "
        f"`sudo apt-get install -y {PACKAGES['egl']}`, or for OSMesa: `sudo apt-get install -y "
        f"{PACKAGES['osmesa']}`, then set MUJOCO_GL=egl (or osmesa) before importing sim2real."
    )


def _probe() -> None:
    import mujoco

    context = mujoco.GLContext(8, 8)
    try:
        context.make_current()
    finally:
        context.free()


def require_rendering(probe: Callable[[], Any] | None = None) -> str:
    """The working headless backend, checked once by creating a tiny GL context.

    Args:
        probe: what creates the test context (tests pass a failing one); default MuJoCo's GLContext.

    Raises:
        RenderingUnavailable: no backend was found or it cannot create a context; the message
            names the Debian packages (``libegl1 libegl-mesa0 libgl1-mesa-dri`` / ``libosmesa6``).
    """
    global _working
    if _working is not None and probe is None:
        return _working
    backend = os.environ.get("MUJOCO_GL") or None
    if backend is None:
        raise RenderingUnavailable(unavailable_message(None, "MUJOCO_GL is unset and no libEGL/libOSMesa is installed"))
    try:
        (probe or _probe)()
    except Exception as err:  # any failure to get a context means the same fix
        raise RenderingUnavailable(unavailable_message(backend, f"{type(err).__name__}: {err}")) from err
    if probe is None:
        _working = backend
    return backend
