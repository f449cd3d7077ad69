"""The panel on a neural medium: the medium (albedo, mean free path, g), its bake on the active object (baked,
stale or missing; where it is stored; which lamps count) and Bake Scattering. A medium is drawn instead of the BSDF
summary (``owns``): it has no shader form to switch and no BSDF comparison."""
from __future__ import annotations

from ..nodes import neural_medium as medium_nodes
from ..operators import medium_bake
from ..operators.neural_medium import LAMINA_OT_bake_medium

EDIT_HINT = "Edit the medium on the Lamina Scatter / Absorption nodes (then bake again)"


def owns(mat) -> bool:
    return medium_nodes.is_medium(mat)


def draw_material(layout, context, mat) -> None:
    box = layout.box()
    box.label(text=f"{mat.name}: neural medium")
    try:
        p = medium_nodes.current_params(mat)
    except Exception as e:  # noqa: BLE001 - a hand-edited node tree: say so instead of failing to draw
        box.label(text=f"Cannot read the medium: {e}", icon="ERROR")
        return
    col = box.column(align=True)
    col.label(text="Albedo " + ", ".join(f"{a:.3f}" for a in p.albedo))
    col.label(text="Mean free path " + ", ".join(f"{m:.3g}" for m in p.mean_free_path) + " (scene units)")
    col.label(text=f"Anisotropy g {p.g:+.2f}")
    box.label(text=EDIT_HINT, icon="NODE")
    _draw_bake(layout, context)


def _draw_bake(layout, context) -> None:
    obj = context.active_object
    box = layout.box()
    box.label(text="Orders ≥ 2 (baked)")
    if medium_bake.medium_material(obj) is None:
        box.label(text="Select an object that uses this medium to bake it", icon="INFO")
        return
    state, line = medium_bake.bake_state(obj, context.scene)
    icon = {"baked": "CHECKMARK", "stale": "ERROR", "unknown": "ERROR"}.get(state, "INFO")
    box.label(text=line, icon=icon)
    col = box.column(align=True)
    col.label(text=f"Stored in the mesh {obj.data.name} (point attributes)")
    if obj.data.users > 1:
        col.label(text=f"{obj.data.users} objects share this mesh and its bake", icon="ERROR")
    lamps, notes = medium_bake.scene_lamps(context.scene)
    col.label(text=f"{len(lamps)} lamp(s); other objects cast shadows")
    for note in notes:
        col.label(text=note, icon="INFO")
    if obj.animation_data is not None or any(getattr(o, "animation_data", None) for o in context.scene.objects
                                               if o.type == "LIGHT"):
        col.label(text="Animated: the bake holds one frame", icon="ERROR")
    bounces = context.scene.cycles.volume_bounces
    if bounces > 0:
        col.label(text=f"Volume bounces = {bounces}: Cycles also renders orders ≥ 2,", icon="ERROR")
        col.label(text="and the bake adds them again (set 0 in Light Paths)")
    text = "Bake Scattering" if state == "none" else "Re-bake Scattering"
    box.operator(LAMINA_OT_bake_medium.bl_idname, text=text, icon="RENDER_STILL")
