"""What Cycles' closures evaluate to, in float64 numpy (used to predict a mapping's renders without Blender).

Each function returns the BSDF value without the cosine for light from ``wi`` seen from ``wo`` (local frame,
z = shading normal = geometric normal of the comparison scenes); the renderer multiplies by |cos θi| w.r.t. z.
Cycles' GGX uses the height-correlated Smith G (research notes §6, verified).

A glossy closure whose normal is not the shading normal (tilted flakes) differs from a plain GGX lobe around
that normal in two ways, both read in Cycles' kernel (closure/bsdf_util.h, closure/bsdf_microfacet.h, the
same in 4.2 and 5.0; its ωi is our ωo) and measured (tests/blender/test_cycles_forms.py, tilted flakes):

* Cycles' closure evaluation includes the cosine foreshortening w.r.t. the *closure's* normal N
  (bsdf_microfacet_eval returns F D G / (4 cos(N, ωo)) = f · cos(N, ωi)), so what Cycles renders is
  f · cos(N, ωi) · E, not f · cos θi · E: the value here is f · cos(N, ωi) / cos θi.
* At closure setup Cycles replaces N by ``ensure_valid_specular_reflection(Ng, ωo, N)`` (the material's
  "Bump Map Correction", on by default): where the mirror direction of ωo about N falls below the surface
  (dot(Ng, R) < min(0.9 cos θo, 0.01)), N is turned towards Ng, in the plane of N and Ng, just enough to lift R
  to that threshold. Both forms do this (Glossy BSDF node, OSL microfacet / generalized_schlick_bsdf).
  The weights the mapping computes from the normal (Schlick at the view) use the unbent normal.

Beckmann closures (``beckmann_reflection``, ``beckmann_refraction``) follow Cycles' ``bsdf_microfacet_eval``
(kernel/closure/bsdf_microfacet.h, the same in 4.2 and 5.0; rendered and compared in
tests/blender/test_thin_coat_cycles.py): D = e^{−tan²θh / α²} / (π α² cos⁴θh), the height-correlated
G2 = 1 / (1 + Λ(ωi) + Λ(ωo)) with Cycles' rational Beckmann Λ (Walter et al. 2007 below their Eq. 27, zero for
a = 1 / (α tan θ) ≥ 1.6; not the exact erf form), α clamped to [0, 1] at closure setup.

Light below the surface gives nothing, whatever the closure normal (evaluation tests the smooth normal: 4.2
passes it to bsdf_microfacet_eval, 5.0 in bump_shadowing_term). Blender 4.2's *sampling* does not test the
closure normal, so under environment light reached by BSDF sampling 4.2 renders a little more than any
BSDF: ``ggx_sampling_leak`` models it (5.0 rejects those samples).
"""
from __future__ import annotations

import functools
import os

import numpy as np

from ..reference import microfacet
from ..reference.frames import dot as _dot
from ..reference.frames import normalize as _normalize
from .numpy_math import NumpyMath


def ggx_d(h_local, alpha_x, alpha_y):
    """Anisotropic GGX NDF for half-vectors in the closure's (tangent, bitangent, normal) frame."""
    hx, hy, hz = h_local[:, 0] / alpha_x, h_local[:, 1] / alpha_y, h_local[:, 2]
    t = hx * hx + hy * hy + hz * hz
    return np.where(hz > 0, 1.0 / (np.pi * alpha_x * alpha_y * t * t), 0.0)


def ggx_lambda(v_local, alpha_x, alpha_y):
    z2 = np.maximum(v_local[:, 2] ** 2, 1e-300)
    a2 = (alpha_x * v_local[:, 0]) ** 2 + (alpha_y * v_local[:, 1]) ** 2
    return 0.5 * (np.sqrt(1.0 + a2 / z2) - 1.0)


def _frame(normal, tangent, n):
    nz = _normalize(np.broadcast_to(normal, (n, 3)))
    t = np.broadcast_to(tangent, (n, 3))
    t = _normalize(t - _dot(t, nz)[:, None] * nz)
    return t, np.cross(nz, t), nz


def ensure_valid_specular_reflection(normal, wo):
    """Cycles' ``ensure_valid_specular_reflection(Ng, I, N)`` with Ng = z, I = ``wo`` (N, 3 each): ``normal``
    where the mirror direction of ``wo`` about it is above the threshold min(0.9 cos θo, 0.01), else the
    normal turned towards z (keeping its azimuth) until the mirror direction is at the threshold."""
    normal = np.asarray(normal, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    iz = wo[:, 2]
    r_z = 2.0 * _dot(normal, wo) * normal[:, 2] - iz
    threshold = np.minimum(0.9 * iz, 0.01)
    valid = r_z >= threshold
    if valid.all():
        return normal
    x = normal * np.array([1.0, 1.0, 0.0])
    length = np.linalg.norm(x, axis=1, keepdims=True)
    x = np.where(length > 0.0, x / np.where(length > 0.0, length, 1.0), normal)  # safe_normalize_fallback
    ix = _dot(wo, x)
    a = np.maximum(ix * ix + iz * iz, 1e-300)
    b = 2.0 * (a + iz * threshold)
    c = (threshold + iz) ** 2
    root = np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))
    nz2 = np.where(ix < 0.0, 0.25 * (b + root) / a, 0.25 * (b - root) / a)
    nx, nz = np.sqrt(np.maximum(1.0 - nz2, 0.0)), np.sqrt(np.maximum(nz2, 0.0))
    bent = nx[:, None] * x + nz[:, None] * np.array([0.0, 0.0, 1.0])
    return np.where(valid[:, None], normal, bent)


