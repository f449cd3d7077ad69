"""Spherical warping and joint spherical warping of vMF lobes (thin transparent coat with ENDF, paper sec. 4.1-4.2).

Conventions: float64, vectorised numpy (arguments broadcast over leading rows); directions are unit rows pointing
away from the surface: ``o`` towards the light, ``r`` / ``t`` the reflected / transmitted directions; ``eta`` is
the relative index eta_t / eta_i across the interface in the direction of travel (1.5: air into glass). Lobes are
vMF densities M(x; mu, kappa) as in ``vmf`` (per unit solid angle, integrating to 1).

Exact (to rounding): the warps Phi and Psi (Eqs. 10-11) and the Jacobians of Eqs. 12, 13 and 21. Approximations
by design (the paper's): the single warps (Eqs. 12-13: the vMF lobe whose peak density matches J D(m) at the
warped mean; the exact warped lobe is anisotropic, a line at grazing incidence) and the joint warps (Eqs. 18 and
21: first moments matched through ``vmf.convolve``). Brute force for the exact distributions of Eqs. 16 and 20:
``exact_samples_*`` (Monte Carlo push-forward of independent o and m) and ``exact_density_*`` (quadrature of
Eq. 16 / 20 over the narrower of the two lobes). Measured errors of the approximations are stated in
tests/unit/test_warping.py.

Pairs (o, m) with o . m <= 0 (a back-facing microfacet) carry no light, as in Eqs. 16 / 20 which take the one
pre-image m with o . m > 0; the exact distributions therefore integrate to the front-facing (and, for
transmission, non-TIR) fraction of pairs, 1 - O(e^{-kappa}) for the paper's lobes.

Total internal reflection (only for eta < 1, e.g. leaving a coat): ``refract`` flags it (ok = False, t = 0). The
refraction Jacobians both tend to 0 at the critical angle (cos_t -> 0), so the warped and joint kappa fall
continuously to 0 (a uniform lobe) there; beyond it the warps return kappa = 0, the grazing refracted direction
(the limit at the critical angle) as mu, and valid = False: the caller should give that lobe zero weight (Fresnel
reflectance is 1 there).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import vmf
from .frames import as_directions, basis, dot, from_frame, normalize

GRAZING_COS = 1e-9  # |o . mu_m| floor in Eq. 12: keeps kappa finite (<= 2.5e8 kappa_m) at exactly grazing incidence


class Lobe(NamedTuple):
    mu: np.ndarray  # (N, 3) unit mean directions (the grazing direction where not valid)
    kappa: np.ndarray  # (N,) concentrations >= 0 (inf: a Dirac lobe)
    valid: np.ndarray  # (N,) False where the lobe does not exist (TIR); kappa is 0 there


# ------------------------------------------------------------------------------------------ warps (Eqs. 10-11)

def reflect(o, m):
    """Phi(o; m) = 2 (m . o) m - o (Eq. 10)."""
    o, m = as_directions(o), as_directions(m)
    return 2.0 * dot(o, m)[..., None] * m - o


def _cos_transmitted(c, eta):
    """cos theta_t = sqrt(1 - (1 - c^2) / eta^2) for |c| = |o . m| and its TIR flag (the radicand < 0)."""
    radicand = 1.0 - (1.0 - c * c) / (eta * eta)
    return np.sqrt(np.maximum(radicand, 0.0)), radicand < 0.0


def refract(o, m, eta):
    """Psi(o; m, eta) (Eq. 11) and ok (False under TIR). The normal is first turned to face o (Eq. 11 assumes
    m . o > 0), so t is always on the far side of the facet. Under TIR t is the grazing (critical-angle) limit."""
    o, m = np.broadcast_arrays(as_directions(o), as_directions(m))
    eta = np.asarray(eta, dtype=float)
    c = dot(o, m)
    m = np.where(c[..., None] < 0.0, -m, m)
    c = np.abs(c)
    cos_t, tir = _cos_transmitted(c, eta)
    t = (c / eta - cos_t)[..., None] * m - o / eta[..., None]
    return np.where(tir[..., None], normalize(c[..., None] * m - o), t), ~tir


# ------------------------------------------------------------------------------------------ Jacobians

def reflection_jacobian(o, m):
    """||dm/dr||_Phi = 1 / (4 |o . m|) (sec. 4.1, Eq. 12); |o . m| floored at GRAZING_COS."""
    return 0.25 / np.maximum(np.abs(dot(as_directions(o), as_directions(m))), GRAZING_COS)


def refraction_jacobian(o, m, eta):
    """||dm/dt||_Psi = eta^2 |t . m| / (o . m + eta t . m)^2 (Eq. 13, [WMLT07]), 0 under TIR.

    With c = |o . m| and t . m = -cos_t the denominator c - eta cos_t = (1 - eta^2) / (c + eta cos_t), so the form
    eta^2 cos_t (c + eta cos_t)^2 / (eta^2 - 1)^2 does not cancel as eta -> 1 (where it tends to +inf: the facet
    orientation stops mattering)."""
    eta = np.asarray(eta, dtype=float)
    c = np.abs(dot(as_directions(o), as_directions(m)))
    cos_t, tir = _cos_transmitted(c, eta)
    num = eta * eta * cos_t * (c + eta * cos_t) ** 2
    den = (eta - 1.0) ** 2 * (eta + 1.0) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        j = np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), np.inf)
    return np.where(tir | (cos_t == 0.0), 0.0, j)


def incident_refraction_jacobian(o, m, eta):
    """||do/dt||_Psi = eta^2 |t . m| / |o . m| = eta^2 cos_t / c (Eq. 21: Snell's solid-angle ratio at fixed m),
    0 under TIR; |o . m| floored at GRAZING_COS."""
    eta = np.asarray(eta, dtype=float)
    c = np.abs(dot(as_directions(o), as_directions(m)))
    cos_t, tir = _cos_transmitted(c, eta)
    return np.where(tir, 0.0, eta * eta * cos_t / np.maximum(c, GRAZING_COS))


def _scaled(jacobian, kappa):
    """J kappa with 0 * inf and inf * 0 read as 0 (a collapsed Jacobian or a uniform lobe stays uniform)."""
    jacobian, kappa = np.broadcast_arrays(np.asarray(jacobian, dtype=float), np.asarray(kappa, dtype=float))
    zero = (jacobian == 0.0) | (kappa == 0.0)
    return np.where(zero, 0.0, np.where(zero, 1.0, jacobian) * np.where(zero, 1.0, kappa))


# ------------------------------------------------------------------------------------------ single warps (4.1)

def warp_reflect(o, mu_m, kappa_m):
    """vMF lobe of reflected directions for a collimated o and NDF lobe (mu_m, kappa_m) (Eq. 12):
    mu_r = Phi(o; mu_m), kappa_r = kappa_m / (4 |o . mu_m|)."""
    mu = reflect(o, mu_m)
    kappa = _scaled(reflection_jacobian(o, mu_m), kappa_m)
    return Lobe(mu, kappa, np.ones(kappa.shape, dtype=bool))


def warp_refract(o, mu_m, kappa_m, eta):
    """vMF lobe of transmitted directions (Eq. 13): mu_t = Psi(o; mu_m, eta), kappa_t = ||dm/dt||_Psi kappa_m;
    under TIR kappa = 0, valid = False (module docstring)."""
    mu, ok = refract(o, mu_m, eta)
    kappa = np.where(ok, _scaled(refraction_jacobian(o, mu_m, eta), kappa_m), 0.0)
    return Lobe(mu, kappa, ok)


# ------------------------------------------------------------------------------------------ joint warps (4.2)

def joint_reflect(mu_o, kappa_o, mu_m, kappa_m):
    """vMF lobe approximating D(r) of Eq. 16 (Eq. 18): mu = Phi(mu_o; mu_m), A3(kappa) = A3(kappa_m / (4 |mu_o .
    mu_m|)) A3(kappa_o) (||do/dr||_Phi = 1), evaluated on the complements by ``vmf.convolve``."""
    mu = reflect(mu_o, mu_m)
    kappa = vmf.convolve(_scaled(reflection_jacobian(mu_o, mu_m), kappa_m), kappa_o)
    return Lobe(mu, kappa, np.ones(kappa.shape, dtype=bool))


def joint_refract(mu_o, kappa_o, mu_m, kappa_m, eta):
    """vMF lobe approximating D(t) of Eq. 20 (Eq. 21): mu = Psi(mu_o; mu_m, eta), A3(kappa) = A3(||dm/dt|| kappa_m)
    A3(||do/dt|| kappa_o), both Jacobians at the mean directions; under TIR kappa = 0, valid = False."""
    mu, ok = refract(mu_o, mu_m, eta)
    k_m = _scaled(refraction_jacobian(mu_o, mu_m, eta), kappa_m)
    k_o = _scaled(incident_refraction_jacobian(mu_o, mu_m, eta), kappa_o)
    return Lobe(mu, np.where(ok, vmf.convolve(k_m, k_o), 0.0), ok)


def endf_kappa_reflect(mu_o, mu_m, kappa_joint):
    """ENDF concentration of Eq. 19: ||dr/dm||_Phi kappa_r = 4 |mu_o . mu_m| kappa_r."""
    return _scaled(1.0 / reflection_jacobian(mu_o, mu_m), kappa_joint)


def endf_kappa_refract(mu_o, mu_m, kappa_joint, eta):
    """ENDF concentration of Eq. 22: ||dt/dm||_Psi kappa_t (0 under TIR)."""
    j = refraction_jacobian(mu_o, mu_m, eta)
    with np.errstate(divide="ignore"):
        inv = np.where(j > 0.0, 1.0 / np.where(j > 0.0, j, 1.0), 0.0)
    return _scaled(inv, kappa_joint)


# ------------------------------------------------------------------------------------------ brute force (16, 20)

def _pairs(mu_o, kappa_o, mu_m, kappa_m, n, seed):
    u = np.random.default_rng(seed).random((4, n))
    return vmf.sample_around(mu_o, kappa_o, u[0], u[1]), vmf.sample_around(mu_m, kappa_m, u[2], u[3])


def exact_samples_reflect(mu_o, kappa_o, mu_m, kappa_m, n, seed):
    """Reflected directions r = Phi(o; m) of n independent pairs o ~ M(mu_o, kappa_o), m ~ M(mu_m, kappa_m), front-
    facing pairs only (o . m > 0): samples of Eq. 16's D(r). Returns (r, kept fraction)."""
    o, m = _pairs(mu_o, kappa_o, mu_m, kappa_m, n, seed)
    keep = dot(o, m) > 0.0
    return reflect(o[keep], m[keep]), keep.mean()


def exact_samples_refract(mu_o, kappa_o, mu_m, kappa_m, eta, n, seed):
    """Transmitted directions t = Psi(o; m, eta) of front-facing, non-TIR pairs: samples of Eq. 20's D(t).
    Returns (t, kept fraction)."""
    o, m = _pairs(mu_o, kappa_o, mu_m, kappa_m, n, seed)
    t, ok = refract(o, m, eta)
    keep = ok & (dot(o, m) > 0.0)
    return t[keep], keep.mean()


def sample_moments(dirs, weights=None):
    """Mean direction and moment-matched vMF kappa of sample rows (optionally weighted; RGB weights are averaged
    over channels): 1 - A3 estimated as the weighted mean of |d - mu|^2 / 2."""
    w = np.ones(len(dirs)) if weights is None else np.asarray(weights, dtype=float)
    w = w.mean(axis=1) if w.ndim == 2 else w
    mean = np.sum(dirs * w[:, None], axis=0)
    mu = mean / np.linalg.norm(mean)
    d = dirs - mu
    return mu, vmf.kappa_from_complement(0.5 * np.sum(w * dot(d, d)) / np.sum(w))


def lobe_rule(mu, kappa, extent=40.0, n_s=64, n_phi=48):
    """Directions and solid-angle weights covering w = 1 - x . mu in [0, min(2, extent / kappa)] around each
    unit mu: Gauss-Legendre (8-node panels) in s = sqrt(w), dw = 2 s ds, midpoint in phi (periodic: spectral)."""
    w_max = np.minimum(2.0, extent / max(float(kappa), 1e-300))
    x, wt = np.polynomial.legendre.leggauss(8)
    edges = np.linspace(0.0, np.sqrt(w_max), n_s // 8 + 1)
    half = 0.5 * np.diff(edges)[:, None]
    s = (edges[:-1, None] + half * (x + 1.0)).ravel()
    ws = (half * wt).ravel() * 2.0 * s
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    w = s * s
    sin_t = s * np.sqrt(2.0 - w)
    local = np.stack([np.outer(sin_t, np.cos(phi)), np.outer(sin_t, np.sin(phi)),
                      np.outer(1.0 - w, np.ones(n_phi))], axis=-1).reshape(-1, 3)
    mu = as_directions(mu)
    dirs = from_frame(local, *basis(np.repeat(mu, len(local), axis=0)), np.repeat(mu, len(local), axis=0))
    return dirs, np.repeat(ws, n_phi) * (2.0 * np.pi / n_phi)


def _integrate(points, integrand, nodes, weights, chunk=256):
    out = np.empty(len(points))
    for i in range(0, len(points), chunk):
        p = points[i:i + chunk, None, :]
        out[i:i + chunk] = np.sum(integrand(p, nodes[None, :, :]) * weights, axis=1)
    return out


def exact_density_reflect(r, mu_o, kappa_o, mu_m, kappa_m, n_s=64, n_phi=48):
    """D(r) of Eq. 16 at unit rows r by quadrature over the lobe that is narrower after warping to r-space:
    over o (Eq. 16 as written, m the half vector) when kappa_o >= kappa_m / (4 |mu_o . mu_m|), else over m,
    D(r) = int D(m) D(Phi(r; m)) [r . m > 0] dw_m (||do/dr||_Phi = 1 at fixed m)."""
    r, mu_o, mu_m = as_directions(r), as_directions(mu_o)[0], as_directions(mu_m)[0]
    if kappa_o >= kappa_m * float(reflection_jacobian(mu_o, mu_m)[0]):
        def f(x, o):
            h = normalize(o + x)
            return vmf.density_around(o, mu_o, kappa_o) * vmf.density_around(h, mu_m, kappa_m) * 0.25 / np.maximum(
                dot(o, h), 1e-300)
        nodes, weights = lobe_rule(mu_o, kappa_o, n_s=n_s, n_phi=n_phi)
    else:
        def f(x, m):
            c = dot(x, m)
            o = 2.0 * c[..., None] * m - x
            return np.where(c > 0.0, vmf.density_around(m, mu_m, kappa_m) * vmf.density_around(o, mu_o, kappa_o), 0.0)
        nodes, weights = lobe_rule(mu_m, kappa_m, n_s=n_s, n_phi=n_phi)
    return _integrate(r, f, nodes, weights)


def exact_density_refract(t, mu_o, kappa_o, mu_m, kappa_m, eta, n_s=64, n_phi=48):
    """D(t) of Eq. 20 at unit rows t by quadrature over the narrower warped lobe: over o (Eq. 20 as written, m =
    -+(o + eta t) normalised to face o, kept where t . m < 0) or over m, D(t) = int D(m) D(o) ||do/dt|| dw_m with
    o the reverse refraction of t (index 1 / eta), kept where t . m < 0 and no TIR."""
    t, mu_o, mu_m = as_directions(t), as_directions(mu_o)[0], as_directions(mu_m)[0]
    eta = float(eta)
    j_m = float(refraction_jacobian(mu_o, mu_m, eta)[0])
    j_o = float(incident_refraction_jacobian(mu_o, mu_m, eta)[0])
    if kappa_o * j_o >= kappa_m * j_m:
        def f(x, o):
            v = o + eta * x
            m = normalize(np.where((dot(o, v) < 0.0)[..., None], -v, v))
            cm, tm = dot(o, m), dot(x, m)
            jac = eta * eta * np.abs(tm) / np.maximum((cm + eta * tm) ** 2, 1e-300)
            return np.where(tm < 0.0, vmf.density_around(o, mu_o, kappa_o) * vmf.density_around(m, mu_m, kappa_m) * jac, 0.0)
        nodes, weights = lobe_rule(mu_o, kappa_o, n_s=n_s, n_phi=n_phi)
    else:
        def f(x, m):
            tm = dot(x, m)
            x_b, m_b = np.broadcast_arrays(x, m)
            o, ok = refract(x_b.reshape(-1, 3), m_b.reshape(-1, 3), 1.0 / eta)
            o, ok = o.reshape(m_b.shape), ok.reshape(tm.shape)
            cm = np.maximum(dot(o, m), 1e-300)
            val = vmf.density_around(m, mu_m, kappa_m) * vmf.density_around(o, mu_o, kappa_o) * eta * eta * np.abs(tm) / cm
            return np.where(ok & (tm < 0.0), val, 0.0)
        nodes, weights = lobe_rule(mu_m, kappa_m, n_s=n_s, n_phi=n_phi)
    return _integrate(t, f, nodes, weights)


# ------------------------------------------------------------------------------------------ validation (Figs. 6-7)

# The paper's validation examples (Figs. 6-7, read from the caption): mu_o . mu_m and (kappa_o, kappa_m); mu_m = +z,
# mu_o in the xz plane, 0.707 read as cos 45 deg, eta = 1.5 for refraction.
FIGURE_EXAMPLES = ((1.0, 50.0, 200.0), (float(np.sqrt(0.5)), 100.0, 100.0), (0.5, 200.0, 50.0))
FIGURE_ETA = 1.5


def exact_moments(nodes, weights, density):
    """Mass, mean direction and moment-matched kappa of a density tabulated on a lobe rule."""
    mu, kappa = sample_moments(nodes, density * weights)
    return np.sum(density * weights), mu, kappa


def joint_warp_error(kind: str, cos_om: float, kappa_o: float, kappa_m: float, eta: float = FIGURE_ETA) -> dict:
    """The joint warp (Eq. 18 for kind "r", Eq. 21 for "t") against the exact Eq. 16 / 20 by quadrature over a lobe
    rule around the approximating lobe (deterministic): the exact distribution's mass on the rule, the angle
    (degrees) between its mean direction and mu_hat, kappa_hat's relative error against its moment-matched kappa,
    and the L1 distance int |D_exact - M(mu_hat, kappa_hat)| (0 identical, 2 disjoint)."""
    z = np.array([0.0, 0.0, 1.0])
    mu_o = np.array([np.sqrt(max(0.0, 1.0 - cos_om * cos_om)), 0.0, cos_om])
    if kind == "r":
        lobe = joint_reflect(mu_o, kappa_o, z, kappa_m)
        exact = lambda x: exact_density_reflect(x, mu_o, kappa_o, z, kappa_m)  # noqa: E731
    else:
        lobe = joint_refract(mu_o, kappa_o, z, kappa_m, eta)
        exact = lambda x: exact_density_refract(x, mu_o, kappa_o, z, kappa_m, eta)  # noqa: E731
    mu_hat, kappa_hat = lobe.mu[0], lobe.kappa[0]
    nodes, weights = lobe_rule(mu_hat, kappa_hat)
    d_exact = exact(nodes)
    mass, mu, kappa = exact_moments(nodes, weights, d_exact)
    l1 = np.sum(np.abs(d_exact - vmf.density_around(nodes, mu_hat, kappa_hat)) * weights)
    angle = np.degrees(np.arccos(np.clip(mu @ mu_hat, -1.0, 1.0)))
    return {"mass": float(mass), "angle": float(angle), "kappa_error": float(kappa_hat / kappa - 1.0),
            "l1": float(l1)}
