"""The ``expr`` backend that builds Cycles shader nodes inside a node group (works on SVM, every GPU, EEVEE)."""
from __future__ import annotations

import math
import numbers

import bpy

from .expr import (BULK_INPUT, MAX_CONDUCTOR_WEIGHT, MAX_MIX_WEIGHT, METAL_MIN_RATIO, MIN_COS, MIN_LOG, MIN_TANGENT,
                   lobe_fresnel, schlick_at_view)

GENERATOR_VERSION = 11  # bump when generated shaders change, so cached groups are not reused
COLUMN = 190
ROW = 150


class NodeValue:
    """An output socket (float or colour) plus its column in the layout. Arithmetic with a value of another type
    (not a number, tuple or NodeValue) is left to that value (``NotImplemented``)."""

    def __init__(self, backend: "NodeBackend", socket, kind: str, depth: int):
        self.b, self.socket, self.kind, self.depth = backend, socket, kind, depth

    def _op(self, op, o, swap=False):
        if not isinstance(o, (NodeValue, int, float, tuple, list)):
            return NotImplemented
        return self.b.binary(op, o, self) if swap else self.b.binary(op, self, o)

    def __add__(self, o):
        return self._op("ADD", o)

    def __radd__(self, o):
        return self._op("ADD", o, True)

    def __sub__(self, o):
        return self._op("SUBTRACT", o)

    def __rsub__(self, o):
        return self._op("SUBTRACT", o, True)

    def __mul__(self, o):
        return self._op("MULTIPLY", o)

    def __rmul__(self, o):
        return self._op("MULTIPLY", o, True)

    def __truediv__(self, o):
        return self._op("DIVIDE", o)

    def __rtruediv__(self, o):
        return self._op("DIVIDE", o, True)

    def __neg__(self):
        return self.b.binary("MULTIPLY", self, -1.0)


def _kind(v) -> str:
    if isinstance(v, NodeValue):
        return v.kind
    return "color" if isinstance(v, (tuple, list)) else "float"


def _depth(*values) -> int:
    return 1 + max((v.depth for v in values if isinstance(v, NodeValue)), default=0)


