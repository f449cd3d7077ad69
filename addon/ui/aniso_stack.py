"""The panel on an anisotropic stack: one line per interface and per non-empty medium, and which inputs textures
drive."""
from __future__ import annotations

from ..models import aniso_stack as model
from ..operators.aniso_stack import stack_lines
from .summary import linked_sockets

EDIT_HINT = "Edit the roughnesses, rotations and media on the Lamina node"
# Every interface's tangent is the Geometry node's (Cycles' generated one, UV maps or not), turned by its Rotation.
TANGENT_NOTE = "Tangents: radial about the object's Z (any mesh, no UV map needed), turned by Rotation"


def draw_summary(box, mat, p, node) -> None:
    box.label(text=f"{mat.name}: anisotropic stack of {len(p.interfaces)} interface(s)")
    col = box.column(align=True)
    for line in stack_lines(p):
        col.label(text=line)
    driven = {s.name for s in linked_sockets(node, model.ID, p)}
    if driven:
        col.label(text=f"Texture-driven: {', '.join(sorted(driven))}")
    col.label(text=TANGENT_NOTE, icon="ORIENTATION_NORMAL")
