"""Texture-driven Lamina layers in Blender: find the Image Textures linked into the Lamina node's layer inputs,
read their pixels as Cycles sees them, and wire baked multiple-scattering maps into its ``MS`` inputs.

Reading (``read_source``): ``image_values.read_output``, the values as Cycles feeds them to the input.

Wiring (``wire``): one Image Texture node per map (``bake.textures.map_layout``), tagged ``node["lamina_bake"]``,
loaded as Non-Color with channel-packed alpha so RGB and A stay raw, sharing the source textures' Vector input
(their default UV map when it is unlinked) and interpolation; the Color output feeds a colour/vector ``MS``
input, Alpha a float one, and a Separate Color node (also tagged) floats stored in R, G or B. Re-wiring
replaces only tagged nodes; everything is created before anything is removed or linked.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ..bake import textures
from ..bake.textures import BakeError
from ..models import spongecake as model
from . import MAPPINGS, image_values
from . import material as lamina_material

TAG = lamina_material.BAKE_TAG  # the rebuild (material._replace) recognises these nodes too
KINDS = {p.name: p.kind for p in model.LAYER}


@dataclass(frozen=True)
class Source:
    """An Image Texture output linked into a texturable layer input of the Lamina node."""

    key: tuple  # (layer index, parameter name): a bake.textures input key
    socket: str  # the shader input, e.g. "L1 Albedo"
    node: object  # the ShaderNodeTexImage
    output: str  # "Color" or "Alpha"

    @property
    def label(self) -> str:
        image = self.node.image
        return f"image {image.name!r} ({self.socket})" if image else f"node {self.node.name!r} ({self.socket})"


def _input(node, name: str):
    return node.inputs[lamina_material.socket_key(node, name)]


def sources(mat) -> list[Source]:
    """The Image Textures driving the layer inputs of a Lamina material's node; BakeError for a layer input
    driven by anything a bake cannot follow (another node type, an input that is not texturable)."""
    model_id, p = lamina_material.current_params(mat)
    node = lamina_material.shader_node(mat)
    allowed = textures.texturable_inputs(p)
    found = []
    for s in MAPPINGS[model_id].sockets(p):
        if s.baked or s.layer is None:  # substrate inputs do not enter the multiple-scattering prediction
            continue
        output = image_values.linked_from(_input(node, s.name))
        if output is None:
            continue
        key = (s.layer, s.param.name)
        if key not in allowed:
            raise BakeError(f"{mat.name}: {s.name} is linked, but with multiple scattering only "
                            f"{', '.join(allowed.values())} can be driven by textures")
        if output.node.bl_idname != "ShaderNodeTexImage":
            raise BakeError(f"{mat.name}: {s.name} is driven by a {output.node.bl_label} node; Lamina bakes only "
                            f"Image Texture nodes linked directly (bake that node into an image first)")
        found.append(Source(key, s.name, output.node, output.name))
    return found


def read_source(source: Source) -> np.ndarray:
    """The values an input receives from its texture (``image_values.read_output``): row 0 = top."""
    return image_values.read_output(source.node, source.output, KINDS[source.key[1]], source.label)


def read_inputs(found: list[Source], warnings: list[str]) -> dict:
    """{input key: values} at one size: the largest width and the largest height among the textures; a smaller
    texture is resampled (bilinear, or nearest for Closest interpolation) with a warning."""
    values = {s.key: read_source(s) for s in found}
    size = tuple(max(v.shape[i] for v in values.values()) for i in (0, 1))
    for s in found:
        if values[s.key].shape[:2] != size:
            h, w = values[s.key].shape[:2]
            warnings.append(f"{s.label}: resampled from {w} x {h} to {size[1]} x {size[0]} (the largest size)")
            values[s.key] = textures.resample(values[s.key], size, nearest=s.node.interpolation == "Closest")
    return values


def vector_source(found: list[Source]):
    """The output socket feeding the textures' Vector inputs (None: their default UV map); BakeError when they
    differ, since one baked texel must correspond to one source texel."""
    feeds = {s.node.name: image_values.linked_from(s.node.inputs["Vector"]) for s in found}
    distinct = {(f.node.name, f.identifier) if f is not None else None for f in feeds.values()}
    if len(distinct) > 1:
        raise BakeError(f"the textures {', '.join(sorted(feeds))} use different Vector inputs; Lamina bakes "
                        f"textures that share one mapping (link the same UV/Mapping node to all of them)")
    return next(iter(feeds.values()))


def baked_nodes(mat) -> list:
    return [n for n in mat.node_tree.nodes if n.get(TAG)]


def unwire(mat) -> None:
    """Remove Lamina's baked texture nodes (and images no one else uses); the user's nodes stay."""
    lamina_material.remove_nodes(mat, baked_nodes(mat))


def _load_map(path: str):
    image = bpy.data.images.load(path, check_existing=True)
    image.colorspace_settings.name = "Non-Color"
    image.alpha_mode = "CHANNEL_PACKED"
    if bpy.data.filepath:
        try:
            image.filepath = bpy.path.relpath(path)  # moves with the project folder
        except ValueError:  # another drive (Windows): keep the absolute path
            pass
    return image


def wire(mat, layout: dict, paths: dict, found: list[Source]) -> None:
    """Feed the Lamina node's ``MS`` inputs from the baked maps, replacing earlier baked nodes."""
    tree = mat.node_tree
    node = lamina_material.shader_node(mat)
    if node is None:
        raise BakeError(f"{mat.name} has no Lamina node any more; nothing was wired")
    vector = vector_source(found)
    template = found[0].node
    images = {name: _load_map(paths[name]) for name in layout}
    old = baked_nodes(mat)
    created, links = [], []

    def new(kind, location):
        n = tree.nodes.new(kind)
        n[TAG] = True
        n.location = location
        created.append(n)
        return n

    try:
        x, y = node.location.x - 560, node.location.y
        for i, (name, channels) in enumerate(layout.items()):
            tex = new("ShaderNodeTexImage", (x, y - 300 * i))
            tex.image = images[name]
            tex.label = f"Lamina bake: {name}"
            tex.interpolation, tex.projection, tex.extension = (template.interpolation, template.projection,
                                                                template.extension)
            if vector is not None:
                tree.links.new(vector, tex.inputs["Vector"])
            separate = None
            for c, entry in enumerate(channels):
                if entry is None or entry[1] > 0:  # unused, or the G/B of a colour already linked
                    continue
                target = _input(node, entry[0])
                if c == 3:
                    links.append((tex.outputs["Alpha"], target))
                elif channels[c:c + 3] == tuple((entry[0], k) for k in range(3)):  # a colour or vector input
                    links.append((tex.outputs["Color"], target))
                else:  # a float stored in R, G or B
                    if separate is None:
                        separate = new("ShaderNodeSeparateColor", (x + 300, y - 300 * i))
                        tree.links.new(tex.outputs["Color"], separate.inputs[0])
                    links.append((separate.outputs[c], target))
    except BaseException:
        for n in created:
            tree.nodes.remove(n)
        raise
    lamina_material.remove_nodes(mat, old, keep={image.name for image in images.values()})
    for output, target in links:
        tree.links.new(output, target)
