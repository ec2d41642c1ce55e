"""Visual effects: colours, procedural textures, lights and cameras (:mod:`randomizers.visual.textures`, about to be
split by role)."""

from __future__ import annotations

from randomizers.visual.textures import (
    PATTERNS,
    VISUAL_EFFECTS,
    CameraFovy,
    CameraPose,
    GeomColor,
    Light,
    MaterialColor,
    Product,
    Texture,
    TextureUploader,
    add_texture_uploader,
    hsv_to_rgb,
    render_texture,
    renderer_uploader,
    rgb_to_hsv,
    texture_uploaders,
)
from randomizers.visual.textures import _TextureGeometry as _TextureGeometry  # tests reach it

__all__ = [
    "PATTERNS",
    "VISUAL_EFFECTS",
    "CameraFovy",
    "CameraPose",
    "GeomColor",
    "Light",
    "MaterialColor",
    "Product",
    "Texture",
    "TextureUploader",
    "add_texture_uploader",
    "hsv_to_rgb",
    "render_texture",
    "renderer_uploader",
    "rgb_to_hsv",
    "texture_uploaders",
]
