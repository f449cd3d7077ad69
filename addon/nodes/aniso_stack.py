"""Anisotropic Stack → Cycles closures (both forms), written once with ``expr`` backends.

The reference computes the stack's lobes from the view once for any backend (``reference.aniso_stack.lobes``);
here it runs on the expression backend through ``StackOps``, and each lobe becomes one closure whose weight
depends on the view only (research notes §4, §6):

* the top interface: Cycles' anisotropic GGX conductor with the exact Fresnel per microfacet at its (αx, αy,
  tangent) — OSL ``conductor_bsdf`` (a dielectric top: ``dielectric_bsdf`` without transmission), node groups the
  Metallic BSDF (physical conductor; a dielectric is a conductor of extinction 0, whose Fresnel is the dielectric
  one). This is the reference's surface lobe exactly; but Blender 4.2's OSL ``conductor_bsdf`` approximates the
  conductor Fresnel (measured 1% off for a metal of k ≈ 2-4 on the plane, far more for k near 0): not predicted.
  Blender 4.2 has no Metallic BSDF node: its node group renders a Fresnel-free Glossy BSDF whose colour is the
  lobe's mean Fresnel FGD / E at the isotropic equivalent roughness. [approx: top-fresnel-mean-blender-4.2] Later
  node groups do so where αx / αy < 0.1, which the Metallic BSDF's anisotropy cannot reach (a Mix Shader picks
  one of the two per pixel). [approx: metal-anisotropy-range]
* interface j > 0: weight × the Fresnel-free anisotropic GGX (Glossy BSDF / ``microfacet("ggx", ...)``) with the
  lobe's own tangent, the reference's reflection lobe exactly.

Tangents: each lobe's tangent is the surface tangent (Cycles' default: the Geometry node's Tangent, radial
around z without UVs) turned about the normal by the lobe's angle; the closure's αx is the smaller roughness,
along the tangent (the Glossy BSDF's Anisotropy ≥ 0).

The tables of the adding loop (FGD, escaping fraction, GGX albedo; ``reference.aniso_stack_tables``) are
functions of (cos θ, α) once the IORs are fixed. The IORs and extinctions are therefore part of the shader's
structure (``structure_key``; not sockets), and each table the material needs is replaced by a polynomial in
(√µ, √α) of degrees ``FIT_DEGREES``, fitted by least squares to the reference's lookup when the shader is
generated (``table_fit``): arithmetic only, the same in OSL, math nodes and numpy. [approx: table-polynomials]
"""
from __future__ import annotations

import hashlib
import math
from functools import lru_cache

import numpy as np

from ..models import aniso_stack as model
from ..reference import aniso_stack as reference
from ..reference import aniso_stack_tables as tables
from ..reference import microfacet
from .expr import METAL_MIN_RATIO
from .principled import Counterpart
from .spongecake import Socket
from .thin_coat import BackendOps, fresnel_conductor

FIT_DEGREES = (8, 6)  # polynomial degrees in √µ and √α of the table fits
FIT_NODES = 65  # fit grid per axis
MIN_ROOT_ALPHA = math.sqrt(tables.MIN_ALPHA)


def _config(**kw) -> dict:
    return {**model.default_params().to_dict(), **kw}


APPROXIMATIONS = {
    "table-polynomials": ("the adding loop's tables (FGD, escaping fraction, GGX albedo, the conductor's Gauss rule) "
                          "at the material's IORs as polynomials of degrees 8 × 6 in (√cos, √α), fitted when the "
                          "shader is generated", _config()),
    "metal-anisotropy-range": ("node groups only: a top interface with αx / αy < 0.1, beyond the Metallic BSDF's "
                               "anisotropy, rendered as on Blender 4.2 (its mean Fresnel)",
                               _config(interfaces=[{"type": "conductor", "alpha": [0.01, 0.5]}], media=[])),
    "top-fresnel-mean-blender-4.2": ("Blender 4.2's node group only (no Metallic BSDF node): the top interface's "
                                     "Fresnel as its mean over the lobe (FGD / E), not per microfacet",
                                     _config(interfaces=[{"type": "conductor", "alpha": [0.05, 0.3]}], media=[])),
}


