"""Write a shading formula once, run it on three backends.

A model's Cycles mapping (``nodes/<model>.py``) is a function ``shade(b, inputs)`` that builds the
closure mix with the backend ``b``: float/colour arithmetic through Python operators and ``b.exp`` &c.,
closures through ``b.glossy`` &c. The same function then

* emits OSL source (``OslBackend``, here),
* builds Cycles math nodes (``nodes.node_backend.NodeBackend``, bpy), and
* evaluates in numpy what Cycles will render (``NumpyBackend``, here) so the mapping's error against the
  reference can be measured without Blender.

Values are scalars or RGB colours. Directions are tangent-space vectors (x tangent, y bitangent, z normal);
the backend turns them into world space. The view direction is ``wo``; nothing may depend on ``wi``:
closure weights in Cycles can only depend on the view (research notes §6).
"""
from __future__ import annotations

import numpy as np

from . import closures_np
from .numpy_math import MIN_LOG, NumpyMath

# Smallest cosine a weight formula divides by: keeps grazing pixels finite (they get weight → 0 anyway).
MIN_COS = 1e-6
# Script-node input fed by the Geometry node's Tangent: Cycles' default tangent for anisotropic closures
# (radial around z of the generated coordinates); OSL's dPdu differs from it (measured, tests/blender).
TANGENT_INPUT = "LaminaTangent"
# A direction projected into the tangent plane shorter than this is replaced by the default tangent.
MIN_TANGENT = 1e-6
# Largest grey weight a node group gives a closure without a colour input (Mix Shaders, whose factor Cycles clamps to
# [0, 1], one per unit: ``NodeBackend._scaled``); mappings cap such weights at it so that both forms agree.
MAX_MIX_WEIGHT = 4
# The largest grey weight of the node group's conductor (two Mix Shaders: ``NodeBackend.conductor``).
MAX_CONDUCTOR_WEIGHT = 2
# The smallest α_x / α_y of the node group's anisotropic Metallic BSDF (aspect² = 1 − 0.9 · anisotropy ≥ 0.1).
METAL_MIN_RATIO = 0.1
# The Shader input that carries the material a model wraps (micrograin's bulk).
BULK_INPUT = "Bulk"


# --------------------------------------------------------------------------------------------- numpy


LAMBERT_CLOSURES = ("diffuse", "translucent", "transparent")  # closures without parameters (on the normal)


