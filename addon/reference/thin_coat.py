"""Thin transparent coat with the extended normal distribution function (ENDF; paper: thin_layers_endf, Sec. 5).

Conventions: float64, vectorised numpy; ``eval(p, wi, wo)`` is the BSDF (no cosine) for light from ``wi`` seen from
``wo`` (local frame, z the macro normal). The model is built from the view: the paper traces from the viewing
direction o = ``wo`` (Sec. 4: "we regard the viewing direction as the incident"), so it is not reciprocal (the
paper does not claim it; docs/accuracy.md measures it) and ``sample`` draws ``wi`` given ``wo``.

The BSDF is a sum of lobes, all evaluated from the view's mean path (Sec. 5.1: the "remaining terms" at the mean
directions; with µm = n and no bump the mean path is the mirror path, refracted at angle θt inside):

* order 0, the top interface: the microfacet BRDF F(i·h) G1(o) G1(i) D(h) / (4 cos θo cos θi) (Eq. 1-2) with
  the vMF NDF D = M(m; n, κ1) / A3(κ1) (Eq. 6), Smith masking G1 from Eq. 7 with the projected area of Eq. 8,
  Fresnel Eq. 9. Exact given Eq. 8.
* reflection order k = 1..bounces (k reflections at the bottom, k − 1 inside the top): the ENDF lobe
  f_k(o, i) = W_k(o) D̂_k(h) / (4 |o·h| cos θi), D̂_k = M(h; n, κ̂_k) (Eq. 19: D(i) = D̂(h) ||dh/di||), whose
  concentration comes from joint spherical warping (Eq. 26 generalised to k bounces): every microfacet lobe on the
  path is warped to the exit direction by its Jacobian chain (Eqs. 12, 13, 21, 24), the warped lobes are
  convolved (Eq. 18: mean cosines multiply, ``vmf.convolve``), then κ̂ = 4 cos θo κ_i (Eq. 19).
  W_k is the product of the path's interaction energies at the mean directions (``_interaction``), and the
  absorption e^{−σa d / cos θt} per traversal (Eq. 27).
* over a diffuse base, order k is Lambertian in i: the light enters at its own angle (``entry``), is reflected
  by the base k times with k − 1 internal reflections of cosine-distributed light in between (hemispherical
  means), and leaves towards o.
* ``slab`` (no base): transmission order j = 0..bounces (j reflections at the bottom) is the vMF lobe of exit
  directions around −o of Eq. 23, f = W M(i; −o, κ) / |cos θi| (the slab's Eq. 23 generalised like Eq. 26).

Our reading of the remaining terms (Sec. 5.1 names them M_t M_r M_t, Eqs. 2 and 4, but their product is not
dimensionless as printed): each interaction contributes what its microfacet BSDF transmits or reflects in total,
integrated over its own NDF and evaluated at the mean directions: the visible-normal average of F G1(out) (resp.
(1 − F) G1(out)) is F(c) G1(w_out) at the mean normal n (the incoming masking G1(in) is the visible-normal
normalisation). With these weights the lobes carry the energy the mean path carries: ∫ f_k cos θi ≤ W_k.

``lobes(ops, ...)`` computes the weights and concentrations once for any backend: the reference passes
``Float64Ops`` (exact vMF inverse, exact Fresnel), the Cycles mapping its expression backend (nodes.thin_coat).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..models.thin_coat import Params, params_from_dict  # noqa: F401  (the Python API: reference.thin_coat)
from . import lobes as lobe_choice
from . import microfacet, vmf
from .frames import as_directions, dot, normalize, reflect

# ``sample(p, wo, u)`` draws the light direction for a view (the model is built from the view), the opposite of
# the other references; a model bulk under a porous layer is sampled accordingly (``micrograin.samples_from_view``).
SAMPLES_FROM_VIEW = True
DIFFUSE_NODES = 32  # Gauss-Legendre nodes of the hemispherical means over internal cosines (diffuse base)


class Lobe(NamedTuple):
    """One term of the BSDF seen from the view: ``kind`` in surface / reflection / diffuse / transmission,
    ``order`` (bottom reflections), ``weight`` its energy factor (colour; a diffuse lobe's view part only),
    ``kappa`` its concentration (reflection: the ENDF κ̂ of half vectors; transmission: of exit directions;
    surface: κ1; diffuse: unused)."""

    kind: str
    order: int
    weight: object
    kappa: object


# ------------------------------------------------------------------------------- masking (Eqs. 7-8)

def projected_area(ops, cos_v, kappa):
    """∫⟨v, m⟩ M(m; n, κ) dm ≈ a cos(b arccos(v·n)), a = (A3 + 1)² / 4, b = A3^{1/3} (Eq. 8)."""
    a3 = 1.0 - ops.complement(kappa)
    a = 0.25 * (a3 + 1.0) * (a3 + 1.0)
    b = ops.exp(ops.log(ops.maximum(a3, 1e-30)) / 3.0)
    return a * ops.cos(b * ops.acos(ops.minimum(cos_v, 1.0)))


def smith_g1(ops, cos_v, kappa):
    """G1(v) = cos θv A3 / ∫⟨v, m⟩M dm (Eq. 7 with D = M / A3, Eq. 6), the integral by Eq. 8; clipped to [0, 1]
    (Eq. 8 is an approximation: it may slightly exceed the exact G1's bound)."""
    a3 = 1.0 - ops.complement(kappa)
    return ops.minimum(cos_v * a3 / ops.maximum(projected_area(ops, cos_v, kappa), 1e-30), 1.0)


# ------------------------------------------------------------------------------- the mean path

def refracted_cosine(ops, c, eta):
    """cos θt inside the coat for cos θ = c outside (Snell; always real for η ≥ 1)."""
    return ops.sqrt(ops.maximum(1.0 - (1.0 - c * c) / (eta * eta), 0.0))


def entry(ops, c, eta, kappa_top, sigma_d):
    """What crossing the top inwards at cos θ = c and reaching the bottom leaves of the light: the energy
    (1 − F(c)) G1(θt) and the absorption e^{−σa d / cos θt} (Eq. 27), a colour."""
    ct = refracted_cosine(ops, c, eta)
    crossing = (1.0 - ops.fresnel_dielectric(c, eta)) * smith_g1(ops, ct, kappa_top)
    return ops.scale(ops.exp(ops.scale(sigma_d, -1.0 / ops.maximum(ct, 1e-30))), crossing)


def _bottom_fresnel(ops, p_base, ct, eta, n):
    """Reflectance of the bottom interface at the mean normal seen from inside at cos θt, a colour."""
    if p_base.type == "conductor":
        return ops.fresnel_conductor(ct, ops.scale(ops.color(p_base.eta, n), 1.0 / eta),
                                     ops.scale(ops.color(p_base.k, n), 1.0 / eta))
    relative = p_base.ior / eta if p_base.type == "dielectric_rough" else 1.0 / eta
    return ops.scale(ops.color((1.0, 1.0, 1.0), n), ops.fresnel_dielectric(ct, relative))


def _exit_jacobian(c_o, ct, eta):
    """Solid angle inside per solid angle outside at the exit, ||dt/di|| = cos θo / (η² cos θt) (Eq. 21)."""
    return c_o / (eta * eta * ct)


def _facet_refraction_jacobian(c_o, ct, eta):
    """||dm/di|| of the refraction out of the coat at the mean normal (Eq. 13 in the cancellation-free form of
    ``warping.refraction_jacobian``): cos θo (cos θo + η cos θt)² / (η² − 1)², +inf-bound as η → 1 (the facets
    stop deflecting). Entering, ||dm/dt|| is this times η² cos θt / cos θo, which the exit Jacobian
    ``_exit_jacobian`` cancels: both top crossings warp κ1 by this same factor."""
    s = c_o + eta * ct
    return c_o * s * s / ((eta * eta - 1.0) * (eta * eta - 1.0))


def _convolved(ops, kappas):
    """κ of the convolution of vMF lobes (Eq. 18 repeated): the mean cosines multiply, so the complements combine
    as u = u1 + u2 − u1 u2 (``vmf.convolve``), which keeps the digits of sharp lobes where A3 rounds to 1."""
    u = None
    for kappa in kappas:
        uj = ops.complement(kappa)
        u = uj if u is None else u + uj - u * uj
    return ops.kappa(u)


def lobes(ops, p: Params, cos_o, n: int, inputs: dict | None = None) -> list[Lobe]:
    """The BSDF's lobes for n views at cos θo (module docstring). ``inputs`` may replace the node-editable values
    (``eta``, ``kappa_top``, ``kappa_bottom``, ``sigma_d`` = σa d, ``albedo``) by backend values."""
    inputs = inputs or {}
    eta = inputs.get("eta", p.eta)
    k1 = inputs.get("kappa_top", p.kappa_top)
    k2 = inputs.get("kappa_bottom", p.kappa_bottom)
    sigma_d = inputs.get("sigma_d", ops.color(tuple(s * p.depth for s in p.sigma_a), n))
    c_o = cos_o
    ct = refracted_cosine(ops, c_o, eta)
    out = [Lobe("surface", 0, ops.color((1.0, 1.0, 1.0), n), k1)]
    if p.bounces == 0 and not p.transmits:
        return out
    f_top = ops.fresnel_dielectric(c_o, eta)  # = the internal reflectance at θt (Fresnel is symmetric)
    down = ops.exp(ops.scale(sigma_d, -1.0 / ops.maximum(ct, 1e-30)))  # one traversal at θt (Eq. 27)
    leave = (1.0 - f_top) * smith_g1(ops, c_o, k1)
    if p.base.type == "diffuse":
        return out + _diffuse_lobes(ops, p, eta, inputs.get("albedo", ops.color(p.base.albedo, n)),
                                    ops.scale(down, leave), sigma_d)
    enter = entry(ops, c_o, eta, k1, sigma_d)
    bottom = ops.scale(_bottom_fresnel(ops, p.base, ct, eta, n) * down, smith_g1(ops, ct, k2))
    top_inside = ops.scale(down, f_top * smith_g1(ops, ct, k1))  # reflected under the top and back down
    j_exit = _exit_jacobian(c_o, ct, eta)
    top_kappa = k1 * _facet_refraction_jacobian(c_o, ct, eta)
    bottom_kappa = k2 / (4.0 * ct) * j_exit  # Eq. 12's 1 / (4 cos) at the bottom, then out through the top
    inside_kappa = k1 / (4.0 * ct) * j_exit
    weight = ops.scale(enter, leave)
    for k in range(1, p.bounces + 1):
        weight = weight * bottom if k == 1 else weight * top_inside * bottom
        kappa_i = _convolved(ops, [top_kappa] + [bottom_kappa] * k + [inside_kappa] * (k - 1) + [top_kappa])
        out.append(Lobe("reflection", k, weight, 4.0 * c_o * kappa_i))  # Eq. 19 at µ = n
    if p.transmits:
        out += _slab_lobes(ops, p, eta, enter, top_inside, bottom, top_kappa, bottom_kappa, inside_kappa,
                           c_o, ct, k2)
    return out


def _slab_lobes(ops, p, eta, enter, top_inside, bottom, top_kappa, bottom_kappa, inside_kappa, c_o, ct, k2):
    """Transmission orders j = 0..bounces through a free-standing slab (Eq. 23): out through the bottom parallel
    to the view, the bottom's exit facets warped like the top's (``_facet_refraction_jacobian``)."""
    leave = (1.0 - ops.fresnel_dielectric(c_o, eta)) * smith_g1(ops, c_o, k2)
    exit_kappa = k2 * _facet_refraction_jacobian(c_o, ct, eta)
    weight = ops.scale(enter, leave)
    out = []
    for j in range(p.bounces + 1):
        if j:
            weight = weight * bottom * top_inside
        kappa = _convolved(ops, [top_kappa] + [bottom_kappa] * j + [inside_kappa] * j + [exit_kappa])
        out.append(Lobe("transmission", j, weight, kappa))
    return out


def _hemispherical_mean(f):
    """2 ∫0^1 f(µ) µ dµ by Gauss-Legendre (``DIFFUSE_NODES``) over the last axis of f(µ)."""
    x, w = np.polynomial.legendre.leggauss(DIFFUSE_NODES)
    mu = 0.5 * (x + 1.0)
    return np.sum(f(mu) * w * mu, axis=-1)


def diffuse_means(eta, sigma_d):
    """For cosine-distributed light inside the coat: the share the top reflects back from inside, r̄_i =
    1 − (1 − r̄_e) / η² (r̄_e the outside hemispherical Fresnel reflectance; the rough top's masking is left out),
    and the coat's one-way transmittance τ̄ = 2 ∫ e^{−σa d / µ} µ dµ = 2 E3(σa d), a colour."""
    r_e = _hemispherical_mean(lambda mu: microfacet.fresnel_dielectric(mu, eta))
    sigma_d = np.asarray(sigma_d, dtype=float)
    through = _hemispherical_mean(lambda mu: np.exp(-sigma_d[..., None] / mu))
    return 1.0 - (1.0 - r_e) / (eta * eta), through


def _diffuse_lobes(ops, p, eta, albedo, view, sigma_d):
    """Orders over a Lambertian base, view part only (``eval`` multiplies by ``entry`` at the light's angle):
    ρ / (π η²) · view · (ρ r̄_i τ̄²)^{k−1}, view = (1 − F(θo)) G1(θo) e^{−σa d / cos θt}; 1 / η² is the radiance
    compression of light leaving the coat."""
    r_i, through = ops.diffuse_means(eta, sigma_d)
    loop = ops.scale(albedo * through * through, r_i)
    weight = ops.scale(albedo * view, 1.0 / (np.pi * eta * eta))
    out = []
    for k in range(1, p.bounces + 1):
        out.append(Lobe("diffuse", k, weight, None))
        weight = weight * loop
    return out


class Float64Ops:
    """The operations ``lobes`` needs, exact in float64 numpy (floats (N,), colours (N, 3))."""

    exp, log, sqrt, cos, acos = np.exp, np.log, np.sqrt, np.cos, np.arccos
    maximum, minimum = staticmethod(np.maximum), staticmethod(np.minimum)
    complement = staticmethod(vmf.mean_cosine_complement)
    kappa = staticmethod(vmf.kappa_from_complement)
    fresnel_dielectric = staticmethod(microfacet.fresnel_dielectric)
    diffuse_means = staticmethod(diffuse_means)

    @staticmethod
    def scale(color, s):
        return np.asarray(color, dtype=float) * np.asarray(s, dtype=float)[..., None]

    @staticmethod
    def fresnel_conductor(c, eta, k):
        return microfacet.fresnel_conductor(c, np.asarray(eta)[0], np.asarray(k)[0])

    @staticmethod
    def color(values, n):
        return np.broadcast_to(np.asarray(values, dtype=float), (n, 3)).copy()


F64 = Float64Ops()


# ------------------------------------------------------------------------------- evaluation

class Sample(NamedTuple):
    """Sampled light directions ``wi`` for each view, with weight f |cos wi| / pdf, and pdf."""

    wi: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray


def _seen_from_above(p: Params, wi, wo):
    """(p, wi, wo) with the viewer above: a slab seen from below is the slab upside down (κ1 and κ2 exchanged)."""
    below = wo[:, 2] < 0.0
    if not (p.transmits and below.any()):
        return [(p, wi, wo, ~below)]
    flip = np.array([1.0, 1.0, -1.0])
    upside_down = Params(p.kappa_bottom, p.kappa_top, p.eta, p.sigma_a, p.depth, p.base, p.bounces)
    return [(p, wi, wo, ~below), (upside_down, wi * flip, wo * flip, below)]


def lobes_at(p: Params, wo):
    """The lobes (float64) for views ``wo`` above the surface."""
    return lobes(F64, p, np.maximum(wo[:, 2], 1e-12), len(wo))


def _surface(p: Params, wi, wo):
    """Order 0: F(i·h) G1(o) G1(i) D(h) / (4 cos θo cos θi), D = M / A3 (Eqs. 1, 2, 6-9)."""
    h = normalize(wi + wo)
    ci, co = np.maximum(wi[:, 2], 1e-100), np.maximum(wo[:, 2], 1e-100)  # G1 -> 0 makes f -> 0 there
    d = vmf.density_around(h, np.array([0.0, 0.0, 1.0]), p.kappa_top) / vmf.a3(p.kappa_top)
    g = smith_g1(F64, ci, p.kappa_top) * smith_g1(F64, co, p.kappa_top)
    return microfacet.fresnel_dielectric(dot(wi, h), p.eta) * g * d / (4.0 * ci * co)


def lobe_value(p: Params, lobe: Lobe, wi, wo):
    """One lobe's f(wi, wo) (N, 3) for views above (module docstring)."""
    up = wi[:, 2] > 0.0
    ci = np.abs(wi[:, 2])
    if lobe.kind == "transmission":
        dens = vmf.density_around(wi, -wo, lobe.kappa) / np.maximum(ci, 1e-300)
        return np.where(~up[:, None] & (ci[:, None] > 0), lobe.weight * dens[:, None], 0.0)
    if lobe.kind == "surface":
        value = _surface(p, wi, wo)[:, None] * lobe.weight
    elif lobe.kind == "diffuse":
        sigma_d = np.asarray(p.sigma_a, dtype=float) * p.depth
        value = lobe.weight * entry(F64, np.minimum(ci, 1.0), p.eta, p.kappa_top, sigma_d[None, :])
    else:
        h = normalize(wi + wo)
        dens = vmf.density_around(h, np.array([0.0, 0.0, 1.0]), lobe.kappa) / (4.0 * np.maximum(dot(wo, h), 1e-300)
                                                                          * np.maximum(ci, 1e-300))
        value = lobe.weight * dens[:, None]
    return np.where(up[:, None], value, 0.0)


def eval_orders(p: Params, wi, wo):
    """f(wi, wo) per order (bounces + 1, N, 3), no cosine: order 0 the top surface (light above) or the straight
    transmission of a slab (light below), order k the k-th subsurface reflection or transmission order."""
    wi, wo = as_directions(wi), as_directions(wo)
    wi, wo = np.broadcast_arrays(wi, wo)
    out = np.zeros((p.bounces + 1, len(wo), 3))
    for q, a, b, rows in _seen_from_above(p, wi, wo):
        if not rows.any():
            continue
        a, b = a[rows], b[rows]
        for lobe in lobes_at(q, b):
            value = lobe_value(q, lobe, a, b)
            out[lobe.order, rows] += np.where(b[:, 2:] > 0.0, value, 0.0)
    return out


def eval(p: Params, wi, wo):
    """The BSDF f(wi, wo) (N, 3), no cosine: the sum of ``eval_orders``."""
    return eval_orders(p, wi, wo).sum(axis=0)


# ------------------------------------------------------------------------------- sampling (Sec. 5.4)

def _lobe_probabilities(p: Params, wo, found):
    """(N, L) probabilities of picking each lobe: its expected albedo (the surface F(θo), a reflection or
    transmission lobe its weight, a diffuse lobe its weight times π, an upper bound of ∫ entry cos), channel-averaged."""
    f = microfacet.fresnel_dielectric(wo[:, 2], p.eta)
    energy = [np.maximum(f, 1e-3) if lobe.kind == "surface"
              else np.mean(lobe.weight, axis=1) * (np.pi if lobe.kind == "diffuse" else 1.0) for lobe in found]
    e = np.stack(energy, axis=1)
    return e / e.sum(axis=1, keepdims=True)


def _reflection_pdf(kappa, wi, wo):
    """Density of wi = reflect(wo, h), h ~ M(n, κ) on the whole sphere: (M(h) + M(−h)) / (4 |wo·h|). Every h on
    the great circle orthogonal to wo reflects to −wo: the density has an integrable spike there (below the
    horizon for views above, where reflection lobes are zero)."""
    h = normalize(wi + wo)
    z = np.array([0.0, 0.0, 1.0])
    dens = vmf.density_around(h, z, kappa) + vmf.density_around(-h, z, kappa)
    return np.divide(dens, 4.0 * np.abs(dot(wo, h)), out=np.zeros(len(wo)), where=np.abs(dot(wo, h)) > 0)


def _lobe_pdf(lobe: Lobe, wi, wo):
    """Density of ``_lobe_sample``: cosine (diffuse), the vMF around −wo (transmission), else the (E)NDF's
    reflection density."""
    if lobe.kind == "diffuse":
        return lobe_choice.cosine_pdf(1.0, wi)
    if lobe.kind == "transmission":
        return vmf.density_around(wi, -wo, lobe.kappa)
    return _reflection_pdf(lobe.kappa, wi, wo)


def _lobe_sample(lobe: Lobe, wo, u1, u2):
    kappa = np.broadcast_to(np.asarray(lobe.kappa if lobe.kappa is not None else 0.0), (len(wo),))
    if lobe.kind == "diffuse":
        return lobe_choice.cosine_sample(1.0, u1, u2)
    if lobe.kind == "transmission":
        return vmf.sample_around(-wo, kappa, u1, u2)
    return reflect(wo, vmf.sample(kappa, u1, u2))


def _pdf_above(p: Params, wi, wo):
    found = lobes_at(p, wo)
    prob = _lobe_probabilities(p, wo, found)
    return sum(prob[:, column] * _lobe_pdf(lobe, wi, wo) for column, lobe in enumerate(found))


def pdf(p: Params, wi, wo):
    """Solid-angle density (N,) of ``sample``'s wi given wo."""
    wi, wo = np.broadcast_arrays(as_directions(wi), as_directions(wo))
    out = np.zeros(len(wo))
    for q, a, b, rows in _seen_from_above(p, wi, wo):
        if rows.any():
            out[rows] = _pdf_above(q, a[rows], b[rows])
    return out


def _sample_above(p: Params, wo, u):
    found = lobes_at(p, wo)
    lobe, _, _ = lobe_choice.choose(_lobe_probabilities(p, wo, found), u[:, 0])
    wi = np.empty_like(wo)
    for column, lb in enumerate(found):
        m = lobe == column
        if m.any():
            wi[m] = _lobe_sample(lb._replace(kappa=_rows(lb.kappa, m)), wo[m], u[m, 1], u[m, 2])
    return wi


def _rows(kappa, m):
    return None if kappa is None else np.broadcast_to(np.asarray(kappa), m.shape)[m]


def sample(p: Params, wo, u) -> Sample:
    """Sample wi for each view wo from u in [0, 1)^3: u0 picks a lobe by ``_lobe_probabilities``; the surface and
    reflection lobes reflect wo about a half vector drawn from their (E)NDF (Sec. 5.4: one draw per bounce
    order, not one per interface), a diffuse lobe draws a cosine, a transmission lobe its vMF around −wo."""
    wo, u = as_directions(wo), as_directions(u)
    wi = -wo  # views below an opaque coat: nothing to draw (weight and pdf 0)
    for q, _, b, rows in _seen_from_above(p, wo, wo):
        if rows.any():
            drawn = _sample_above(q, b[rows], u[rows])
            wi[rows] = drawn if q is p else drawn * np.array([1.0, 1.0, -1.0])
    density = pdf(p, wi, wo)
    value = eval(p, wi, wo) * np.abs(wi[:, 2:])
    weight = np.divide(value, density[:, None], out=np.zeros_like(value), where=density[:, None] > 0)
    return Sample(wi, weight, density)


def lobe_samples(p: Params, lobe: Lobe, wo, n: int, rng):
    """n directions drawn from one lobe's own sampler for the single view ``wo`` (1, 3) above, and their weights
    f_lobe |cos wi| / pdf_lobe (n, 3): each lobe integrated alone, without variance from lobes of other widths."""
    ws = np.repeat(wo, n, axis=0)
    u = rng.random((2, n))
    x = _lobe_sample(lobe, ws, u[0], u[1])
    density = _lobe_pdf(lobe, x, ws)[:, None]
    value = lobe_value(p, lobe, x, ws) * np.abs(x[:, 2:])
    return x, np.divide(value, density, out=np.zeros_like(value), where=density > 0)


def directional_albedo(p: Params, wo, n: int = 16384, seed: int = 0, orders: bool = False):
    """∫ f(wi, wo) |cos wi| dwi (N, 3) (per order (bounces + 1, N, 3) with ``orders``): seeded Monte Carlo, n samples
    of each lobe's own sampler (``lobe_samples``). Zero for views below an opaque coat."""
    wo = as_directions(wo)
    rng = np.random.default_rng(seed)
    albedo = np.zeros((p.bounces + 1, len(wo), 3))
    for row in range(len(wo)):
        seen = [v for v in _seen_from_above(p, wo[row:row + 1], wo[row:row + 1]) if v[3].all()]
        if not seen:
            continue
        q, _, w, _ = seen[0]
        for lobe in lobes_at(q, w):
            albedo[lobe.order, row] += lobe_samples(q, lobe, w, n, rng)[1].mean(axis=0)
    return albedo if orders else albedo.sum(axis=0)


def furnace_albedo(p: Params, wo, n: int = 4096, seed: int = 0):
    """What a white furnace returns towards wo (N, 3): the directional albedo (the model has no Dirac)."""
    return directional_albedo(p, wo, n=n, seed=seed)
