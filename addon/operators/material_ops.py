"""Operators that create Lamina materials and switch their form. Every one is undoable and creates new data
instead of editing the user's: an existing material is never modified, only a slot's link may change."""
from __future__ import annotations

import math

import bpy

from .. import presets
from ..models import micrograin, thin_coat
from ..models import spongecake as model
from ..models.params import ParamError
from ..nodes import material as lamina_material
from ..nodes import wrap
from . import blend_io

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
        mat = built_or_reported(self, lambda: lamina_material.new_material(model.ID, validated.params, self.form,
                                                                           name=name), "Could not build SpongeCake")
        if mat is None:
            return {"CANCELLED"}
        assign_to_active_slot(context.active_object, mat)
        warn_if_osl_is_off(self, context, self.form)
        self.report({"INFO"}, f"Added material {mat.name}")
        return {"FINISHED"}


def warn_if_osl_is_off(op, context, form: str) -> None:
    """Tell the user how to see an OSL form; the scene's settings are theirs to change."""
    if form == "osl" and not context.scene.cycles.shading_system:
        op.report({"WARNING"}, "OSL form: enable Render Properties > Open Shading Language (CPU or OptiX) to see "
                               "it; Lamina does not change scene settings")


def built_or_reported(op, build, failure: str):
    """``build()``'s material, or None after reporting ``failure`` and removing whatever the failed build had
    already created (e.g. the material before its OSL script failed to compile)."""
    before = blend_io.snapshot()
    try:
        return build()
    except ParamError as e:
        op.report({"ERROR"}, str(e))
    except Exception as e:  # noqa: BLE001 - e.g. an OSL compile failure
        op.report({"ERROR"}, f"{failure}: {type(e).__name__}: {e}")
    blend_io.remove_new_data(before)
    return None


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
        warn_if_osl_is_off(self, context, self.form)
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
    kw = {"name": prm.label, "default": prm.default, "description": prm.description,
          **{bound: getattr(prm, bound) for bound in ("min", "max") if getattr(prm, bound) is not None}}
    if prm.kind == "float":
        return bpy.props.FloatProperty(**({"subtype": prm.subtype} if prm.subtype else {}), **{**kw, **overrides})
    if prm.kind == "int":
        return bpy.props.IntProperty(**{**kw, **{k: int(v) for k, v in kw.items() if k in ("min", "max")},
                                        **overrides})
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
            ior, k = conductor_values(self, "conductor")
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


def draw_conductor(col, op, choice: str) -> None:
    """The conductor enum ``choice`` of a dialog, and its ``<choice>_ior`` / ``<choice>_k`` when Custom."""
    col.prop(op, choice)
    if getattr(op, choice) == CUSTOM:
        col.prop(op, f"{choice}_ior")
        col.prop(op, f"{choice}_k")


def conductor_values(op, choice: str) -> tuple:
    """(n, k) of the conductor a dialog's enum ``choice`` names, or of its Custom ``<choice>_ior`` / ``<choice>_k``."""
    name = getattr(op, choice)
    if name == CUSTOM:
        return tuple(getattr(op, f"{choice}_ior")), tuple(getattr(op, f"{choice}_k"))
    return micrograin.CONDUCTORS[name]


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


# ------------------------------------------------------------------------------------------ thin coat

COAT_PRESET_ITEMS = [(CUSTOM, "Custom", "Set the interfaces, the coat and the base below")] + [
    (n, wrap.label(n), presets.description(thin_coat.ID, n)) for n in presets.names(thin_coat.ID)]
BASE_ITEMS = [(key, thin_coat.BASE_LABELS[key], description) for key, description in (
    ("diffuse", "A matte (Lambertian) base under the coat: lacquered wood, glazed ceramic, varnished paint"),
    ("conductor", "A metal under the coat: varnished or lacquered metal, car paint's metal base"),
    ("dielectric_rough", "An opaque rough dielectric under the coat (the paper's case): only its Fresnel "
                         "reflection shows; the light it refracts is absorbed"),
    ("slab", "No base: a free-standing thin transparent sheet that reflects and transmits (leaves of glass, "
             "foils, varnish films)"))]
