"""Add Porous Layer: a micrograin layer (dust, rust, dirt, spray paint) over any material, from the dialog and from
the CLI (``add_porous_file``)."""
from __future__ import annotations

import bpy

from .. import presets
from ..models import micrograin
from ..models.params import ParamError
from ..nodes import wrap
from . import blend_io
from .material_ops import (CUSTOM, AddMaterialDialog, assign_to_active_slot, built_or_reported, conductor_values, declared,
                           draw_conductor, metal_items, preset_items, warn_if_osl_is_off)

PRESET_ITEMS = preset_items(micrograin.ID, "Set the filling factor and the grains below")
ROUGHNESS_ITEMS = [
    ("anfractuosity", "Anfractuosity β", "Set the grains' shape: height over radius (the paper's beta)"),
    ("roughness", "Equivalent roughness α",
     "Set the GGX roughness the grains look like (α̃ of Eq. 18); Lamina derives the anfractuosity at this filling "
     "factor, so the highlight keeps its sharpness when the filling factor changes"),
]
GRAIN_ITEMS = [(key, micrograin.GRAIN_LABELS[key], description) for key, description in (
    ("diffuse", "Matte (Lambertian) grains: dust, dirt, mud"),
    ("dielectric", "Matte grains under a specular dielectric coat: glossy dust, paint"),
    ("conductor", "Specular grains with a complex IOR: rust, metallic spray paint, soot"))]
CONDUCTOR_ITEMS = metal_items(micrograin.CONDUCTORS, "Grains of")


class LAMINA_OT_add_porous_layer(AddMaterialDialog, bpy.types.Operator):
    """Add a micrograin porous layer (dust, rust, dirt, spray paint) over the active material: a new material
    wrapping a copy of it (the original is never changed)"""

    bl_idname = "lamina.add_porous_layer"
    bl_label = "Add Porous Layer"
    dialog_width = 360

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS, default=CUSTOM,
                                   description="A porous layer after the paper's Fig. 1, or Custom (the "
                                               "preset's bulk is ignored: the bulk is your material)")
    filling_factor: declared(micrograin.LAYER, "filling_factor", default=0.3)
    roughness_control: bpy.props.EnumProperty(name="Roughness", items=ROUGHNESS_ITEMS, default="anfractuosity",
                                              description="Set the grains' shape or the roughness they look like")
    anfractuosity: declared(micrograin.LAYER, "anfractuosity")
    roughness: declared((micrograin.ROUGHNESS,), "roughness")
    grain_type: bpy.props.EnumProperty(name="Grains", items=GRAIN_ITEMS, default="diffuse",
                                       description="The grains' micro-BRDF")
    grain_color: declared(micrograin.GRAIN["diffuse"], "albedo", default=(0.70, 0.68, 0.64))
    grain_ior: declared(micrograin.GRAIN["dielectric"], "ior")
    conductor: bpy.props.EnumProperty(name="Conductor", items=CONDUCTOR_ITEMS, default="gold",
                                      description="What the conductor grains are made of")
    conductor_ior: declared(micrograin.GRAIN["conductor"], "ior", name="IOR n")
    conductor_k: declared(micrograin.GRAIN["conductor"], "k", name="Extinction k")
    assign_to_slot: bpy.props.BoolProperty(
        name="Assign to slot", default=True,
        description="Put the new material in the active slot instead of the original (which stays in the file, "
                    "with a fake user if nothing else uses it)")

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        mat = getattr(obj, "active_material", None)
        if mat is None:
            cls.poll_message_set("The active object has no active material")
            return False
        if wrap.has_porous_layer(mat):
            cls.poll_message_set("Already has a porous layer: edit its Filling Factor on the Lamina node")
            return False
        return True

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "preset")
        if self.preset != CUSTOM:  # the preset's values (not editable here: on the Lamina node afterwards)
            p = micrograin.params_from_dict({**self.layer_dict(), "bulk": {"type": micrograin.WRAPPED}})
            col = layout.column(align=True)
            col.label(text=presets.description(micrograin.ID, self.preset), icon="INFO")
            grains = micrograin.GRAIN_LABELS[p.grain.type].lower()
            col.label(text=f"Grains: {grains}; filling factor {p.filling_factor:.2f}; "
                           f"anfractuosity β {p.anfractuosity:.2f} (α {p.roughness:.3f})")
            col.label(text="Your material is the bulk; edit the values on the Lamina node afterwards")
        else:
            self._draw_custom(layout.column())
        layout.row().prop(self, "form", expand=True)
        layout.prop(self, "assign_to_slot")

    def _draw_custom(self, col) -> None:
        col.prop(self, "filling_factor", slider=True)
        col.row().prop(self, "roughness_control", expand=True)
        col.prop(self, self.roughness_control, slider=True)
        col.label(text=self._other_control())
        col.prop(self, "grain_type")
        if self.grain_type != "conductor":
            col.prop(self, "grain_color")
        if self.grain_type == "dielectric":
            col.prop(self, "grain_ior")
        if self.grain_type == "conductor":
            draw_conductor(col, self, "conductor")

    def _other_control(self) -> str:
        """The value the chosen roughness control implies for the other one (Eq. 18)."""
        tau0 = self.filling_factor
        if self.roughness_control == "anfractuosity":
            return f"Equivalent roughness α = {micrograin.equivalent_roughness(tau0, self.anfractuosity):.3f}"
        beta = micrograin.anfractuosity_for(tau0, self.roughness)
        if beta > 1.0:
            return f"Anfractuosity β = 1 (largest α here: {micrograin.equivalent_roughness(tau0, 1.0):.3f})"
        return f"Anfractuosity β = {max(beta, micrograin.MIN_ANFRACTUOSITY):.3f}"

    def layer_dict(self) -> dict:
        """The micrograin dict the dialog describes (a preset's, or the Custom settings); no bulk."""
        if self.preset != CUSTOM:
            return presets.load(micrograin.ID, self.preset)
        data = {"filling_factor": self.filling_factor}
        if self.roughness_control == "anfractuosity":
            data["anfractuosity"] = self.anfractuosity
        else:
            data["roughness"] = self.roughness
        grain = {"type": self.grain_type}
        if self.grain_type != "conductor":
            grain["albedo"] = list(self.grain_color)
        if self.grain_type == "dielectric":
            grain["ior"] = self.grain_ior
        if self.grain_type == "conductor":
            ior, k = conductor_values(self, "conductor", micrograin.CONDUCTORS)
            grain["ior"], grain["k"] = list(ior), list(k)
        data["grain"] = grain
        return data

    def execute(self, context):
        obj = context.active_object
        source = getattr(obj, "active_material", None)
        if source is None:
            self.report({"ERROR"}, "The active object has no active material to add a porous layer to")
            return {"CANCELLED"}
        warnings = []
        name = f"{source.name} + {wrap.label(None if self.preset == CUSTOM else self.preset)}"
        mat = built_or_reported(
            self, lambda: wrap.add_porous_layer(source, self.layer_dict(), self.form, name=name, warnings=warnings),
            f"Could not add a porous layer to {source.name}")
        if mat is None:
            return {"CANCELLED"}
        for w in warnings:
            self.report({"WARNING"}, w)
        if self.assign_to_slot:
            assign_to_active_slot(obj, mat)
            if wrap.keep(source):
                self.report({"INFO"}, f"{source.name} is no longer used: kept with a fake user so saving keeps it")
        elif wrap.keep(mat):
            self.report({"INFO"}, f"{mat.name} is not assigned: kept with a fake user (pick it in a slot)")
        warn_if_osl_is_off(self, context, self.form)
        self.report({"INFO"}, f"Added material {mat.name} (a porous layer over {source.name})")
        return {"FINISHED"}


