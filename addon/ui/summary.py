"""What the per-model panel summaries (``ui/<model id>.py``) share: which of the Lamina node's inputs a link drives."""
from __future__ import annotations

from ..nodes import MAPPINGS


def linked(node, name: str) -> bool:
    """Whether the node's input ``name`` (node-group name, or its OSL form with underscores) has a link."""
    socket = node.inputs.get(name) or node.inputs.get(name.replace(" ", "_"))
    return socket is not None and socket.is_linked


def linked_sockets(node, model_id: str, p) -> list:
    """The Lamina node's sockets (the mapping's ``Socket``: name and declared ``param``) that a link drives."""
    if node is None or model_id not in MAPPINGS:
        return []
    return [s for s in MAPPINGS[model_id].sockets(p) if s.kind != "shader" and linked(node, s.name)]