def bent_normal(normal, wo):
    """A closure's ``normal`` (N, 3, or one for all views) as Cycles uses it: normalised, then
    ``ensure_valid_specular_reflection``."""
    n = len(wo)
    return ensure_valid_specular_reflection(_normalize(np.broadcast_to(normal, (n, 3)).astype(np.float64)), wo)


def _in_closure_frame(wi, wo, normal, tangent, n):
    """``wi`` and ``wo`` in the frame of the closure's bent ``normal`` (``bent_normal``) and ``tangent``."""
    t, b, nz = _frame(bent_normal(normal, wo), tangent, n)

    def local(v):
        return np.stack([_dot(v, t), _dot(v, b), _dot(v, nz)], axis=1)

    return local(wi), local(wo)


def _ggx(wi, wo, alpha_x, alpha_y, normal, tangent, f0, below_normal: bool, conductor=None):
    """GGX as Cycles evaluates it around the bent ``normal``, as a BSDF w.r.t. z (light above the surface
    only): for light above the closure's normal, or (``below_normal``) for light below it."""
    n = len(wi)
    ax = np.broadcast_to(np.asarray(alpha_x, dtype=float), (n,))
    ay = ax if alpha_y is None else np.broadcast_to(np.asarray(alpha_y, dtype=float), (n,))
    li, lo = _in_closure_frame(wi, wo, normal, tangent, n)
    ok = ((li[:, 2] < 0) if below_normal else (li[:, 2] > 0)) & (lo[:, 2] > 0) & (wi[:, 2] > 0) & (wo[:, 2] > 0)
    h = _normalize(li + lo)
    g2 = 1.0 / (1.0 + ggx_lambda(li, ax, ay) + ggx_lambda(lo, ax, ay))  # Λ depends on cos² only
    with np.errstate(divide="ignore", invalid="ignore"):
        # D G / (4 cos(N, ωi) cos(N, ωo)) · cos(N, ωi) / cos θi: the closure's cosine, not the surface's
        # (below the normal: what Cycles 4.2's sampling returns, D G / (4 cos(N, ωo)))
        f = np.where(ok, ggx_d(h, ax, ay) * g2 / (4.0 * np.abs(wi[:, 2]) * np.abs(lo[:, 2])), 0.0)
    f = np.repeat(f[:, None], 3, axis=1)
    if f0 is not None:
        f = f * microfacet.schlick(f0, _dot(li, h))
    if conductor is not None:
        f = f * microfacet.fresnel_conductor(_dot(li, h), *conductor)
    return f


def ggx_conductor(wi, wo, alpha_x, alpha_y, tangent, eta, k):
    """Cycles' anisotropic GGX conductor (OSL conductor_bsdf, the Metallic BSDF's physical conductor) around z with
    the exact Fresnel of η + ik per microfacet."""
    return _ggx(wi, wo, alpha_x, alpha_y, (0.0, 0.0, 1.0), tangent, None, False, conductor=(eta, k))


def ggx_reflection(wi, wo, alpha_x, alpha_y=None, normal=(0.0, 0.0, 1.0), tangent=(1.0, 0.0, 0.0), f0=None):
    """What Cycles renders for a GGX reflection closure (height-correlated Smith G) around ``normal``
    (anisotropic along ``tangent``), times Schlick's F when ``f0`` is given, as a BSDF w.r.t. z: the normal
    bent by ``ensure_valid_specular_reflection`` and the closure's own cosine (module docstring)."""
    return _ggx(wi, wo, alpha_x, alpha_y, normal, tangent, f0, below_normal=False)


def ggx_sampling_leak(wo, alpha_x, alpha_y=None, normal=(0.0, 0.0, 1.0), tangent=(1.0, 0.0, 0.0), f0=None,
                      quadrature=(64, 128)):
    """Blender 4.2 only: the directional albedo (N, 3) that a GGX closure adds, beyond ``ggx_reflection``,
    under a uniform environment of radiance 1 that is reached by BSDF sampling alone (the furnace scene).

    4.2's bsdf_microfacet_sample rejects a sampled reflection only when it is below the geometric normal, not
    when it is below the closure's normal (5.0 rejects both), and returns D G / (4 cos(N, ωo)) for it, while
    evaluation gives 0 there. So BSDF-sampled rays gather light from the wedge above the surface and below a
    tilted closure normal that no BSDF describes: with light sampling (MIS) it is weighted by the BSDF's MIS
    weight, and a sun (angle 0, never hit by BSDF rays) gets none of it."""
    from ..reference.scenes import directional_albedo

    wo = np.asarray(wo, dtype=np.float64)
    n, per = len(wo), 16
    nq = 2 * quadrature[0] * quadrature[1]
    out = np.zeros((n, 3))
    for s0 in range(0, n, per):
        sl = slice(s0, min(s0 + per, n))

        def take(v, per_pixel_ndim, _sl=sl):  # a per-pixel value: this chunk's, repeated over the nq directions
            if v is None:
                return None
            v = np.asarray(v, dtype=np.float64)
            return np.repeat(v[_sl], nq, axis=0) if v.ndim == per_pixel_ndim else v

        args = [take(alpha_x, 1), take(alpha_y, 1), take(normal, 2), take(tangent, 2), take(f0, 2)]
        out[sl] = directional_albedo(lambda wi, w, _a=args: _ggx(wi, w, *_a, below_normal=True), wo[sl],
                                     quadrature, chunk=per * nq)
    return out


def diffuse(wi, wo):
    same = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.repeat(np.where(same, 1.0 / np.pi, 0.0)[:, None], 3, axis=1)


