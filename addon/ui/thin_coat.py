"""The panel on a thin coat: base, both interfaces' roughness and κ, η, the absorption σa·d, the bounces, and which
inputs textures drive."""
from __future__ import annotations

from ..models import thin_coat as model
from ..operators.thin_coat import base_text, interface_text
from .summary import linked_sockets

EDIT_HINT = "Edit the coat and the base on the Lamina node"


def draw_summary(box, mat, p, node) -> None:
    box.label(text=f"{mat.name}: thin coat over {model.BASE_LABELS[p.base.type].lower()}")
    linked = linked_sockets(node, model.ID, p)
    base_params = {prm for declared in model.BASE.values() for prm in declared}
    driven = {s.param.name for s in linked if s.param not in base_params}  # the coat's own inputs
    col = box.column(align=True)
    col.label(text=f"Base: {base_text(p)}")
    for side in model.INTERFACES:
        name = side.capitalize()
        if side == "bottom" and p.base.type == "diffuse":
            col.label(text="Bottom: no effect over a diffuse base")
        elif {f"kappa_{side}", f"roughness_{side}"} & driven:
            col.label(text=f"{name}: roughness texture-driven (κ = 2 / α² per texel)")
        else:
            col.label(text=f"{name}: {interface_text(p, side)}")
    col.label(text="Coat IOR η: texture-driven" if "eta" in driven else f"Coat IOR η {p.eta:.3f}")
    if {"sigma_a", "depth"} & driven:
        col.label(text="Absorption σa·d: texture-driven")
    else:
        col.label(text=f"Absorption σa·d: ({', '.join(f'{s * p.depth:.3g}' for s in p.sigma_a)})")
    col.label(text=f"Bounces: {p.bounces} (subsurface reflections; 0 = the top interface only)")
    if p.merge_orders:
        col.label(text="Orders ≥ 2 merged into one lobe (Cycles forms)")
    if linked:
        col.label(text="Texture-driven: " + ", ".join(s.name for s in linked), icon="TEXTURE")
    elif node is not None:
        col.label(text="No texture-driven inputs")
