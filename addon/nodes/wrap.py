"""Add a micrograin porous layer (dust, rust, dirt, spray paint) over any existing material.

``add_porous_layer`` never edits the material it is given: it copies it and, in the copy, puts a micrograin
Lamina node between the shader that fed the active Material Output's Surface and that output (the old shader
goes into the node's Bulk input). The bulk recorded in the copy's ``lamina`` dict is the material's own shader
(``{"type": "shader"}``: Cycles only, no reference to compare with), or, when the old shader is another Lamina
material's node (SpongeCake), that model with its current parameters: its node is renamed ``Lamina Bulk`` and
rebuilt in the layer's form, so switching forms and comparing against the reference work as for a preset.
"""
from __future__ import annotations

import bpy

from ..models import micrograin as model
from ..models.params import ParamError
from . import FORMS
from . import material as lamina_material

DEFAULT_LABEL = "Porous layer"
_RESERVED = ("Lamina", lamina_material.BULK_NODE)  # node names the layer's machinery looks up


def surface_input(mat):
    """The Surface input of the material's active output for Cycles, or None (no node tree, no output)."""
    tree = mat.node_tree
    if tree is None or (bpy.app.version < (5, 0, 0) and not mat.use_nodes):
        return None
    out = tree.get_output_node("CYCLES")
    return None if out is None else out.inputs["Surface"]


def has_porous_layer(mat) -> bool:
    return lamina_material.is_lamina(mat) and lamina_material.info(mat).get("model") == model.ID


def refusal(mat) -> str | None:
    """Why ``mat`` cannot get a porous layer (one line), or None when it can."""
    if mat is None:
        return "no active material to add a porous layer to"
    if has_porous_layer(mat):
        return f"{mat.name} already has a porous layer; edit its Filling Factor on the Lamina node"
    surface = surface_input(mat)
    if surface is None:
        return f"nothing to wrap: {mat.name} has no Material Output (or does not use nodes)"
    if not surface.is_linked:
        return f"nothing to wrap: nothing is linked into the Surface of {mat.name}'s Material Output"
    if surface.links[0].is_muted:
        return f"nothing to wrap: the Surface link of {mat.name}'s Material Output is muted"
    return None


def _lamina_bulk(mat, surface):
    """(model id, current params) when the output is fed directly by a Lamina material's own node of a model
    that can be a micrograin bulk, else None."""
    if not lamina_material.is_lamina(mat):
        return None
    node = lamina_material.shader_node(mat)
    model_id = lamina_material.info(mat).get("model")
    if node is None or surface.links[0].from_node != node or model_id not in model.bulk_types():
        return None
    model_id, p = lamina_material.current_params(mat)
    return model_id, p


def porous_params(source, data: dict, warnings: list | None = None):
    """The validated micrograin parameters of a layer over ``source``: ``data`` with its bulk replaced by what
    ``source`` renders (raises ParamError with a one-line reason when ``source`` cannot be wrapped)."""
    reason = refusal(source)
    if reason:
        raise ParamError(reason)
    if not isinstance(data, dict):
        raise ParamError(f"micrograin: expected a dict, got {type(data).__name__}")
    bulk = _lamina_bulk(source, surface_input(source))
    bulk = {"type": model.WRAPPED} if bulk is None else {"type": bulk[0], **bulk[1].to_dict()}
    validated = model.validate({**data, "bulk": bulk})
    if warnings is not None:
        warnings += validated.warnings
    return validated.params


def add_porous_layer(source, data: dict, form: str = "nodes", name: str | None = None,
                     warnings: list | None = None) -> bpy.types.Material:
    """A new material: a copy of ``source`` with a micrograin porous layer over its surface shader.

    ``data`` is a micrograin dict (``models.micrograin``; its ``bulk`` is ignored: the bulk is ``source``'s
    shader). ``name`` defaults to "<source> + Porous layer" (Blender adds .001 if taken). ``source`` is never
    modified. Raises ParamError (nothing created) when ``source`` has no linked Material Output Surface or
    already is a micrograin material, and for a bad ``data``; ``warnings`` collects clamping messages.
    """
    if form not in FORMS:
        raise ValueError(f"unknown form {form!r}; expected one of {', '.join(FORMS)}")
    p = porous_params(source, data, warnings)
    source_output = surface_input(source).node.name
    mat = source.copy()
    try:
        mat.name = name or f"{source.name} + {DEFAULT_LABEL}"
        mat.use_fake_user = False
        nodes = mat.node_tree.nodes
        out, old_lamina = nodes[source_output], nodes.get("Lamina")
        for reserved in _RESERVED:  # a node with a name the layer looks up: kept, renamed
            if reserved in nodes:
                nodes[reserved].name = f"{reserved} (under porous layer)"
        if p.bulk.type != model.WRAPPED:  # the Lamina node that fed the output becomes the layer's bulk
            old_lamina.name = lamina_material.BULK_NODE
        lamina_material.insert_layer(mat, model.ID, p, form, out.inputs["Surface"])
    except BaseException:
        bpy.data.materials.remove(mat)
        raise
    return mat


def label(preset: str | None) -> str:
    """The name suffix for a preset id ("rust_on_metal" -> "Rust on metal"), or the default."""
    return preset.replace("_", " ").capitalize() if preset else DEFAULT_LABEL


def replace_everywhere(old, new) -> int:
    """Point every object material slot that uses ``old`` at ``new`` (a slot linked to shared mesh data changes
    for every object using that data); returns how many object slots used ``old``."""
    slots = [slot for obj in bpy.data.objects for slot in obj.material_slots if slot.material == old]
    for slot in slots:
        if slot.material == old:
            slot.material = new
    return len(slots)


def keep(mat) -> bool:
    """Give ``mat`` a fake user if nothing else uses it (so saving keeps it); True if it got one."""
    if mat.users == 0 and not mat.use_fake_user:
        mat.use_fake_user = True
        return True
    return False

