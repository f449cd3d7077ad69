"""Thin Coat → Cycles closures (both forms), written once with ``expr`` backends.

The reference computes the BSDF's lobes from the view once for any backend (``reference.thin_coat.lobes``); here
it runs on the expression backend through ``BackendOps`` (float32-safe vMF helpers, Fresnel and the diffuse means
in backend math), and each lobe becomes one closure whose weight depends on the view only. Both forms render what
``NumpyBackend`` predicts (tests/blender/test_thin_coat_cycles.py); the errors below are against the reference.

* The top interface (order 0): Cycles' Beckmann reflection with α = sqrt(2 / κ1) (research notes §2) and the
  dielectric Fresnel per microfacet (OSL ``dielectric_bsdf`` without transmission; node group: the Metallic BSDF
  with extinction 0, see ``NodeBackend.beckmann``; Blender 4.2 has no such node: ``expr.lobe_fresnel``). The vMF
  NDF D = M / A3 with the masking of Eq. 8 becomes Beckmann's D with Cycles' height-correlated G2 (its rational Λ);
  the colour G1(o)² / G2(o, o) = G1(o)² (1 + 2Λ(o))
  makes the masking exact at the mirror configuration, where the two NDFs differ by their normalisation
  1 / (A3 (1 − e^{−2κ1})) = 1 + O(1/κ1) (matching that peak too was measured worse: both NDFs carry the same
  energy). The colour is capped at ``expr.MAX_MIX_WEIGHT`` (only reached at grazing views of smooth tops).
  [approx: surface-as-beckmann]
* Reflection order k: the ENDF lobe W_k M(h; κ̂_k) / (4 |o·h| cos θi) as a Fresnel-free Beckmann reflection with
  α = sqrt(2 / κ̂_k), kept in [sqrt(2 / 10⁶), 1] (Cycles clamps α to 1). The two lobes agree near the mirror
  configuration of narrow lobes; wide lobes (a rough bottom, grazing views: κ̂ ∝ cos²θo) differ in shape: the ENDF
  has no masking and divides by |o·h| where a microfacet lobe divides by cos θo. Scaling by the masking at the
  mirror configuration (as for the top) overshoots the lobe's energy many times over at grazing views. The 1 / |o·h|
  skews the ENDF lobe towards grazing (a view table cannot undo that: it depends on the light), and to first order in
  the half vector's tilt it is a vMF lobe about κ̂ n − o / cos θo, so the closure's normal leans away from the view by
  tan δ = tan θo / (κ̂ − 1), at most ``MAX_ENDF_TILT`` (``endf_axis``; Cycles bends it back where the mirror
  direction would fall below the surface, as for every glossy closure). The cap 0.1 was chosen among 0.01–0.3 on
  varnished_metal and smooth_over_rough with a throwaway script during development (larger tilts help the plane of
  smooth_over_rough's wide lobes and hurt its sphere); the effect is measured in docs/accuracy.md. The colour is
  W_k ε(θo, κ̂), ε the ratio of the ENDF lobe's energy to the tilted closure's by a fit (``energy_ratio``;
  ``energy_ratio_error``; training/thin_coat_energy_fit.py). [approx: endf-as-beckmann]
* Diffuse orders (Lambertian base): one Diffuse BSDF of colour π ē Σ_k W_k (the orders share the closure's
  shape, so their sum is exact and costs one closure at any bounce count), the light-side factor entry(θi) (the
  crossing of the top and the absorption on the way in, ``reference.thin_coat.entry``) replaced by its
  cosine-weighted hemispherical mean ē (``mean_entry``, 3 nodes): a closure weight cannot depend on the light; the
  energy under uniform light is kept (the view's entry(θo), exact at the mirror configuration only, was tried and
  measured worse on glazed_ceramic). [approx: diffuse-entry-mean] The hemispherical means inside the coat (r̄_i,
  and τ̄ = 2 E3(σa d) per channel) come from fits (``diffuse_means``; ``diffuse_means_error``: 4.5e-5 and 1.8e-4).
  [approx: diffuse-means-fit]
* Slab transmission order j: the vMF lobe W_j M(i; −o, κ_j) of exit directions, as Cycles' Beckmann refraction
  without Fresnel around the closure normal o (the view itself) into a medium of relative IOR ``SLAB_IOR``: at
  normal incidence a microfacet tilted by θm deviates the refracted ray by (1 − 1/η) θm, so the Beckmann lobe of
  slopes α = sqrt(2 / κ) / (1 − 1/η) is the vMF lobe of directions to second order (peak and width), centred on −o,
  and like the vMF it carries its weight (no Fresnel; both lose what leaves above the surface). IOR 10 keeps
  α ≤ 1 down to κ = 2.5; an IOR near 1 would need α ≫ 1 (and Cycles samples IOR 1 as straight-through,
  tests/blender/test_cycles_facts.py). [approx: transmission-as-refraction]

The vMF helpers run in float32 in both forms (``complement``, ``kappa_from_complement``): mean cosines are carried
by their complements u = 1 − A3, which the reference's convolution combines without forming A3 (float32 cannot
resolve 1 − u below 6e-8). The inverse takes Banerjee's approximation refined
by two Newton steps in OSL (relative error 1.5e-4); the node group skips the Newton steps (4.9%, at κ ≈ 5;
``kappa_error``). [approx: kappa-without-newton]

Seen from below (the far side of a plane) Cycles flips the normal towards the viewer and renders the coat as if seen
from above: a slab's two interfaces are not exchanged as in the reference, and an opaque base is not black.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..models import thin_coat as model
from ..reference import thin_coat as reference
from ..reference.vmf import INVERSE_BELOW, SERIES_BELOW
from . import principled_coat
from .closures_np import rational_beckmann_lambda
from .expr import MAX_MIX_WEIGHT, fresnel_dielectric
from .principled import Counterpart
from .spongecake import Socket

COAT_PANEL = "Coat"
BASE_PANEL = "Base"
SLAB_IOR = 10.0  # the slab's refraction closures: relative IOR of the medium they pretend to enter
MAX_LOBE_KAPPA = model.MAX_KAPPA  # α ≥ sqrt(2 / 1e6) for every lobe
NEWTON_STEPS = {"osl": 2, "nodes": 0}  # refinements of Banerjee's inverse per form
MAX_ENDF_TILT = 0.1  # the reflection orders' closure normals lean at most this far from the normal (tan δ; endf_axis)
MERGED_FROM = 2  # merge_orders: the reflection and transmission orders from this one on become one lobe per kind


def _config(**kw) -> dict:
    """The model's defaults (a clear coat over the paper's rough dielectric) with ``kw`` changed."""
    return {**model.default_params().to_dict(), "bounces": 1, **kw}


# The fitted mapping (``fitted``) rescales these closures per view and may add a few: offered here.
FITTABLE = True

APPROXIMATIONS = {
    "surface-as-beckmann": ("the top's vMF NDF with Eq. 8's masking rendered as Beckmann with Cycles' G2, scaled by "
                            "the masking ratio at the mirror configuration",
                            _config(kappa_top=10.0, bounces=0)),
    "lobe-fresnel-blender-4.2": ("Blender 4.2's node group only (no Metallic BSDF node): the top's Fresnel as its "
                                 "mean over the lobe by a fit, not per microfacet (the bench predicts 4.3+: measured "
                                 "in tests/unit/test_thin_coat_mapping.py)",
                                 _config(kappa_top=30.0, bounces=0)),
    "endf-as-beckmann": ("each reflection order's ENDF vMF lobe rendered as Beckmann with Cycles' G2 about a normal "
                         "leaning away from the view (the ENDF's 1 / (o·h) to first order), scaled to its energy by "
                         "a fit (α ≤ 1, κ̂ ≤ 1e6)",
                         _config(kappa_top=1e6, kappa_bottom=30.0, bounces=2)),
    "diffuse-entry-mean": ("a diffuse order's light-side factor (top crossing, absorption) replaced by its "
                           "cosine-weighted hemispherical mean (3 nodes)",
                              _config(kappa_top=1e6, sigma_a=[1.0, 1.0, 1.0], depth=1.0, bounces=1,
                                      base={"type": "diffuse", "albedo": [0.8, 0.8, 0.8]})),
    "diffuse-means-fit": ("r̄_i and τ̄ = 2 E3(σa d) inside the coat by fits (abs. error < 2e-4)",
                          _config(kappa_top=1e6, sigma_a=[0.2, 0.2, 0.2], depth=1.0, bounces=4,
                                  base={"type": "diffuse", "albedo": [0.95, 0.95, 0.95]})),
    "kappa-without-newton": ("node group: the vMF inverse A3⁻¹ by Banerjee's approximation without Newton steps",
                             _config(kappa_top=1e6, kappa_bottom=45.0, bounces=1)),
    "merged-orders": ("merge_orders: the reflection (and a slab's transmission) orders from the second on as one "
                      "lobe per kind (summed weight, the concentration of their weighted mean cosine)",
                      _config(kappa_top=1e6, kappa_bottom=30.0, bounces=4, merge_orders=True)),
    "transmission-as-refraction": ("a slab's transmitted vMF lobes as Beckmann refraction about the view at IOR 10 "
                                   "(the same energy)",
                                   _config(kappa_top=100.0, kappa_bottom=100.0, bounces=1, base={"type": "slab"})),
}


def cheaper_variants(p: model.Params) -> list[tuple[str, model.Params]]:
    """What Fit to budget may build instead (``budget``): fewer subsurface bounces, and with more than
    ``MERGED_FROM`` bounces the orders from ``MERGED_FROM`` on merged (``merged_orders``)."""
    out = [(f"{k} bounce{'s' * (k != 1)}", replace(p, bounces=k)) for k in range(p.bounces)]
    if not p.merge_orders and p.base.type != "diffuse":
        out += [(f"{k} bounces, orders ≥ {MERGED_FROM} merged", replace(p, bounces=k, merge_orders=True))
                for k in range(MERGED_FROM + 1, p.bounces + 1)]
    return out


def approximations_used(p: model.Params) -> list[str]:
    """The names of the ``APPROXIMATIONS`` the mapping makes for ``p``, in that table's order (the Blender 4.2 one
    is listed for every coat: it says so itself)."""
    used = {"surface-as-beckmann", "lobe-fresnel-blender-4.2"}
    if p.base.type == "diffuse":
        if p.bounces >= 1:
            used.add("diffuse-entry-mean")
        if p.bounces >= 2:  # the orders past the first loop through the coat's hemispherical means
            used.add("diffuse-means-fit")
    elif p.bounces >= 1:
        used |= {"endf-as-beckmann", "kappa-without-newton"}
    if p.transmits:
        used |= {"transmission-as-refraction", "kappa-without-newton"}
    if p.merge_orders and p.base.type != "diffuse" and p.bounces > MERGED_FROM:
        used.add("merged-orders")
    return [name for name in APPROXIMATIONS if name in used]


# Compared beside the coat (``principled``): Blender's Principled BSDF coat, ``principled_coat``.
PRINCIPLED = Counterpart("Principled coat", principled_coat.MAPPING)


def principled_settings(p: model.Params) -> dict:
    """Blender's Principled BSDF coat set up from the same parameters (``principled_coat.settings``): what an
    artist would otherwise use, rendered beside the coat in comparisons and the render-time baseline."""
    return principled_coat.settings(p)


# ------------------------------------------------------------------------------------------ sockets

def _layer_param(name: str):
    return next(prm for prm in model.LAYER if prm.name == name)


def sockets(p: model.Params) -> list[Socket]:
    """The coat's inputs (roughness per interface instead of κ, the model's ``ROUGHNESS`` alternatives), then the
    base's, from the model declaration. No bottom roughness over a diffuse base (it has no effect there)."""
    sides = ("top",) if p.base.type == "diffuse" else model.INTERFACES
    out = [Socket(model.ROUGHNESS[side].label, "float", model.ROUGHNESS[side], None, COAT_PANEL) for side in sides]
    out += [Socket(prm.label, prm.kind, prm, None, COAT_PANEL)
            for prm in map(_layer_param, ("eta", "sigma_a", "depth"))]
    out += [Socket(prm.label, prm.kind, prm, None, BASE_PANEL) for prm in model.BASE[p.base.type]]
    return out


