"""The panel on a porous layer: grains, filling factor, the equivalent roughness (Eq. 18) and the bulk."""
from __future__ import annotations

from ..models import MODELS
from ..models import micrograin as model
from ..nodes import material as lamina_material
from .summary import linked

EDIT_HINT = "Edit the filling factor and grains on the Lamina node"


def draw_summary(box, mat, p, node) -> None:
    box.label(text=f"{mat.name}: micrograin porous layer")
    col = box.column(align=True)
    grain = model.GRAIN_LABELS[p.grain.type].lower()
    if p.grain.type == "dielectric":
        grain += f" (IOR {p.grain.ior:.2f})"
    col.label(text=f"Grains: {grain}")
    textured = node is not None and linked(node, "Filling Factor")
    col.label(text="Filling factor: texture-driven" if textured else f"Filling factor: {p.filling_factor:.2f}")
    if node is not None and (textured or linked(node, "Anfractuosity")):
        col.label(text="Equivalent roughness: varies (texture-driven inputs)")
    else:
        col.label(text=f"Equivalent roughness α: {p.roughness:.3f} (anfractuosity {p.anfractuosity:.2f})")
    if p.bulk.type == model.WRAPPED:
        col.label(text="Bulk: the material's own shader (Bulk input)")
    else:
        bulk = getattr(MODELS.get(p.bulk.type), "LABEL", p.bulk.type)
        col.label(text=f"Bulk: {bulk} (node {lamina_material.BULK_NODE})")


def draw_compare_settings(col, settings) -> None:
    col.prop(settings, "blends")