# Complex IORs (R, G, B at about 650, 550, 450 nm) of common metals, rounded from published tables.
METALS = {k: micrograin.CONDUCTORS[k] for k in ("aluminium", "gold", "copper", "silver")}
METAL_ITEMS = [(k, k.capitalize(), f"A base of {k} (complex IOR, RGB)") for k in METALS] + [
    (CUSTOM, "Custom", "Set the metal's complex IOR (n, k) below")]


def kappa_text(kappa: float) -> str:
    """κ as the dialog and the panel show it: "κ 200", "κ 20000", "κ 1e+06"."""
    return f"κ {kappa:.0f}" if kappa < 1e5 else f"κ {kappa:.0e}"


def interface_text(p, side: str) -> str:
    """"roughness α 0.100 (κ 200)" for the top or bottom interface of thin-coat parameters ``p``."""
    return f"roughness α {getattr(p, f'roughness_{side}'):.3g} ({kappa_text(getattr(p, f'kappa_{side}'))})"


def sigma_a_from_color(color) -> list[float]:
    """The absorption coefficient σa whose transmittance over one unit of depth is ``color``: −ln(color), with
    black kept finite (σa ≤ the declaration's maximum)."""
    top = next(p.max for p in thin_coat.LAYER if p.name == "sigma_a")
    return [top if c <= 0.0 else min(-math.log(float(c)), top) for c in color]