def structure_key(p: model.Params) -> tuple:
    return p.base.type, p.bounces, p.merge_orders and p.bounces >= MERGED_FROM + 1


def _is_base(p: model.Params, s: Socket) -> bool:
    return s.param in model.BASE[p.base.type]


def input_values(p: model.Params) -> dict:
    """Socket name → value (roughness = sqrt(2 / κ))."""
    return {s.name: getattr(p.base if _is_base(p, s) else p, s.param.name) for s in sockets(p)}


def with_values(p: model.Params, values: dict) -> model.Params:
    """``p`` with the values read from the shader's inputs (a roughness gives κ = 2 / α², kept in [1e-3, 1e6])."""
    data = p.to_dict()
    for s in sockets(p):
        value = values[s.name]
        if _is_base(p, s):
            data["base"][s.param.name] = value
        elif s.param.name.startswith("roughness_"):
            data.pop("kappa_" + s.param.name.split("_", 1)[1], None)
            data[s.param.name] = value
        else:
            data[s.param.name] = value
    return model.params_from_dict(data)


# ------------------------------------------------------------------------------------------ shading

def shade(b, p: model.Params) -> None:
    """Build the closure mix on backend ``b`` (module docstring)."""
    ops = BackendOps(b)
    mu = b.cos_view()
    eta = b.minimum(b.maximum(b.input("Coat IOR", "float"), _layer_param("eta").min), _layer_param("eta").max)
    sigma_d = b.scale(b.maximum(b.input("Absorption", "color"), 0.0), b.maximum(b.input("Depth", "float"), 0.0))
    inputs = {"eta": eta, "sigma_d": sigma_d, "kappa_top": kappa_from_roughness(b, b.input("Top Roughness", "float"))}
    if p.base.type != "diffuse":
        inputs["kappa_bottom"] = kappa_from_roughness(b, b.input("Bottom Roughness", "float"))
    base = p.base
    if base.type == "dielectric_rough":
        base = replace(base, ior=b.input("Base IOR", "float"))
    elif base.type == "conductor":
        base = replace(base, eta=b.input("Base IOR", "color"), k=b.input("Base Extinction", "color"))
    elif base.type == "diffuse":
        inputs["albedo"] = b.input("Base Color", "color")
    k1 = inputs["kappa_top"]
    diffuse = None  # every order over a Lambertian base: one Diffuse closure (their sum, exact)
    lobes = reference.lobes(ops, replace(p, base=base), mu, 0, inputs)
    for lobe in merged_orders(ops, lobes) if p.merge_orders else lobes:
        if lobe.kind == "surface":
            alpha = lobe_alpha(b, k1)
            g1 = reference.smith_g1(ops, mu, k1)
            scale = b.minimum(g1 * g1 * _inverse_g2(b, mu, alpha), MAX_MIX_WEIGHT)
            b.beckmann(b.scale(ops.color(lobe.weight, 0), scale), alpha, eta)
        elif lobe.kind == "reflection":
            alpha = lobe_alpha(b, lobe.kappa)
            b.beckmann(b.scale(lobe.weight, energy_ratio(b, mu, lobe.kappa, alpha)), alpha,
                       normal=endf_axis(b, mu, lobe.kappa))
        elif lobe.kind == "diffuse":
            diffuse = lobe.weight if diffuse is None else diffuse + lobe.weight
        else:
            stretch = 1.0 - 1.0 / SLAB_IOR  # direction deviation per facet tilt at normal incidence
            alpha = lobe_alpha(b, lobe.kappa, stretch)
            b.refraction(lobe.weight, alpha, SLAB_IOR, b.view())
    if diffuse is not None:
        b.diffuse(b.scale(diffuse * mean_entry(ops, eta, k1, sigma_d), np.pi))


