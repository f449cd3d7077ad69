"""Operators that create Lamina materials and switch their form. Every one is undoable and creates new data
instead of editing the user's: an existing material is never modified, only a slot's link may change."""
from __future__ import annotations

import bpy

from .. import presets
from ..models import spongecake as model
from ..models.params import ParamError
from ..nodes import material as lamina_material

SCRATCH = "SCRATCH"
LAYER_ITEMS = [(t, t.capitalize() if t != "hg" else "Henyey-Greenstein", "") for t in model.LAYER_TYPES]
SUBSTRATE_ITEMS = [(t, t.capitalize(), "") for t in model.SUBSTRATE_TYPES]
FORM_ITEMS = [("nodes", "Node group", "Native nodes: every device, fastest, most approximate"),
              ("osl", "OSL", "OSL script: CPU and OptiX only, exact Fresnel")]


def preset_items(self, context):
    items = [(SCRATCH, "From scratch", "Build the stack from the layer settings below")]
    items += [(n, n.replace("_", " ").capitalize(), presets.description(model.ID, n)) for n in presets.names(model.ID)]
    return items


def scratch_dict(n_layers: int, layer_types, substrate: str, delta: bool) -> dict:
    layers = [{"type": t, "roughness": 0.3 if t != "hg" else 0.0} for t in layer_types[:n_layers]]
    return {"layers": layers, "substrate": None if substrate == "none" else {"type": substrate},
            "delta_transmission": delta}


class LAMINA_OT_add_spongecake(bpy.types.Operator):
    """Add a new SpongeCake material to the active object, from a preset or from scratch"""

    bl_idname = "lamina.add_spongecake"
    bl_label = "Add SpongeCake Material"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=preset_items)
    layers: bpy.props.IntProperty(name="Layers", default=1, min=1, max=model.MAX_LAYERS)
    layer_1: bpy.props.EnumProperty(name="Layer 1", items=LAYER_ITEMS, default="surface")
    layer_2: bpy.props.EnumProperty(name="Layer 2", items=LAYER_ITEMS, default="surface")
    layer_3: bpy.props.EnumProperty(name="Layer 3", items=LAYER_ITEMS, default="surface")
    layer_4: bpy.props.EnumProperty(name="Layer 4", items=LAYER_ITEMS, default="surface")
    substrate: bpy.props.EnumProperty(name="Substrate", items=SUBSTRATE_ITEMS, default="none")
    delta_transmission: bpy.props.BoolProperty(name="Delta transmission", default=False)
    multiple_scattering: bpy.props.BoolProperty(
        name="Multiple scattering", default=False,
        description="Add the network-predicted multiple scattering (stacks of 1 or 2 layers)")
    form: bpy.props.EnumProperty(name="Form", items=FORM_ITEMS, default="nodes")

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and hasattr(obj.data, "materials")

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "preset")
        col = layout.column()
        col.enabled = self.preset == SCRATCH
        col.prop(self, "layers")
        for k in range(self.layers):
            col.prop(self, f"layer_{k + 1}")
        col.prop(self, "substrate")
        col.prop(self, "delta_transmission")
        row = layout.row()
        row.enabled = self._layer_count() <= model.MS_MAX_LAYERS
        row.prop(self, "multiple_scattering")
        if not row.enabled:
            layout.label(text=f"Multiple scattering needs 1 or {model.MS_MAX_LAYERS} layers", icon="INFO")
        layout.prop(self, "form", expand=True)

    def _layer_count(self) -> int:
        return self.layers if self.preset == SCRATCH else len(presets.load(model.ID, self.preset)["layers"])

    def execute(self, context):
        if self.preset == SCRATCH:
            types = [getattr(self, f"layer_{k + 1}") for k in range(model.MAX_LAYERS)]
            data, name = scratch_dict(self.layers, types, self.substrate, self.delta_transmission), "SpongeCake"
        else:
            data, name = presets.load(model.ID, self.preset), f"SpongeCake {self.preset}"
        ms_possible = self._layer_count() <= model.MS_MAX_LAYERS
        data["multiple_scattering"] = self.multiple_scattering and ms_possible
        if self.multiple_scattering and not ms_possible:
            self.report({"WARNING"}, f"Multiple scattering needs 1 or {model.MS_MAX_LAYERS} layers: left off")
        try:
            validated = model.validate(data)
        except ParamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for w in validated.warnings:
            self.report({"WARNING"}, w)
        mat = lamina_material.new_material(model.ID, validated.params, self.form, name=name)
        assign_to_active_slot(context.active_object, mat)
        if self.form == "osl" and not context.scene.cycles.shading_system:
            self.report({"WARNING"}, "OSL form: enable Render Properties > Open Shading Language (CPU or OptiX) "
                                     "to see it; Lamina does not change scene settings")
        self.report({"INFO"}, f"Added material {mat.name}")
        return {"FINISHED"}


def assign_to_active_slot(obj, mat) -> None:
    """Link ``mat`` in the active slot (a new slot when there is none); the previous material stays in the file."""
    if len(obj.material_slots) == 0:
        obj.data.materials.append(mat)
    else:
        obj.material_slots[obj.active_material_index].material = mat


class LAMINA_OT_set_form(bpy.types.Operator):
    """Switch the active Lamina material between its node-group and OSL forms, keeping the parameter values"""

    bl_idname = "lamina.set_form"
    bl_label = "Set Lamina Form"
    bl_options = {"REGISTER", "UNDO"}

    form: bpy.props.EnumProperty(name="Form", items=FORM_ITEMS)

    @classmethod
    def poll(cls, context):
        return lamina_material.is_lamina(getattr(context, "material", None))

    def execute(self, context):
        mat = context.material
        try:
            lamina_material.set_form(mat, self.form)
        except Exception as e:  # noqa: BLE001 - e.g. OSL compile failure: report, leave the material as it was
            self.report({"ERROR"}, f"Could not switch {mat.name}: {e}")
            return {"CANCELLED"}
        if self.form == "osl" and not context.scene.cycles.shading_system:
            self.report({"WARNING"}, "Enable Render Properties > Open Shading Language to render the OSL form")
        return {"FINISHED"}
