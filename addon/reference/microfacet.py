"""Isotropic GGX microfacets (z = normal), Fresnel terms and the rough conductor / dielectric BSDFs.

Directions are unit rows of (N, 3) float64 arrays. Conventions: ``wi`` points to the light, ``wo`` to the
viewer, both away from the surface. The rough dielectric follows Walter et al. 2007 Eq. 21 as printed (the
``eta_o**2`` factor is the Jacobian of refraction, no extra 1/eta**2 radiance scaling): its transmitted
throughput integrates to 1 - F, and it obeys f(i, o) / eta_o**2 = f(o, i) / eta_i**2.
"""
from __future__ import annotations

import numpy as np

from .frames import dot, normalize, reflect


def ggx_d(m, alpha):
    """GGX normal distribution D(m) = alpha^2 / (pi (sin^2 + alpha^2 cos^2)^2), zero below the horizon."""
    a2 = alpha * alpha
    q = m[:, 0] ** 2 + m[:, 1] ** 2 + a2 * m[:, 2] ** 2
    return np.divide(a2, np.pi * q * q, out=np.zeros_like(q), where=m[:, 2] > 0)


def smith_lambda(w, alpha):
    """Smith Lambda of GGX, (sqrt(1 + alpha^2 tan^2) - 1) / 2 in a cancellation-free form; inf at grazing."""
    z = np.abs(w[:, 2])
    r2 = alpha * alpha * (w[:, 0] ** 2 + w[:, 1] ** 2)
    den = 2.0 * z * (np.sqrt(z * z + r2) + z)
    return np.divide(r2, den, out=np.full_like(z, np.inf), where=den > 0)


def g2(wi, wo, alpha):
    """Height-correlated Smith masking-shadowing 1 / (1 + Lambda(wi) + Lambda(wo)) (0 at grazing)."""
    return 1.0 / (1.0 + smith_lambda(wi, alpha) + smith_lambda(wo, alpha))


def vndf_pdf(wi, m, alpha):
    """Density of visible normals D_wi(m) = G1(wi) <wi, m> D(m) / cos(wi), for wi above the horizon."""
    z = wi[:, 2]
    r2 = alpha * alpha * (wi[:, 0] ** 2 + wi[:, 1] ** 2)
    # cos(wi) (1 + Lambda(wi)) = (z + sqrt(z^2 + alpha^2 r^2)) / 2, finite at grazing incidence
    return 2.0 * np.maximum(dot(wi, m), 0.0) * ggx_d(m, alpha) / (z + np.sqrt(z * z + r2))


def sample_vndf(wi, alpha, u1, u2):
    """Visible normal of GGX for wi above the horizon (Heitz 2018, 'Sampling the GGX distribution of visible
    normals')."""
    v = normalize(wi * np.array([alpha, alpha, 1.0]))
    len2 = v[:, 0] ** 2 + v[:, 1] ** 2
    inv = np.divide(1.0, np.sqrt(len2), out=np.zeros_like(len2), where=len2 > 0)
    t1 = np.stack([-v[:, 1] * inv, v[:, 0] * inv, np.zeros_like(inv)], axis=1)
    t1 = np.where((len2 > 0)[:, None], t1, [1.0, 0.0, 0.0])
    t2 = np.cross(v, t1)
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    p1, p2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + v[:, 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
    nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * v
    return normalize(np.stack([alpha * nh[:, 0], alpha * nh[:, 1], np.maximum(nh[:, 2], 0.0)], axis=1))


def schlick(f0, cos):
    """Schlick's Fresnel f0 + (1 - f0)(1 - cos)^5 per channel: f0 (3,), cos (N,) -> (N, 3)."""
    c = np.clip(np.abs(cos), 0.0, 1.0)[:, None]
    f0 = np.asarray(f0, dtype=float)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def fresnel_dielectric(cos_i, eta):
    """Exact unpolarised Fresnel reflectance for |cos_i| and relative IOR eta = eta_t / eta_i (1 under TIR)."""
    c = np.clip(np.abs(cos_i), 0.0, 1.0)
    sin_t2 = (1.0 - c * c) / (eta * eta)
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin_t2))
    rs_den, rp_den = c + eta * cos_t, eta * c + cos_t
    rs = np.divide(c - eta * cos_t, rs_den, out=np.ones_like(c), where=rs_den > 0)
    rp = np.divide(eta * c - cos_t, rp_den, out=np.ones_like(c), where=rp_den > 0)
    return np.where(sin_t2 >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))


def fresnel_conductor(cos_i, eta, k):
    """Exact unpolarised Fresnel reflectance of a conductor with complex IOR eta + i k: cos (N,) -> (N, 3).

    In real arithmetic (a² + b² = |n² − sin²θ|, a = Re sqrt(n² − sin²θ), as pbrt's FrConductor); the same values
    as the complex Snell form (the tests compare them)."""
    c = np.clip(np.abs(np.asarray(cos_i, dtype=float)), 0.0, 1.0)[:, None]
    eta2, k2 = np.asarray(eta, dtype=float) ** 2, np.asarray(k, dtype=float) ** 2
    c2 = c * c
    s2 = 1.0 - c2
    t0 = eta2 - k2 - s2
    a2b2 = np.sqrt(t0 * t0 + 4.0 * eta2 * k2)
    two_a_c = 2.0 * c * np.sqrt(np.maximum(0.5 * (a2b2 + t0), 0.0))
    t1 = a2b2 + c2
    rs = np.divide(t1 - two_a_c, t1 + two_a_c, out=np.ones_like(t1 * two_a_c), where=t1 + two_a_c > 0)
    t3 = c2 * a2b2 + s2 * s2
    t4 = two_a_c * s2
    rp = rs * np.divide(t3 - t4, t3 + t4, out=np.ones_like(t3 * t4), where=t3 + t4 > 0)
    return 0.5 * (rs + rp)


