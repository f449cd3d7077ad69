"""Multiple scattering for artists: turn it on or off, re-bake the network's prediction into the Lamina node's
``MS`` inputs, and re-bake automatically shortly after the parameters change (debounced, no undo steps)."""
from __future__ import annotations

import bpy

from ..models.params import ParamError
from ..nodes import material as lamina_material

REBAKE_DELAY = 0.3  # seconds after the latest edit


def _poll_lamina(context) -> bool:
    return lamina_material.is_lamina(getattr(context, "material", None))


class LAMINA_OT_set_multiple_scattering(bpy.types.Operator):
    """Turn the network-predicted multiple scattering of the active Lamina material on or off (stacks of 1 or 2
    layers), keeping the parameter values and the form"""

    bl_idname = "lamina.set_multiple_scattering"
    bl_label = "Set Multiple Scattering"
    bl_options = {"REGISTER", "UNDO"}

    enabled: bpy.props.BoolProperty(name="Multiple scattering", default=True)

    @classmethod
    def poll(cls, context):
        return _poll_lamina(context)

    def execute(self, context):
        mat = context.material
        try:
            lamina_material.set_multiple_scattering(mat, self.enabled)
        except ParamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        except Exception as e:  # noqa: BLE001 - e.g. OSL compile failure: report, leave the material as it was
            self.report({"ERROR"}, f"Could not rebuild {mat.name}: {e}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Multiple scattering {'on' if self.enabled else 'off'} for {mat.name}")
        return {"FINISHED"}


class LAMINA_OT_rebake(bpy.types.Operator):
    """Write the network's multiple-scattering prediction for the current parameters into the Lamina node
    (inputs driven by textures are left alone)"""

    bl_idname = "lamina.rebake"
    bl_label = "Re-bake Multiple Scattering"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _poll_lamina(context)

    def execute(self, context):
        mat = context.material
        if not lamina_material.ms_enabled(mat):
            self.report({"WARNING"}, f"{mat.name} has multiple scattering off: nothing to bake")
            return {"CANCELLED"}
        if lamina_material.bake_constants(mat):
            self.report({"INFO"}, f"Re-baked multiple scattering of {mat.name}")
        else:
            self.report({"INFO"}, f"Multiple scattering of {mat.name} was up to date")
        return {"FINISHED"}


# ------------------------------------------------------------------------------------------ auto re-bake

@bpy.app.handlers.persistent
def on_depsgraph_update(scene, depsgraph):
    """Schedule a re-bake when an updated material with multiple scattering is stale. Writing the new values
    triggers another update, but the material is no longer stale then, so nothing more is scheduled."""
    if not getattr(bpy.context.window_manager, "lamina_auto_rebake", False):
        return
    for update in depsgraph.updates:
        if not isinstance(update.id, bpy.types.Material):
            continue
        mat = update.id.original
        if lamina_material.ms_enabled(mat) and lamina_material.ms_is_stale(mat):
            _schedule_rebake()
            return


def _schedule_rebake() -> None:
    """One pending re-bake, REBAKE_DELAY after the latest edit (a slider drag re-bakes once, when it pauses)."""
    if bpy.app.timers.is_registered(rebake_stale):
        bpy.app.timers.unregister(rebake_stale)
    bpy.app.timers.register(rebake_stale, first_interval=REBAKE_DELAY)


def rebake_stale():
    """Timer callback, runs once: re-bake every stale material (outside operators, so no undo step)."""
    for mat in bpy.data.materials:
        if lamina_material.ms_enabled(mat) and lamina_material.ms_is_stale(mat):
            lamina_material.bake_constants(mat)


def register():
    bpy.types.WindowManager.lamina_auto_rebake = bpy.props.BoolProperty(
        name="Auto re-bake", default=True,
        description="Re-bake multiple scattering shortly after the layer parameters change")
    bpy.app.handlers.depsgraph_update_post.append(on_depsgraph_update)


def unregister():
    if bpy.app.timers.is_registered(rebake_stale):
        bpy.app.timers.unregister(rebake_stale)
    bpy.app.handlers.depsgraph_update_post.remove(on_depsgraph_update)
    del bpy.types.WindowManager.lamina_auto_rebake
