"""The Lamina panel: add a material, switch its form and multiple scattering, compare it with the reference."""
from __future__ import annotations

import bpy

from ..models import MODELS
from ..nodes import material as lamina_material


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
        layout.operator("lamina.add_spongecake", icon="MATERIAL")
        mat = getattr(context, "material", None)
        if not lamina_material.is_lamina(mat):
            layout.label(text="The active material is not a Lamina material", icon="INFO")
            return
        box = layout.box()
        info = lamina_material.info(mat)
        form = lamina_material.form_of(mat)
        box.label(text=f"{mat.name}: {info['model']}, {len(info['params']['layers'])} layer(s)")
        row = box.row(align=True)
        for value, label in (("nodes", "Node group"), ("osl", "OSL")):
            op = row.operator("lamina.set_form", text=label, depress=(form == value))
            op.form = value
        scene = context.scene
        if form == "osl" and not (scene.render.engine == "CYCLES" and scene.cycles.shading_system):
            box.label(text="OSL renders only in Cycles with Open Shading Language on", icon="ERROR")
        box.label(text="Edit the layer parameters on the Lamina node", icon="NODE")
        _draw_multiple_scattering(layout.box(), context, mat)


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
        col = layout.column(align=True)
        col.prop(settings, "samples")
        col.prop(settings, "resolution")
        col.prop(settings, "scene")
        col.prop(settings, "multiple_scattering")
        if settings.multiple_scattering:
            col.prop(settings, "ms_paths")
            col.prop(settings, "ms_stride")
        layout.operator("lamina.compare", icon="IMAGE_REFERENCE")
        for line in settings.last_report.splitlines():
            layout.label(text=line)


classes = (LAMINA_PT_main, LAMINA_PT_compare)