def conductor_eval(wi, wo, alpha, eta, k):
    """Rough GGX conductor BRDF F D G2 / (4 cos_i cos_o) (no cosine), zero unless both directions are above."""
    h = normalize(wi + wo)
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    ci, co = np.where(ok, wi[:, 2], 1.0), np.where(ok, wo[:, 2], 1.0)
    f = fresnel_conductor(dot(wi, h), eta, k) * (ggx_d(h, alpha) * g2(wi, wo, alpha) / (4.0 * ci * co))[:, None]
    return np.where(ok[:, None], f, 0.0)


def reflection_pdf(wi, wo, alpha):
    """Density of wo = reflect(wi, m) with m a visible normal for wi (upper hemisphere): D_wi(h) / (4 <wi, h>)."""
    h = normalize(wi + wo)
    wih = dot(wi, h)
    return np.divide(vndf_pdf(wi, h, alpha), 4.0 * wih, out=np.zeros_like(wih), where=wih > 0)


def conductor_sample(wi, alpha, u1, u2):
    """Reflect wi (above the horizon) about a sampled GGX visible normal."""
    return reflect(wi, sample_vndf(wi, alpha, u1, u2))


def _refraction_half(wi, wo, eta):
    """Generalised half vector of refraction (pointing up), and whether it refracts wi into wo."""
    h = normalize(wi + eta[:, None] * wo)
    h = h * np.where(h[:, 2] < 0, -1.0, 1.0)[:, None]
    ok = (dot(wi, h) > 0) & (dot(wo, h) < 0)
    return h, ok


def _refraction_jacobian(wi, wo, h, eta):
    """|d omega_h / d omega_o| of refraction: eta^2 |<wo, h>| / (<wi, h> + eta <wo, h>)^2 (Walter 2007 Eq. 17)."""
    den = dot(wi, h) + eta * dot(wo, h)
    den2 = den * den
    return np.divide(eta * eta * np.abs(dot(wo, h)), den2, out=np.zeros_like(den), where=den2 > 0)


def _flip(wi, wo, ior):
    """Mirror a configuration with wi below the horizon to wi above (both directions negated, IOR inverted)."""
    below = (wi[:, 2] < 0)[:, None]
    eta = np.where(below[:, 0], 1.0 / ior, ior)
    return np.where(below, -wi, wi), np.where(below, -wo, wo), eta


def dielectric_eval(wi, wo, alpha, ior):
    """Rough GGX dielectric BSDF (Walter 2007 Eqs. 20-21, height-correlated G2), achromatic (N,); wi may be below."""
    wi, wo, eta = _flip(wi, wo, ior)
    ci, co = wi[:, 2], wo[:, 2]
    ok = (ci > 0) & (co != 0)
    ci, co_abs = np.where(ok, ci, 1.0), np.where(ok, np.abs(co), 1.0)
    dg = g2(wi, wo, alpha) / (ci * co_abs)
    hr = normalize(wi + wo)
    f_r = fresnel_dielectric(dot(wi, hr), eta) * ggx_d(hr, alpha) * dg / 4.0
    ht, refracts = _refraction_half(wi, wo, eta)
    f_t = (dot(wi, ht) * (1.0 - fresnel_dielectric(dot(wi, ht), eta)) * ggx_d(ht, alpha) * dg
           * _refraction_jacobian(wi, wo, ht, eta))
    return np.where(ok & (co > 0), f_r, np.where(ok & refracts, f_t, 0.0))


def dielectric_pdf(wi, wo, alpha, ior):
    """Exact density of ``dielectric_sample``: Fresnel-weighted reflection plus refraction of a visible normal."""
    wi, wo, eta = _flip(wi, wo, ior)
    p_r = fresnel_dielectric(dot(wi, normalize(wi + wo)), eta) * reflection_pdf(wi, wo, alpha)
    ht, refracts = _refraction_half(wi, wo, eta)
    p_t = (1.0 - fresnel_dielectric(dot(wi, ht), eta)) * vndf_pdf(wi, ht, alpha) * _refraction_jacobian(wi, wo, ht, eta)
    return p_r + np.where(refracts, p_t, 0.0)


def dielectric_sample(wi, alpha, ior, u0, u1, u2):
    """Sample a visible normal, then reflect with probability F or refract (Walter 2007); wi may be below."""
    below = (wi[:, 2] < 0)[:, None]
    wi_up, _, eta = _flip(wi, wi, ior)
    m = sample_vndf(wi_up, alpha, u1, u2)
    c = dot(wi_up, m)
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - c * c) / (eta * eta)))
    refracted = (-wi_up / eta[:, None]) + ((c / eta - cos_t)[:, None]) * m
    wo = np.where((u0 < fresnel_dielectric(c, eta))[:, None], reflect(wi_up, m), refracted)
    return np.where(below, -wo, wo)