def translucent(wi, wo):
    opposite = (wi[:, 2] < 0) & (wo[:, 2] > 0)
    return np.repeat(np.where(opposite, 1.0 / np.pi, 0.0)[:, None], 3, axis=1)


def velvet(wi, wo, sigma):
    """Cycles' Ashikhmin velvet (Sheen BSDF node, distribution Ashikhmin; OSL ``ashikhmin_velvet``) around z, as a
    BSDF: D G / (4 cos θi cos θo) with the inverted-Gaussian D = e^{−cot²θh / σ²} / (π σ² sin⁴θh) (Ashikhmin et al.
    2000) and G = min(1, 2 cos θh cos θi / (ωi·h), 2 cos θh cos θo / (ωi·h)) (kernel
    closure/bsdf_ashikhmin_velvet.h, the same in 4.2 and 5.0), σ clamped to at least 0.01 at closure setup; zero
    where h is within 1e-5 of the normal in cosine. Not energy-normalised: its albedo rises past 1 at grazing
    views for large σ."""
    n = len(wi)
    s2 = np.maximum(np.broadcast_to(np.asarray(sigma, dtype=float), (n,)), 0.01) ** 2
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    ci, co = np.where(ok, wi[:, 2], 1.0), np.where(ok, wo[:, 2], 1.0)
    h = _normalize(wi + wo)
    ch, hi = h[:, 2], np.abs(_dot(wi, h))
    ok &= (np.abs(ch) < 1.0 - 1e-5) & (hi > 1e-5)
    sin2 = np.where(ok, 1.0 - ch * ch, 1.0)
    ratio = np.maximum(ch / np.where(ok, hi, 1.0), 1e-5)
    d = np.exp(-(ch * ch / sin2) / s2) / (np.pi * s2 * sin2 * sin2)
    g = np.minimum(1.0, np.minimum(2.0 * ratio * ci, 2.0 * ratio * co))
    f = np.where(ok, d * g / (4.0 * ci * co), 0.0)
    return np.repeat(f[:, None], 3, axis=1)


# Cycles' Microfiber sheen table (``table_sheen_ltc``, intern/cycles/scene/shader.tables, Apache-2.0; the bytes of the
# bpy 4.2 and 5.0 binaries, tests/blender/test_cycles_facts.py): the LTC's a, b and the albedo R over (roughness
# rows, cos θo columns), 32 x 32 each, from Zeltner et al. 2022.
SHEEN_TABLE = os.path.join(os.path.dirname(__file__), "sheen_ltc.npy")
SHEEN_MIN_ROUGHNESS = 1e-3  # Cycles clamps a sheen closure's roughness to [1e-3, 1] at setup


@functools.cache
def sheen_table() -> np.ndarray:
    """(3, 32, 32) float32: a, b, R, each over (roughness, cos θo) (``SHEEN_TABLE``)."""
    return np.load(SHEEN_TABLE)


def table_2d(table, x, y):
    """Cycles' ``lookup_table_read_2D``: ``table`` (rows over y, columns over x, both on [0, 1] uniformly) read
    bilinearly at x, y (clamped to [0, 1])."""
    ny, nx = table.shape

    def cell(v, size):
        f = np.clip(v, 0.0, 1.0) * (size - 1)
        i = np.minimum(f.astype(int), size - 1)
        return i, np.minimum(i + 1, size - 1), f - i

    ix, jx, tx = cell(np.asarray(x, dtype=float), nx)
    iy, jy, ty = cell(np.asarray(y, dtype=float), ny)
    table = table.astype(np.float64)

    def row(r):
        return (1.0 - tx) * table[r, ix] + tx * table[r, jx]

    return (1.0 - ty) * row(iy) + ty * row(jy)


def sheen_transform(cos_o, roughness):
    """The LTC's a, b and the albedo R that Cycles reads at closure setup for views of cosine ``cos_o``."""
    r = np.clip(roughness, SHEEN_MIN_ROUGHNESS, 1.0)
    return tuple(table_2d(plane, cos_o, r) for plane in sheen_table())


def sheen(wi, wo, roughness):
    """Cycles' Microfiber sheen (Sheen BSDF node, distribution Microfiber; OSL ``sheen``) around z (kernel
    closure/bsdf_sheen.h, the same in 4.2 and 5.0), as a BSDF: Zeltner et al. 2022's linearly transformed cosine,
    f cos θi = R · z a² / (π ((a x + b z)² + (a y)² + z²)²), (x, y, z) the light in the frame whose x axis is the
    view's azimuth, a, b, R read from ``sheen_table`` at (cos θo, roughness). The cosine is divided out; a view
    along the normal takes x along the frame's first axis (Cycles' frame is undefined there)."""
    n = len(wi)
    a, b, albedo = sheen_transform(wo[:, 2], np.broadcast_to(np.asarray(roughness, dtype=float), (n,)))
    azimuth = wo * np.array([1.0, 1.0, 0.0])
    length = np.linalg.norm(azimuth, axis=1, keepdims=True)
    t = np.where(length > 1e-12, azimuth / np.maximum(length, 1e-300), np.array([1.0, 0.0, 0.0]))
    x, y, z = _dot(wi, t), wi[:, 0] * -t[:, 1] + wi[:, 1] * t[:, 0], wi[:, 2]
    ok = (z > 0) & (wo[:, 2] > 0)
    len_sqr = (a * x + b * z) ** 2 + (a * y) ** 2 + z * z
    f = np.where(ok, albedo * (a / np.where(ok, len_sqr, 1.0)) ** 2 / np.pi, 0.0)
    return np.repeat(f[:, None], 3, axis=1)