def merged_orders(ops, lobes: list) -> list:
    """``lobes`` with the reflection and the transmission orders from ``MERGED_FROM`` on each merged into one lobe:
    their summed weight, and the concentration whose mean cosine is their mean cosines' mean weighted by the weights'
    grey (moment matching on 1 − A3, as the vMF convolution does). [approx: merged-orders]"""
    out, merged = [], {}
    for lobe in lobes:
        if lobe.kind in ("reflection", "transmission") and lobe.order >= MERGED_FROM:
            merged.setdefault(lobe.kind, []).append(lobe)
        else:
            out.append(lobe)
    b = ops.b
    for kind, group in merged.items():
        weight, total, moment = group[0].weight, None, None
        for lobe in group[1:]:
            weight = weight + lobe.weight
        for lobe in group:
            grey = b.channel_mean(lobe.weight)
            total = grey if total is None else total + grey
            term = grey * ops.complement(lobe.kappa)
            moment = term if moment is None else moment + term
        kappa = group[0].kappa if len(group) == 1 else ops.kappa(moment / b.maximum(total, 1e-30))
        out.append(reference.Lobe(kind, MERGED_FROM, weight, kappa))
    return out


# Gauss-Legendre nodes in v = cos²θ on [0, 1] for the cosine-weighted mean over the light's directions.
ENTRY_NODES = 3