def approximations_used(p: model.Params) -> list[str]:
    """The names of the ``APPROXIMATIONS`` the mapping makes for ``p``, in that table's order (the Blender 4.2 one is
    listed for every stack: it says so itself)."""
    top = p.interfaces[0]
    used = {"top-fresnel-mean-blender-4.2"}
    if len(p.interfaces) > 1:
        used.add("table-polynomials")
    if min(top.alpha) < METAL_MIN_RATIO * max(top.alpha):
        used.add("metal-anisotropy-range")
    return [name for name in APPROXIMATIONS if name in used]


# Compared beside the stack (``principled``): ``principled_settings`` in one line.
PRINCIPLED = Counterpart(
    "Principled BSDF",
    "base from the bottom interface seen from the medium above it: a conductor as Metallic 1 with Base Color its exact "
    "Fresnel reflectance at normal incidence, a dielectric as a black Base Color with IOR the relative IOR (or its "
    "inverse below 1); Roughness (alpha_x alpha_y)^(1/4), Anisotropic (1 - alpha_min / alpha_max) / 0.9, Anisotropic "
    "Rotation the larger alpha's direction / 360; more than one interface: Coat Weight 1, Coat IOR the top's mean IOR, "
    "Coat Roughness sqrt(the top's RMS alpha); the media's absorption and the middle interfaces have no counterpart")


def principled_settings(p: model.Params) -> dict:
    """Blender's Principled BSDF standing for the stack: an anisotropic GGX base from the bottom interface seen from
    the medium above it (as ``principled_coat`` does for thin coats: a metal with the conductor's colour at normal
    incidence, or a black dielectric of the relative IOR) and, for more than one interface, a coat from the top one
    (its IOR and isotropic equivalent roughness)."""
    bottom, top = p.interfaces[-1], p.interfaces[0]
    above = p.interfaces[-2].ior if len(p.interfaces) > 1 else (1.0, 1.0, 1.0)
    eta, k = reference.relative(bottom, above)
    out = {"Roughness": _principled_roughness(bottom), "Anisotropic": _principled_anisotropy(bottom),
           "Anisotropic Rotation": (_larger_alpha_angle(bottom) / 360.0) % 1.0}
    if bottom.type == "conductor":
        f0 = microfacet.fresnel_conductor(np.array([1.0]), eta, k)[0]
        out.update({"Base Color": tuple(float(c) for c in f0), "Metallic": 1.0})
    else:
        relative = float(np.mean(eta))
        out.update({"Base Color": (0.0, 0.0, 0.0), "Metallic": 0.0, "IOR": max(relative, 1.0 / relative)})
    if len(p.interfaces) > 1:
        out.update({"Coat Weight": 1.0, "Coat IOR": float(np.mean(top.ior)),
                    "Coat Roughness": math.sqrt(reference.rms_alpha(reference.F64, top.alpha_x, top.alpha_y))})
    return out


def _larger_alpha_angle(interface) -> float:
    """The direction (degrees) of the interface's larger α: Principled's tangent carries the larger one."""
    return interface.rotation + (0.0 if interface.alpha_x >= interface.alpha_y else 90.0)


def _principled_roughness(interface) -> float:
    return min(math.sqrt(math.sqrt(interface.alpha_x * interface.alpha_y)), 1.0)


def _principled_anisotropy(interface) -> float:
    """Principled's anisotropy a with α_x / α_y = (1 − 0.9a) (Cycles: aspect = sqrt(1 − 0.9a)), in [0, 1]."""
    ratio = min(interface.alpha_x, interface.alpha_y) / max(interface.alpha_x, interface.alpha_y)
    return float(min(max((1.0 - ratio) / 0.9, 0.0), 1.0))


# ------------------------------------------------------------------------------------------ sockets

def _interface_panel(j: int) -> str:
    return f"Interface {j + 1}"


def _medium_panel(j: int) -> str:
    return f"Medium {j + 1}"


TEXTURED_MEDIUM = tuple(prm for prm in model.MEDIUM if prm.texturable)  # absorption, depth


