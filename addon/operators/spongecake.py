"""Add SpongeCake Material: a stack of SGGX / Henyey-Greenstein layers from a preset or built in the dialog."""
from __future__ import annotations

import bpy

from .. import presets
from ..models import spongecake as model
from .material_ops import CUSTOM, AddMaterialDialog, add_material, label, preset_items

LAYER_ITEMS = [(t, t.capitalize() if t != "hg" else "Henyey-Greenstein", "") for t in model.LAYER_TYPES]
SUBSTRATE_ITEMS = [(t, t.capitalize(), "") for t in model.SUBSTRATE_TYPES]
PRESET_ITEMS = preset_items(model.ID, "Build the stack from the layer settings below")


def scratch_dict(n_layers: int, layer_types, substrate: str, delta: bool) -> dict:
    layers = [{"type": t, "roughness": 0.3 if t != "hg" else 0.0} for t in layer_types[:n_layers]]
    return {"layers": layers, "substrate": None if substrate == "none" else {"type": substrate},
            "delta_transmission": delta}


class LAMINA_OT_add_spongecake(AddMaterialDialog, bpy.types.Operator):
    """Add a new SpongeCake material to the active object, from a preset or from scratch"""

    bl_idname = "lamina.add_spongecake"
    bl_label = "Add SpongeCake Material"

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS)
    layers: bpy.props.IntProperty(name="Layers", default=1, min=1, max=model.MAX_LAYERS)
    layer_1: bpy.props.EnumProperty(name="Layer 1", items=LAYER_ITEMS, default="surface")
    layer_2: bpy.props.EnumProperty(name="Layer 2", items=LAYER_ITEMS, default="surface")
    layer_3: bpy.props.EnumProperty(name="Layer 3", items=LAYER_ITEMS, default="surface")
    layer_4: bpy.props.EnumProperty(name="Layer 4", items=LAYER_ITEMS, default="surface")
    substrate: bpy.props.EnumProperty(name="Substrate", items=SUBSTRATE_ITEMS, default="none")
    delta_transmission: bpy.props.BoolProperty(name="Delta transmission", default=False)
    multiple_scattering: bpy.props.BoolProperty(
        name="Multiple scattering", default=False,
        description="Add the network-predicted multiple scattering (networks for 1 and 2 layers; deeper stacks "
                    "grouped in two)")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "preset")
        col = layout.column()
        col.enabled = self.preset == CUSTOM
        col.prop(self, "layers")
        for k in range(self.layers):
            col.prop(self, f"layer_{k + 1}")
        col.prop(self, "substrate")
        col.prop(self, "delta_transmission")
        layout.prop(self, "multiple_scattering")
        layout.prop(self, "form", expand=True)
        layout.prop(self, "mapping", expand=True)

    def execute(self, context):
        if self.preset == CUSTOM:
            types = [getattr(self, f"layer_{k + 1}") for k in range(model.MAX_LAYERS)]
            data, name = scratch_dict(self.layers, types, self.substrate, self.delta_transmission), model.LABEL
        else:
            data, name = presets.load(model.ID, self.preset), f"{model.LABEL} {label(self.preset)}"
        data["multiple_scattering"] = self.multiple_scattering
        return add_material(self, context, model.ID, data, name)


ADD = (LAMINA_OT_add_spongecake.bl_idname, "MATERIAL")  # the panel's Add button: operator and icon
classes = (LAMINA_OT_add_spongecake,)