class NumpyBackend(NumpyMath):
    """Evaluate a mapping in float64 for N view directions ``wo`` (local frame, z = normal). ``inputs``: socket name
    → value, or a ``view_table.ViewTable`` that the material feeds the input from (evaluated at ``wo``).

    ``metallic_node``: whether the node group predicted (form "nodes") has Blender 4.3+'s Metallic BSDF node (a
    Beckmann reflection with the dielectric Fresnel per microfacet); Blender 4.2's takes the Fresnel at the view
    (``lobe_fresnel``). The Blender tests set it from the running Blender."""

    metallic_node = True

    def __init__(self, wo: np.ndarray, inputs: dict, form: str = "osl", bulk=None):
        self.form = form  # "osl" or "nodes": which Cycles form to predict
        self.wo = np.asarray(wo, dtype=np.float64)
        self.n = len(self.wo)
        self._inputs = inputs
        self._bulk = bulk  # wo -> NumpyBackend holding the closures of the shader plugged into a Shader input
        self.closures: list[tuple] = []

    # -- inputs and geometry
    def input(self, name: str, kind: str):
        v = self._inputs[name]
        v = np.asarray(v.at(self.wo, self._inputs) if hasattr(v, "at") else v, dtype=np.float64)
        if kind == "float":
            return np.broadcast_to(v, (self.n,)).copy()
        return np.broadcast_to(v, (self.n, 3)).copy()

    def cos_view(self):
        return np.maximum(self.wo[:, 2], MIN_COS)

    def direction(self, v):
        """Tangent-space direction → unit vector in the frame the closures use (here the local frame)."""
        v = np.broadcast_to(v, (self.n, 3))
        return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)

    def normal(self):
        return np.broadcast_to(np.array([0.0, 0.0, 1.0]), (self.n, 3))

    def backfacing(self):
        """1 where the viewer is below the surface (Cycles then flips the normal towards it), else 0."""
        return np.where(self.wo[:, 2] < 0.0, 1.0, 0.0)

    def upper_hemisphere(self, d):
        """The unit direction ``d`` (from ``direction``), or −d where it points below the tangent plane."""
        return np.where(d[:, 2:3] < 0.0, -d, d)

    def view(self):
        """The unit view direction ωo (a direction, as ``direction`` returns)."""
        return self.wo / np.maximum(np.linalg.norm(self.wo, axis=1, keepdims=True), 1e-12)

    def dot(self, a, b):
        return np.einsum("ij,ij->i", a, b)

    def dot_view(self, d):
        return self.dot(d, self.wo)

    def tangent_plane(self, d):
        """``d`` projected into the tangent plane, normalised (the default tangent where it vanishes)."""
        v = d * np.array([1.0, 1.0, 0.0])
        length = np.linalg.norm(v, axis=1, keepdims=True)
        return np.where(length > MIN_TANGENT, v / np.maximum(length, MIN_TANGENT), np.array([1.0, 0.0, 0.0]))

    def scale(self, color, s):
        return color * np.asarray(s)[..., None]

    def rotated_tangent(self, angle):
        """The tangent turned by ``angle`` (radians) about the normal, towards the bitangent."""
        angle = np.broadcast_to(angle, (self.n,))
        return np.stack([np.cos(angle), np.sin(angle), np.zeros(self.n)], axis=1)

    def shared(self, name: str, body, *args) -> list:
        """``body(self, *args)``: a list of values (node groups build it once, as a nested group ``name``)."""
        return body(self, *args)

    def ramp(self, values, x):
        """The piecewise linear colour through ``values`` (K, 3) on K uniform knots in [0, 1], at ``x`` clamped to
        [0, 1] (a Color Ramp)."""
        values = np.asarray(values, dtype=np.float64)
        knots = np.linspace(0.0, 1.0, len(values))
        x = np.clip(np.broadcast_to(x, (self.n,)), 0.0, 1.0)
        return np.stack([np.interp(x, knots, values[:, c]) for c in range(3)], axis=1)

    def has_metal(self) -> bool:
        """Whether the predicted form has ``metal`` (OSL; node groups on Blender 4.3+)."""
        return self.form == "osl" or self.metallic_node

    # -- closures (recorded, evaluated by ``evaluate``)
    def _add(self, kind, color, **kw):
        self.closures.append((kind, color, kw))

    def glossy(self, color, alpha_x, alpha_y, normal, tangent=None, f0=None):
        if f0 is not None and self.form == "nodes":
            color, f0 = schlick_at_view(self, color, f0, normal), None
        if tangent is None:
            tangent = self.tangent_plane(np.broadcast_to([1.0, 0.0, 0.0], (self.n, 3)))
        self._add("ggx", color, alpha_x=alpha_x, alpha_y=alpha_y, normal=normal, tangent=tangent, f0=f0)

    def metal(self, alpha_x, alpha_y, tangent, eta, k, weight=1.0):
        """Anisotropic GGX with the exact Fresnel of complex IOR η + ik per microfacet (k = 0: a dielectric's
        reflection), ``alpha_x`` ≤ ``alpha_y``, ``alpha_x`` along ``tangent``, times a grey ``weight`` in [0, 1]
        (node groups: ``alpha_x`` ≥ ``metal_min_ratio`` ``alpha_y``)."""
        self._add("ggx_conductor", np.ones((self.n, 3)) * np.asarray(weight, dtype=float)[..., None],
                  alpha_x=alpha_x, alpha_y=alpha_y, tangent=tangent, eta=eta, k=k)

    @property
    def metal_min_ratio(self) -> float:
        return METAL_MIN_RATIO if self.form == "nodes" else 0.0

    def diffuse(self, color):
        self._add("diffuse", color)

    def translucent(self, color):
        self._add("translucent", color)

    def transparent(self, color):
        self._add("transparent", color)

    def closure_count(self) -> int:
        """How many closures the node group and OSL forms make of those recorded: the ones without parameters are
        summed into one per kind (``NodeBackend._lambert``)."""
        lambert = [kind for kind, _, _ in self.closures if kind in LAMBERT_CLOSURES]
        return len(self.closures) - len(lambert) + len(set(lambert))

    def _grey(self, color, cap: float):
        """What a node group renders of a closure it weighs in grey through Mix Shaders: the channels' mean, capped."""
        grey = np.minimum(np.mean(np.broadcast_to(color, (self.n, 3)), axis=1), cap)
        return np.repeat(grey[:, None], 3, axis=1)

    def conductor(self, color, alpha, eta, k):
        """The physical conductor; node groups weigh it in grey (``NodeBackend.conductor``)."""
        if self.form == "nodes":
            color = self._grey(color, MAX_CONDUCTOR_WEIGHT)
        self._add("conductor", color, alpha=alpha, eta=eta, k=k)

    def dielectric(self, color, alpha, ior):
        self._add("dielectric", color, alpha=alpha, ior=ior)

    def beckmann(self, color, alpha, eta=None, normal=None):
        """Beckmann reflection around ``normal`` (a direction; the shading normal by default); with ``eta`` the
        dielectric Fresnel per microfacet (Blender 4.2's node group: its mean over the lobe, ``lobe_fresnel``)."""
        if eta is not None and self.form == "nodes":
            color, eta = (self._grey(color, MAX_MIX_WEIGHT), eta) if self.metallic_node else (
                lobe_fresnel(self, color, eta, alpha), None)
        self._add("beckmann", color, alpha=alpha, eta=eta, **({} if normal is None else {"normal": normal}))

    def refraction(self, color, alpha, ior, normal, distribution="beckmann"):
        """Refraction without Fresnel (``distribution``: "beckmann" or "ggx") around ``normal`` (a direction) into
        a medium of relative ``ior``."""
        self._add(f"{distribution}_refraction", color, alpha=alpha, ior=ior, normal=normal)

    def velvet(self, color, sigma):
        """Cycles' Ashikhmin velvet around the shading normal (``closures_np.velvet``)."""
        self._add("velvet", color, sigma=sigma)

    def sheen(self, color, roughness):
        """Cycles' Microfiber sheen around the shading normal (``closures_np.sheen``)."""
        self._add("sheen", color, roughness=roughness)

    def glossy_toon(self, color, size, smooth):
        """Cycles' glossy Toon BSDF around the shading normal (``closures_np.glossy_toon``)."""
        self._add("glossy_toon", color, size=size, smooth=smooth)

    def diffuse_toon(self, color, size, smooth):
        """Cycles' diffuse Toon BSDF around the shading normal (``closures_np.diffuse_toon``)."""
        self._add("diffuse_toon", color, size=size, smooth=smooth)

    def bulk(self, weight):
        """The shader plugged into the ``Bulk`` input, scaled by ``weight``."""
        for kind, color, kw in self._bulk(self.wo).closures:
            self._add(kind, np.broadcast_to(color, (self.n, 3)) * np.asarray(weight)[..., None], **kw)

    def transparency(self) -> np.ndarray:
        """The summed weight of transparent closures (light passing straight through), (N, 3)."""
        return sum((np.broadcast_to(c, (self.n, 3)) for k, c, _ in self.closures if k == "transparent"),
                   np.zeros((self.n, 3)))

    def sampling_leak_blender42(self) -> np.ndarray:
        """Blender 4.2 only, (N, 3): what its GGX sampling adds under a uniform environment of radiance 1 reached
        by BSDF sampling alone (the furnace scene), from light below a tilted closure normal that evaluation
        gives 0 (``closures_np.ggx_sampling_leak``); zero for closures around the shading normal."""
        out = np.zeros((self.n, 3))
        for kind, color, kw in self.closures:
            if kind == "ggx":
                out += color * closures_np.ggx_sampling_leak(self.wo, **kw)
        return out

    def evaluate(self, wi: np.ndarray) -> np.ndarray:
        """The BSDF value (no cosine) that the recorded closures give for light from ``wi``."""
        wi = np.asarray(wi, dtype=np.float64)
        f = np.zeros((self.n, 3))
        for kind, color, kw in self.closures:
            f += color * closures_np.EVAL[kind](wi, self.wo, **kw)
        return f

    def unit_albedo(self, kind: str, kw: dict, quadratures=closures_np.ALBEDO, quadrature=(64, 128)) -> np.ndarray:
        """The directional albedo (N, 3) at the recorded views of one closure ``kind`` with parameters ``kw`` (as
        recorded) and a white colour: its own quadrature in ``quadratures`` (``closures_np.ALBEDO``: Lambert exactly,
        Beckmann lobes of any sharpness in slope space), else ``reference.scenes.directional_albedo``'s direction grid
        of ``quadrature`` nodes, each view's parameters taken from its row. Kept for the last few hundred closures
        (``_unit_albedos``): the mappings and fits of one material share most of theirs."""
        from ..reference.scenes import directional_albedo

        key = _albedo_key(kind, kw, self.wo, kind in quadratures and quadratures[kind], quadrature)
        if key not in _unit_albedos:
            if kind in quadratures:
                value = np.broadcast_to(quadratures[kind](self.wo, **kw), (self.n, 3))
            else:
                def evaluate(wi, rows):
                    taken = {k: self._per_row(v, rows) for k, v in kw.items()}
                    return closures_np.EVAL[kind](wi, self.wo[rows], **taken)

                value = directional_albedo(evaluate, self.wo, quadrature, by_row=True)
            if len(_unit_albedos) >= UNIT_ALBEDOS_KEPT:
                _unit_albedos.clear()
            _unit_albedos[key] = value
        return _unit_albedos[key]

    def _per_row(self, v, rows):
        a = np.asarray(v) if v is not None else None
        return a[rows] if a is not None and a.ndim and a.shape[0] == self.n else v


