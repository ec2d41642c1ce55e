"""Visual effects: colours, procedural textures, lights and cameras, without recompiling the model.

They are :class:`randomizers.Effect` values like the physics effects, so
:class:`randomizers.PhysicsRandomizer` (and therefore ``sim2real.wrap``) drives them unchanged:
selection by name pattern, ``scale`` / ``add`` / ``set``, schedules, one keyed stream per effect,
every value reported by address (``geom_rgba[palm][0]``, ``light_diffuse[key][1]``,
``cam_fovy[overview]``, ``tex_rgb1[grid][2]``) and a bitwise ``restore_nominal()``.

Colour, light and camera edits are plain writes into ``MjModel`` arrays that the next render reads.
Texture edits rewrite ``model.tex_data`` and must then reach the GPU copy held by every live
``mujoco.MjrContext``: :class:`Texture` calls each function registered with
:func:`add_texture_uploader` (``sim2real`` registers the renderers it finds inside environments;
:func:`renderer_uploader` covers a bare ``mujoco.Renderer``). Contexts created later read the
rewritten data by themselves. Light positions and directions and camera poses reach
``MjData`` (``light_xpos``, ``cam_xpos``...) at the next ``mj_kinematics``/``mj_forward``/``mj_step``.

The package's modules, by role: :mod:`~randomizers.visual.arguments` (what every visual effect takes: name patterns,
one operation, :class:`Product`), :mod:`~randomizers.visual.colors` (:class:`GeomColor`, :class:`MaterialColor`, RGB
and HSV), :mod:`~randomizers.visual.lights` (:class:`Light`), :mod:`~randomizers.visual.cameras`
(:class:`CameraFovy`, :class:`CameraPose`) and :mod:`~randomizers.visual.textures` (:class:`Texture` and the texture
uploaders).

Example:
    >>> import mujoco, numpy as np
    >>> from randomizers import PhysicsRandomizer, Uniform
    >>> from randomizers.visual import GeomColor, Light
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><light name="top" pos="0 0 2"/>'
    ...     '<geom name="palm" size=".1" rgba=".8 .2 .2 1"/></worldbody></mujoco>')
    >>> r = PhysicsRandomizer([GeomColor(add=Uniform(-0.1, 0.1), geoms="palm"),
    ...                        Light(scale=Uniform(0.5, 1.5), attribute="diffuse", shared=True)], seed=0)
    >>> r.bind(model, mujoco.MjData(model))
    >>> r.begin_episode()
    >>> r.apply()
    >>> sorted(r.current_params)[:4]
    ['geom_rgba[palm][0]', 'geom_rgba[palm][1]', 'geom_rgba[palm][2]', 'light_diffuse[top][0]']
    >>> bool(model.geom_rgba[0, 0] != np.float32(0.8))
    True
    >>> r.restore_nominal()
    >>> model.geom_rgba[0].tolist() == np.array([.8, .2, .2, 1], np.float32).tolist()
    True
"""

from __future__ import annotations

from randomizers.effects import Effect
from randomizers.visual.arguments import Product
from randomizers.visual.cameras import CameraFovy, CameraPose
from randomizers.visual.colors import GeomColor, MaterialColor, hsv_to_rgb, rgb_to_hsv
from randomizers.visual.lights import Light
from randomizers.visual.textures import (
    PATTERNS,
    Texture,
    TextureUploader,
    add_texture_uploader,
    render_texture,
    renderer_uploader,
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

#: Every visual effect class (``randomizers.config`` registers them for YAML).
VISUAL_EFFECTS: tuple[type[Effect], ...] = (GeomColor, MaterialColor, Texture, Light, CameraPose, CameraFovy)
