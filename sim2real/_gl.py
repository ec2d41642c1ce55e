"""Headless OpenGL selection: must run before mujoco or dm_control is imported."""

from __future__ import annotations

import ctypes.util
import os


def select_backend() -> str | None:
    """Sets ``MUJOCO_GL`` to ``egl`` (else ``osmesa``) when unset and the library is installed.

    Returns the backend in effect (None when nothing headless was found: rendering then raises
    an error naming the Debian packages to install, see issue #4).
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