class PorousError(Exception):
    """The file cannot get the porous layer: unknown material, nothing to wrap, already a porous layer, not saved."""


def add_porous_file(blend: str, material: str, data: dict, form: str, out: str,
                    preset: str | None = None) -> tuple[str, list[str]]:
    """Open ``blend``, add a porous layer over ``material`` (a new material, assigned to every object slot that
    used the original; the original stays in the file with a fake user) and save the file as ``out`` atomically.
    Returns a one-line summary and the warnings. Nothing is saved when it is refused (PorousError, or
    ``blend_io.BlendArgumentError`` for a file Blender cannot read or a material it does not have)."""
    blend_io.open_blend(blend)
    source = blend_io.find_material(material, blend)
    warnings = []
    try:
        mat = wrap.add_porous_layer(source, data, form, name=f"{source.name} + {wrap.label(preset)}",
                                    warnings=warnings)
    except ParamError as e:
        raise PorousError(str(e)) from None
    slots = wrap.replace_everywhere(source, mat)
    source.use_fake_user = True
    if slots == 0:
        wrap.keep(mat)
        warnings.append(f"no object uses {source.name}: {mat.name} is in the file with a fake user, assigned nowhere")
    if form == "osl" and not any(s.cycles.shading_system for s in bpy.data.scenes):
        warnings.append("the OSL form renders only with Render Properties > Open Shading Language on (CPU or "
                        "OptiX); Lamina does not change scene settings")
    blend_io.save_copy(out)
    return (f"added {mat.name!r} over {source.name!r} in {slots} object slot(s), {source.name!r} kept with a fake "
            f"user"), warnings


def can_add(mat) -> bool:
    """Whether the panel's Add Porous Layer button applies to the active material (what the operator's poll says)."""
    return mat is not None and not wrap.has_porous_layer(mat)


ADD = (LAMINA_OT_add_porous_layer.bl_idname, "MOD_PARTICLES")  # the panel's Add button: operator and icon
classes = (LAMINA_OT_add_porous_layer,)