def mean_entry(ops, eta, kappa_top, sigma_d):
    """The cosine-weighted hemispherical mean of the diffuse orders' light-side factor ``reference.thin_coat.entry``
    (the top's crossing and the absorption on the way in), 2 ∫ entry(µ) µ dµ = ∫ entry(√v) dv, by ``ENTRY_NODES``
    Gauss-Legendre nodes in v: exact under uniform light (the furnace), not per light direction."""
    x, w = np.polynomial.legendre.leggauss(ENTRY_NODES)
    total = None
    for xj, wj in zip(x, w):
        term = ops.scale(reference.entry(ops, float(np.sqrt(0.5 * (xj + 1.0))), eta, kappa_top, sigma_d), 0.5 * wj)
        total = term if total is None else total + term
    return total


def kappa_from_roughness(b, alpha):
    """κ = 2 / max(α², 2e-6), kept in [1e-3, 1e6] (the model's ``kappa_from_roughness``)."""
    kappa = 2.0 / b.maximum(alpha * alpha, 2.0 / model.MAX_KAPPA)
    return b.maximum(kappa, model.MIN_KAPPA)


def lobe_alpha(b, kappa, stretch: float = 1.0):
    """The Beckmann α rendering a vMF lobe of concentration κ (α = sqrt(2 / κ) / ``stretch``: half vectors 1,
    refracted directions 1 − 1/η), kept in [sqrt(2 / 1e6), 1] (Cycles clamps α to 1)."""
    k_alpha = b.minimum(b.maximum(kappa, 2.0 / (stretch * stretch)), MAX_LOBE_KAPPA)
    return b.sqrt(2.0 / k_alpha) / stretch


