"""Feed a Lamina node's inputs from ``view_table.ViewTable``s: a packed float image per table (named by its content,
shared by the materials with the same values) in an Image Texture node (Linear, Extend) whose Vector comes from the
nested group that computes the view's texel coordinates (from the view, and from the value fed to the input a table's
``Axis`` follows). The nodes are tagged ``VIEW_TAG``; they are native, so a saved file renders the same without
Lamina."""
from __future__ import annotations

import hashlib
import math

import bpy

from .image_values import linked_from
from .node_backend import NodeBackend, shared_group

VIEW_TAG = "lamina_view"


def wire(node, tables: list[tuple]) -> list:
    """Link each (input socket of ``node``, ``ViewTable``, the input of ``node`` its ``Axis`` follows or None) in
    ``tables`` from its table's lookup, unlink inputs fed by Lamina's lookups that ``tables`` does not name, and
    return Lamina's lookup nodes that feed nothing any more (for the caller to remove with their images). An input
    the user linked from another node is left alone."""
    tree = node.id_data
    wanted = {socket.identifier: table for socket, table, _ in tables}
    for socket in node.inputs:
        for link in socket.links:
            table = wanted.get(socket.identifier)
            if link.from_node.get(VIEW_TAG) and (table is None or _image_name(link.from_node) != table.name):
                tree.links.remove(link)
    lookups = {}
    for socket, table, follows in tables:
        if socket.is_linked:  # by the user, or by this table's lookup
            continue
        if table.name not in lookups:
            lookups[table.name] = _lookup(tree, node, table, follows)
        tree.links.new(lookups[table.name].outputs["Color"], socket)
    return _unused(tree)


def fed(socket) -> bool:
    """Whether ``socket`` is linked from a Lamina view lookup."""
    return any(link.from_node.get(VIEW_TAG) for link in socket.links)


def lookups(tree) -> list:
    """Lamina's view-table nodes in ``tree``: the Image Texture nodes and their coordinate groups."""
    return [n for n in tree.nodes if n.get(VIEW_TAG)]


def _image_name(tex) -> str | None:
    return getattr(getattr(tex, "image", None), "name", None)


def _lookup(tree, node, table, follows=None):
    """The Image Texture node of ``table`` (the one already in ``tree``, or a new one with its coordinates; those of a
    table with an ``Axis`` take the value of what feeds ``follows``, or its constant)."""
    found = next((n for n in tree.nodes if n.get(VIEW_TAG) and _image_name(n) == table.name), None)
    if found is not None:
        return found
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex[VIEW_TAG] = True
    tex.image = bpy.data.images.get(table.name) or _image(table)
    tex.interpolation, tex.extension = "Linear", "EXTEND"
    tex.label = "Lamina view table"
    tex.parent = node.parent
    tex.location = (node.location.x - 320, node.location.y - 420)
    coords = tree.nodes.new("ShaderNodeGroup")
    coords[VIEW_TAG] = True
    coords.node_tree = _coordinates_group(table)
    coords.parent = node.parent
    coords.location = (tex.location.x - 220, tex.location.y)
    tree.links.new(coords.outputs[0], tex.inputs["Vector"])
    if table.axis is not None:
        source = linked_from(follows)
        if source is None:
            coords.inputs[0].default_value = follows.default_value
        else:
            tree.links.new(source, coords.inputs[0])
    return tex


def _image(table):
    """A new float image of ``table``'s pixels, Non-Color, packed into the file."""
    pixels = table.pixels()
    height, width = pixels.shape[:2]
    image = bpy.data.images.new(table.name, width, height, alpha=True, float_buffer=True, is_data=True)
    image.alpha_mode = "CHANNEL_PACKED"
    image.pixels.foreach_set(pixels.ravel())
    image.pack()
    return image


def _coordinates_group(table):
    """The nested group whose output is the view's texel coordinates in ``table``'s image (``ViewTable.at``); with an
    ``Axis``, its input is the value of the input the axis follows."""
    (sx, ox), (sy, oy) = table.texel_coordinates()
    rows, columns = table.shape
    name = f"Lamina view coordinates {rows}x{columns} asin from {table.lowest:.6g}"
    if table.axis is None:
        return shared_group(name, lambda b: [_coordinates(b, sx, ox, sy, oy, columns > 1)], [])
    axis = table.axis
    digest = hashlib.md5(repr(axis.to_json()[1:]).encode()).hexdigest()[:8]
    return shared_group(f"{name} over {digest}",
                        lambda b, value: [_coordinates(b, sx, ox, sy, oy, False, axis.position(value, b))], ["float"])


def _coordinates(b: NodeBackend, sx, ox, sy, oy, over_azimuth: bool, along=None):
    """The texel coordinates of the view (and of the value's position ``along`` an axis); a table of one azimuth
    (its two equal columns) needs none of the azimuth math."""
    x = ox if along is None else b.multiply_add(along, sx, ox)  # beyond the ends, Extend takes the end's column
    if over_azimuth:
        view, normal, tangent = b.view(), b.normal(), b.tangent()
        turn = b.fract(b.atan2(b.dot(view, b.cross(normal, tangent)), b.dot(view, tangent)) * (0.5 / math.pi))
        x = b.multiply_add(turn, sx, ox)
    return b.combine(x, b.multiply_add(b.asin(b.sqrt(b.cos_view())), sy, oy), 0.0)


def _unused(tree) -> list:
    """Lamina's lookup nodes that feed nothing: Image Textures without links out, and coordinate groups that feed
    only those."""
    ours = lookups(tree)
    idle = [n for n in ours if n.bl_idname == "ShaderNodeTexImage" and not n.outputs["Color"].is_linked]
    return idle + [n for n in ours if n.bl_idname == "ShaderNodeGroup"
                   and all(link.to_node in idle for o in n.outputs for link in o.links)]
