"""What Cycles' closures evaluate to, in float64 numpy (used to predict a mapping's renders without Blender).

Each function returns the BSDF value without the cosine for light from ``wi`` seen from ``wo`` (local frame,
z = shading normal). Cycles' GGX uses the height-correlated Smith G (research notes §6, verified).
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


def ggx_reflection(wi, wo, alpha_x, alpha_y=None, normal=(0.0, 0.0, 1.0), tangent=(1.0, 0.0, 0.0), f0=None):
    """GGX reflection with height-correlated Smith G around ``normal`` (anisotropic along ``tangent``),
    times Schlick's F when ``f0`` is given."""
    n = len(wi)
    ax = np.broadcast_to(np.asarray(alpha_x, dtype=float), (n,))
    ay = ax if alpha_y is None else np.broadcast_to(np.asarray(alpha_y, dtype=float), (n,))
    t, b, nz = _frame(normal, tangent, n)

    def local(v):
        return np.stack([_dot(v, t), _dot(v, b), _dot(v, nz)], axis=1)

    li, lo = local(wi), local(wo)
    ok = (li[:, 2] > 0) & (lo[:, 2] > 0) & (wi[:, 2] > 0) & (wo[:, 2] > 0)
    h = _normalize(li + lo)
    g2 = 1.0 / (1.0 + ggx_lambda(li, ax, ay) + ggx_lambda(lo, ax, ay))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(ok, ggx_d(h, ax, ay) * g2 / (4.0 * np.abs(li[:, 2]) * np.abs(lo[:, 2])), 0.0)
    f = np.repeat(f[:, None], 3, axis=1)
    if f0 is not None:
        f = f * microfacet.schlick(f0, _dot(li, h))
    return f


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
    """Cycles' rough glass (Glass BSDF / dielectric_bsdf): Walter et al.'s GGX dielectric."""
    return np.repeat(microfacet.dielectric_eval(wi, wo, alpha, ior)[:, None], 3, axis=1)


EVAL = {
    "ggx": ggx_reflection,
    "diffuse": diffuse,
    "translucent": translucent,
    "transparent": transparent,
    "conductor": conductor,
    "dielectric": dielectric,
}