def endf_axis(b, mu, kappa):
    """The closure normal of a reflection order: the ENDF lobe W M(h; κ̂) / (4 |o·h|) divides by o·h where a
    microfacet lobe divides by cos θo, and M(h; κ̂) cos θo / (o·h) ≈ M(h; κ̂) e^{1 − (o·h) / cos θo} (first order in
    the half vector's tilt) is a vMF lobe of axis κ̂ n − o / cos θo: the normal tilted away from the view by
    tan δ = tan θo / (κ̂ − 1), at most ``MAX_ENDF_TILT``. [approx: endf-as-beckmann]"""
    sin_o = b.sqrt(1.0 - mu * mu)
    tan_tilt = b.minimum(sin_o / (mu * b.maximum(kappa - 1.0, 1e-6)), MAX_ENDF_TILT)
    cos_tilt = 1.0 / b.sqrt(1.0 + tan_tilt * tan_tilt)
    return b.scale(b.normal(), cos_tilt) - b.scale(b.tangent_plane(b.view()), tan_tilt * cos_tilt)


# The energy of an ENDF lobe over that of Cycles' Beckmann lobe standing in for it, ε(µ, κ̂) ≈ e0(κ̂) (L + (1 − L) /
# (1 + c s^q)), s = α tan θo, L = 1/2 + l1 e^{−l2 κ̂}, e0 = E_ENDF(1, κ̂) / E_Beckmann(1, α) at normal incidence:
# E_ENDF(1, κ̂) = (1 − e^{−κ̂ (1 − 1/√2)}) / (1 − e^{−2κ̂}) exactly, E_Beckmann(1, α) ≈ 1 − g1 e^{−g2 / α²}.
# Fitted to quadratures of the closure about ``endf_axis`` for µ in [0.005, 1], κ̂ in [0.01, 1e4] by
# training/thin_coat_energy_fit.py (``energy_ratio_error``).
ENERGY_FIT = (1.0435, 1.9141, 0.1856, 1.5875)  # c, q, l1, l2
NORMAL_ALBEDO_FIT = (1.1188, 0.7247)  # g1, g2