def sockets(p: model.Params) -> list[Socket]:
    """Per interface its roughnesses and rotation, per non-empty medium its absorption and depth, from the model
    declaration; named "<label> <index>" (1-based)."""
    out = []
    for j in range(len(p.interfaces)):
        out += [Socket(f"{prm.label} {j + 1}", prm.kind, prm, j, _interface_panel(j)) for prm in model.ROUGHNESS]
        if j < len(p.media) and _has_medium(p, j):
            out += [Socket(f"{prm.label} {j + 1}", prm.kind, prm, j, _medium_panel(j)) for prm in TEXTURED_MEDIUM]
    return out


def _has_medium(p: model.Params, j: int) -> bool:
    """Whether medium j gets sockets: any medium that is not an empty gap (depth 0) of a clear medium."""
    m = p.media[j]
    return m.depth > 0.0 or any(m.sigma_a) or any(m.sigma_s)


def structure_key(p: model.Params) -> tuple:
    """Interface types with their IORs (the table fits depend on them), and per medium whether it has sockets, its
    scattering and g."""
    interfaces = tuple((i.type, tuple(i.ior), tuple(i.k)) for i in p.interfaces)
    media = tuple((_has_medium(p, j), tuple(m.sigma_s), m.g) for j, m in enumerate(p.media))
    return interfaces, media


def _target(p: model.Params, s: Socket):
    return p.interfaces[s.layer] if s.param in model.ROUGHNESS else p.media[s.layer]


def input_values(p: model.Params) -> dict:
    return {s.name: getattr(_target(p, s), s.param.name) for s in sockets(p)}


def with_values(p: model.Params, values: dict) -> model.Params:
    data = p.to_dict()
    for s in sockets(p):
        if s.param in model.ROUGHNESS:
            entry = data["interfaces"][s.layer]
            if s.param.name == "rotation":
                entry["rotation"] = values[s.name]
            else:
                entry["alpha"][0 if s.param.name == "alpha_x" else 1] = values[s.name]
        else:
            data["media"][s.layer][s.param.name] = values[s.name]
    return model.params_from_dict(data)


def _inputs(b, p: model.Params) -> dict:
    """The reference's ``inputs`` from the sockets, kept in the declared ranges."""
    out = {}
    for s in sockets(p):
        value = b.input(s.name, s.param.kind)
        out[(s.param.name, s.layer)] = b.minimum(b.maximum(value, s.param.min), s.param.max)
    return out


# ------------------------------------------------------------------------------------------ shading

def shade(b, p: model.Params) -> None:
    """Build the closure mix on backend ``b`` (module docstring)."""
    ops = StackOps(b)
    for lobe in reference.lobes(ops, p, b.cos_view(), 0, _inputs(b, p)):
        if lobe.kind == "surface":
            _top(b, ops, p.interfaces[0], lobe)
        else:
            tangent, ax, ay = _ordered(b, lobe.alpha_u, lobe.alpha_v, lobe.angle)
            b.glossy(lobe.weight, ax, ay, b.normal(), tangent)


def _ordered(b, alpha_u, alpha_v, angle):
    """(tangent, αx, αy) with αx = min(αu, αv) along the tangent (turned by 90° where αv < αu)."""
    swap = b.step_below(alpha_v, alpha_u)
    tangent = b.rotated_tangent(angle + swap * (0.5 * math.pi))
    return tangent, b.minimum(alpha_u, alpha_v), b.maximum(alpha_u, alpha_v)


def _top(b, ops, interface, lobe) -> None:
    """The top interface's exact microfacet BRDF where the form has a conductor closure with a tangent that is
    anisotropic enough, else a Fresnel-free lobe of its mean Fresnel (module docstring)."""
    tangent, ax, ay = _ordered(b, lobe.alpha_u, lobe.alpha_v, lobe.angle)
    if b.has_metal() and not b.metal_min_ratio:
        b.metal(ax, ay, tangent, tuple(interface.ior), tuple(interface.k))
        return
    mean = 1.0
    if b.has_metal():  # node groups: beyond the Metallic BSDF's anisotropy, the mean Fresnel
        mean = b.step_below(ax / ay, b.metal_min_ratio)
        b.metal(ax, ay, tangent, tuple(interface.ior), tuple(interface.k), 1.0 - mean)
    mu = b.cos_view()
    alpha = reference.rms_alpha(ops, ax, ay)
    fgd = reference.reflectance(ops, interface, (1.0, 1.0, 1.0), mu, alpha)
    color = b.scale(fgd, mean / b.maximum(ops.ggx_albedo(mu, alpha), 1e-3))
    b.glossy(color, ax, ay, b.normal(), tangent)


