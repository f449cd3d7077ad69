"""What Cycles' closures evaluate to, in float64 numpy (used to predict a mapping's renders without Blender).

Each function returns the BSDF value without the cosine for light from ``wi`` seen from ``wo`` (local frame,
z = shading normal). Cycles' GGX uses the height-correlated Smith G (research notes §6, verified).
"""
from __future__ import annotations

import numpy as np


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _normalize(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def ggx_d(cos_m, alpha):
    c2 = cos_m * cos_m
    t = c2 * (alpha * alpha - 1.0) + 1.0
    return np.where(cos_m > 0, alpha * alpha / (np.pi * t * t), 0.0)


def ggx_lambda(cos_v, alpha):
    c2 = np.clip(cos_v * cos_v, 1e-300, 1.0)
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 - c2) / c2) - 1.0)


def schlick(f0, cos_h):
    c = np.clip(1.0 - cos_h, 0.0, 1.0)[:, None]
    return f0 + (1.0 - f0) * c**5


def ggx_reflection(wi, wo, alpha, normal, f0=None):
    """GGX microfacet reflection with height-correlated Smith G around ``normal`` (and optional Schlick F)."""
    alpha = np.broadcast_to(np.asarray(alpha, dtype=float), (len(wi),))
    n = _normalize(np.broadcast_to(normal, wi.shape))
    ci, co = _dot(wi, n), _dot(wo, n)
    ok = (ci > 0) & (co > 0) & (wi[:, 2] > 0) & (wo[:, 2] > 0)
    h = _normalize(wi + wo)
    d = ggx_d(_dot(h, n), alpha)
    g2 = 1.0 / (1.0 + ggx_lambda(ci, alpha) + ggx_lambda(co, alpha))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(ok, d * g2 / (4.0 * np.abs(ci) * np.abs(co)), 0.0)
    f = np.repeat(f[:, None], 3, axis=1)
    if f0 is not None:
        f = f * schlick(np.broadcast_to(f0, wi.shape), np.abs(_dot(wi, h)))
    return f


def diffuse(wi, wo):
    same = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return np.repeat(np.where(same, 1.0 / np.pi, 0.0)[:, None], 3, axis=1)


def translucent(wi, wo):
    opposite = (wi[:, 2] < 0) & (wo[:, 2] > 0)
    return np.repeat(np.where(opposite, 1.0 / np.pi, 0.0)[:, None], 3, axis=1)


def transparent(wi, wo):
    return np.zeros((len(wi), 3))


def conductor_fresnel(cos_i, eta, k):
    """Exact unpolarised Fresnel reflectance of a conductor with complex IOR eta + i k."""
    c = np.clip(cos_i, 0.0, 1.0)[:, None]
    n = np.asarray(eta, dtype=complex) + 1j * np.asarray(k, dtype=float)
    s2 = 1.0 - c * c
    ct = np.sqrt(1.0 - s2 / (n * n))
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def conductor(wi, wo, alpha, eta, k):
    h = _normalize(wi + wo)
    return ggx_reflection(wi, wo, alpha, (0.0, 0.0, 1.0)) * conductor_fresnel(np.abs(_dot(wi, h)), eta, k)


def dielectric_fresnel(cos_i, eta):
    c = np.clip(cos_i, 0.0, 1.0)
    s2t = (1.0 - c * c) / (eta * eta)
    ct = np.sqrt(np.clip(1.0 - s2t, 0.0, 1.0))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return np.where(s2t >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))


def dielectric(wi, wo, alpha, ior):
    """The reflection part of a rough dielectric (the comparison scenes light the outside only)."""
    h = _normalize(wi + wo)
    return ggx_reflection(wi, wo, alpha, (0.0, 0.0, 1.0)) * dielectric_fresnel(np.abs(_dot(wi, h)), ior)[:, None]


EVAL = {
    "ggx": ggx_reflection,
    "diffuse": diffuse,
    "translucent": translucent,
    "transparent": transparent,
    "conductor": conductor,
    "dielectric": dielectric,
}