def energy_ratio(b, mu, kappa, alpha):
    """ε(µ, κ̂): what a reflection order's Beckmann closure is scaled by so that it carries the ENDF lobe's energy
    W ∫ M(h; κ̂) over the half vectors that reflect the view above the surface (``ENERGY_FIT``)."""
    c, q, l1, l2 = ENERGY_FIT
    g1, g2 = NORMAL_ALBEDO_FIT
    k = b.maximum(kappa, 1e-6)
    e_endf = (1.0 - b.exp(-(1.0 - 0.5 ** 0.5) * k)) / (1.0 - b.exp(-2.0 * k))
    e_beckmann = 1.0 - g1 * b.exp(-g2 / (alpha * alpha))
    s = alpha * b.sqrt(1.0 - mu * mu) / mu
    limit = 0.5 + l1 * b.exp(-l2 * k)
    return e_endf / e_beckmann * (limit + (1.0 - limit) / (1.0 + c * b.exp(q * b.log(s))))


def _inverse_g2(b, mu, alpha):
    """1 / G2 of Cycles' Beckmann at the mirror configuration, 1 + 2Λ(θo) (``closures_np.beckmann_lambda``)."""
    return 1.0 + 2.0 * beckmann_lambda(b, mu, alpha)


def beckmann_lambda(b, mu, alpha):
    """Cycles' rational Beckmann Λ (``closures_np.rational_beckmann_lambda``) at cos θ = µ ≥ MIN_COS."""
    return rational_beckmann_lambda(b, alpha * alpha * b.maximum(1.0 / (mu * mu) - 1.0, 0.0))


# ------------------------------------------------------------------------------------------ vMF in backend math

def complement(b, kappa):
    """u = 1 − A3(κ) = 1/κ − 2 e^{−2κ} / (1 − e^{−2κ}) (float32-safe: no overflow; 1/κ where e^{−2κ} vanishes),
    its series 1 − κ/3 below κ = 0.05 (next term κ³/45 < 3e-6)."""
    small = b.step_below(kappa, SERIES_BELOW)
    k = b.maximum(kappa, SERIES_BELOW)
    e = b.exp(-2.0 * k)
    direct = 1.0 / k - 2.0 * e / (1.0 - e)
    return direct * (1.0 - small) + (1.0 - kappa / 3.0) * small


def _a3_derivative(b, kappa):
    """dA3/dκ = 1/κ² − 1/sinh²κ = 1/κ² − 4 e^{−2κ} / (1 − e^{−2κ})², its series 1/3 − κ²/15 below 0.05."""
    small = b.step_below(kappa, SERIES_BELOW)
    k = b.maximum(kappa, SERIES_BELOW)
    e = b.exp(-2.0 * k)
    direct = 1.0 / (k * k) - 4.0 * e / ((1.0 - e) * (1.0 - e))
    return direct * (1.0 - small) + (1.0 / 3.0 - kappa * kappa / 15.0) * small


def kappa_from_complement(b, u, newton: int):
    """κ with 1 − A3(κ) = u: 1/u below u = 1e-3 (exact to e^{−2000}), else Banerjee's r (3 − r²) / (1 − r²) with
    r = 1 − u, 1 − r² = u (2 − u), refined by ``newton`` Newton steps on u(κ)."""
    u = b.minimum(b.maximum(u, 1e-30), 1.0)
    sharp = b.step_below(u, INVERSE_BELOW)
    us = b.maximum(u, INVERSE_BELOW)  # the Banerjee branch, kept finite where it is not used
    r = 1.0 - us
    kappa = r * (3.0 - r * r) / (us * (2.0 - us))
    for _ in range(newton):
        kappa = b.maximum(kappa + (complement(b, kappa) - us) / _a3_derivative(b, kappa), 1e-6)
    return (1.0 / u) * sharp + kappa * (1.0 - sharp)


# ------------------------------------------------------------------------------------------ Fresnel and means

