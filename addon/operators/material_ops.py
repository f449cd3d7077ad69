"""What every model's Add dialog shares (``operators/<model id>.py`` holds each dialog), and the form switch.
Every operator is undoable and creates new data instead of editing the user's: an existing material is never
modified, only a slot's link may change."""
from __future__ import annotations

import math
import threading

import bpy

from .. import presets
from ..models import MODELS
from ..models.metals import METALS
from ..models.params import ParamError
from ..nodes import choice, fittable
from ..nodes import material as lamina_material
from . import blend_io
from .progress import begin_modal, end_modal

CUSTOM = "CUSTOM"
FORM_ITEMS = [("nodes", "Node group", "Native nodes: every device, fastest, most approximate"),
              ("osl", "OSL", "OSL script: CPU and OptiX only, exact Fresnel")]
MAPPING_ITEMS = [("analytic", "Analytic", "The mapping's own formulas of the view (instant)"),
                 ("fitted", "Fitted", "Per-view tables fitted to the reference (seconds, cached)"),
                 ("auto", "Auto", "Whichever of the two renders closer to the reference on the comparison scenes")]


def label(name: str) -> str:
    """A preset or metal identifier as the UI shows it: "rust_on_metal" -> "Rust on metal"."""
    return name.replace("_", " ").capitalize()


def preset_items(model_id: str, custom: str) -> list[tuple]:
    """The Preset enum of a model's Add dialog: Custom (tooltip ``custom``), then the model's presets."""
    return [(CUSTOM, "Custom", custom)] + [(n, label(n), presets.description(model_id, n))
                                           for n in presets.names(model_id)]


def declared(decl, param: str, **overrides):
    """A Blender property from the model's declaration of parameter ``param`` (range, label, description),
    with ``overrides`` (e.g. a dialog default)."""
    prm = next(p for p in decl if p.name == param)
    kw = {"name": prm.label, "default": prm.default, "description": prm.description,
          **{bound: getattr(prm, bound) for bound in ("min", "max") if getattr(prm, bound) is not None}}
    if prm.kind == "bool":
        return bpy.props.BoolProperty(**{**{k: v for k, v in kw.items() if k not in ("min", "max")}, **overrides})
    if prm.kind == "float":
        return bpy.props.FloatProperty(**({"subtype": prm.subtype} if prm.subtype else {}), **{**kw, **overrides})
    if prm.kind == "int":
        return bpy.props.IntProperty(**{**kw, **{k: int(v) for k, v in kw.items() if k in ("min", "max")},
                                        **overrides})
    subtype = "COLOR" if prm.kind == "color" and prm.max == 1.0 else "NONE"
    return bpy.props.FloatVectorProperty(size=3, subtype=subtype, **{**kw, **overrides})


def metal_items(choices: dict, what: str) -> list[tuple]:
    """A conductor enum over ``choices`` (name -> (n, k)), "a base of gold" etc. by ``what``, then Custom."""
    return [(k, label(k), f"{what} {label(k).lower()} (complex IOR, RGB)") for k in choices] + [
        (CUSTOM, "Custom", "Set the complex IOR (n, k) below")]


def draw_conductor(col, op, choice: str) -> None:
    """The conductor enum ``choice`` of a dialog, and its ``<choice>_ior`` / ``<choice>_k`` when Custom."""
    col.prop(op, choice)
    if getattr(op, choice) == CUSTOM:
        col.prop(op, f"{choice}_ior")
        col.prop(op, f"{choice}_k")


def conductor_values(op, choice: str, choices: dict = METALS) -> tuple:
    """(n, k) of the conductor a dialog's enum ``choice`` names in ``choices``, or of its Custom
    ``<choice>_ior`` / ``<choice>_k``."""
    name = getattr(op, choice)
    if name == CUSTOM:
        return tuple(getattr(op, f"{choice}_ior")), tuple(getattr(op, f"{choice}_k"))
    return choices[name]


def sigma_a_from_color(color, decl) -> list[float]:
    """The absorption coefficient σa whose transmittance over one unit of depth is ``color``: −ln(color), with
    black kept finite (σa ≤ the maximum of ``sigma_a`` in the declaration ``decl``)."""
    top = next(p.max for p in decl if p.name == "sigma_a")
    return [top if c <= 0.0 else min(-math.log(float(c)), top) for c in color]


def has_material_slots(context) -> bool:
    obj = context.active_object
    return obj is not None and hasattr(obj.data, "materials")


class AddMaterialDialog:
    """What every Add dialog shares (a mixin before ``bpy.types.Operator``): undoable, the Form choice, offered with an
    active object that has material slots, drawn as a dialog ``dialog_width`` wide."""

    bl_options = {"REGISTER", "UNDO"}
    dialog_width = 300

    form: bpy.props.EnumProperty(name="Form", items=FORM_ITEMS, default="nodes")
    mapping: bpy.props.EnumProperty(name="Mapping", items=MAPPING_ITEMS, default="auto",
                                    description="How the closures are found (models with a fitted mapping)")

    @classmethod
    def poll(cls, context):
        return has_material_slots(context)

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self, width=self.dialog_width)