class StackOps(BackendOps):
    """The operations ``reference.aniso_stack.lobes`` needs (``reference.aniso_stack.Float64Ops``) on an ``expr``
    backend: its math, and the tables as fitted polynomials (``table_fit``)."""

    def __init__(self, b):
        super().__init__(b)
        self.sin, self.atan2, self.mean = b.sin, b.atan2, b.channel_mean
        self._columns = {}  # (fit key, id(µ)) -> (µ, columns): lookups at the same cosine share them

    def pow(self, x, y: float):
        return self.b.exp(y * self.b.log(x))

    def _lookup(self, key: tuple, mu, alpha):
        fit = table_fit(*key)
        if (key, id(mu)) not in self._columns:
            self._columns[key, id(mu)] = mu, fit_columns(self.b, fit, mu)
        value = evaluate_fit(self.b, fit, mu, alpha, self._columns[key, id(mu)][1])
        return self.b.minimum(self.b.maximum(value, 0.0), 1.0)  # every table holds fractions

    def ggx_albedo(self, cos, alpha):
        return self._lookup(("albedo",), cos, alpha)

    def fgd_conductor(self, cos, alpha, eta, k):
        """E (w1 F(c1) + (1 − w1) F(c2)) with the exact Fresnel, as ``tables.Tables.conductor_fgd``."""
        b = self.b
        rule = self._lookup(("rule",), cos, alpha)
        c1, c2, w1 = (b.channel(rule, i) for i in range(3))
        eta, k = b.scale(tuple(eta), 1.0), b.scale(tuple(k), 1.0)
        f1, f2 = (fresnel_conductor(b, c, eta, k) for c in (c1, c2))
        return b.scale(b.scale(f1, w1) + b.scale(f2, 1.0 - w1), self.ggx_albedo(cos, alpha))

    def fgd_dielectric(self, cos, alpha, eta):
        return self._per_eta("fgd", cos, alpha, eta)

    def escape(self, cos, alpha, eta):
        if all(e >= 1.0 for e in eta):
            return 1.0
        return self._per_eta("escape", cos, alpha, eta)

    def _per_eta(self, name, cos, alpha, eta):
        """A dielectric table per distinct relative IOR, in the cosine on the interface's rarer side (the tables'
        axis: smooth across the critical angle), channels combined by masks."""
        out = None
        for e in sorted(set(eta)):
            mask = tuple(1.0 if x == e else 0.0 for x in eta)
            value = self.b.scale(mask, self._lookup((name, e), rarer_cos(self.b, cos, e), alpha))
            out = value if out is None else out + value
        return out


def rarer_cos(b, mu, eta: float):
    """``tables.rarer_cos`` for one constant relative IOR."""
    if eta >= 1.0:
        return mu
    return b.sqrt(1.0 - (1.0 - mu * mu) * (1.0 / (eta * eta)))


# ------------------------------------------------------------------------------------------ table fits

def _fit_axes():
    x = np.linspace(0.0, 1.0, FIT_NODES)
    y = np.linspace(MIN_ROOT_ALPHA, 1.0, FIT_NODES)
    return np.meshgrid(x, y, indexing="ij")


def _basis(tx, ty):
    dx, dy = FIT_DEGREES
    return np.stack([tx ** i * ty ** j for i in range(dx + 1) for j in range(dy + 1)], axis=-1)


def _unit_x(x):
    """√µ → [−1, 1] (the polynomials' first variable)."""
    return 2.0 * x - 1.0


def _unit_y(y):
    """√α → [−1, 1] (the polynomials' second variable)."""
    return (2.0 / (1.0 - MIN_ROOT_ALPHA)) * (y - MIN_ROOT_ALPHA) - 1.0


