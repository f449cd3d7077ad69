"""The Lamina panel: add a material, switch its form and multiple scattering, compare it with the reference."""
from __future__ import annotations

import bpy

from ..models import MODELS, aniso_stack, micrograin, thin_coat
from ..nodes import material as lamina_material
from ..nodes import wrap
from ..operators import compare_run, material_ops


class LAMINA_PT_main(bpy.types.Panel):
    bl_space_type = "NODE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Lamina"
    bl_label = "Lamina"

    @classmethod
    def poll(cls, context):
        space = context.space_data
        return space is not None and getattr(space, "tree_type", "") == "ShaderNodeTree"

    def draw(self, context):
        layout = self.layout
        mat = getattr(context, "material", None)
        col = layout.column(align=True)
        col.operator("lamina.add_spongecake", icon="MATERIAL")
        col.operator("lamina.add_thin_coat", icon="MATSHADERBALL")
        row = col.row(align=True)
        row.enabled = mat is not None and not wrap.has_porous_layer(mat)  # what the operator's poll says, but visible
        row.operator("lamina.add_porous_layer", icon="MOD_PARTICLES")
        if not lamina_material.is_lamina(mat):
            layout.label(text="The active material is not a Lamina material", icon="INFO")
            return
        box = layout.box()
        info = lamina_material.info(mat)
        form = lamina_material.form_of(mat)
        if info["model"] == micrograin.ID:
            _draw_micrograin(box, mat)
        elif info["model"] == thin_coat.ID:
            _draw_thin_coat(box, mat)
        elif info["model"] == aniso_stack.ID:
            _draw_aniso_stack(box, mat)
        else:
            box.label(text=f"{mat.name}: {info['model']}, {len(info['params']['layers'])} layer(s)")
        row = box.row(align=True)
        for value, label in (("nodes", "Node group"), ("osl", "OSL")):
            op = row.operator("lamina.set_form", text=label, depress=(form == value))
            op.form = value
        scene = context.scene
        if form == "osl" and not (scene.render.engine == "CYCLES" and scene.cycles.shading_system):
            box.label(text="OSL renders only in Cycles with Open Shading Language on", icon="ERROR")
        if info["model"] == micrograin.ID:
            box.label(text="Edit the filling factor and grains on the Lamina node", icon="NODE")
            return
        if info["model"] == thin_coat.ID:
            box.label(text="Edit the coat and the base on the Lamina node", icon="NODE")
            return
        if info["model"] == aniso_stack.ID:
            box.label(text="Edit the roughnesses, rotations and media on the Lamina node", icon="NODE")
            return
        box.label(text="Edit the layer parameters on the Lamina node", icon="NODE")
        if hasattr(MODELS[info["model"]], "MS_MAX_LAYERS"):
            _draw_multiple_scattering(layout.box(), context, mat)


def _linked(node, name: str) -> bool:
    socket = node.inputs.get(name) or node.inputs.get(name.replace(" ", "_"))  # node group / OSL names
    return socket is not None and socket.is_linked


def _draw_micrograin(box, mat) -> None:
    """A porous layer's summary from the Lamina node's current inputs: grains, filling factor, α̃ (Eq. 18), bulk."""
    box.label(text=f"{mat.name}: micrograin porous layer")
    try:
        _, p = lamina_material.current_params(mat)
    except Exception as e:  # noqa: BLE001 - a hand-edited node tree: say so instead of failing to draw
        box.label(text=f"Cannot read the Lamina node: {e}", icon="ERROR")
        return
    node = lamina_material.shader_node(mat)
    if node is None:
        box.label(text="The Lamina node was removed: showing the stored values", icon="ERROR")
    col = box.column(align=True)
    grain = micrograin.GRAIN_LABELS[p.grain.type].lower()
    if p.grain.type == "dielectric":
        grain += f" (IOR {p.grain.ior:.2f})"
    col.label(text=f"Grains: {grain}")
    textured = node is not None and _linked(node, "Filling Factor")
    col.label(text="Filling factor: texture-driven" if textured else f"Filling factor: {p.filling_factor:.2f}")
    if node is not None and (textured or _linked(node, "Anfractuosity")):
        col.label(text="Equivalent roughness: varies (texture-driven inputs)")
    else:
        col.label(text=f"Equivalent roughness α: {p.roughness:.3f} (anfractuosity {p.anfractuosity:.2f})")
    if p.bulk.type == micrograin.WRAPPED:
        col.label(text="Bulk: the material's own shader (Bulk input)")
    else:
        bulk = getattr(MODELS.get(p.bulk.type), "LABEL", p.bulk.type)
        col.label(text=f"Bulk: {bulk} (node {lamina_material.BULK_NODE})")


