"""Blender operators and the window-manager settings they use. Each model's Add dialog lives in
``operators/<model id>.py`` (``classes``, and ``ADD``: the panel's button), found through the model registry."""
import importlib

import bpy

from ..models import REGISTRY
from . import asset_library, bake_ops, budget_ops, compare_op, material_ops, ms_ops

MODEL_OPERATORS = {model_id: importlib.import_module(f".{model_id}", __name__) for model_id in REGISTRY}

classes = (
    compare_op.LaminaCompareSettings,
    *material_ops.classes,
    *(cls for module in MODEL_OPERATORS.values() for cls in module.classes),
    ms_ops.LAMINA_OT_set_multiple_scattering,
    ms_ops.LAMINA_OT_rebake,
    compare_op.LAMINA_OT_compare,
    bake_ops.LAMINA_OT_bake_textures,
    *budget_ops.classes,
    *asset_library.classes,
)


def register():
    done = []
    try:
        for cls in classes:
            bpy.utils.register_class(cls)
            done.append(cls)
    except Exception:  # leave nothing half-registered behind
        for cls in reversed(done):
            bpy.utils.unregister_class(cls)
        raise
    bpy.types.WindowManager.lamina_compare = bpy.props.PointerProperty(type=compare_op.LaminaCompareSettings)
    bpy.types.WindowManager.lamina_error_budget = budget_ops.budget_setting()
    bpy.types.WindowManager.lamina_budget_view = budget_ops.view_setting()
    ms_ops.register()


def unregister():
    ms_ops.unregister()
    del bpy.types.WindowManager.lamina_budget_view
    del bpy.types.WindowManager.lamina_error_budget
    del bpy.types.WindowManager.lamina_compare
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