class NodeBackend:
    form = "nodes"

    def __init__(self, tree: bpy.types.NodeTree, group_input, group_output):
        self.tree = tree
        self.nodes = tree.nodes
        self.links = tree.links
        self.group_input = group_input
        self.group_output = group_output
        self._rows: dict[int, int] = {}
        self._shader = None
        self._geometry = None
        self._frame = None
        self._made: dict[tuple, NodeValue] = {}  # pure math nodes by operation and inputs (``_pure``)
        self._lamberts: dict[str, object] = {}  # summed colours of closures without parameters (``_lambert``)
        self._locations: dict[str, tuple] = {}  # node name → location, written by ``finish``

    # -- layout
    # Every write to a node or link makes Blender update the whole tree, so building a tree costs its size squared:
    # a new node is renamed at once (Blender's search for a free "Math.NNN" name grows with the nodes of that name)
    # and the locations are written together in ``finish`` (one write for the tree).
    def _node(self, bl_idname: str, depth: int, **props):
        node = self.nodes.new(bl_idname)
        node.name = f"n{len(self.nodes)}"
        for k, v in props.items():
            setattr(node, k, v)
        row = self._rows.get(depth, 0)
        self._rows[depth] = row + 1
        self._locations[node.name] = (depth * COLUMN, -row * ROW)
        node.hide = bl_idname in ("ShaderNodeMath", "ShaderNodeVectorMath")
        return node

    def shared(self, name: str, body, *args) -> list:
        """``body(backend, *args)`` (a list of float or colour values) as a Group node of the nested group ``name``,
        made on first use and then reused by every tree of the file: the caller's tree stays small (see ``_node``).
        ``name`` must identify what ``body`` computes."""
        group = shared_group(name, body, [_kind(a) for a in args])
        depth = _depth(*args) + 1
        node = self._node("ShaderNodeGroup", depth)
        node.node_tree = group
        for value, socket in zip(args, node.inputs):
            self._link_or_set(value, socket)
        kinds = [SHARED_KINDS[item.socket_type] for item in group.interface.items_tree if item.in_out == "OUTPUT"]
        return [NodeValue(self, socket, kind, depth) for socket, kind in zip(node.outputs, kinds)]

    def _place_nodes(self):
        """Write the locations ``_node`` chose, leaving the other nodes where they are."""
        flat = [0.0] * (2 * len(self.nodes))
        self.nodes.foreach_get("location", flat)
        for i, node in enumerate(self.nodes):
            if node.name in self._locations:
                flat[2 * i:2 * i + 2] = self._locations[node.name]
        self.nodes.foreach_set("location", flat)

    def _link_or_set(self, value, socket):
        if isinstance(value, NodeValue):
            self.links.new(value.socket, socket)
        elif isinstance(value, (tuple, list)):
            n = len(socket.default_value)
            socket.default_value = (tuple(float(x) for x in value) + (1.0,) * n)[:n]  # RGB into RGBA: alpha 1
        else:
            socket.default_value = float(value) if not hasattr(socket.default_value, "__len__") else (value,) * 3

    # -- inputs and geometry
    def input(self, name: str, kind: str) -> NodeValue:
        return NodeValue(self, self.group_input.outputs[name], "color" if kind == "vector" else kind, 0)

    def geometry(self):
        if self._geometry is None:
            geo = self._node("ShaderNodeNewGeometry", 0)  # its Tangent is the closures' default tangent
            self._geometry = (geo.outputs["Normal"], geo.outputs["Incoming"], geo.outputs["Tangent"],
                              geo.outputs["Backfacing"])
        return self._geometry

    def cos_view(self):
        return self.maximum(self.dot(self.normal(), self.view()), MIN_COS)

    def direction(self, v: NodeValue) -> NodeValue:
        """Tangent-space direction → world: x·T + y·(N×T) + z·N, normalised."""
        n, t = self.normal(), self.tangent()
        sep = self._node("ShaderNodeSeparateXYZ", _depth(v))
        self._link_or_set(v, sep.inputs[0])
        comp = [NodeValue(self, sep.outputs[i], "float", _depth(v)) for i in range(3)]
        bitangent = self.cross(n, t)
        world = self.scale(t, comp[0]) + self.scale(bitangent, comp[1]) + self.scale(n, comp[2])
        return self._vector("NORMALIZE", world)

    def normal(self):
        return NodeValue(self, self.geometry()[0], "color", 1)

    def tangent(self):
        """The Geometry node's tangent, the x axis of the closures' tangent frame (``direction``)."""
        return NodeValue(self, self.geometry()[2], "color", 1)

    def cross(self, a, b):
        return self._vector("CROSS_PRODUCT", a, b)

    def fract(self, x):
        return self._math("FRACT", x)

    def combine(self, x, y, z):
        """A vector of three floats (Combine XYZ)."""
        node = self._node("ShaderNodeCombineXYZ", _depth(x, y, z))
        for value, socket in zip((x, y, z), node.inputs):
            self._link_or_set(value, socket)
        return NodeValue(self, node.outputs[0], "color", _depth(x, y, z))

    def view(self):
        """The unit view direction ωo: the Geometry node's Incoming."""
        return NodeValue(self, self.geometry()[1], "color", 1)

    def backfacing(self):
        return NodeValue(self, self.geometry()[3], "float", 1)

    def upper_hemisphere(self, d: NodeValue) -> NodeValue:
        """``d``, or −d where it points below the tangent plane: d · (1 − 2 [d·N < 0])."""
        below = self.step_below(self.dot(d, self.normal()), 0.0)
        return self.scale(d, 1.0 - 2.0 * below)

    def dot(self, a, b):
        return self._vector("DOT_PRODUCT", a, b, out="Value")

    def dot_view(self, d: NodeValue):
        return self.dot(d, self.view())

    def tangent_plane(self, d: NodeValue):
        n, t = self.normal(), self.tangent()
        v = d - self.scale(n, self.dot(d, n))
        use_v = self._math("GREATER_THAN", self._vector("LENGTH", v, out="Value"), MIN_TANGENT)
        mix = self._node("ShaderNodeMix", _depth(v, use_v), data_type="VECTOR")
        self._link_or_set(use_v, mix.inputs["Factor"])
        self._link_or_set(t, mix.inputs[4])  # A (vector)
        self._link_or_set(self._vector("NORMALIZE", v), mix.inputs[5])  # B (vector)
        return NodeValue(self, mix.outputs[1], "color", _depth(v, use_v))

    # -- math
    def binary(self, op: str, a, b):
        if isinstance(a, NodeValue) and _is_identity(op, b):
            return a  # a · 1, a / 1, a + 0, a − 0: no node (Cycles would evaluate one where ``a`` varies)
        if isinstance(b, NodeValue) and _is_identity(op, a, swapped=True):
            return b
        if "color" in (_kind(a), _kind(b)):
            if _kind(a) == "float" and op == "MULTIPLY":
                a, b = b, a
            if _kind(b) == "float" and op in ("MULTIPLY", "DIVIDE"):
                return self.scale(a, b if op == "MULTIPLY" else 1.0 / b)
            return self._vector(op, _as_color(a), _as_color(b))
        return self._math(op, a, b)

    def _math(self, op: str, *args):
        return self._pure("ShaderNodeMath", op, args, 0, "float")

    def _vector(self, op: str, *args, out: str = "Vector"):
        return self._pure("ShaderNodeVectorMath", op, args, out, "float" if out == "Value" else "color")

    def _pure(self, bl_idname: str, op: str, args, out, kind: str) -> NodeValue:
        """A Math or Vector Math node of ``op`` on ``args``, made once per tree: the same operation on the same
        sockets and constants reuses the node that computes it (Cycles' SVM evaluates every node)."""
        key = (bl_idname, op, out, tuple(_identity(a) for a in args))
        if key not in self._made:
            node = self._node(bl_idname, _depth(*args), operation=op)
            for value, socket in zip(args, node.inputs):
                self._link_or_set(value, socket)
            self._made[key] = NodeValue(self, node.outputs[out], kind, _depth(*args))
        return self._made[key]

    def _per_channel(self, fn, x):
        """``fn`` of a float, or of each channel of a colour (Separate XYZ, three Math nodes, Combine XYZ)."""
        if _kind(x) != "color":
            return fn(x)
        if not isinstance(x, NodeValue):
            x = tuple(x)
            sep = None
        else:
            sep = self._node("ShaderNodeSeparateXYZ", _depth(x))
            self._link_or_set(x, sep.inputs[0])
        parts = [fn(NodeValue(self, sep.outputs[i], "float", _depth(x)) if sep else x[i]) for i in range(3)]
        comb = self._node("ShaderNodeCombineXYZ", _depth(*parts))
        for value, socket in zip(parts, comb.inputs):
            self._link_or_set(value, socket)
        return NodeValue(self, comb.outputs[0], "color", _depth(*parts))

    def exp(self, x):
        return self._per_channel(lambda v: self._math("EXPONENT", v), x)

    def log(self, x):
        return self._per_channel(lambda v: self._math("LOGARITHM", self.maximum(v, MIN_LOG), math.e), x)

    def sqrt(self, x):
        return self._per_channel(lambda v: self._math("SQRT", self.maximum(v, 0.0)), x)

    def abs(self, x):
        return self._per_channel(lambda v: self._math("ABSOLUTE", v), x)

    def cos(self, x):
        return self._math("COSINE", x)

    def acos(self, x):
        return self._math("ARCCOSINE", x)  # Cycles' safe_acosf clamps to [-1, 1]

    def sin(self, x):
        return self._math("SINE", x)

    def asin(self, x):
        return self._math("ARCSINE", x)  # Cycles' safe_asinf clamps to [-1, 1]

    def atan2(self, y, x):
        return self._math("ARCTAN2", y, x)

    def multiply_add(self, a, s, c):
        """a · s + c in one node (Math or Vector Math Multiply Add)."""
        if "color" in (_kind(a), _kind(c)):
            return self._vector("MULTIPLY_ADD", _as_color(a), s, _as_color(c))
        return self._math("MULTIPLY_ADD", a, s, c)

    def channel(self, color, i: int):
        sep = self._node("ShaderNodeSeparateXYZ", _depth(color))
        self._link_or_set(color, sep.inputs[0])
        return NodeValue(self, sep.outputs[i], "float", _depth(color))

    def channel_mean(self, color):
        return self._vector("DOT_PRODUCT", _as_color(color), (1.0 / 3.0,) * 3, out="Value")

    def rotated_tangent(self, angle):
        """The Geometry node's tangent turned by ``angle`` about the normal: cos·T + sin·(N × T)."""
        n, t = self.normal(), self.tangent()
        return self.scale(t, self.cos(angle)) + self.scale(self.cross(n, t), self.sin(angle))

    def ramp(self, values, x):
        """``expr.NumpyBackend.ramp`` as a Color Ramp (linear) with a stop per knot: Cycles tabulates a ramp at 256
        points and interpolates linearly, so 16 stops at i / 15 (multiples of 1/255) are reproduced exactly."""
        ramp = self._node("ShaderNodeValToRGB", _depth(x))
        ramp.color_ramp.interpolation = "LINEAR"
        elements = ramp.color_ramp.elements  # a new ramp has stops at 0 and 1; the others are inserted in order
        last = len(values) - 1
        for i in range(1, last):
            elements.new(i / last)
        for element, value in zip(elements, values):
            element.color = (*(float(v) for v in value), 1.0)
        self._link_or_set(x, ramp.inputs["Fac"])
        return NodeValue(self, ramp.outputs["Color"], "color", _depth(x))

    @staticmethod
    def has_metal() -> bool:
        return hasattr(bpy.types, "ShaderNodeBsdfMetallic")

    def step_below(self, x, edge):
        return self._math("LESS_THAN", x, edge)

    def maximum(self, a, b):
        if "color" in (_kind(a), _kind(b)):
            return self._vector("MAXIMUM", _as_color(a), _as_color(b))
        return self._math("MAXIMUM", a, b)

    def minimum(self, a, b):
        if "color" in (_kind(a), _kind(b)):
            return self._vector("MINIMUM", _as_color(a), _as_color(b))
        return self._math("MINIMUM", a, b)

    def scale(self, color, s):
        if isinstance(color, NodeValue) and _is_identity("MULTIPLY", s):
            return color
        node = self._node("ShaderNodeVectorMath", _depth(color, s), operation="SCALE")
        self._link_or_set(color, node.inputs[0])
        self._link_or_set(s, node.inputs["Scale"])
        return NodeValue(self, node.outputs["Vector"], "color", _depth(color, s))

    # -- closures, summed with Add Shader nodes into the group output
    def _closure(self, bl_idname: str, inputs: dict, **props):
        depth = _depth(*inputs.values()) + 1
        node = self._node(bl_idname, depth, **props)
        for name, value in inputs.items():
            self._link_or_set(value, node.inputs[name])
        self._add(node.outputs[0], depth)

    def _add(self, shader_socket, depth):
        if self._shader is None:
            self._shader = (shader_socket, depth)
            return
        prev, prev_depth = self._shader
        d = max(depth, prev_depth) + 1
        add = self._node("ShaderNodeAddShader", d)
        self.links.new(prev, add.inputs[0])
        self.links.new(shader_socket, add.inputs[1])
        self._shader = (add.outputs[0], d)

    def bulk(self, weight):
        """The group's Shader input scaled by ``weight``: a Mix Shader towards its empty (black) second input."""
        depth = _depth(weight) + 1
        mix = self._node("ShaderNodeMixShader", depth)
        self._link_or_set(1.0 - weight, mix.inputs["Fac"])
        self.links.new(self.group_input.outputs[BULK_INPUT], mix.inputs[1])
        self._add(mix.outputs[0], depth)

    def finish(self):
        for bl_idname, color in self._lamberts.items():
            self._closure(bl_idname, {"Color": color})
        self._lamberts.clear()
        if self._shader is not None:
            self._locations[self.group_output.name] = ((self._shader[1] + 1) * COLUMN, 0)
            self.links.new(self._shader[0], self.group_output.inputs["BSDF"])
        self._remove_dead_nodes()
        self._place_nodes()

    def _remove_dead_nodes(self):
        """Remove the nodes that feed nothing (what only fed a closure a fitted table or pruning replaced): Cycles
        would skip them, and the group reads better without them."""
        keep = {self.group_input.name, self.group_output.name}
        while True:
            dead = [n for n in self.nodes if n.name not in keep and n.outputs and not any(o.is_linked for o in n.outputs)]
            if not dead:
                return
            for node in dead:
                self.nodes.remove(node)

    def _roughness(self, alpha):
        return self.sqrt(alpha)  # closures in nodes take Blender's roughness r, with α = r² (research notes §6)

    def glossy(self, color, alpha_x, alpha_y, normal, tangent=None, f0=None):
        """Glossy BSDF (GGX). Mappings pass alpha_x ≤ alpha_y; the node's parametrisation is
        α_u = r²(1 − a), α_v = r²/(1 − a) (Cycles' node_glossy_bsdf), so r⁴ = α_x α_y, a = 1 − sqrt(α_x/α_y)."""
        if f0 is not None:
            color = schlick_at_view(self, color, f0, normal)
        inputs = {"Color": color, "Normal": normal}
        if alpha_x is alpha_y:
            inputs["Roughness"] = self._roughness(alpha_x)
        else:
            inputs.update(self._anisotropic(alpha_x, alpha_y, tangent))
        self._closure("ShaderNodeBsdfGlossy", inputs, distribution="GGX")

    def _anisotropic(self, alpha_x, alpha_y, tangent) -> dict:
        """Roughness, Anisotropy and Tangent inputs for α_x ≤ α_y along ``tangent`` (``glossy``)."""
        return {"Roughness": self.sqrt(self.sqrt(alpha_x * alpha_y)),
                "Anisotropy": 1.0 - self.sqrt(alpha_x / alpha_y), "Tangent": tangent}

    metal_min_ratio = METAL_MIN_RATIO

    def metal(self, alpha_x, alpha_y, tangent, eta, k, weight=1.0):
        """Blender 4.3+'s Metallic BSDF (GGX, physical conductor) through a Mix Shader of factor ``weight`` (see
        ``expr.NumpyBackend.metal``). With roughness r and anisotropy a it has α = r² / s along its Tangent and r² s
        across, s² = 1 − 0.9a ≥ ``METAL_MIN_RATIO`` (Cycles' svm_node_closure_bsdf): its Tangent is our bitangent
        N × T (α_y, the larger), s² = α_x / α_y, r² = α_y s."""
        ratio = self.maximum(alpha_x / alpha_y, METAL_MIN_RATIO)
        inputs = {"IOR": eta, "Extinction": k, "Roughness": self.sqrt(alpha_y * self.sqrt(ratio)),
                  "Anisotropy": (1.0 - ratio) * (1.0 / (1.0 - METAL_MIN_RATIO)),
                  "Tangent": self.cross(self.normal(), tangent)}
        depth = _depth(weight, *inputs.values()) + 1
        metal = self._node("ShaderNodeBsdfMetallic", depth, distribution="GGX", fresnel_type="PHYSICAL_CONDUCTOR")
        for name, value in inputs.items():
            self._link_or_set(value, metal.inputs[name])
        mix = self._node("ShaderNodeMixShader", depth + 1)
        self._link_or_set(weight, mix.inputs["Fac"])
        self.links.new(metal.outputs[0], mix.inputs[2])
        self._add(mix.outputs[0], depth + 1)

    def diffuse(self, color):
        self._lambert("ShaderNodeBsdfDiffuse", color)

    def translucent(self, color):
        self._lambert("ShaderNodeBsdfTranslucent", color)

    def transparent(self, color):
        self._lambert("ShaderNodeBsdfTransparent", color)

    def _lambert(self, bl_idname: str, color):
        """Closures without parameters (all on the shading normal) are summed by colour and made once, in
        ``finish``: the same light for fewer closures to evaluate."""
        previous = self._lamberts.get(bl_idname)
        self._lamberts[bl_idname] = color if previous is None else self.binary("ADD", previous, color)

    def conductor(self, color, alpha, eta, k):
        """Metallic BSDF with the physical conductor Fresnel (4.3+), whose colour inputs are then unused. 4.2 has no
        such node: a Principled metal with the complex IOR's normal-incidence reflectance as F0 (F82 model).
        [approx: conductor-f0-blender-4.2] The (grey) weight w goes through Mix Shaders, whose factor Cycles
        clamps to [0, 1], so w up to ``MAX_CONDUCTOR_WEIGHT`` is split into min(w, 1), min(max(w − 1, 0), 1), ..."""
        depth = _depth(color, alpha, eta, k) + 1
        if hasattr(bpy.types, "ShaderNodeBsdfMetallic"):
            metal = self._node("ShaderNodeBsdfMetallic", depth, distribution="GGX", fresnel_type="PHYSICAL_CONDUCTOR")
            inputs = {"Roughness": self._roughness(alpha), "IOR": eta, "Extinction": k}
        else:
            k2 = k * k if isinstance(k, NodeValue) else tuple(float(x) * float(x) for x in k)
            f0 = ((eta - 1.0) * (eta - 1.0) + k2) / ((eta + 1.0) * (eta + 1.0) + k2)
            metal = self._node("ShaderNodeBsdfPrincipled", depth, distribution="GGX")
            inputs = {"Base Color": f0, "Metallic": 1.0, "Roughness": self._roughness(alpha)}
        for name, value in inputs.items():
            self._link_or_set(value, metal.inputs[name])
        gray = self._vector("DOT_PRODUCT", color, (1.0 / 3.0,) * 3, out="Value")
        for j in range(MAX_CONDUCTOR_WEIGHT):
            part = self.minimum(self.maximum(gray - float(j), 0.0), 1.0) if j else self.minimum(gray, 1.0)
            mix = self._node("ShaderNodeMixShader", max(_depth(part), depth) + 1)
            self._link_or_set(part, mix.inputs["Fac"])
            self.links.new(metal.outputs[0], mix.inputs[2])
            self._add(mix.outputs[0], max(_depth(part), depth) + 1)

    def beckmann(self, color, alpha, eta=None, normal=None):
        """Beckmann reflection around ``normal`` (a direction; the shading normal by default). Without ``eta``: a
        Glossy BSDF (Beckmann, no Fresnel). With ``eta`` (the dielectric Fresnel per microfacet; ``color`` must be
        grey): Blender 4.3+'s Metallic BSDF (Beckmann, physical conductor of IOR η and extinction 0, whose Fresnel is
        then the dielectric one) scaled by Mix and Add Shaders (``_scaled``); Blender 4.2 has no such node: a Glossy
        BSDF whose colour takes the lobe's mean Fresnel (``lobe_fresnel``)."""
        at_normal = {} if normal is None else {"Normal": normal}
        if eta is None or not hasattr(bpy.types, "ShaderNodeBsdfMetallic"):
            if eta is not None:
                color = lobe_fresnel(self, color, eta, alpha)
            self._closure("ShaderNodeBsdfGlossy", {"Color": color, "Roughness": self._roughness(alpha), **at_normal},
                          distribution="BECKMANN")
            return
        depth = _depth(color, alpha, eta, *at_normal.values()) + 1
        metal = self._node("ShaderNodeBsdfMetallic", depth, distribution="BECKMANN", fresnel_type="PHYSICAL_CONDUCTOR")
        for name, value in {"Roughness": self._roughness(alpha), "IOR": eta, "Extinction": (0.0, 0.0, 0.0),
                            **at_normal}.items():
            self._link_or_set(value, metal.inputs[name])
        gray = self._vector("DOT_PRODUCT", color, (1.0 / 3.0,) * 3, out="Value") if _kind(color) == "color" else color
        self._scaled(metal.outputs[0], gray, depth)

    def _scaled(self, shader_socket, weight, depth):
        """The closure ``shader_socket`` times a weight in [0, MAX_MIX_WEIGHT]: Mix Shaders (whose factor Cycles clamps
        to [0, 1]) with factors min(max(w − j, 0), 1), j = 0, 1, ..., summed (Cycles sums the weights of every path to a
        closure; a doubling tree of Add Shaders would be exponential in Cycles' weight transform)."""
        for j in range(MAX_MIX_WEIGHT):
            part = self.minimum(self.maximum(weight - float(j), 0.0), 1.0) if j else self.minimum(weight, 1.0)
            d = max(_depth(part), depth) + 1
            mix = self._node("ShaderNodeMixShader", d)
            self._link_or_set(part, mix.inputs["Fac"])
            self.links.new(shader_socket, mix.inputs[2])
            self._add(mix.outputs[0], d)

    def refraction(self, color, alpha, ior, normal, distribution="beckmann"):
        """Refraction BSDF (no Fresnel; ``distribution`` "beckmann" or "ggx") around ``normal`` (a direction)."""
        self._closure("ShaderNodeBsdfRefraction", {"Color": color, "Roughness": self._roughness(alpha), "IOR": ior,
                                                   "Normal": normal}, distribution=distribution.upper())

    def velvet(self, color, sigma):
        """Sheen BSDF, Ashikhmin distribution (its Roughness is the velvet's σ)."""
        self._closure("ShaderNodeBsdfSheen", {"Color": color, "Roughness": sigma}, distribution="ASHIKHMIN")

    def glossy_toon(self, color, size, smooth):
        """Toon BSDF, glossy component."""
        self._closure("ShaderNodeBsdfToon", {"Color": color, "Size": size, "Smooth": smooth}, component="GLOSSY")

    def diffuse_toon(self, color, size, smooth):
        """Toon BSDF, diffuse component."""
        self._closure("ShaderNodeBsdfToon", {"Color": color, "Size": size, "Smooth": smooth}, component="DIFFUSE")

    def dielectric(self, color, alpha, ior):
        self._closure("ShaderNodeBsdfGlass", {"Color": color, "Roughness": self._roughness(alpha), "IOR": ior},
                      distribution="GGX")


