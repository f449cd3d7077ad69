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

Light below the surface gives nothing, whatever the closure normal (evaluation tests the smooth normal: 4.2
passes it to bsdf_microfacet_eval, 5.0 in bump_shadowing_term). Blender 4.2's *sampling* does not test the
closure normal, so under environment light reached by BSDF sampling 4.2 renders a little more than any
BSDF: ``ggx_sampling_leak`` models it (5.0 rejects those samples).
"""
from __future__ import annotations

import numpy as np

from ..reference import microfacet
from ..reference.frames import dot as _dot
from ..reference.frames import normalize as _normalize


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


def _ggx(wi, wo, alpha_x, alpha_y, normal, tangent, f0, below_normal: bool):
    """GGX as Cycles evaluates it around the bent ``normal``, as a BSDF w.r.t. z (light above the surface
    only): for light above the closure's normal, or (``below_normal``) for light below it."""
    n = len(wi)
    ax = np.broadcast_to(np.asarray(alpha_x, dtype=float), (n,))
    ay = ax if alpha_y is None else np.broadcast_to(np.asarray(alpha_y, dtype=float), (n,))
    normal = ensure_valid_specular_reflection(_normalize(np.broadcast_to(normal, (n, 3)).astype(np.float64)), wo)
    t, b, nz = _frame(normal, tangent, n)

    def local(v):
        return np.stack([_dot(v, t), _dot(v, b), _dot(v, nz)], axis=1)

    li, lo = local(wi), local(wo)
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
    return f


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


EVAL = {
    "ggx": ggx_reflection,
    "diffuse": diffuse,
    "translucent": translucent,
    "transparent": transparent,
    "conductor": conductor,
    "dielectric": dielectric,
}
