"""Operators that create Lamina materials and switch their form. Every one is undoable and creates new data
instead of editing the user's: an existing material is never modified, only a slot's link may change."""
from __future__ import annotations

import os

import bpy

from .. import presets
from ..models import micrograin
from ..models import spongecake as model
from ..models.params import ParamError
from ..nodes import material as lamina_material
from ..nodes import wrap

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


# ------------------------------------------------------------------------------------------ porous layer

CUSTOM = "CUSTOM"
POROUS_PRESET_ITEMS = [(CUSTOM, "Custom", "Set the filling factor and the grains below")] + [
    (n, wrap.label(n), presets.description(micrograin.ID, n)) for n in presets.names(micrograin.ID)]
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
CONDUCTOR_ITEMS = [(k, k.replace("_", " ").capitalize(), f"Grains of {k.replace('_', ' ')} (complex IOR, RGB)")
                   for k in micrograin.CONDUCTORS] + [(CUSTOM, "Custom", "Set the complex IOR (n, k) below")]


def _declared(decl, param: str, **overrides):
    """A Blender property from the model's declaration of parameter ``param`` (range, label, description),
    with ``overrides`` (e.g. a dialog default)."""
    prm = next(p for p in decl if p.name == param)
    kw = {"name": prm.label, "default": prm.default, "min": prm.min, "max": prm.max,
          "description": prm.description}
    if prm.kind == "float":
        return bpy.props.FloatProperty(**({"subtype": prm.subtype} if prm.subtype else {}), **{**kw, **overrides})
    subtype = "COLOR" if prm.kind == "color" and prm.max == 1.0 else "NONE"
    return bpy.props.FloatVectorProperty(size=3, subtype=subtype, **{**kw, **overrides})


class LAMINA_OT_add_porous_layer(bpy.types.Operator):
    """Add a micrograin porous layer (dust, rust, dirt, spray paint) over the active material: a new material
    wrapping a copy of it (the original is never changed)"""

    bl_idname = "lamina.add_porous_layer"
    bl_label = "Add Porous Layer"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=POROUS_PRESET_ITEMS, default=CUSTOM,
                                   description="A porous layer after the paper's Fig. 1, or Custom (the "
                                               "preset's bulk is ignored: the bulk is your material)")
    filling_factor: _declared(micrograin.LAYER, "filling_factor", default=0.3)
    roughness_control: bpy.props.EnumProperty(name="Roughness", items=ROUGHNESS_ITEMS, default="anfractuosity",
                                              description="Set the grains' shape or the roughness they look like")
    anfractuosity: _declared(micrograin.LAYER, "anfractuosity")
    roughness: _declared((micrograin.ROUGHNESS,), "roughness")
    grain_type: bpy.props.EnumProperty(name="Grains", items=GRAIN_ITEMS, default="diffuse",
                                       description="The grains' micro-BRDF")
    grain_color: _declared(micrograin.GRAIN["diffuse"], "albedo", default=(0.70, 0.68, 0.64))
    grain_ior: _declared(micrograin.GRAIN["dielectric"], "ior")
    conductor: bpy.props.EnumProperty(name="Conductor", items=CONDUCTOR_ITEMS, default="gold",
                                      description="What the conductor grains are made of")
    conductor_ior: _declared(micrograin.GRAIN["conductor"], "ior", name="IOR n")
    conductor_k: _declared(micrograin.GRAIN["conductor"], "k", name="Extinction k")
    form: bpy.props.EnumProperty(name="Form", items=FORM_ITEMS, default="nodes")
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

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self, width=360)

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
            col.prop(self, "conductor")
            if self.conductor == CUSTOM:
                col.prop(self, "conductor_ior")
                col.prop(self, "conductor_k")

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
            ior, k = ((self.conductor_ior, self.conductor_k) if self.conductor == CUSTOM
                      else micrograin.CONDUCTORS[self.conductor])
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
        try:
            mat = wrap.add_porous_layer(source, self.layer_dict(), self.form, name=name, warnings=warnings)
        except ParamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        except Exception as e:  # noqa: BLE001 - e.g. OSL compile failure: report; nothing was created
            self.report({"ERROR"}, f"Could not add a porous layer to {source.name}: {e}")
            return {"CANCELLED"}
        for w in warnings:
            self.report({"WARNING"}, w)
        if self.assign_to_slot:
            assign_to_active_slot(obj, mat)
            if wrap.keep(source):
                self.report({"INFO"}, f"{source.name} is no longer used: kept with a fake user so saving keeps it")
        elif wrap.keep(mat):
            self.report({"INFO"}, f"{mat.name} is not assigned: kept with a fake user (pick it in a slot)")
        if self.form == "osl" and not context.scene.cycles.shading_system:
            self.report({"WARNING"}, "OSL form: enable Render Properties > Open Shading Language (CPU or OptiX) "
                                     "to see it; Lamina does not change scene settings")
        self.report({"INFO"}, f"Added material {mat.name} (a porous layer over {source.name})")
        return {"FINISHED"}


class PorousError(Exception):
    """The file cannot get the porous layer: unknown material, nothing to wrap, already a porous layer, not saved."""


def add_porous_file(blend: str, material: str, data: dict, form: str, out: str,
                    preset: str | None = None) -> tuple[str, list[str]]:
    """Open ``blend``, add a porous layer over ``material`` (a new material, assigned to every object slot that
    used the original; the original stays in the file with a fake user) and save the file as ``out`` atomically.
    Returns a one-line summary and the warnings. Nothing is saved when it is refused (PorousError)."""
    from ..bake.exr import atomic_path

    bpy.ops.wm.open_mainfile(filepath=blend)
    source = bpy.data.materials.get(material)
    if source is None:
        names = ", ".join(sorted(m.name for m in bpy.data.materials)) or "none"
        raise PorousError(f"no material {material!r} in {blend} (it has: {names})")
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
    with atomic_path(out) as tmp:
        os.remove(tmp)  # Blender would keep a .blend1 backup of the file it saves over
        if "FINISHED" not in bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True):
            raise PorousError(f"could not save {out}")
    return (f"added {mat.name!r} over {source.name!r} in {slots} object slot(s), {source.name!r} kept with a fake "
            f"user"), warnings