def _draw_aniso_stack(box, mat) -> None:
    """An anisotropic stack's summary from the Lamina node's current inputs: one line per interface (type, IOR,
    roughnesses, rotation) and per non-empty medium, and which inputs textures drive."""
    read = _current_params(box, mat, "anisotropic stack")
    if read is None:
        return
    model_id, p = read
    box.label(text=f"{mat.name}: anisotropic stack of {len(p.interfaces)} interface(s)")
    node = lamina_material.shader_node(mat)
    driven = {s.name for s in _linked_sockets(node, model_id, p)}
    col = box.column(align=True)
    for j, interface in enumerate(p.interfaces):
        ior = "/".join(f"{n:.3g}" for n in sorted(set(interface.ior)))
        if interface.type == "conductor":
            ior = ", ".join(f"{n:.3g}+{k:.3g}i" for n, k in zip(interface.ior, interface.k))
        col.label(text=f"{j + 1}. {aniso_stack.INTERFACE_LABELS[interface.type]} {ior}: α {interface.alpha_x:.3g} × "
                       f"{interface.alpha_y:.3g}, rotation {interface.rotation:.0f}°")
        if j < len(p.media) and (p.media[j].depth > 0.0):
            m = p.media[j]
            col.label(text=f"   medium: σa·d {', '.join(f'{a * m.depth:.3g}' for a in m.sigma_a)}"
                           + (f", scattering g {m.g:.2f}" if any(m.sigma_s) else ""))
    if driven:
        col.label(text=f"Texture-driven: {', '.join(sorted(driven))}")


def _current_params(box, mat, what: str):
    """(model id, parameters) of ``mat``, or None after saying in ``box`` that its Lamina node cannot be read."""
    try:
        return lamina_material.current_params(mat)
    except Exception as e:  # noqa: BLE001 - a hand-edited node tree: say so instead of failing to draw
        box.label(text=f"{mat.name}: {what}")
        box.label(text=f"Cannot read the Lamina node: {e}", icon="ERROR")
        return None


def _linked_sockets(node, model_id: str, p) -> list:
    """The Lamina node's sockets (the mapping's ``Socket``: name and declared ``param``) that a link drives."""
    from ..nodes import MAPPINGS

    if node is None or model_id not in MAPPINGS:
        return []
    return [s for s in MAPPINGS[model_id].sockets(p) if s.kind != "shader" and _linked(node, s.name)]


def _draw_thin_coat(box, mat) -> None:
    """A thin coat's summary from the Lamina node's current inputs: base, both interfaces' roughness and κ, η,
    the absorption σa·d, the bounces, and which inputs textures drive."""
    read = _current_params(box, mat, "thin coat")
    if read is None:
        return
    model_id, p = read
    box.label(text=f"{mat.name}: thin coat over {thin_coat.BASE_LABELS[p.base.type].lower()}")
    node = lamina_material.shader_node(mat)
    if node is None:
        box.label(text="The Lamina node was removed: showing the stored values", icon="ERROR")
    linked = _linked_sockets(node, model_id, p)
    base_params = {prm for declared in thin_coat.BASE.values() for prm in declared}
    driven = {s.param.name for s in linked if s.param not in base_params}  # the coat's own inputs
    col = box.column(align=True)
    col.label(text=f"Base: {material_ops.base_text(p)}")
    for side in thin_coat.INTERFACES:
        name = side.capitalize()
        if side == "bottom" and p.base.type == "diffuse":
            col.label(text="Bottom: no effect over a diffuse base")
        elif {f"kappa_{side}", f"roughness_{side}"} & driven:
            col.label(text=f"{name}: roughness texture-driven (κ = 2 / α² per texel)")
        else:
            col.label(text=f"{name}: {material_ops.interface_text(p, side)}")
    col.label(text="Coat IOR η: texture-driven" if "eta" in driven else f"Coat IOR η {p.eta:.3f}")
    if {"sigma_a", "depth"} & driven:
        col.label(text="Absorption σa·d: texture-driven")
    else:
        col.label(text=f"Absorption σa·d: ({', '.join(f'{s * p.depth:.3g}' for s in p.sigma_a)})")
    col.label(text=f"Bounces: {p.bounces} (subsurface reflections; 0 = the top interface only)")
    if linked:
        col.label(text="Texture-driven: " + ", ".join(s.name for s in linked), icon="TEXTURE")
    elif node is not None:
        col.label(text="No texture-driven inputs")