def sheen_albedo(wo, roughness):
    """The sheen closure's directional albedo: R exactly (the transform keeps z, so the LTC integrates to 1 over
    the upper hemisphere)."""
    albedo = sheen_transform(wo[:, 2], np.broadcast_to(np.asarray(roughness, dtype=float), (len(wo),)))[2]
    return np.repeat(np.where(wo[:, 2] > 0, albedo, 0.0)[:, None], 3, axis=1)


TOON_MIN_SIZE = 1e-5  # Cycles clamps a toon closure's Size to [1e-5, 1] at setup


def _toon(wi, wo, axis, size, smooth):
    """Cycles' Toon BSDF (kernel closure/bsdf_toon.h, the same in 4.2 and 5.0) as a BSDF, the cosine w.r.t. z
    divided out: Cycles evaluates f · cos θi = I(γ) / (2π (1 − cos S)), γ the angle between ωi and ``axis``,
    I = 1 within a = size · π/2 and falling linearly to 0 over s = smooth · π/2 more, S = min(a + s, π/2) the cone
    it samples; zero outside that cone and where ωi or ωo is below the surface. No cosine falloff and no masking:
    light at grazing incidence counts fully (a wide lobe without Smith's shadowing)."""
    a = np.clip(size, TOON_MIN_SIZE, 1.0) * (0.5 * np.pi)
    s = np.clip(smooth, 0.0, 1.0) * (0.5 * np.pi)
    cone = min(a + s, 0.5 * np.pi)
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    angle = np.arccos(np.clip(_dot(wi, axis), -1.0, 1.0))
    falloff = 1.0 - (angle - a) / s if s > 0.0 else np.zeros_like(angle)
    intensity = np.where(angle < a, 1.0, np.where(angle < a + s, falloff, 0.0))
    ci = np.where(ok, wi[:, 2], 1.0)
    f = np.where(ok & (angle < cone), intensity / (2.0 * np.pi * (1.0 - np.cos(cone)) * ci), 0.0)
    return np.repeat(f[:, None], 3, axis=1)


def glossy_toon(wi, wo, size, smooth):
    """Cycles' glossy Toon BSDF around z (``_toon`` about the mirror direction of ωo)."""
    return _toon(wi, wo, wo * np.array([-1.0, -1.0, 1.0]), size, smooth)


def diffuse_toon(wi, wo, size, smooth):
    """Cycles' diffuse Toon BSDF around z (``_toon`` about the normal): with size 1, f · cos θi = 1 / (2π) over the
    hemisphere, albedo 1."""
    return _toon(wi, wo, np.array([0.0, 0.0, 1.0]), size, smooth)


def transparent(wi, wo):
    return np.zeros((len(wi), 3))


def conductor(wi, wo, alpha, eta, k):
    return microfacet.conductor_eval(wi, wo, alpha, eta, k)


def dielectric(wi, wo, alpha, ior):
    """Cycles' rough glass (Glass BSDF / dielectric_bsdf): Walter et al.'s GGX dielectric with ωi and ωo exchanged.
    Cycles evaluates the adjoint (a path tracer's throughput from the camera, no radiance scaling): seen from
    above with light from below, a white furnace shows F + (1 − F), not F + (1 − F)/η² (measured, bpy 5.0).
    SpongeCake's reference substrate is a half-space with that 1/η² [approx: dielectric-substrate-adjoint];
    micrograin's dielectric bulk is a glass as renderers see it, like this."""
    return np.repeat(microfacet.dielectric_eval(wo, wi, alpha, ior)[:, None], 3, axis=1)


def rational_beckmann_lambda(b, s):
    """Cycles' Smith Λ for Beckmann as a function of s = α² tan²θ on an ``expr`` backend ``b`` (its rational
    approximation, kernel ``bsdf_lambda_from_sqr_alpha_tan_n``): with a = 1 / sqrt(s), ((0.396 a − 1.259) a + 1) /
    ((2.181 a + 3.535) a), and 0 for a ≥ 1.6 (s < 0.39)."""
    flat = b.step_below(s, 0.39)
    a = 1.0 / b.sqrt(b.maximum(s, 0.39))
    return ((0.396 * a - 1.259) * a + 1.0) / ((2.181 * a + 3.535) * a) * (1.0 - flat)


def beckmann_lambda(cos_v, alpha):
    """Cycles' Smith Λ for Beckmann at cos θ = ``cos_v`` (``rational_beckmann_lambda`` in numpy)."""
    c2 = np.minimum(np.asarray(cos_v, dtype=float) ** 2, 1.0)
    s = np.asarray(alpha, dtype=float) ** 2 * np.maximum(1.0 / np.maximum(c2, 1e-300) - 1.0, 0.0)
    return rational_beckmann_lambda(NumpyMath, s)


def beckmann_d(cos_h, alpha):
    """Cycles' Beckmann NDF e^{−tan²θh / α²} / (π α² cos⁴θh) (even in cos θh, as in the kernel)."""
    c2 = np.minimum(np.asarray(cos_h, dtype=float) ** 2, 1.0)
    a2 = np.asarray(alpha, dtype=float) ** 2
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        d = np.exp(-(1.0 - c2) / (c2 * a2)) / (np.pi * a2 * c2 * c2)
    return np.where(c2 > 0.0, d, 0.0)


def _cycles_alpha(alpha, n):
    return np.clip(np.broadcast_to(np.asarray(alpha, dtype=float), (n,)), 0.0, 1.0)  # clamped at closure setup