class LAMINA_OT_add_thin_coat(bpy.types.Operator):
    """Add a new Thin Coat material to the active object (a clear or tinted transparent coat, rough on both sides,
    over a diffuse, metal or dielectric base, or a free-standing thin sheet), from a preset or custom"""

    bl_idname = "lamina.add_thin_coat"
    bl_label = "Add Thin Coat Material"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=COAT_PRESET_ITEMS, default=CUSTOM,
                                   description="A coat after the paper's Figs. 16 and 18 and common finishes, "
                                               "or Custom")
    roughness_top: _declared((thin_coat.ROUGHNESS["top"],), "roughness_top", soft_max=1.0, precision=3)
    roughness_bottom: _declared((thin_coat.ROUGHNESS["bottom"],), "roughness_bottom", soft_max=1.0, precision=3)
    eta: _declared(thin_coat.LAYER, "eta")
    coat_color: bpy.props.FloatVectorProperty(
        name="Coat Color", size=3, subtype="COLOR", default=(1.0, 1.0, 1.0), min=0.0, max=1.0,
        description="What is left of light that crosses one unit of depth straight down, exp(-sigma_a) per "
                    "channel: white is a clear coat; a thicker coat (Depth) looks deeper")
    depth: _declared(thin_coat.LAYER, "depth")
    base_type: bpy.props.EnumProperty(name="Base", items=BASE_ITEMS, default="diffuse",
                                      description="What is under the coat")
    base_color: _declared(thin_coat.BASE["diffuse"], "albedo")
    base_ior: _declared(thin_coat.BASE["dielectric_rough"], "ior")
    metal: bpy.props.EnumProperty(name="Metal", items=METAL_ITEMS, default="aluminium",
                                  description="What the metal base is made of")
    metal_ior: _declared(thin_coat.BASE["conductor"], "eta", name="IOR n", default=METALS["aluminium"][0])
    metal_k: _declared(thin_coat.BASE["conductor"], "k", name="Extinction k", default=METALS["aluminium"][1])
    bounces: _declared(thin_coat.STACK, "bounces")
    form: bpy.props.EnumProperty(name="Form", items=FORM_ITEMS, default="nodes")

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and hasattr(obj.data, "materials")

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self, width=380)

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "preset")
        if self.preset != CUSTOM:
            self._draw_preset(layout.column(align=True))
        else:
            self._draw_custom(layout.column())
        col = layout.column(align=True)
        col.prop(self, "bounces")
        col.label(text="0: the top interface only (fastest); each bounce adds a lobe,", icon="INFO")
        col.label(text="the first carries most of the energy: 2 is usually enough")
        layout.row().prop(self, "form", expand=True)

    def _draw_preset(self, col) -> None:
        """The preset's description and values (edit them on the Lamina node afterwards)."""
        p = thin_coat.params_from_dict(self.coat_dict())
        col.label(text=presets.description(thin_coat.ID, self.preset), icon="INFO")
        col.label(text=f"Top: {interface_text(p, 'top')}")
        if p.base.type != "diffuse":
            col.label(text=f"Bottom: {interface_text(p, 'bottom')}")
        sigma_d = ", ".join(f"{s * p.depth:.2g}" for s in p.sigma_a)
        col.label(text=f"Coat IOR η {p.eta:.2f}; absorption σa·d ({sigma_d})")
        col.label(text=f"Base: {base_text(p)}")
        col.label(text="Edit the values on the Lamina node afterwards")

    def _draw_custom(self, col) -> None:
        col.label(text="Interfaces (roughness α = sqrt(2 / κ))")
        for side in thin_coat.INTERFACES:
            split = col.split(factor=0.78)
            split.enabled = side == "top" or self.base_type != "diffuse"
            split.prop(self, f"roughness_{side}", slider=True)
            split.label(text=kappa_text(thin_coat.kappa_from_roughness(getattr(self, f"roughness_{side}"))))
        if self.base_type == "diffuse":
            col.label(text="The bottom roughness has no effect over a diffuse base")
        col.separator()
        col.prop(self, "eta")
        col.prop(self, "coat_color")
        col.prop(self, "depth")
        tint = ", ".join(f"{c ** (2.0 * self.depth):.2f}" for c in self.coat_color)
        col.label(text=f"Round trip at normal incidence keeps ({tint})")
        col.separator()
        col.prop(self, "base_type")
        if self.base_type == "diffuse":
            col.prop(self, "base_color")
        elif self.base_type == "dielectric_rough":
            col.prop(self, "base_ior")
        elif self.base_type == "conductor":
            draw_conductor(col, self, "metal")

    def coat_dict(self) -> dict:
        """The thin-coat dict the dialog describes (a preset's or the Custom settings) with the dialog's bounces."""
        if self.preset != CUSTOM:
            data = presets.load(thin_coat.ID, self.preset)
        else:
            data = {"roughness_top": self.roughness_top, "roughness_bottom": self.roughness_bottom,
                    "eta": self.eta, "sigma_a": sigma_a_from_color(self.coat_color), "depth": self.depth}
            base = {"type": self.base_type}
            if self.base_type == "diffuse":
                base["albedo"] = list(self.base_color)
            elif self.base_type == "dielectric_rough":
                base["ior"] = self.base_ior
            elif self.base_type == "conductor":
                ior, k = conductor_values(self, "metal")
                base["eta"], base["k"] = list(ior), list(k)
            data["base"] = base
        data = {k: v for k, v in data.items() if k not in ("name", "description")}
        return {**data, "bounces": self.bounces}

    def execute(self, context):
        try:
            validated = thin_coat.validate(self.coat_dict())
        except ParamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for w in validated.warnings:
            self.report({"WARNING"}, w)
        name = f"{thin_coat.LABEL} {wrap.label(self.preset)}" if self.preset != CUSTOM else thin_coat.LABEL
        mat = built_or_reported(self, lambda: lamina_material.new_material(thin_coat.ID, validated.params, self.form,
                                                                           name=name), "Could not build the Thin Coat material")
        if mat is None:
            return {"CANCELLED"}
        assign_to_active_slot(context.active_object, mat)
        warn_if_osl_is_off(self, context, self.form)
        self.report({"INFO"}, f"Added material {mat.name}")
        return {"FINISHED"}


def base_text(p) -> str:
    """The base of thin-coat parameters ``p`` in words, with its values."""
    b = p.base
    label = thin_coat.BASE_LABELS[b.type]
    if b.type == "diffuse":
        return f"{label}, colour ({', '.join(f'{c:.2f}' for c in b.albedo)})"
    if b.type == "dielectric_rough":
        return f"{label}, IOR {b.ior:.2f}"
    if b.type == "conductor":
        named = next((k for k, (n, k_) in METALS.items()
                      if all(math.isclose(a, c, rel_tol=1e-3) for a, c in zip(n + k_, tuple(b.eta) + tuple(b.k)))),
                     None)
        return f"{label}, {named}" if named else f"{label}, n ({', '.join(f'{c:.2f}' for c in b.eta)})"
    return label