UNIT_ALBEDOS_KEPT = 512
_unit_albedos: dict = {}


def _albedo_key(kind: str, kw: dict, wo: np.ndarray, own, quadrature) -> tuple:
    """What a closure's unit albedo depends on: its kind and parameters, the views, and how it is integrated."""
    parts = [kind.encode(), wo.tobytes(), repr(own).encode(), repr(quadrature).encode()]
    for name in sorted(kw):
        value = kw[name]
        parts.append(name.encode() + (b"none" if value is None else np.asarray(value, dtype=float).tobytes()))
    return tuple(parts)


def closure_furnace(backend_at, wo: np.ndarray, quadrature=(64, 128), quadratures=closures_np.ALBEDO) -> np.ndarray:
    """What a white furnace shows towards ``wo`` (N, 3) through the closures that ``backend_at(wo)`` records (a
    shaded ``NumpyBackend``): each closure's colour times its ``NumpyBackend.unit_albedo`` (with ``quadratures``:
    ``closures_np.ALBEDO``, or ``closures_np.SHARP_ALBEDO`` which adds GGX reflection; the others on a ``quadrature``
    direction grid), plus transparency."""
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    n = len(wo)
    padded = np.concatenate([wo, wo[:1]]) if n == 3 else wo  # see ``NumpyBackend._per_row``
    b = backend_at(padded)
    out = b.transparency()
    for kind, color, kw in b.closures:
        if kind != "transparent":  # no BSDF value: counted in ``transparency``
            out = out + np.broadcast_to(color, (b.n, 3)) * b.unit_albedo(kind, kw, quadratures, quadrature)
    return out[:n]


