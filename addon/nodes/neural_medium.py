"""The neural medium's Cycles material (bpy): Cycles' own homogeneous volume for single scattering, and a surface
that adds the baked light of orders >= 2 (``bake/neural_medium.py``) from per-point attributes of the mesh.

Volume: Volume Scatter (Color = sigma_s / its largest channel, Density = that largest channel per scene unit,
Anisotropy = g) plus Volume Absorption (Cycles absorbs Density x (1 - Color): Density = the largest sigma_a per scene
unit); checked against the numpy truth in tests/blender/test_neural_medium_cycles.py.

Surface: the node group "Lamina Medium Bake": max(c0 + cx wx + cy wy + cz wz, 0) with w the Geometry node's
Incoming (towards the viewer, world space) and c the mesh's point attributes ``lamina_medium_c0`` .. ``_cz``
(absent before a bake: 0), as Emission on front faces only (a ray leaving the object through its back face already
carries the light the bake stores for its entry point), added to a white Transparent BSDF (the boundary stays
index-matched: rays cross it unbent). Everything is plain Cycles nodes and mesh data: the file renders the same
without Lamina. The material's ``lamina_medium`` property stores the dict it was made from.
"""
from __future__ import annotations

import json
import math

import bpy

from ..bake.neural_medium import COEFFICIENTS
from ..models import neural_medium as model
from .material import empty_material
from .subsurface_np import subsurface_settings

PROPERTY = "lamina_medium"
GROUP = "Lamina Medium Bake"
ATTRIBUTES = tuple(f"lamina_medium_{c}" for c in COEFFICIENTS)
SCATTER, ABSORB = "Lamina Scatter", "Lamina Absorption"


def is_medium(mat) -> bool:
    return mat is not None and PROPERTY in mat.keys()


def volume_values(p) -> dict:
    """Node name -> {input: value} of the volume that renders ``p``."""
    sigma_s, sigma_a = p.per_scene_unit()
    top_s, top_a = max(max(sigma_s), 1e-12), max(max(sigma_a), 1e-12)
    return {SCATTER: {"Color": (*[s / top_s for s in sigma_s], 1.0), "Density": top_s, "Anisotropy": p.g},
            ABSORB: {"Color": (*[1.0 - a / top_a for a in sigma_a], 1.0), "Density": top_a}}


def current_params(mat):
    """The medium as the material renders it now: its volume nodes read back (an edit there is a change of the
    medium, and makes a bake stale), the scale from the stored dict. Raises ValueError when a node is missing."""
    stored = json.loads(mat[PROPERTY])
    nodes = mat.node_tree.nodes
    missing = [n for n in (SCATTER, ABSORB) if n not in nodes]
    if missing:
        raise ValueError(f"the node(s) {', '.join(missing)} were removed")
    scale = stored["scale"]
    scatter, absorb = nodes[SCATTER].inputs, nodes[ABSORB].inputs
    sigma_s = [c * scatter["Density"].default_value * scale for c in scatter["Color"].default_value[:3]]
    sigma_a = [(1.0 - c) * absorb["Density"].default_value * scale for c in absorb["Color"].default_value[:3]]
    return model.params_from_dict({"sigma_s": sigma_s, "sigma_a": sigma_a,
                                   "g": scatter["Anisotropy"].default_value, "scale": scale})


