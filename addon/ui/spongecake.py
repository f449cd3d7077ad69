"""The panel on a SpongeCake material: its layers, the multiple-scattering switch and bake state, and the
compare settings of multiple scattering."""
from __future__ import annotations

import bpy

from ..bake.spongecake import NETWORK_LAYERS
from ..models import spongecake as model
from ..nodes import material as lamina_material

EDIT_HINT = "Edit the layer parameters on the Lamina node"


def draw_summary(box, mat, p, node) -> None:
    box.label(text=f"{mat.name}: {model.LABEL}, {len(p.layers)} layer(s)")


def draw_extra(layout, context, mat) -> None:
    """The on/off toggle; when on, the predicted energy share or a stale warning, re-bake and texture baking."""
    box = layout.box()
    on = lamina_material.ms_enabled(mat)
    op = box.row().operator("lamina.set_multiple_scattering", text="Multiple scattering", depress=on,
                            icon="CHECKBOX_HLT" if on else "CHECKBOX_DEHLT")
    op.enabled = not on
    if not on:
        return
    if len(lamina_material.info(mat)["params"]["layers"]) > NETWORK_LAYERS:
        box.label(text=f"Lobes: {NETWORK_LAYERS}-layer network, layers grouped in two (an approximation)", icon="INFO")
    stale = lamina_material.ms_is_stale(mat)
    if stale:
        box.label(text="Needs a re-bake: parameters, network or Lamina changed", icon="ERROR")
    else:
        box.label(text=f"Multiple scattering: {lamina_material.ms_energy_share(mat):.0%} of the leaving energy")
    row = box.row(align=True)
    row.alert = stale
    row.operator("lamina.rebake", text="Re-bake", icon="FILE_REFRESH")
    row.prop(context.window_manager, "lamina_auto_rebake")
    if hasattr(bpy.types, "LAMINA_OT_bake_textures"):
        box.operator("lamina.bake_textures", icon="TEXTURE")
    texels = lamina_material.texel_energy(mat)
    if texels is not None:
        box.label(text=texels.note(), icon="INFO")


def draw_compare_settings(col, settings) -> None:
    col.prop(settings, "multiple_scattering")
    if settings.multiple_scattering:
        col.prop(settings, "ms_paths")
        col.prop(settings, "ms_stride")