# ----------------------------------------------------------------------------------------------- OSL


class OslValue:
    """An OSL expression string with its type ("float", "color", or "vector" / "normal" for directions)."""

    def __init__(self, code: str, kind: str):
        self.code = code
        self.kind = kind

    def _bin(self, other, op, swap=False):
        if not isinstance(other, (OslValue, int, float, tuple, list)):
            return NotImplemented  # e.g. a lazy value of a mapping's own (nodes.thin_coat) takes over
        o = _osl(other)
        kinds = (self.kind, o.kind)
        kind = "vector" if {"vector", "normal"} & set(kinds) else "color" if "color" in kinds else "float"
        a, b = (o, self) if swap else (self, o)
        return OslValue(f"({a.code} {op} {b.code})", kind)

    def __add__(self, o):
        return self._bin(o, "+")

    def __radd__(self, o):
        return self._bin(o, "+", True)

    def __sub__(self, o):
        return self._bin(o, "-")

    def __rsub__(self, o):
        return self._bin(o, "-", True)

    def __mul__(self, o):
        return self._bin(o, "*")

    def __rmul__(self, o):
        return self._bin(o, "*", True)

    def __truediv__(self, o):
        return self._bin(o, "/")

    def __rtruediv__(self, o):
        return self._bin(o, "/", True)

    def __neg__(self):
        return OslValue(f"(-{self.code})", self.kind)


def _osl(v) -> OslValue:
    if isinstance(v, OslValue):
        return v
    if isinstance(v, (tuple, list)):
        return OslValue("color({})".format(", ".join(_num(x) for x in v)), "color")
    return OslValue(_num(v), "float")


def _num(x: float) -> str:
    return repr(float(x))


