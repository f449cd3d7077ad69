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


def ggx_d(h_local, alpha_x, alpha_y):
    """Anisotropic GGX NDF for half-vectors in the closure's (tangent, bitangent, normal) frame."""
    hx, hy, hz = h_local[:, 0] / alpha_x, h_local[:, 1] / alpha_y, h_local[:, 2]
    t = hx * hx + hy * hy + hz * hz
    return np.where(hz > 0, 1.0 / (np.pi * alpha_x * alpha_y * t * t), 0.0)


def ggx_lambda(v_local, alpha_x, alpha_y):
    z2 = np.maximum(v_local[:, 2] ** 2, 1e-300)
    a2 = (alpha_x * v_local[:, 0]) ** 2 + (alpha_y * v_local[:, 1]) ** 2
    return 0.5 * (np.sqrt(1.0 + a2 / z2) - 1.0)


def schlick(f0, cos_h):
    c = np.clip(1.0 - cos_h, 0.0, 1.0)[:, None]
    return f0 + (1.0 - f0) * c**5


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
        f = f * schlick(np.broadcast_to(f0, wi.shape), np.abs(_dot(li, h)))
    return f


def ggx_transmission_eta1(wi, wo, alpha, normal=(0.0, 0.0, 1.0)):
    """Cycles' isotropic GGX refraction with eta = 1 (verified against renders): D(h) G2 / (4 |cos i| |cos o|)
    with h = normalize(wi + wo) turned to the normal's side — the form of a flake layer's transmission (Eq. 13).
    (Cycles' anisotropic refraction does not follow this form.)"""
    n = len(wi)
    ax = ay = np.broadcast_to(np.asarray(alpha, dtype=float), (n,))
    t, b, nz = _frame(normal, (1.0, 0.0, 0.0), n)

    def local(v):
        return np.stack([_dot(v, t), _dot(v, b), _dot(v, nz)], axis=1)

    li, lo = local(wi), local(wo)
    ok = (li[:, 2] * lo[:, 2] < 0) & (wi[:, 2] * wo[:, 2] < 0)
    h = _normalize(li + lo)
    h = h * np.where(h[:, 2:] < 0, -1.0, 1.0)
    g2 = 1.0 / (1.0 + ggx_lambda(li, ax, ay) + ggx_lambda(lo, ax, ay))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(ok, ggx_d(h, ax, ay) * g2 / (4.0 * np.abs(li[:, 2] * lo[:, 2])), 0.0)
    return np.repeat(f[:, None], 3, axis=1)


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
    return ggx_reflection(wi, wo, alpha) * conductor_fresnel(np.abs(_dot(wi, h)), eta, k)


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
    return ggx_reflection(wi, wo, alpha) * dielectric_fresnel(np.abs(_dot(wi, h)), ior)[:, None]


EVAL = {
    "ggx": ggx_reflection,
    "ggx_transmission": ggx_transmission_eta1,
    "diffuse": diffuse,
    "translucent": translucent,
    "transparent": transparent,
    "conductor": conductor,
    "dielectric": dielectric,
}
