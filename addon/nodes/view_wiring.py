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
            if link.from_node.get(VIEW_TAG) and (table is None or _table_name(link.from_node) != table.name):
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
    """Lamina's view-table nodes in ``tree``: the Image Texture nodes, their coordinate groups and, for a table over a
    colour input's channels, the nodes that split and join the channels."""
    return [n for n in tree.nodes if n.get(VIEW_TAG)]


TABLE_KEY = "lamina_view_table"  # the table whose value a lookup's output node gives (nodes inside a lookup: "")


def _table_name(tex) -> str | None:
    """The table a lookup's output node gives: its ``TABLE_KEY``, else its image's name (an Image Texture)."""
    return tex.get(TABLE_KEY, getattr(getattr(tex, "image", None), "name", None))


def _lookup(tree, node, table, follows=None):
    """The node whose Color output is ``table`` at the view (the one already in ``tree``, or new ones): an Image
    Texture with its coordinates, whose ``Axis`` value (if any) is the output that feeds ``follows`` (a table has an
    axis only for a linked input: ``material.texel_energy``); for an axis over a colour's channels, one such lookup
    per channel at that channel's value, joined by a Combine Color."""
    found = next((n for n in tree.nodes if n.get(VIEW_TAG) and _table_name(n) == table.name), None)
    if found is not None:
        return found
    x, y = node.location.x - 320, node.location.y - 420
    value = None if table.axis is None else linked_from(follows)
    if table.axis is None or not table.axis.channels:
        return _texture(tree, node, table, (x, y), value)
    split = _new(tree, node, "ShaderNodeSeparateColor", (x - 660, y))
    tree.links.new(value, split.inputs[0])
    join = _new(tree, node, "ShaderNodeCombineColor", (x + 220, y))
    join[TABLE_KEY] = table.name
    for c in range(3):
        tex = _texture(tree, node, table, (x, y - 300 * c), split.outputs[c])
        tex[TABLE_KEY] = ""
        channel = _new(tree, node, "ShaderNodeSeparateColor", (x + 110, y - 300 * c))
        tree.links.new(tex.outputs["Color"], channel.inputs[0])
        tree.links.new(channel.outputs[c], join.inputs[c])
    return join


def _new(tree, node, kind: str, location):
    n = tree.nodes.new(kind)
    n[VIEW_TAG] = True
    n.parent = node.parent
    n.location = location
    return n


def _texture(tree, node, table, location, value=None):
    """An Image Texture node of ``table``'s image with its coordinates group; ``value`` (an output socket) feeds the
    group's input where the table has an ``Axis``."""
    tex = _new(tree, node, "ShaderNodeTexImage", location)
    tex.image = bpy.data.images.get(table.name) or _image(table)
    tex.interpolation, tex.extension = "Linear", "EXTEND"
    tex.label = "Lamina view table"
    coords = _new(tree, node, "ShaderNodeGroup", (location[0] - 220, location[1]))
    coords.node_tree = _coordinates_group(table)
    tree.links.new(coords.outputs[0], tex.inputs["Vector"])
    if table.axis is not None:
        tree.links.new(value, coords.inputs[0])
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
    """Lamina's lookup nodes that feed nothing, or only other such nodes."""
    ours = lookups(tree)
    idle: list = []
    grew = True
    while grew:
        fresh = [n for n in ours if n not in idle and all(link.to_node in idle for o in n.outputs for link in o.links)]
        idle += fresh
        grew = bool(fresh)
    return idle