def fresnel_conductor(b, c, eta, k):
    """Unpolarised Fresnel reflectance of a conductor of complex IOR η + ik (colours) at cos θ = c (float): the closed
    form with a² + b² = sqrt((η² − k² − s²)² + 4η²k²), s² = 1 − c² (equals ``microfacet.fresnel_conductor``)."""
    white = (1.0, 1.0, 1.0)
    c2 = b.scale(white, c * c)
    s2 = b.scale(white, 1.0 - c * c)
    t0 = eta * eta - k * k - s2
    a2b2 = b.sqrt(t0 * t0 + 4.0 * (eta * eta) * (k * k))
    a = b.sqrt(0.5 * (a2b2 + t0))
    t1 = a2b2 + c2
    t2 = b.scale(a, 2.0 * c)
    rs = (t1 - t2) / (t1 + t2)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4)
    return 0.5 * (rp + rs)


# r̄_e(η) = (c0 √t + c1 + c2 t + c3 t²) t with t = (η − 1) / (η + 1): the hemispherical Fresnel reflectance from
# outside, least squares on η in [1.0001, 3] (``diffuse_means_error`` measures r̄_i).
OUTSIDE_FRESNEL_FIT = (-1.11210002, 0.71264023, 1.19624816, 0.11152269)
# 2 E3(x) ≈ e^{−x} (1 + a x + d x²) / (1 + (a + 1) x + c x² + d x³ / 2): exact at 0 with slope −2 and 2 e^{−x} / x
# as x → ∞; (a, c, d) minimise the largest error over x in [0, 200] (``diffuse_means_error`` measures it).
TRANSMITTANCE_FIT = (11.8804906, 18.26160046, 8.95368252)


def diffuse_means(b, eta, sigma_d):
    """(r̄_i, τ̄) of ``reference.thin_coat.diffuse_means`` by the fits ``OUTSIDE_FRESNEL_FIT`` and
    ``TRANSMITTANCE_FIT``: r̄_i = 1 − (1 − r̄_e) / η², τ̄ = 2 E3(σa d) per channel."""
    c0, c1, c2, c3 = OUTSIDE_FRESNEL_FIT
    t = (eta - 1.0) / (eta + 1.0)
    r_e = (c0 * b.sqrt(t) + c1 + c2 * t + c3 * t * t) * t
    r_i = 1.0 - (1.0 - r_e) / (eta * eta)
    a, c, d = TRANSMITTANCE_FIT
    x = sigma_d
    x2 = x * x
    through = b.exp(-1.0 * x) * (1.0 + a * x + d * x2) / (1.0 + (a + 1.0) * x + c * x2 + (0.5 * d) * (x2 * x))
    return r_i, through


class BackendOps:
    """The operations ``reference.thin_coat.lobes`` needs (see ``reference.thin_coat.Float64Ops``) on an ``expr``
    backend: its math, float32-safe vMF helpers, Fresnel and the diffuse means by fits."""

    def __init__(self, b):
        self.b = b
        self.newton = NEWTON_STEPS[getattr(b, "form", "osl")]
        self.exp, self.log, self.sqrt, self.cos, self.acos = b.exp, b.log, b.sqrt, b.cos, b.acos
        self.maximum, self.minimum = b.maximum, b.minimum

    def scale(self, color, s):
        return self.b.scale(self.color(color, 0), s)

    def complement(self, kappa):
        return complement(self.b, kappa)

    def kappa(self, u):
        return kappa_from_complement(self.b, u, self.newton)

    def fresnel_dielectric(self, c, eta):
        """Handles η < 1: total internal reflection gives 1 (the square root clamps at 0)."""
        return fresnel_dielectric(self.b, c, eta)

    def fresnel_conductor(self, c, eta, k):
        return fresnel_conductor(self.b, c, eta, k)

    def diffuse_means(self, eta, sigma_d):
        return diffuse_means(self.b, eta, sigma_d)

    def color(self, values, n):
        """A constant colour for the backend (numpy: one row per view); backend colours pass through."""
        if isinstance(values, (tuple, list)):
            if hasattr(self.b, "wo"):
                return np.broadcast_to(np.asarray(values, dtype=self.b.wo.dtype), (self.b.n, 3)).copy()
            return tuple(float(v) for v in values)
        return values


# ------------------------------------------------------------------------------------------ measurements