def beckmann_reflection(wi, wo, alpha, eta=None, normal=(0.0, 0.0, 1.0)):
    """What Cycles renders for a Beckmann reflection closure around ``normal`` (the shading normal z by default;
    bent as GGX's, ``bent_normal``), as a BSDF w.r.t. z: D G2 / (4 cos(N, ωo) cos θi) (the closure's cosine of ωi
    included, module docstring), times the dielectric Fresnel F(ωi·h, η) per microfacet when ``eta`` is given (OSL
    ``dielectric_bsdf`` with no transmission tint), else no Fresnel (OSL ``microfacet("beckmann", ...)``, the Glossy
    BSDF node)."""
    n = len(wi)
    a = _cycles_alpha(alpha, n)
    li, lo = _in_closure_frame(wi, wo, normal, (1.0, 0.0, 0.0), n)
    ok = (li[:, 2] > 0) & (lo[:, 2] > 0) & (wi[:, 2] > 0) & (wo[:, 2] > 0)
    ci, co = np.where(ok, li[:, 2], 1.0), np.where(ok, lo[:, 2], 1.0)
    h = _normalize(li + lo)
    g2 = 1.0 / (1.0 + beckmann_lambda(ci, a) + beckmann_lambda(co, a))
    f = np.where(ok, beckmann_d(h[:, 2], a) * g2 / (4.0 * np.where(ok, wi[:, 2], 1.0) * co), 0.0)
    f = np.repeat(f[:, None], 3, axis=1)
    if eta is not None:
        f = f * microfacet.fresnel_dielectric(_dot(li, h), np.broadcast_to(np.asarray(eta, dtype=float), (n,)))[:, None]
    return f


def _at_cosine(cos):
    """A direction at |``cos``| to the closure's normal, in its frame (the isotropic ``ggx_d`` and ``ggx_lambda``
    of a cosine: D even in cos θh, as in Cycles' kernel)."""
    c = np.minimum(np.abs(np.asarray(cos, dtype=float)), 1.0)
    return np.stack([np.sqrt(1.0 - c * c), np.zeros_like(c), c], axis=1)


def _refraction(wi, wo, alpha, ior, normal, d_of_cos, lambda_of_cos):
    """What Cycles renders for a Fresnel-free microfacet refraction closure of NDF ``d_of_cos`` and Smith
    ``lambda_of_cos`` (both of a cosine to ``normal``) around ``normal`` (N, 3), as a BSDF w.r.t. z (light below
    the surface only). Cycles' eval (its ωi is our ωo; kernel closure/bsdf_microfacet.h, the same in 4.2 and 5.0):
    H = −(η ωi + ωo) normalised, D(H) G2 |H·ωo| |H·ωi| η² / (cos(N, ωo) |η ωi + ωo|²), which includes the closure's
    cosine of ωi, so the value here is that over |cos θi|; valid for ωo above N and the surface, ωi below both."""
    n = len(wi)
    a = _cycles_alpha(alpha, n)
    eta = np.broadcast_to(np.asarray(ior, dtype=float), (n,))
    normal = _normalize(np.broadcast_to(np.asarray(normal, dtype=float), (n, 3)))
    c_v, c_l = _dot(normal, wo), _dot(normal, wi)
    ok = (c_v > 0) & (c_l < 0) & (wi[:, 2] < 0) & (wo[:, 2] > 0)
    ht = -(eta[:, None] * wi + wo)
    len2 = np.maximum(_dot(ht, ht), 1e-300)
    h = ht / np.sqrt(len2)[:, None]
    g2 = 1.0 / (1.0 + lambda_of_cos(c_v, a) + lambda_of_cos(c_l, a))
    with np.errstate(divide="ignore", invalid="ignore"):
        value = (d_of_cos(_dot(normal, h), a) * g2 * np.abs(_dot(h, wo) * _dot(h, wi)) * eta * eta
                 / (np.where(ok, c_v, 1.0) * len2 * np.maximum(np.abs(wi[:, 2]), 1e-300)))
    return np.repeat(np.where(ok, value, 0.0)[:, None], 3, axis=1)


def beckmann_refraction(wi, wo, alpha, ior, normal):
    """Cycles' Beckmann refraction closure (no Fresnel: Refraction BSDF node, OSL ``microfacet("beckmann", normal,
    ..., ior, 1)``) around ``normal`` (``_refraction``)."""
    return _refraction(wi, wo, alpha, ior, normal, beckmann_d, beckmann_lambda)


def ggx_refraction(wi, wo, alpha, ior, normal):
    """Cycles' GGX refraction closure (no Fresnel: Refraction BSDF node, OSL ``microfacet("ggx", normal, ..., ior,
    1)``) around ``normal`` (``_refraction``): about the view with a large ``ior``, a lobe about the straight-through
    direction with GGX's long tails (a forward-scattering medium's)."""
    return _refraction(wi, wo, alpha, ior, normal, lambda c, a: ggx_d(_at_cosine(c), a, a),
                       lambda c, a: ggx_lambda(_at_cosine(c), a, a))


# The albedo of Beckmann lobes of any width: for α below GRID_ALPHA by Gauss-Hermite nodes in microfacet slope space
# (the slopes of a Beckmann NDF are Gaussian: s = α t, t ~ e^{−|t|²} / π), so that a lobe as sharp as α = 1e-3 is
# integrated as well as a rough one; from GRID_ALPHA on by ``reference.scenes.directional_albedo``'s direction grid
# (accurate there; the slope rule loses ~1% where the horizon cuts a rough lobe). Measured against a 256 x 512 grid
# in tests/unit/test_thin_coat_mapping.py.
HERMITE_NODES = 32
GRID_ALPHA = 0.1
# Where the horizon cuts a sharp lobe (cos θo < HORIZON_WIDTHS α) the Gauss-Hermite rule is off by up to 7% (a
# discontinuous integrand): there a Halton set of HALTON_POINTS Gaussian slopes is used instead.
HORIZON_WIDTHS = 10.0
HALTON_POINTS = 16384


