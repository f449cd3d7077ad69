"""What an Image Texture feeds a shader input, as Cycles sees it (bpy; reads, never changes anything).

``Image.pixels`` rows start at the BOTTOM; they are flipped so that row 0 is the top, like ``bake.exr`` and
``bake.textures``. Float images hold scene-linear values in memory whatever their colour space (Blender converts
them on load) and Non-Color images raw data, so both are used as they are; 8-bit images hold the file's values, so an
sRGB one is linearised as Cycles does (the sRGB transfer function) and a linear one used as it is; other colour
spaces are refused. A Color output linked to a float input becomes its Rec.709 luminance, an Alpha output linked to a
colour or vector input a grey, as Cycles converts them (the scene-linear space is assumed to be Blender's default,
Rec.709).
"""
from __future__ import annotations

import bpy
import numpy as np

from ..bake import textures
from ..bake.textures import BakeError

LINEAR_SPACES = ("Linear Rec.709", "Working Space")  # 8-bit images in these hold linear values


def linked_from(socket):
    """The output socket feeding ``socket`` (through reroutes), or None when unlinked or the link is muted."""
    while socket.is_linked:
        link = socket.links[0]
        if link.is_muted:
            return None
        if link.from_node.bl_idname != "NodeReroute":
            return link.from_socket
        socket = link.from_node.inputs[0]
    return None


def read_output(node, output: str, kind: str, label: str) -> np.ndarray:
    """The values a ``kind`` input ("float", "color", "vector") receives from the Image Texture ``node``'s ``output``
    ("Color" or "Alpha"): H x W or H x W x 3, row 0 = top; BakeError naming ``label`` when it cannot be read."""
    image = node.image
    if image is None:
        raise BakeError(f"{label}: the Image Texture node has no image")
    if image.source not in ("FILE", "GENERATED"):
        raise BakeError(f"{label}: {image.source.lower()} images cannot be baked; use a single image")
    w, h = image.size
    if w == 0 or h == 0 or len(image.pixels) == 0:
        path = bpy.path.abspath(image.filepath) if image.filepath else "(no file path)"
        raise BakeError(f"{label}: the image has no pixels: the file {path} is missing or unreadable")
    c = image.channels
    px = np.empty(w * h * c, dtype=np.float32)
    image.pixels.foreach_get(px)
    px = px.reshape(h, w, c)[::-1]  # Blender's rows start at the bottom
    if output == "Alpha":
        value = px[:, :, 3] if c == 4 else np.ones((h, w), dtype=np.float32)
    else:
        value = _linear(image, px[:, :, :3] if c >= 3 else np.repeat(px[:, :, :1], 3, axis=2), label)
    if kind == "float":
        return textures.luminance(value) if value.ndim == 3 else value
    return value if value.ndim == 3 else np.repeat(value[:, :, None], 3, axis=2)


def _linear(image, rgb, label: str):
    space = image.colorspace_settings
    if image.is_float or space.is_data or space.name in LINEAR_SPACES:
        return rgb
    if space.name == "sRGB":
        return textures.srgb_to_linear(rgb)
    raise BakeError(f"{label}: colour space {space.name!r} cannot be baked; use sRGB, Linear Rec.709 or "
                    f"Non-Color")
