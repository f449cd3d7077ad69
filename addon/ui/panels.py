"""The Lamina panel: add a material, switch its form, compare it with the reference. What is particular to a model
(its Add button, its summary, extra boxes and compare settings) is drawn by its module ``ui/<model id>.py`` with
the operators of ``operators/<model id>.py``, both found through the model registry."""
from __future__ import annotations

import importlib
import textwrap

import bpy

from ..models import MEDIA, MODELS, REGISTRY
from ..nodes import fittable
from ..nodes import material as lamina_material
from ..operators import MODEL_OPERATORS, asset_library, budget_ops, compare_run
from ..operators.material_ops import MAPPING_ITEMS

MODEL_UI = {model_id: importlib.import_module(f".{model_id}", __package__) for model_id in REGISTRY}


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
        _draw_add_buttons(layout.column(align=True), mat)
        _draw_asset_library(layout)
        medium = next((MODEL_UI[m] for m in MEDIA if MODEL_UI[m].owns(mat)), None)
        if medium is not None:
            medium.draw_material(layout, context, mat)
            return
        if not lamina_material.is_lamina(mat):
            layout.label(text="The active material is not a Lamina material", icon="INFO")
            return
        model_ui = MODEL_UI[lamina_material.info(mat)["model"]]
        box = layout.box()
        _draw_summary(box, mat, model_ui)
        form = lamina_material.form_of(mat)
        row = box.row(align=True)
        for value, label in (("nodes", "Node group"), ("osl", "OSL")):
            op = row.operator("lamina.set_form", text=label, depress=(form == value))
            op.form = value
        if fittable(lamina_material.info(mat)["model"]):
            _draw_mapping(box, mat)
        scene = context.scene
        if form == "osl" and not (scene.render.engine == "CYCLES" and scene.cycles.shading_system):
            box.label(text="OSL renders only in Cycles with Open Shading Language on", icon="ERROR")
        box.label(text=model_ui.EDIT_HINT, icon="NODE")
        if hasattr(model_ui, "draw_extra"):
            model_ui.draw_extra(layout, context, mat)


def _draw_asset_library(layout) -> None:
    """Every preset in the Asset Browser: add the library (built if missing), or rebuild it once it is there."""
    if asset_library.library_entry(asset_library.library_folder(create=False)) is None:
        layout.operator("lamina.add_asset_library", icon="ASSET_MANAGER")
    else:
        layout.operator("lamina.build_asset_library", text="Rebuild Lamina Asset Library", icon="FILE_REFRESH")


def _draw_add_buttons(col, mat) -> None:
    """Each model's Add button, in registry order; greyed where it does not apply to the active material (what the
    operator's poll says, but visible)."""
    for operators in MODEL_OPERATORS.values():
        idname, icon = operators.ADD
        row = col.row(align=True)
        row.enabled = operators.can_add(mat) if hasattr(operators, "can_add") else True
        row.operator(idname, icon=icon)


def _draw_mapping(box, mat) -> None:
    """Analytic / Fitted / Auto, both mappings' predicted errors, which one renders, and a Refit when stale."""
    current = lamina_material.mapping_of(mat)
    row = box.row(align=True)
    for value, label, _ in MAPPING_ITEMS:
        row.operator("lamina.set_mapping", text=label, depress=(current == value)).mapping = value
    record = lamina_material.fit_record(mat)
    if record is None:
        return
    box.label(text=f"Renders the {record['used']} mapping", icon="CHECKMARK" if record["used"] == "fitted" else "INFO")
    if record["error"]:
        box.label(text="Predicted error: " + ", ".join(f"{name} {100 * e:.1f}%" for name, e in record["error"].items()))
    if record.get("note"):
        box.label(text=record["note"], icon="INFO")
    if lamina_material.fit_is_stale(mat):
        renders = "the old fit" if record["used"] == "fitted" else "the analytic mapping"
        box.label(text=f"Values changed since the fit: it renders {renders}", icon="ERROR")
        box.operator("lamina.set_mapping", text="Refit", icon="FILE_REFRESH").mapping = current