def _draw_multiple_scattering(box, context, mat) -> None:
    """The on/off toggle; when on, the predicted energy share or a stale warning, re-bake and texture baking."""
    on = lamina_material.ms_enabled(mat)
    info = lamina_material.info(mat)
    max_layers = MODELS[info["model"]].MS_MAX_LAYERS
    row = box.row()
    row.enabled = on or len(info["params"]["layers"]) <= max_layers  # turning off always works
    op = row.operator("lamina.set_multiple_scattering", text="Multiple scattering", depress=on,
                      icon="CHECKBOX_HLT" if on else "CHECKBOX_DEHLT")
    op.enabled = not on
    if not row.enabled:
        box.label(text=f"Multiple scattering needs 1 or {max_layers} layers", icon="INFO")
    if not on:
        return
    stale = lamina_material.ms_is_stale(mat)
    if stale:
        box.label(text="Parameters changed since the last bake", icon="ERROR")
    else:
        box.label(text=f"Multiple scattering: {lamina_material.ms_energy_share(mat):.0%} of the leaving energy")
    row = box.row(align=True)
    row.alert = stale
    row.operator("lamina.rebake", text="Re-bake", icon="FILE_REFRESH")
    row.prop(context.window_manager, "lamina_auto_rebake")
    if hasattr(bpy.types, "LAMINA_OT_bake_textures"):
        box.operator("lamina.bake_textures", icon="TEXTURE")


class LAMINA_PT_compare(bpy.types.Panel):
    bl_space_type = "NODE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Lamina"
    bl_label = "Compare with reference"
    bl_parent_id = "LAMINA_PT_main"

    @classmethod
    def poll(cls, context):
        return lamina_material.is_lamina(getattr(context, "material", None))

    def draw(self, context):
        layout = self.layout
        settings = context.window_manager.lamina_compare
        mat = context.material
        info = lamina_material.info(mat)
        wrapped = compare_run.refusal(*lamina_material.current_params(mat)) is not None
        if wrapped:
            layout.label(text="Comparison needs a reference bulk: this porous", icon="INFO")
            layout.label(text="layer wraps the material's own shader")
        col = layout.column(align=True)
        col.enabled = not wrapped
        col.prop(settings, "samples")
        col.prop(settings, "resolution")
        col.prop(settings, "scene")
        if hasattr(MODELS.get(info["model"]), "MS_MAX_LAYERS"):
            col.prop(settings, "multiple_scattering")
            if settings.multiple_scattering:
                col.prop(settings, "ms_paths")
                col.prop(settings, "ms_stride")
        if info["model"] == micrograin.ID:
            col.prop(settings, "blends")
        if compare_run.has_principled(info["model"]):
            col.prop(settings, "principled")
        if compare_run.has_truth(info["model"]):
            col.prop(settings, "truth")
            if settings.truth:
                col.prop(settings, "truth_paths")
                col.prop(settings, "truth_stride")
        row = layout.row()
        row.enabled = not wrapped
        row.operator("lamina.compare", icon="IMAGE_REFERENCE")
        for line in settings.last_report.splitlines():
            layout.label(text=line)


classes = (LAMINA_PT_main, LAMINA_PT_compare)