def _unit(x, y):
    return _unit_x(x), _unit_y(y)


def table_function(name: str, *args):
    """The reference lookup a fit stands for, as f(µ, α) → (N, C): "albedo", "rule" (the conductor's Gauss rule c1,
    c2, w1), "fgd" (η) and "escape" (η), the last two in the cosine on the rarer side (``tables.rarer_cos``)."""
    t = tables.load()
    if name == "albedo":
        return lambda mu, a: t.albedo(mu, a)[:, None]
    if name == "rule":
        return lambda mu, a: np.stack([tables.interpolate(r, tables.cell(mu, a)) for r in t.rule], axis=-1)
    eta = args[0]
    lookup = t.fgd if name == "fgd" else t.escape
    return lambda mu_rare, a: lookup(tables.denser_cos(mu_rare, eta), a, [eta])


@lru_cache(maxsize=256)
def table_fit(name: str, *args) -> np.ndarray:
    """Least-squares coefficients (dx + 1, dy + 1, C) of ``table_function(name, *args)`` on a ``FIT_NODES``² grid in
    (√µ, √α)."""
    x, y = _fit_axes()
    values = table_function(name, *args)(x.ravel() ** 2, y.ravel() ** 2)
    coefficients, *_ = np.linalg.lstsq(_basis(*_unit(x.ravel(), y.ravel())), values, rcond=None)
    return coefficients.reshape(FIT_DEGREES[0] + 1, FIT_DEGREES[1] + 1, -1)


def evaluate_fit(b, fit: np.ndarray, mu, alpha, columns=None):
    """The fitted polynomial at (µ, α) on backend ``b``: a float for one channel, else a colour. ``columns``: those
    of ``fit_columns(b, fit, mu)`` when already built (lookups at the same µ share them)."""
    columns = fit_columns(b, fit, mu) if columns is None else columns

    def in_alpha(b, alpha, *columns):
        return [_horner(b, list(columns), _unit_y(b.sqrt(b.minimum(b.maximum(alpha, tables.MIN_ALPHA), 1.0))))]

    kind = "float" if fit.shape[2] == 1 else "color"
    return b.shared(f"Lamina polynomial {len(columns)} {kind} {tables.MIN_ALPHA:g}", in_alpha, alpha, *columns)[0]


def fit_columns(b, fit: np.ndarray, mu) -> list:
    """Per power of the roughness variable, its coefficient as a polynomial in the cosine variable (Horner); one
    shared computation per fit (a nested group in node groups)."""
    scalar = fit.shape[2] == 1

    def constant(c):
        return float(c[0]) if scalar else tuple(float(v) for v in c)

    def columns(b, mu):
        tx = _unit_x(b.sqrt(b.minimum(mu, 1.0)))
        return [_horner(b, [constant(c) for c in fit[:, j]], tx) for j in range(fit.shape[1])]

    digest = hashlib.md5(np.ascontiguousarray(fit, dtype=np.float64).tobytes()).hexdigest()[:8]
    return b.shared(f"Lamina table {digest}", columns, mu)


def _horner(b, terms, t):
    acc = terms[-1]
    for term in terms[-2::-1]:
        acc = b.multiply_add(acc, t, term)
    return acc


def fit_error(name: str, *args, n: int = 4000, seed: int = 0) -> dict:
    """The fit against the reference lookup at ``n`` random points uniform in (√µ, √α): max and RMS absolute
    error."""
    from .expr import NumpyBackend

    rng = np.random.default_rng(seed)
    x, y = rng.random(n), MIN_ROOT_ALPHA + (1.0 - MIN_ROOT_ALPHA) * rng.random(n)
    b = NumpyBackend(np.tile([0.0, 0.0, 1.0], (n, 1)), {})
    got = np.asarray(evaluate_fit(b, table_fit(name, *args), x * x, y * y)).reshape(n, -1)
    error = got - table_function(name, *args)(x * x, y * y)
    return {"max": float(np.abs(error).max()), "rms": float(np.sqrt(np.mean(error ** 2)))}