class OslBackend:
    """Emit the body of an OSL surface shader: temporaries as local variables, closures summed into BSDF.

    In Cycles' OSL, ``I`` points from the surface towards the viewer (its Layer Weight shader uses
    dot(I, N) as the facing cosine), so ωo = I.

    ``form`` "nodes" takes the node group's branches instead (``metal_min_ratio``, Schlick's Fresnel at the view), so
    that the node group's arithmetic can be counted in the same terms (``nodes.budget.shader_size``); that code is
    never compiled.
    """

    def __init__(self, params: list[tuple[str, str, object]], form: str = "osl"):
        self.params = params  # (osl name, kind, default)
        self.form = form
        self.lines: list[str] = []
        self.closures: list[str] = []
        self.lamberts: dict[str, list[str]] = {}  # closure call -> the colours summed into it (``_lambert``)
        self.tables: list[str] = []  # constant arrays, declared as parameters (``ramp``)
        self._count = 0

    def input(self, name: str, kind: str):
        return OslValue(osl_identifier(name), "color" if kind in ("color", "vector") else kind)

    def bulk(self, weight):
        self._closure(weight, osl_identifier(BULK_INPUT))

    def _let(self, value: OslValue, kind=None) -> OslValue:
        self._count += 1
        name = f"t{self._count}"
        kind = kind or value.kind
        self.lines.append(f"{kind} {name} = {value.code};")
        return OslValue(name, kind)

    def cos_view(self):
        return self._let(OslValue(f"max(dot(N, I), {MIN_COS!r})", "float"))

    def direction(self, v):
        v = _osl(v)
        return self._let(OslValue(f"normalize({v.code}[0] * Tn + {v.code}[1] * Bn + {v.code}[2] * N)", "normal"))

    def normal(self):
        return OslValue("N", "normal")

    def backfacing(self):
        return self._let(OslValue("(backfacing() ? 1.0 : 0.0)", "float"))

    def upper_hemisphere(self, d):
        return self._let(OslValue(f"dot({d.code}, N) < 0.0 ? -{d.code} : {d.code}", "normal"))

    def view(self):
        return self._let(OslValue("normalize(I)", "normal"))

    def dot(self, a, b):
        return self._let(OslValue(f"dot({a.code}, {b.code})", "float"))

    def dot_view(self, d):
        return self.dot(d, OslValue("I", "vector"))

    def tangent_plane(self, d):
        v = self._let(OslValue(f"{d.code} - dot({d.code}, N) * N", "vector"))
        return self._let(OslValue(f"length({v.code}) > {MIN_TANGENT!r} ? normalize({v.code}) : Tn", "vector"))

    def _call(self, fn, *args):
        args = [_osl(a) for a in args]
        kind = "color" if any(a.kind == "color" for a in args) else "float"
        return self._let(OslValue(f"{fn}({', '.join(a.code for a in args)})", kind))

    def exp(self, x):
        return self._call("exp", x)

    def log(self, x):
        return self._call("log", self.maximum(x, MIN_LOG))

    def sqrt(self, x):
        return self._call("sqrt", self.maximum(x, 0.0))

    def abs(self, x):
        return self._call("abs", x)

    def cos(self, x):
        return self._call("cos", x)

    def acos(self, x):
        return self._call("acos", self.maximum(self.minimum(x, 1.0), -1.0))

    def sin(self, x):
        return self._call("sin", x)

    def atan2(self, y, x):
        return self._call("atan2", y, x)

    def multiply_add(self, a, s, c):
        return self._let(_osl(a) * s + c)

    def channel(self, color, i: int):
        c = self._let(_osl(color), "color")
        return self._let(OslValue(f"{c.code}[{i}]", "float"))

    def channel_mean(self, color):
        c = self._let(_osl(color), "color")
        return self._let(OslValue(f"({c.code}[0] + {c.code}[1] + {c.code}[2]) / 3.0", "float"))

    def rotated_tangent(self, angle):
        a = self._let(_osl(angle), "float")
        return self._let(OslValue(f"cos({a.code}) * Tn + sin({a.code}) * Bn", "vector"))

    def has_metal(self) -> bool:
        return True

    def shared(self, name: str, body, *args) -> list:
        """``NumpyBackend.shared``: inline."""
        return body(self, *args)

    def ramp(self, values, x):
        """``NumpyBackend.ramp``: a constant array of colours, interpolated linearly. The array is a shader parameter
        (no socket: ``osl.parse_params``), which OSL keeps as a constant; a local array would be filled at every
        shading point."""
        values = np.asarray(values, dtype=np.float64)
        self._count += 1
        name, last = f"table{self._count}", len(values) - 1
        entries = ", ".join(_osl(tuple(v)).code for v in values)
        self.tables.append(f"color {name}[{len(values)}] = {{{entries}}}")
        t = self._let(OslValue(f"clamp({_osl(x).code}, 0.0, 1.0) * {_num(last)}", "float"))
        i = self._let(OslValue(f"min((int)floor({t.code}), {last - 1})", "int"))
        return self._let(OslValue(f"mix({name}[{i.code}], {name}[{i.code} + 1], {t.code} - {i.code})", "color"))

    def step_below(self, x, edge):
        return self._let(OslValue(f"({_osl(x).code} < {_osl(edge).code} ? 1.0 : 0.0)", "float"))

    def maximum(self, a, b):
        return self._call("max", a, b)

    def minimum(self, a, b):
        return self._call("min", a, b)

    def scale(self, color, s):
        product = _osl(color) * s
        return self._let(product, "vector" if product.kind == "vector" else "color")

    def _closure(self, color, call: str):
        self.closures.append(f"{_osl(color).code} * {call}")

    def glossy(self, color, alpha_x, alpha_y, normal, tangent=None, f0=None):
        if f0 is not None and self.form == "nodes":
            color, f0 = schlick_at_view(self, color, f0, normal), None
        ax, ay, t = _osl(alpha_x).code, _osl(alpha_y).code, "Tn" if tangent is None else tangent.code
        if f0 is None:
            self._closure(color, f'microfacet("ggx", {normal.code}, {t}, {ax}, {ay}, 1.0, 0)')
        else:
            self._closure(1.0, f'generalized_schlick_bsdf({normal.code}, {t}, {_osl(color).code}, color(0), '
                               f'{ax}, {ay}, {_osl(f0).code}, color(1), 5.0, "ggx")')

    @property
    def metal_min_ratio(self) -> float:
        return METAL_MIN_RATIO if self.form == "nodes" else 0.0

    def metal(self, alpha_x, alpha_y, tangent, eta, k, weight=1.0):
        """A constant extinction 0 is a dielectric: ``dielectric_bsdf`` without transmission, one per distinct IOR
        (Blender 4.2's ``conductor_bsdf`` approximates the Fresnel, far off for small k)."""
        if isinstance(k, tuple) and not any(k):
            for e in sorted(set(eta)):
                mask = _osl(tuple(1.0 if x == e else 0.0 for x in eta)).code
                self._closure(weight, f'dielectric_bsdf(N, {tangent.code}, {mask}, color(0), {_osl(alpha_x).code}, '
                                      f'{_osl(alpha_y).code}, {_num(e)}, "ggx")')
            return
        self._closure(weight, f'conductor_bsdf(N, {tangent.code}, {_osl(alpha_x).code}, {_osl(alpha_y).code}, '
                           f'{_osl(eta).code}, {_osl(k).code}, "ggx")')

    def diffuse(self, color):
        self._lambert("diffuse(N)", color)

    def translucent(self, color):
        self._lambert("translucent(N)", color)

    def transparent(self, color):
        self._lambert("transparent()", color)

    def _lambert(self, call: str, color):
        """``NodeBackend._lambert``: closures without parameters summed by colour, one call each."""
        self.lamberts.setdefault(call, []).append(_osl(color).code)

    def conductor(self, color, alpha, eta, k):
        a = _osl(alpha).code
        self._closure(color, f'conductor_bsdf(N, Tn, {a}, {a}, {_osl(eta).code}, {_osl(k).code}, "ggx")')

    def dielectric(self, color, alpha, ior):
        a = _osl(alpha).code
        self._closure(1.0, f'dielectric_bsdf(N, Tn, {_osl(color).code}, {_osl(color).code}, {a}, {a}, '
                           f'{_osl(ior).code}, "ggx")')

    def beckmann(self, color, alpha, eta=None, normal=None):
        a, n = _osl(alpha).code, "N" if normal is None else normal.code
        if eta is None:
            self._closure(color, f'microfacet("beckmann", {n}, Tn, {a}, {a}, 1.0, 0)')
        else:  # reflection only: no transmission tint
            self._closure(1.0, f'dielectric_bsdf({n}, Tn, {_osl(color).code}, color(0), {a}, {a}, {_osl(eta).code}, '
                               f'"beckmann")')

    def refraction(self, color, alpha, ior, normal, distribution="beckmann"):
        a = _osl(alpha).code
        self._closure(color, f'microfacet("{distribution}", {normal.code}, Tn, {a}, {a}, {_osl(ior).code}, 1)')

    def velvet(self, color, sigma):
        self._closure(color, f"ashikhmin_velvet(N, {_osl(sigma).code})")

    def glossy_toon(self, color, size, smooth):
        self._closure(color, f"glossy_toon(N, {_osl(size).code}, {_osl(smooth).code})")

    def diffuse_toon(self, color, size, smooth):
        self._closure(color, f"diffuse_toon(N, {_osl(size).code}, {_osl(smooth).code})")

    def source(self, shader_name: str, header: str) -> str:
        params = ",\n    ".join([f"{_osl_type(kind)} {osl_identifier(name)} = {_osl_default(kind, d)}"
                                  for name, kind, d in self.params] + self.tables)
        body = "\n    ".join(self.lines)
        lamberts = [f"({' + '.join(colors)}) * {call}" for call, colors in self.lamberts.items()]
        bsdf = " +\n        ".join(self.closures + lamberts) or "0"
        return (f"{header}\n#include \"stdcycles.h\"\n\n"
                f"shader {shader_name}(\n    {params},\n    vector {TANGENT_INPUT} = vector(0),\n"
                f"    output closure color BSDF = 0)\n{{\n"
                f"    vector Tn = normalize({TANGENT_INPUT} - dot({TANGENT_INPUT}, N) * N);\n"
                f"    vector Bn = cross(N, Tn);\n"
                f"    {body}\n    BSDF =\n        {bsdf};\n}}\n")