def volume_of(mat) -> dict | None:
    """The medium dict (scale 1) of a material whose Volume output is a homogeneous Principled Volume (no emission,
    no linked input) or a Volume Scatter plus a Volume Absorption (through an Add Shader, unlinked inputs); None for
    anything else. Principled Volume, as Cycles computes it (node_principled_volume): sigma_s = Color x Density,
    sigma_a = max(1 - Color, 0) x max(1 - sqrt(Absorption Color), 0) x Density."""
    tree = getattr(mat, "node_tree", None)
    out = next((n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial" and n.is_active_output), None) \
        if tree is not None else None
    if out is None or not out.inputs["Volume"].is_linked:
        return None
    node = out.inputs["Volume"].links[0].from_node
    if node.bl_idname == "ShaderNodeVolumePrincipled":
        return _principled_volume(node)
    if node.bl_idname == "ShaderNodeAddShader" and all(i.is_linked for i in node.inputs[:2]):
        parts = {i.links[0].from_node.bl_idname: i.links[0].from_node for i in node.inputs[:2]}
        scatter, absorb = parts.get("ShaderNodeVolumeScatter"), parts.get("ShaderNodeVolumeAbsorption")
        if scatter is None or absorb is None or _any_linked(scatter) or _any_linked(absorb):
            return None
        if getattr(scatter, "phase", "HENYEY_GREENSTEIN") != "HENYEY_GREENSTEIN":  # 5.0 has other phase functions
            return None
        density_s, density_a = scatter.inputs["Density"].default_value, absorb.inputs["Density"].default_value
        return {"sigma_s": [c * density_s for c in scatter.inputs["Color"].default_value[:3]],
                "sigma_a": [max(1.0 - c, 0.0) * density_a for c in absorb.inputs["Color"].default_value[:3]],
                "g": scatter.inputs["Anisotropy"].default_value, "scale": 1.0}
    return None


def _any_linked(node) -> bool:
    return any(i.is_linked for i in node.inputs)


def _principled_volume(node) -> dict | None:
    inputs = node.inputs
    if _any_linked(node) or inputs["Emission Strength"].default_value > 0.0 \
            or inputs["Blackbody Intensity"].default_value > 0.0:
        return None
    density = max(inputs["Density"].default_value, 0.0)
    color = [max(c, 0.0) for c in inputs["Color"].default_value[:3]]
    absorption = [max(1.0 - math.sqrt(max(c, 0.0)), 0.0) for c in inputs["Absorption Color"].default_value[:3]]
    return {"sigma_s": [c * density for c in color],
            "sigma_a": [max(1.0 - c, 0.0) * a * density for c, a in zip(color, absorption)],
            "g": inputs["Anisotropy"].default_value, "scale": 1.0}


def new_material(p, name: str | None = None) -> bpy.types.Material:
    """A new material (never an existing one changed) rendering the medium ``p`` and its bake."""
    mat, tree, out = empty_material(name or model.LABEL)
    mat[PROPERTY] = json.dumps(p.to_dict())
    values = volume_values(p)
    scatter = tree.nodes.new("ShaderNodeVolumeScatter")
    absorb = tree.nodes.new("ShaderNodeVolumeAbsorption")
    for node, name_ in ((scatter, SCATTER), (absorb, ABSORB)):
        node.name = node.label = name_
        for key, value in values[name_].items():
            node.inputs[key].default_value = value
    scatter.location, absorb.location = (-200, -150), (-200, -320)
    both = tree.nodes.new("ShaderNodeAddShader")
    both.location = (50, -200)
    tree.links.new(scatter.outputs[0], both.inputs[0])
    tree.links.new(absorb.outputs[0], both.inputs[1])
    tree.links.new(both.outputs[0], out.inputs["Volume"])
    baked = tree.nodes.new("ShaderNodeGroup")
    baked.node_tree = bake_group()
    baked.name = baked.label = GROUP
    baked.location = (50, 100)
    tree.links.new(baked.outputs[0], out.inputs["Surface"])
    mat.cycles.emission_sampling = "NONE"  # the baked glow is light leaving a volume, found by the rays that see it
    return mat


def bake_group() -> bpy.types.NodeTree:
    """The surface that adds the baked orders >= 2 (module docstring), created once per file."""
    group = bpy.data.node_groups.get(GROUP)
    if group is not None and group.get("lamina_version") == 1:
        return group
    group = bpy.data.node_groups.new(GROUP, "ShaderNodeTree")
    group["lamina_version"] = 1
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    nodes, links = group.nodes, group.links
    geometry = nodes.new("ShaderNodeNewGeometry")
    components = nodes.new("ShaderNodeSeparateXYZ")
    links.new(geometry.outputs["Incoming"], components.inputs[0])
    attributes = []
    for i, name in enumerate(ATTRIBUTES):
        a = nodes.new("ShaderNodeAttribute")
        a.attribute_type, a.attribute_name = "GEOMETRY", name
        a.location = (-600, -150 * i)
        attributes.append(a)
    total = attributes[0].outputs["Vector"]
    for axis, a in zip("XYZ", attributes[1:]):
        term = nodes.new("ShaderNodeVectorMath")
        term.operation = "MULTIPLY_ADD"
        links.new(a.outputs["Vector"], term.inputs[0])
        links.new(components.outputs[axis], term.inputs[1])
        links.new(total, term.inputs[2])
        total = term.outputs[0]
    positive = nodes.new("ShaderNodeVectorMath")
    positive.operation = "MAXIMUM"
    links.new(total, positive.inputs[0])
    positive.inputs[1].default_value = (0.0, 0.0, 0.0)
    front = nodes.new("ShaderNodeMath")
    front.operation = "SUBTRACT"
    front.inputs[0].default_value = 1.0
    links.new(geometry.outputs["Backfacing"], front.inputs[1])
    emission = nodes.new("ShaderNodeEmission")
    links.new(positive.outputs[0], emission.inputs["Color"])
    links.new(front.outputs[0], emission.inputs["Strength"])
    transparent = nodes.new("ShaderNodeBsdfTransparent")
    both = nodes.new("ShaderNodeAddShader")
    links.new(transparent.outputs[0], both.inputs[0])
    links.new(emission.outputs[0], both.inputs[1])
    out = nodes.new("NodeGroupOutput")
    links.new(both.outputs[0], out.inputs[0])
    return group


def store(mesh, coefficients) -> None:
    """Write the bake's (N, 4, 3) coefficients as the mesh's point attributes, replacing earlier ones."""
    for i, name in enumerate(ATTRIBUTES):
        attribute = mesh.attributes.get(name)
        if attribute is not None and (attribute.domain != "POINT" or attribute.data_type != "FLOAT_VECTOR"):
            mesh.attributes.remove(attribute)
            attribute = None
        if attribute is None:
            attribute = mesh.attributes.new(name, "FLOAT_VECTOR", "POINT")
        attribute.data.foreach_set("vector", coefficients[:, i, :].astype("float32").ravel())
    mesh.update()


def has_bake(mesh) -> bool:
    return all(name in mesh.attributes for name in ATTRIBUTES)


def subsurface_material(p, name: str | None = None) -> bpy.types.Material:
    """A new material rendering the medium ``p`` with Cycles' random-walk subsurface scattering instead of a volume
    (a Principled BSDF, ``subsurface_np.subsurface_settings``): what an artist would reach for, compared beside the
    bake. Its ``notes`` (what the random walk cannot match) are stored as the material's ``lamina_notes``."""
    mat, tree, out = empty_material(name or f"{model.LABEL} subsurface")
    sigma_s, sigma_a = p.per_scene_unit()
    settings = subsurface_settings([s + a for s, a in zip(sigma_s, sigma_a)], p.albedo, p.g)
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.subsurface_method = settings["method"]
    for key, value in settings["inputs"].items():
        bsdf.inputs[key].default_value = value
    tree.links.new(bsdf.outputs[0], out.inputs["Surface"])
    mat["lamina_notes"] = json.dumps(settings["notes"])
    return mat