SHARED_SOCKETS = {"float": "NodeSocketFloat", "color": "NodeSocketVector"}  # colours as data (``shared``)
SHARED_KINDS = {socket: kind for kind, socket in SHARED_SOCKETS.items()}


def shared_group(name: str, body, kinds: list[str]):
    """The nested group of ``NodeBackend.shared``: inputs of ``kinds``, outputs what ``body`` returns, named ``name``
    and the generator's version (a file made by an earlier Lamina keeps its groups, which this one does not reuse);
    made on first use, then found by that name."""
    name = f"{name} (v{GENERATOR_VERSION})"
    return bpy.data.node_groups.get(name) or _new_shared_group(name, body, kinds)


def _new_shared_group(name: str, body, kinds: list[str]):
    group = bpy.data.node_groups.new(name, "ShaderNodeTree")
    for i, kind in enumerate(kinds):
        group.interface.new_socket(f"Input {i + 1}", in_out="INPUT", socket_type=SHARED_SOCKETS[kind])
    group_in, group_out = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    b = NodeBackend(group, group_in, group_out)
    values = body(b, *(NodeValue(b, group_in.outputs[i], kind, 0) for i, kind in enumerate(kinds)))
    for j, value in enumerate(values):
        group.interface.new_socket(f"Output {j + 1}", in_out="OUTPUT", socket_type=SHARED_SOCKETS[_kind(value)])
        b._link_or_set(value, group_out.inputs[j])
    b._locations[group_out.name] = ((1 + max((_depth(v) for v in values), default=0)) * COLUMN, 0)
    b._place_nodes()
    return group


def _identity(v):
    """What an input of a pure node is: the socket it is linked from, or its constant value."""
    if isinstance(v, NodeValue):
        return ("socket", v.socket.as_pointer())
    if isinstance(v, (tuple, list)):
        return tuple(float(x) for x in v)
    return float(v)


def _is_identity(op: str, v, swapped: bool = False) -> bool:
    """Whether the constant ``v`` leaves the other operand of ``op`` as it is: 1 for MULTIPLY (either side) and
    DIVIDE (divisor), 0 for ADD (either side) and SUBTRACT (subtrahend); ``swapped``: ``v`` is the first operand."""
    if not isinstance(v, numbers.Real):
        return False
    unit = {"MULTIPLY": 1.0, "ADD": 0.0} if swapped else {"MULTIPLY": 1.0, "DIVIDE": 1.0, "ADD": 0.0, "SUBTRACT": 0.0}
    return op in unit and float(v) == unit[op]


def _as_color(v):
    if isinstance(v, NodeValue) or isinstance(v, (tuple, list)):
        return v
    return (float(v),) * 3