def kappa_error(newton: int, u=None) -> float:
    """Largest relative error of ``kappa_from_complement`` (float64 numpy) against ``vmf.kappa_from_complement`` over
    u in [1e-7, 1] (κ from 0 to 1e7), with ``newton`` steps (the node group: 0, OSL: 2)."""
    from ..reference import vmf
    from .expr import NumpyBackend

    u = np.geomspace(1e-7, 1.0, 2001) if u is None else np.asarray(u, dtype=float)
    b = NumpyBackend(np.tile([0.0, 0.0, 1.0], (len(u), 1)), {})
    exact = vmf.kappa_from_complement(u)
    approx = kappa_from_complement(b, u, newton)
    ok = exact > 0
    return float(np.max(np.abs(approx[ok] / exact[ok] - 1.0)))


def complement_error() -> float:
    """Largest relative error of ``complement`` (float64 numpy) against ``vmf.mean_cosine_complement`` for κ in
    [1e-3, 1e7]."""
    from ..reference import vmf
    from .expr import NumpyBackend

    kappa = np.geomspace(1e-3, 1e7, 2001)
    b = NumpyBackend(np.tile([0.0, 0.0, 1.0], (len(kappa), 1)), {})
    return float(np.max(np.abs(complement(b, kappa) / vmf.mean_cosine_complement(kappa) - 1.0)))


def diffuse_means_error() -> dict:
    """Largest absolute errors of ``diffuse_means`` against ``reference.thin_coat.diffuse_means`` over η in [1.0001, 3]
    and σa d in [0, 1e4]: {"r_i": ..., "tau": ...}."""
    from .expr import NumpyBackend

    eta = np.linspace(1.0001, 3.0, 200)
    sigma_d = np.concatenate([[0.0], np.geomspace(1e-4, 1e4, 199)])
    b = NumpyBackend(np.tile([0.0, 0.0, 1.0], (200, 1)), {})
    r_i, tau = diffuse_means(b, eta, np.repeat(sigma_d[:, None], 3, axis=1))
    ref_r = np.array([reference.diffuse_means(e, 0.0)[0] for e in eta])
    _, ref_tau = reference.diffuse_means(1.5, sigma_d)
    return {"r_i": float(np.max(np.abs(r_i - ref_r))), "tau": float(np.max(np.abs(tau[:, 0] - ref_tau)))}


def endf_energy(mu, kappa, n: tuple = (256, 64)) -> np.ndarray:
    """The energy of a reflection order's ENDF lobe per unit weight, ∫ M(h; κ̂) over the half vectors that reflect the
    view (cos θo = ``mu``) above the surface, by a stratified vMF quadrature (``n`` = (cos, azimuth) strata)."""
    from ..reference import vmf

    u1 = (np.arange(n[0]) + 0.5) / n[0]
    u2 = (np.arange(n[1]) + 0.5) / n[1]
    u1, u2 = (a.ravel() for a in np.meshgrid(u1, u2, indexing="ij"))
    out = []
    for m, k in np.broadcast(mu, kappa):
        h = vmf.sample(np.full(u1.shape, k), u1, u2)
        oh = h[:, 0] * np.sqrt(1.0 - m * m) + h[:, 2] * m
        out.append(np.mean((oh > 0.0) & (2.0 * oh * h[:, 2] - m > 0.0)))
    return np.array(out)


def energy_ratio_error(mu=None, kappa=None) -> float:
    """Largest relative error of ``energy_ratio`` against the ratio of ``endf_energy`` to the albedo of Cycles'
    Beckmann closure about ``endf_axis`` (``closures_np.beckmann_reflection_albedo``) over a grid of views and
    concentrations (by default cos θo in [0.005, 1] and κ̂ in [0.01, 1e4], 8 x 9 points)."""
    from . import closures_np
    from .expr import NumpyBackend

    mu = np.geomspace(0.005, 1.0, 8) if mu is None else np.asarray(mu, dtype=float)
    kappa = np.geomspace(0.01, 1e4, 9) if kappa is None else np.asarray(kappa, dtype=float)
    m, k = (a.ravel() for a in np.meshgrid(mu, kappa, indexing="ij"))
    wo = np.stack([np.sqrt(1.0 - m * m), np.zeros_like(m), m], axis=1)
    b = NumpyBackend(wo, {})
    alpha = lobe_alpha(b, k)
    exact = endf_energy(m, k) / closures_np.beckmann_reflection_albedo(wo, alpha, normal=endf_axis(b, m, k))[:, 0]
    return float(np.max(np.abs(energy_ratio(b, m, k, alpha) / exact - 1.0)))