def add_material(op, context, model_id: str, data: dict, name: str) -> set:
    """The end of an Add dialog: validate ``data`` (refusals reported, clamps warned), build the material in the
    dialog's form, link it in the active slot."""
    model = MODELS[model_id]
    try:
        validated = model.validate(data)
    except ParamError as e:
        op.report({"ERROR"}, str(e))
        return {"CANCELLED"}
    for w in validated.warnings:
        op.report({"WARNING"}, w)
    mat = built_or_reported(op, lambda: lamina_material.new_material(model_id, validated.params, op.form, name=name),
                            f"Could not build the {model.LABEL} material")
    if mat is None:
        return {"CANCELLED"}
    assign_to_active_slot(context.active_object, mat)
    warn_if_osl_is_off(op, context, op.form)
    op.report({"INFO"}, f"Added material {mat.name}")
    if fittable(model_id) and op.mapping != "analytic":
        choose_mapping(context, mat, op.mapping)
    return {"FINISHED"}


def choose_mapping(context, mat, mapping: str) -> None:
    """Give ``mat`` the ``mapping``: fitted and measured in a thread with a progress bar in the UI (the material
    renders as it is until then), at once in background mode (no event loop to finish a modal operator)."""
    if bpy.app.background or context.window is None:
        lamina_material.set_mapping(mat, mapping)
        return
    with context.temp_override(material=mat):
        bpy.ops.lamina.set_mapping("INVOKE_DEFAULT", mapping=mapping, material=mat.name)


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


class LAMINA_OT_set_mapping(bpy.types.Operator):
    """Choose how the active Lamina material's closures are found: analytic, fitted to the reference, or Auto (the
    closer of the two); also refits after the values changed"""

    bl_idname = "lamina.set_mapping"
    bl_label = "Set Lamina Mapping"
    bl_options = {"REGISTER", "UNDO"}

    mapping: bpy.props.EnumProperty(name="Mapping", items=MAPPING_ITEMS, default="auto")
    material: bpy.props.StringProperty(name="Material", description="The material (default: the active one)",
                                       options={"HIDDEN", "SKIP_SAVE"})

    @classmethod
    def poll(cls, context):
        return lamina_material.is_lamina(getattr(context, "material", None))

    def _material(self, context):
        return bpy.data.materials.get(self.material) if self.material else getattr(context, "material", None)

    def execute(self, context):
        mat = self._material(context)
        if not lamina_material.is_lamina(mat):
            self.report({"ERROR"}, f"{self.material or 'The active material'} is not a Lamina material")
            return {"CANCELLED"}
        try:
            lamina_material.set_mapping(mat, self.mapping)
        except Exception as e:  # noqa: BLE001 - report, leave the material as it was
            self.report({"ERROR"}, f"Could not set the mapping of {mat.name}: {e}")
            return {"CANCELLED"}
        record = lamina_material.fit_record(mat)
        if record is not None:
            self.report({"INFO"}, f"{mat.name}: {choice.describe(record)}")
        return {"FINISHED"}

    def invoke(self, context, event):
        """Fit and measure in a thread (numpy only), then rebuild on the main thread from the cache (in background
        mode, at once: no event loop runs a modal operator there)."""
        mat = self._material(context)
        if not lamina_material.is_lamina(mat) or self.mapping == "analytic" or bpy.app.background:
            return self.execute(context)
        model_id, p = lamina_material.current_params(mat)
        if not fittable(model_id):
            return self.execute(context)
        self.material = mat.name
        form = lamina_material.form_of(mat)
        try:
            asked = lamina_material.plan(mat, model_id, p, self.mapping)  # reads a driving texture: main thread
        except Exception as e:  # noqa: BLE001 - report, leave the material as it was
            self.report({"ERROR"}, f"Could not set the mapping of {mat.name}: {e}")
            return {"CANCELLED"}
        # plain state the thread writes: the operator is freed when Esc ends it, the fit goes on and is cached
        self._state = state = {"fraction": 0.0, "error": None, "driven": asked.driven is not None}

        def work():
            try:
                choice.choose(model_id, p, form, asked.mapping, asked.driven,
                              lambda fraction: state.__setitem__("fraction", fraction))
            except Exception as e:  # noqa: BLE001 - reported on the main thread
                state["error"] = e

        self._thread = threading.Thread(target=work, daemon=True)
        self._thread.start()
        self._ticks = 0
        self._timer = begin_modal(self, context, 0.25, 100)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            end_modal(context, self._timer)
            self.report({"WARNING"}, f"{self.material}: mapping left as it was (the fit finishes in the background "
                                     "and is cached)")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._thread.is_alive():
            self._ticks += 1
            # about 10 s; a driven input: the choice at its middle value, then the fits of its other values
            state = self._state
            percent = min(45, self._ticks) + 50 * state["fraction"] if state["driven"] else min(95, self._ticks * 2)
            context.window_manager.progress_update(percent)
            if context.workspace is not None:
                context.workspace.status_text_set(f"Lamina: fitting and measuring {self.material} (Esc: leave it)")
            return {"RUNNING_MODAL"}
        end_modal(context, self._timer)
        if self._state["error"] is not None:
            self.report({"ERROR"}, f"Could not fit {self.material}: {self._state['error']}")
            return {"CANCELLED"}
        return self.execute(context)



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


classes = (LAMINA_OT_set_form, LAMINA_OT_set_mapping)