def _slope_nodes(halton: bool = False):
    """Slopes t (in units of α) and weights for ∫ g(t) e^{−|t|²} / π d²t: a Gauss-Hermite product rule, or (``halton``)
    equal weights on a Halton set mapped to the Gaussian (r = sqrt(−ln u1), φ = 2π u2)."""
    if halton:
        u1 = 1.0 - _radical_inverse(np.arange(1, HALTON_POINTS + 1), 2)
        u2 = _radical_inverse(np.arange(1, HALTON_POINTS + 1), 3)
        r = np.sqrt(-np.log(u1))
        return r * np.cos(2.0 * np.pi * u2), r * np.sin(2.0 * np.pi * u2), np.full(HALTON_POINTS, 1.0 / HALTON_POINTS)
    x, w = np.polynomial.hermite.hermgauss(HERMITE_NODES)
    tx, ty = np.meshgrid(x, x, indexing="ij")
    return tx.ravel(), ty.ravel(), (w[:, None] * w[None, :]).ravel() / np.pi


def _radical_inverse(i, base):
    out, f = np.zeros(len(i)), 1.0 / base
    i = i.copy()
    while np.any(i > 0):
        out += f * (i % base)
        i //= base
        f /= base
    return out


def _grid_albedo(evaluate, wo, per_pixel: dict, rows):
    """``directional_albedo`` of ``evaluate(wi, wo, **kw)`` for the views ``wo[rows]``, the per-pixel keyword values
    repeated over each view's quadrature directions."""
    from ..reference.scenes import directional_albedo

    out = np.zeros((len(wo), 3))
    index = np.flatnonzero(rows)
    nq = 2 * 64 * 128
    for s0 in range(0, len(index), 16):
        chunk = index[s0:s0 + 16]
        kw = {k: (None if v is None else np.repeat(np.broadcast_to(np.asarray(v, dtype=float),
                                                                   (len(wo),) + np.shape(v)[1:])[chunk], nq, axis=0))
              for k, v in per_pixel.items()}
        out[chunk] = directional_albedo(lambda wi, w, _kw=kw: evaluate(wi, w, **_kw), wo[chunk], chunk=len(chunk) * nq)
    return out


def _microfacet_albedo(wo, alpha, normal, scatter):
    """The slope rule for every view: Gauss-Hermite, Halton where the horizon cuts the lobe (``HORIZON_WIDTHS``),
    each rule run on its own views only (``_slope_albedo`` blocks its nodes by the view count, so many views may
    differ from one call over all of them in the last bit)."""
    a = _cycles_alpha(alpha, len(wo))
    normal = np.broadcast_to(np.asarray(normal, dtype=float), (len(wo), 3))
    cut = wo[:, 2] < HORIZON_WIDTHS * a
    out = np.zeros(len(wo))
    for rows, halton in ((~cut, False), (cut, True)):
        if rows.any():
            out[rows] = _slope_albedo(wo[rows], a[rows], normal[rows], _rows(scatter, rows), halton)
    return out


def _beckmann_albedo(evaluate, wo, alpha, normal, scatter, per_pixel: dict):
    """(N, 3): the direction grid (``_grid_albedo`` of ``evaluate`` with ``per_pixel``) for the views whose α is at
    least GRID_ALPHA, the slope rule (``_microfacet_albedo`` with ``scatter``) for the others."""
    n = len(wo)
    a = _cycles_alpha(alpha, n)
    rough = a >= GRID_ALPHA
    out = _grid_albedo(evaluate, wo, per_pixel, rough)
    sharp = ~rough
    if sharp.any():
        normal = np.broadcast_to(np.asarray(normal, dtype=float), (n, 3))
        out[sharp] = _microfacet_albedo(wo[sharp], a[sharp], normal[sharp], _rows(scatter, sharp))[:, None]
    return out


def _rows(scatter, rows):
    index = np.flatnonzero(rows)
    return lambda h, v, r: scatter(h, v, index[r])


