"""Blender operators and the window-manager settings they use."""
import bpy

from . import bake_ops, compare_op, material_ops, ms_ops

classes = (
    compare_op.LaminaCompareSettings,
    material_ops.LAMINA_OT_add_spongecake,
    material_ops.LAMINA_OT_set_form,
    material_ops.LAMINA_OT_add_porous_layer,
    material_ops.LAMINA_OT_add_thin_coat,
    ms_ops.LAMINA_OT_set_multiple_scattering,
    ms_ops.LAMINA_OT_rebake,
    compare_op.LAMINA_OT_compare,
    bake_ops.LAMINA_OT_bake_textures,
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
    ms_ops.register()


def unregister():
    ms_ops.unregister()
    del bpy.types.WindowManager.lamina_compare
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