def _draw_summary(box, mat, model_ui) -> None:
    """The model's summary from the Lamina node's current inputs, or what stops it from being read."""
    model_id = lamina_material.info(mat)["model"]
    try:
        _, p = lamina_material.current_params(mat)
    except Exception as e:  # noqa: BLE001 - a hand-edited node tree: say so instead of failing to draw
        box.label(text=f"{mat.name}: {MODELS[model_id].LABEL}")
        box.label(text=f"Cannot read the Lamina node: {e}", icon="ERROR")
        return
    node = lamina_material.shader_node(mat)
    model_ui.draw_summary(box, mat, p, node)
    if node is None:
        box.label(text="The Lamina node was removed: showing the stored values", icon="ERROR")


class LaminaSubpanel:
    """Where the Lamina panel's sub-panels live."""
    bl_space_type = "NODE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Lamina"
    bl_parent_id = "LAMINA_PT_main"


class LAMINA_PT_compare(LaminaSubpanel, bpy.types.Panel):
    bl_label = "Compare with reference"

    @classmethod
    def poll(cls, context):
        return lamina_material.is_lamina(getattr(context, "material", None))

    def draw(self, context):
        layout = self.layout
        settings = context.window_manager.lamina_compare
        mat = context.material
        model_id = lamina_material.info(mat)["model"]
        wrapped = compare_run.refusal(*lamina_material.current_params(mat)) is not None
        if wrapped:
            layout.label(text="Comparison needs a reference bulk: this porous", icon="INFO")
            layout.label(text="layer wraps the material's own shader")
        col = layout.column(align=True)
        col.enabled = not wrapped
        col.prop(settings, "samples")
        col.prop(settings, "resolution")
        col.prop(settings, "scene")
        if hasattr(MODEL_UI[model_id], "draw_compare_settings"):
            MODEL_UI[model_id].draw_compare_settings(col, settings)
        if compare_run.has_principled(model_id):
            col.prop(settings, "principled")
        if compare_run.has_truth(model_id):
            col.prop(settings, "truth")
            if settings.truth:
                col.prop(settings, "truth_paths")
                col.prop(settings, "truth_stride")
        row = layout.row()
        row.enabled = not wrapped
        row.operator("lamina.compare", icon="IMAGE_REFERENCE")
        for line in settings.last_report.splitlines():
            layout.label(text=line)


class LAMINA_PT_budget(LaminaSubpanel, bpy.types.Panel):
    bl_label = "Fit to budget"

    @classmethod
    def poll(cls, context):
        mat = getattr(context, "material", None)
        return lamina_material.is_lamina(mat) and lamina_material.info(mat)["model"] in MODELS

    def draw(self, context):
        layout = self.layout
        mat = context.material
        reason = budget_ops.refusal(mat)
        row = layout.row(align=True)
        row.enabled = reason is None
        row.prop(context.window_manager, "lamina_error_budget", text="Budget")
        op = row.operator("lamina.fit_to_budget", icon="SORTTIME")
        op.budget, op.view = context.window_manager.lamina_error_budget, context.window_manager.lamina_budget_view
        measure = layout.row()
        measure.enabled = reason is None
        measure.prop(context.window_manager, "lamina_budget_view", expand=True)
        if reason:
            layout.label(text=reason, icon="INFO")
        if not context.scene.cycles.shading_system:
            layout.label(text="OSL is off in this scene: node groups only")
        record = lamina_material.budget_record(mat)
        if record is not None:
            for line in textwrap.wrap(record["summary"], 48):
                layout.label(text=line)
            if budget_ops.is_stale(mat, record):
                layout.label(text="Changed since: Fit to Budget again", icon="ERROR")


classes = (LAMINA_PT_main, LAMINA_PT_compare, LAMINA_PT_budget)