def _slope_albedo(wo, alpha, normal, scatter, halton):
    """∫ over the microfacet normals h of the closure around ``normal``: e^{−|t|²} / π · G2 |h·ωo| / (cos(N, ωo)
    cos θh) · weight, with h from the slopes α t (the NDF's projected density), ``scatter(h_world, wo)`` giving the
    light direction and its weight (Fresnel; 0 where invalid). This is Cycles' eval integrated over the light
    directions (the Jacobian of ωi(h) cancels eval's η² |H·ωi| / |H_t|² or 1 / (4 |H·ωo|))."""
    n = len(wo)
    a = _cycles_alpha(alpha, n)
    tx, ty, w = _slope_nodes(halton)
    normal = _normalize(np.broadcast_to(np.asarray(normal, dtype=float), (n, 3)))
    tangent = wo - _dot(wo, normal)[:, None] * normal  # the slope grid aligned with the view's azimuth
    helper = np.where(np.abs(normal[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    length = np.linalg.norm(tangent, axis=1, keepdims=True)
    e1 = np.where(length > 1e-9, tangent / np.maximum(length, 1e-300), _normalize(np.cross(normal, helper)))
    e2 = np.cross(normal, e1)
    out = np.zeros(n)
    block = max(1, (1 << 21) // max(n, 1))
    for k0 in range(0, len(w), block):
        kt = slice(k0, k0 + block)
        m = len(w[kt])
        h_local = np.stack(np.broadcast_arrays(-a[:, None] * tx[None, kt], -a[:, None] * ty[None, kt],
                                               np.ones((n, m))), axis=-1)
        h_local /= np.linalg.norm(h_local, axis=-1, keepdims=True)
        h = (h_local[..., :1] * e1[:, None] + h_local[..., 1:2] * e2[:, None] + h_local[..., 2:] * normal[:, None])
        v = np.broadcast_to(wo[:, None], (n, m, 3)).reshape(-1, 3)
        wi, weight = scatter(h.reshape(-1, 3), v, np.repeat(np.arange(n), m))
        c_v = np.repeat(_dot(normal, wo), m)
        c_l = _dot(np.repeat(normal, m, axis=0), wi)
        a_r = np.repeat(a, m)
        g2 = 1.0 / (1.0 + beckmann_lambda(c_v, a_r) + beckmann_lambda(c_l, a_r))
        term = g2 * np.abs(_dot(h.reshape(-1, 3), v)) / (np.maximum(c_v, 1e-300) * h_local[..., 2].ravel()) * weight
        out += np.sum((np.where(c_v > 0, term, 0.0)).reshape(n, m) * w[None, kt], axis=1)
    return out


def beckmann_reflection_albedo(wo, alpha, eta=None, normal=(0.0, 0.0, 1.0)):
    """Directional albedo (N, 3) of ``beckmann_reflection``: ∫ f cos θi dωi by slope quadrature around the bent
    normal, counting the light above the surface and the closure normal."""
    n = len(wo)
    eta_n = None if eta is None else np.broadcast_to(np.asarray(eta, dtype=float), (n,))
    bent = bent_normal(normal, wo)

    def scatter(h, v, rows):
        wi = 2.0 * _dot(h, v)[:, None] * h - v
        weight = ((wi[:, 2] > 0) & (_dot(h, v) > 0) & (_dot(wi, bent[rows]) > 0)).astype(float)
        if eta_n is not None:
            weight = weight * microfacet.fresnel_dielectric(_dot(wi, h), eta_n[rows])
        return wi, weight

    return _beckmann_albedo(beckmann_reflection, wo, alpha, bent, scatter, {"alpha": alpha, "eta": eta, "normal": bent})


def beckmann_refraction_albedo(wo, alpha, ior, normal):
    """Directional albedo (N, 3) of ``beckmann_refraction``: the visible microfacets' refracted directions, those
    below the surface and the closure normal, weighted by G2 / G1 (by slope quadrature)."""
    n = len(wo)
    eta = np.broadcast_to(np.asarray(ior, dtype=float), (n,))
    normal_n = _normalize(np.broadcast_to(np.asarray(normal, dtype=float), (n, 3)))

    def scatter(h, v, rows):
        e, nn = eta[rows], normal_n[rows]
        c = _dot(h, v)
        s2 = (1.0 - c * c) / (e * e)
        ct = np.sqrt(np.maximum(1.0 - s2, 0.0))
        wi = (c / e - ct)[:, None] * h - v / e[:, None]  # refracted into the side of index η
        weight = ((c > 0) & (s2 < 1.0) & (wi[:, 2] < 0) & (_dot(nn, wi) < 0)).astype(float)
        return _normalize(wi), weight

    return _beckmann_albedo(beckmann_refraction, wo, alpha, normal_n, scatter,
                            {"alpha": alpha, "ior": ior, "normal": normal_n})


def ggx_conductor_albedo(wo, alpha_x, alpha_y, tangent, eta, k, nodes: int = 32):
    """Directional albedo (N, 3) of ``ggx_conductor`` (``_visible_normal_albedo``)."""
    def value_of(wi, rows):
        return ggx_conductor(wi, wo[rows], *(_at_views(a, rows, len(wo), 1) for a in (alpha_x, alpha_y)),
                             *(_at_views(a, rows, len(wo), 2) for a in (tangent, eta, k)))

    return _visible_normal_albedo(value_of, wo, alpha_x, alpha_y, (0.0, 0.0, 1.0), tangent, nodes)


def ggx_albedo(wo, alpha_x, alpha_y=None, normal=(0.0, 0.0, 1.0), tangent=(1.0, 0.0, 0.0), f0=None, nodes: int = 32):
    """Directional albedo (N, 3) of ``ggx_reflection`` (``_visible_normal_albedo`` around the normal Cycles bends)."""
    bent = ensure_valid_specular_reflection(
        _normalize(np.broadcast_to(np.asarray(normal, dtype=float), (len(wo), 3)).astype(np.float64)), wo)

    def value_of(wi, rows):
        return ggx_reflection(wi, wo[rows], *(_at_views(a, rows, len(wo), 1) for a in (alpha_x, alpha_y)),
                              *(_at_views(a, rows, len(wo), 2) for a in (normal, tangent, f0)))

    return _visible_normal_albedo(value_of, wo, alpha_x, alpha_x if alpha_y is None else alpha_y, bent, tangent,
                                  nodes)


def _at_views(x, rows, n: int, per_view_ndim: int):
    """A closure parameter given per view (``per_view_ndim`` dimensions, the first ``n`` long: 1 for a roughness, 2
    for a direction or a colour) at the views ``rows``; one for every view (or None) as it is."""
    if x is None:
        return None
    a = np.asarray(x, dtype=float)
    return a[rows] if a.ndim == per_view_ndim and a.shape[0] == n else a


PAIRS_PER_BLOCK = 1 << 16  # (quadrature node, view) pairs evaluated at once by ``_visible_normal_albedo``


def _visible_normal_albedo(value_of, wo, alpha_x, alpha_y, normal, tangent, nodes: int):
    """∫ f(ωi, ωo) cos θi dωi (N, 3) for a GGX closure's value ``value_of(wi, rows)`` (light from ``wi`` towards the
    views ``wo[rows]``): f cos θi over the density of reflecting ``wo`` about a visible normal of the GGX around
    ``normal`` (Heitz 2018's sampler in the stretched frame), summed on a ``nodes`` x ``nodes`` product rule
    (Gauss-Legendre in u1, midpoint in u2): exact for lobes of any sharpness, where a direction grid misses a
    near-mirror lobe. The nodes are taken in blocks, each for every view at once."""
    n = len(wo)
    ax = np.broadcast_to(np.asarray(alpha_x, dtype=float), (n,))
    ay = np.broadcast_to(np.asarray(alpha_y, dtype=float), (n,))
    t, b, nz = _frame(normal, tangent, n)
    x, gw = np.polynomial.legendre.leggauss(nodes)
    u1, u2 = np.meshgrid(0.5 * (x + 1.0), (np.arange(nodes) + 0.5) / nodes, indexing="ij")
    r, phi = np.sqrt(u1.ravel()), 2.0 * np.pi * u2.ravel()
    weights = np.repeat(0.5 * gw / nodes, nodes)
    out = np.zeros((n, 3))
    lo = np.stack([_dot(wo, t), _dot(wo, b), _dot(wo, nz)], axis=1)
    v = _normalize(lo * np.stack([ax, ay, np.ones(n)], axis=1))  # the view in the stretched (α = 1) frame
    e1 = np.where((np.hypot(v[:, 0], v[:, 1]) > 1e-12)[:, None],
                  _normalize(np.stack([-v[:, 1], v[:, 0], np.zeros(n)], axis=1) + 1e-300), np.array([[1.0, 0, 0]]))
    e2 = np.cross(v, e1)
    s = 0.5 * (1.0 + v[:, 2])
    g1 = 1.0 / (1.0 + ggx_lambda(lo, ax, ay))
    block = max(1, PAIRS_PER_BLOCK // max(n, 1))
    for k in (slice(k0, k0 + block) for k0 in range(0, len(weights), block)):
        m = len(weights[k])
        rows = np.tile(np.arange(n), m)  # pair j: node j // n, view j % n
        p1, p2 = np.repeat(r[k] * np.cos(phi[k]), n), np.repeat(r[k] * np.sin(phi[k]), n)
        p2 = (1.0 - s[rows]) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s[rows] * p2
        p3 = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
        hs = p1[:, None] * e1[rows] + p2[:, None] * e2[rows] + p3[:, None] * v[rows]
        h = _normalize(np.stack([ax[rows] * hs[:, 0], ay[rows] * hs[:, 1], np.maximum(hs[:, 2], 1e-12)], axis=1))
        lo_k = lo[rows]
        li = 2.0 * _dot(lo_k, h)[:, None] * h - lo_k
        wi = li[:, :1] * t[rows] + li[:, 1:2] * b[rows] + li[:, 2:] * nz[rows]
        # density of wi: D_wo(h) / (4 wo·h) with D_wo(h) = G1(wo) (wo·h) D(h) / cos θo
        density = g1[rows] * ggx_d(h, ax[rows], ay[rows]) / (4.0 * np.maximum(lo_k[:, 2], 1e-300))
        value = value_of(wi, rows) * np.maximum(wi[:, 2:], 0.0)
        value = np.divide(value, density[:, None], out=np.zeros_like(value), where=density[:, None] > 0)
        out += (np.repeat(weights[k], n)[:, None] * value).reshape(m, n, 3).sum(axis=0)
    return np.where(((wo[:, 2] > 0) & (lo[:, 2] > 0))[:, None], out, 0.0)


EVAL = {
    "ggx": ggx_reflection,
    "ggx_conductor": ggx_conductor,
    "diffuse": diffuse,
    "translucent": translucent,
    "transparent": transparent,
    "velvet": velvet,
    "sheen": sheen,
    "glossy_toon": glossy_toon,
    "diffuse_toon": diffuse_toon,
    "conductor": conductor,
    "dielectric": dielectric,
    "beckmann": beckmann_reflection,
    "beckmann_refraction": beckmann_refraction,
    "ggx_refraction": ggx_refraction,
}

# Closures whose directional albedo is computed by its own quadrature (sharp lobes), not on a direction grid.
ALBEDO = {
    "diffuse": lambda wo: np.repeat(np.where(wo[:, 2] > 0, 1.0, 0.0)[:, None], 3, axis=1),  # ∫ cos θi / π = 1
    "beckmann": beckmann_reflection_albedo,
    "beckmann_refraction": beckmann_refraction_albedo,
    "ggx_conductor": ggx_conductor_albedo,
    "sheen": sheen_albedo,
}
# And GGX reflection closures of any sharpness (``ggx_albedo``), translucency (∫ cos θi / π below = 1) and the
# transparent closure (no BSDF value: ``NumpyBackend.transparency`` counts it), where a caller asks for them
# (``closure_furnace``): a SpongeCake form's albedo then needs no direction grid.
SHARP_ALBEDO = {**ALBEDO, "ggx": functools.partial(ggx_albedo, nodes=16), "translucent": ALBEDO["diffuse"],
                "transparent": lambda wo: np.zeros((len(wo), 3))}