def osl_identifier(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name)


def _osl_type(kind: str) -> str:
    return {"float": "float", "color": "color", "vector": "vector", "shader": "closure color"}[kind]


def _osl_default(kind: str, d) -> str:
    if kind == "shader":
        return "0"
    if kind == "float":
        return _num(d)
    return "{}({})".format(_osl_type(kind), ", ".join(_num(x) for x in d))


# Blender 4.2's node group: the Fresnel-weighted albedo of a Beckmann lobe over its Fresnel-free albedo is about
# F(µ + (1 − µ) min(1, a α^q), η), the Fresnel at a cosine pulled towards normal incidence by the roughness; (a, q)
# minimise the largest error over cos θo in [0.01, 1], α in [0.002, 1], η in [1.0001, 3] (measured against F at the
# view in tests/unit/test_thin_coat_mapping.py, test_blender_42_node_group_takes_the_lobes_mean_fresnel).
LOBE_FRESNEL_FIT = (0.62286676, 0.99199374)


def lobe_fresnel(b, color, eta, alpha):
    """Blender 4.2's node group (no Metallic BSDF node) for a Beckmann reflection with the dielectric Fresnel per
    microfacet: a Fresnel-free lobe whose colour takes the lobe's mean Fresnel by ``LOBE_FRESNEL_FIT`` (its energy;
    F(cos θo) would be exact at the mirror configuration only and far too bright on the plane for rough coats).
    [approx: lobe-fresnel-blender-4.2]"""
    a, q = LOBE_FRESNEL_FIT
    mu = b.cos_view()
    pulled = mu + (1.0 - mu) * b.minimum(a * b.exp(q * b.log(alpha)), 1.0)
    return b.scale(color, fresnel_dielectric(b, pulled, eta))


def schlick_at_view(b, color, f0, normal):
    """Node-group approximation: Schlick's Fresnel evaluated at h = normal (exact at the mirror configuration)."""
    return schlick(b, color, f0, b.dot_view(normal))


def schlick(b, color, f0, cos):
    """``color`` times Schlick's Fresnel F(f0) at cos θ = ``cos`` (clamped at 0)."""
    c = 1.0 - b.maximum(cos, 0.0)
    c2 = c * c
    return color * (f0 + b.scale(1.0 - f0, c2 * c2 * c))


def fresnel_dielectric(b, c, eta):
    """Unpolarised Fresnel reflectance at cos θ = c from outside a dielectric of relative IOR η ≥ 1."""
    g = b.sqrt(eta * eta - 1.0 + c * c)
    a = (g - c) / (g + c)
    d = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * a * a * (1.0 + d * d)
