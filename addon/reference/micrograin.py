"""Micrograin porous layer (Lucas et al. 2023): the exact float64 reference.

Conventions (as ``spongecake``): local frame, z = macro normal; directions are unit rows of (N, 3) float64
arrays, ``wi`` points to the light, ``wo`` to the viewer; f has no cosine and is RGB (N, 3). τ0 is the filling
factor, β the anfractuosity, P = −ln(1 − τ0) the grain density in units of the grain's disc (Eq. 13). The
geometric functions take τ0 and β as floats or as arrays that broadcast against the N rows.

Exact (the paper's equations in float64, with the errata of research notes §3 fixed):

* D (Eqs. 16/17) and its sampling (Eq. 20 with its sign corrected); τβ, τ⁺ and w⁺ (Eqs. 21, 22, 24). The
  expm1/log1p forms reduce exactly to GGX(β) (resp. 0) at τ0 = 0 and reach 1 at grazing.
* Λ (Eq. 25) is summed to rounding error with no cancellation (see ``smith_lambda``); ``smith_lambda_paper``
  keeps the printed five-term series for comparison and ``smith_lambda_float32`` is the scheme for float32
  shaders. G is height-correlated, 1 / (1 + Λi + Λo).
* The BSDF is Eq. 1: w⁺ f_S + (1 − w⁺) f_B with the grain BRDF f_S of Eq. 2 (Lambertian Kd, and/or the
  specular microfacet lobe with the exact dielectric or conductor Fresnel factor).

Stand-in: the integrated transmittance T̄ of Eq. 2 is in the paper's unpublished supplemental. For dielectric
grains we use T̄(i, o) = t(θi) t(θo), t = 1 − E_spec, E_spec the directional albedo of the grains' specular
lobe, tabulated per parameter set on 64 cosines (cached) and interpolated linearly (the approach of Mitsuba's
``roughplastic``). Diffuse grains have T̄ = 1 and no specular lobe; conductor grains no diffuse part.

Our choices where the paper is silent: light crosses the layer into a transmitting bulk (a dielectric or a
SpongeCake stack without substrate) through the pores, with no grain term: f_B g(θ) ḡ, θ the angle of the
direction above, g = sqrt(1 − τβ) and ḡ its cosine-weighted mean (``_pore_transmittance``: the pores it sees,
1 − τ⁺, would count twice the pores that w⁺ gives to the grains); with both directions below, f = f_B. A
dielectric bulk is a glass as renderers see it (``_bulk_eval``). A model bulk's Dirac (SpongeCake's delta
transmission) is in ``furnace_albedo`` only: ``eval`` and ``pdf`` leave it out and ``sample`` gives it weight 0.

Eq. 1 itself is not energy-conserving over glossy bulks: w⁺ gives the grains light that the bulk's mirror lobe
also reflects, so white Lambertian grains over a white near-mirror bulk return up to about 9% more than they
receive at normal incidence (measured: tests/unit/test_micrograin_reference.py).
"""
from __future__ import annotations

import importlib
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from ..models.micrograin import SIMPLE_BULKS, Bulk, Params, equivalent_roughness, params_from_dict
from . import lobes, microfacet, spongecake
from .frames import as_directions, dot, normalize, reflect, spherical

__all__ = ["Params", "Sample", "params_from_dict", "ndf", "sample_ndf", "tau_beta", "tau_plus", "w_plus",
           "smith_lambda", "smith_lambda_paper", "smith_lambda_float32", "lambda_scheme", "lambda_numeric", "g1", "g2",
           "specular_albedo", "eval", "pdf", "sample", "directional_albedo", "furnace_albedo", "reflection_terms",
           "hemispherical_mean"]

BLENDS = ("ours", "linear", "deon")
TABLE_SIZE = 64  # cosines of the tabulated specular albedo (T̄ stand-in)


class Sample(NamedTuple):
    """Sampled directions with weight f |cos wo| / pdf, and pdf."""

    wo: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray


# ------------------------------------------------------------------------------------- filling factor

def _log_porosity(tau0):
    """P = −ln(1 − τ0) = π ρ r_s² (Eq. 13)."""
    return -np.log1p(-np.asarray(tau0, dtype=float))


def _log1p_ratio(x):
    """−ln(1 − x) / x, 1 at x = 0."""
    x = np.asarray(x, dtype=float)
    safe = np.where(x > 0, x, 0.5)
    return np.where(x > 0, -np.log1p(-safe) / safe, 1.0)


def _p_over_expm1(tau0):
    """P / (e^P − 1) = P (1 − τ0) / τ0, 1 at τ0 = 0 (the normalisation of Eqs. 16/17)."""
    return _log1p_ratio(tau0) * (1.0 - np.asarray(tau0, dtype=float))


def _depth(p, ratio):
    """P · ratio with 0 · inf = 0: without grains nothing is covered, even at grazing."""
    p, ratio = np.broadcast_arrays(p, ratio)
    return np.multiply(p, ratio, out=np.zeros(p.shape), where=p > 0)


def _gamma_over_cos(cos, sin2, beta):
    """γβ(θ) / cos θ = sqrt(cos² + β² sin²) / cos (Eq. 21), inf at grazing."""
    c = np.abs(cos)
    gamma = np.sqrt(c * c + np.square(beta) * sin2)
    return np.divide(gamma, c, out=np.full(np.broadcast(gamma, c).shape, np.inf), where=c > 0)


def _sin2(cos):
    c = np.abs(np.asarray(cos, dtype=float))
    return (1.0 - c) * (1.0 + c)


def tau_beta(cos_theta, tau0, beta):
    """Visible filling factor τβ(θ) = 1 − (1 − τ0)^{γβ(θ)/cos θ} (Eq. 21): τ0 at normal incidence, 1 at grazing."""
    ratio = _gamma_over_cos(cos_theta, _sin2(cos_theta), beta)
    return -np.expm1(-_depth(_log_porosity(tau0), ratio))


def tau_plus(cos_theta, tau0, beta):
    """Visible filling factor of the grains' upper halves, 1 − sqrt((1 − τβ)(1 − τ0)) (Eq. 22)."""
    ratio = _gamma_over_cos(cos_theta, _sin2(cos_theta), beta)
    return -np.expm1(-0.5 * _depth(_log_porosity(tau0), ratio + 1.0))


def w_plus(wi, wo, tau0, beta):
    """Weight of the grains, 1 − sqrt((1 − τβ(θi))(1 − τβ(θo))) (Eq. 24); symmetric in wi and wo."""
    ratio = (_gamma_over_cos(wi[:, 2], wi[:, 0] ** 2 + wi[:, 1] ** 2, beta)
             + _gamma_over_cos(wo[:, 2], wo[:, 0] ** 2 + wo[:, 1] ** 2, beta))
    return -np.expm1(-0.5 * _depth(_log_porosity(tau0), ratio))


# ------------------------------------------------------------------------------------------------ NDF

def ndf(m, tau0, beta):
    """Micrograin NDF D(m) = P/τ0 · (1 − τ0)^{tan²θm / (β² + tan²θm)} · D_GGX(m; β) (Eqs. 16/17).

    0 below the horizon; P/τ0 → 1 as τ0 → 0 (exactly GGX(β) at τ0 = 0).
    """
    r2 = m[:, 0] ** 2 + m[:, 1] ** 2
    q = r2 + np.square(beta) * m[:, 2] ** 2
    t = np.divide(r2, q, out=np.zeros_like(q), where=q > 0)
    return _log1p_ratio(tau0) * np.exp(-_log_porosity(tau0) * t) * microfacet.ggx_d(m, beta)


def sample_ndf(tau0, beta, u1, u2):
    """Normals m with density D(m) cos θm: the inverse CDF of Eq. 19, Eq. 20 with its sign corrected.

    tan²θm = β² ln(1 − ξτ0) / (ln(1 − τ0) − ln(1 − ξτ0)) (the printed radicand is negative). With
    x = ξτ0 and y = (1 − ξ)τ0 / (1 − ξτ0), ln(1 − τ0) − ln(1 − ξτ0) = ln(1 − y), so
    tan²θm = β² ξ (1 − ξτ0) g(x) / ((1 − ξ) g(y)) with g(x) = −ln(1 − x)/x: GGX's β² ξ/(1 − ξ) at τ0 = 0.
    """
    x = u1 * tau0
    y = (1.0 - u1) * tau0 / (1.0 - x)
    sin2 = np.square(beta) * u1 * (1.0 - x) * _log1p_ratio(x)  # ∝ tan²θm
    cos2 = (1.0 - u1) * _log1p_ratio(y)
    sin_m, cos_m = np.sqrt(sin2 / (sin2 + cos2)), np.sqrt(cos2 / (sin2 + cos2))
    phi = 2.0 * np.pi * u2
    return np.stack([sin_m * np.cos(phi), sin_m * np.sin(phi), cos_m], axis=1)


# -------------------------------------------------------------------------------------------- Smith Λ

_SERIES_TERMS = 64  # terms of J_k's power series; with Y <= 1/2 the remainder is below 1e-17


def _kummer_terms(p):
    """(N, K) terms μ_j = (1/2)_j P^j / ((2)_j j!) of Kummer's M(1/2, 2, P), until P^j/j! < 1e-17."""
    k, term = 0, 1.0
    while term > 1e-17:
        k += 1
        term *= float(np.max(p, initial=0.0)) / k
    j = np.arange(k)
    ratios = (j + 0.5) / ((j + 1.0) * (j + 2.0))
    steps = np.concatenate([np.ones(p.shape + (1,)), p[:, None] * ratios], axis=1)
    return np.cumprod(steps, axis=1)


def _beta_series(y, n_k):
    """J_k(Y) = Σ_j (3/2)_j / j! · Y^{k+j} / (k + j), k = 1..n_k: positive terms, for Y <= 1/2."""
    j = np.arange(_SERIES_TERMS)
    k = np.arange(1, n_k + 1)
    b = np.cumprod(np.concatenate([[1.0], (j[:-1] + 1.5) / (j[:-1] + 1.0)]))
    coefficients = b[:, None] / (j[:, None] + k[None, :])
    powers = np.cumprod(np.repeat(y[:, None], max(_SERIES_TERMS - 1, n_k), axis=1), axis=1)  # Y^1, Y^2, ...
    return (np.concatenate([np.ones((len(y), 1)), powers[:, : _SERIES_TERMS - 1]], axis=1) @ coefficients
            * powers[:, :n_k])


def _beta_recurrence(y, r, r_minus_1, n_k):
    """J_1 = 2(r − 1), J_{k+1} = (k J_k − Y^k r) / (k − 1/2), r = (1 − Y)^{−1/2}: for Y > 1/2, where the
    error stays at rounding level relative to r."""
    j = np.empty(y.shape + (n_k,))
    j[:, 0] = 2.0 * r_minus_1
    y_k_r = r
    for k in range(1, n_k):
        y_k_r = y_k_r * y
        j[:, k] = (k * j[:, k - 1] - y_k_r) / (k - 0.5)
    return j


def _lambda(cos, sin2, tau0, beta):
    """Exact Λ from cos θ and sin² θ (N,); inf at grazing (see ``smith_lambda``)."""
    c = np.abs(cos)
    grazing = c == 0
    c = np.where(grazing, 1.0, c)
    shape = c.shape
    b2s2 = np.broadcast_to(np.square(beta), shape) * sin2
    gamma = np.sqrt(c * c + b2s2)
    y = b2s2 / (gamma * gamma)
    r = gamma / c
    r_minus_1 = b2s2 / (c * (gamma + c))
    p = np.broadcast_to(_log_porosity(tau0), shape)
    mu = _kummer_terms(p)
    j = np.empty_like(mu)
    low = y <= 0.5
    j[low] = _beta_series(y[low], mu.shape[1])
    j[~low] = _beta_recurrence(y[~low], r[~low], r_minus_1[~low], mu.shape[1])
    lam = 0.25 * np.broadcast_to(_p_over_expm1(tau0), shape) * np.sum(mu * j, axis=1)
    return np.where(grazing, np.inf, lam)


def smith_lambda(w, tau0, beta):
    """Exact Smith Λ of the micrograin NDF (Eq. 25 summed), float64; 0 at normal incidence, inf at grazing.

    Expanding (1 − τ0)^{tan²/(β² + tan²)} = (1 − τ0) Σ_k (P s)^k / k!, s = β²/(β² + tan²θm), makes D a
    mixture of slope distributions ∝ (β² + r²)^{−(k+1)}, k >= 1, with weights P^k / (k! (e^P − 1)). Their
    Λ_k depend on Y = β² tan²θ / (1 + β² tan²θ) only; summing them gives

        Λ = P / (4 (e^P − 1)) Σ_{k>=1} μ_{k−1} J_k(Y),   J_k(Y) = ∫_0^Y y^{k−1} (1 − y)^{−3/2} dy,

    μ_j = (1/2)_j P^j / ((2)_j j!) (the terms of Kummer's M(1/2, 2, P)); equivalently
    Λ = P / (4 (e^P − 1)) ∫_0^Y M(1/2, 2, P y) (1 − y)^{−3/2} dy. The paper's terms are
    F_n = cot θ μ_n J_{n+1} / (2 P^n); at P = 0 only J_1 = 2(sqrt(1 + β² tan²θ) − 1) remains: GGX(β).

    J_k is evaluated by its power series (positive terms) where Y <= 1/2 (cot θ >= β), by the forward
    recurrence elsewhere (no cancellation in either); terms are summed until P^k / k! < 1e-17.
    """
    w = as_directions(w)
    return _lambda(w[:, 2], w[:, 0] ** 2 + w[:, 1] ** 2, tau0, beta)


def _paper_terms(mu, beta):
    """F_0..F_4 of Eq. 25 as printed (research notes §3), mu = cot θ."""
    b2, m2 = beta * beta, mu * mu
    s = np.sqrt(b2 + m2)
    return [
        s - mu,
        (b2 + 2 * m2 - 2 * mu * s) / (4 * s),
        (3 * b2 ** 2 + 12 * b2 * m2 + 8 * m2 ** 2 - 8 * mu * s ** 3) / (48 * s ** 3),
        (5 * b2 ** 3 + 30 * b2 ** 2 * m2 + 40 * b2 * m2 ** 2 + 16 * m2 ** 3 - 16 * mu * s ** 5) / (384 * s ** 5),
        (35 * b2 ** 4 + 280 * b2 ** 3 * m2 + 560 * b2 ** 2 * m2 ** 2 + 448 * b2 * m2 ** 3 + 128 * m2 ** 4
         - 128 * mu * s ** 7) / (15360 * s ** 7),
    ]


def smith_lambda_paper(w, tau0, beta, n_terms=4):
    """The paper's truncated series Λ = P / (2 cot θ (e^P − 1)) Σ_{n<=n_terms} P^n F_n (Eq. 25), as printed.

    For comparison only: poor at τ0 = 0.98 near grazing, and every F_n cancels at small θ (float32 directions
    are evaluated in float32, where it overflows to NaN below about 0.01°). 0 at normal incidence, inf at
    grazing.
    """
    if not 0 <= n_terms <= 4:
        raise ValueError("the paper's series is known up to n = 4")
    w = np.atleast_2d(np.asarray(w))
    dtype = np.float32 if w.dtype == np.float32 else np.float64
    w = w.astype(dtype)
    tau0, beta = dtype(tau0), dtype(beta)
    c, s = np.abs(w[:, 2]), np.sqrt(w[:, 0] ** 2 + w[:, 1] ** 2)
    ok = (c > 0) & (s > 0)
    mu = np.where(ok, c, 1) / np.where(ok, s, 1)
    p = -np.log1p(-tau0)
    p_over_expm1 = p * (1 - tau0) / tau0 if tau0 > 0 else dtype(1)
    with np.errstate(over="ignore", invalid="ignore"):  # as printed: μ^{2n} overflows float32 below ~0.01°
        series = sum(p ** n * f for n, f in enumerate(_paper_terms(mu, beta)[: n_terms + 1]))
        lam = p_over_expm1 / 2 * series / mu
    return np.where(ok, lam, np.where(c > 0, 0, np.inf)).astype(dtype)


# Float32 scheme: Gauss-Legendre nodes and weights on [0, 1], and the number of terms of M(1/2, 2, x).
_F32_NODES = 3
_F32_KUMMER_TERMS = 10
_x, _w = np.polynomial.legendre.leggauss(_F32_NODES)
SCHEME_NODES, SCHEME_WEIGHTS = tuple(float(x) for x in 0.5 * (_x + 1.0)), tuple(float(w) for w in 0.5 * _w)
KUMMER_COEFFICIENTS = tuple(float(c) for c in np.cumprod([1.0] + [(j + 0.5) / ((j + 1.0) * (j + 2.0))
                                                                  for j in range(_F32_KUMMER_TERMS - 1)]))


def smith_lambda_float32(cos_theta, tau0, beta):
    """Λ evaluated so that float32 arithmetic suffices (for OSL / GPU); the dtype of the inputs is kept.

    With u = (1 − y)^{−1/2} and then s = ln u, the integral of ``smith_lambda`` becomes

        Λ = P / (2 (e^P − 1)) ∫_0^L e^s M(1/2, 2, P (1 − e^{−2s})) ds,   L = ln sqrt(1 + β² tan²θ),

    whose integrand is smooth, positive and bounded by e^L M(1/2, 2, P), so every step below adds positive
    terms (no cancellation; Λ >= 0, 0 at normal incidence, inf at grazing):

    1. tan²θ = (1 − c)(1 + c) / c² with c >= 1e-18 (finite in float32), r = sqrt(1 + β² tan²θ).
    2. L = ln r; for β² tan²θ < 1/4, L = 2 atanh(z) with z = (r − 1)/(r + 1) = β² tan²θ / (r + 1)², by its
       series 2z (1 + z²/3 + z⁴/5 + z⁶/7) (z < 0.06: remainder below 1e-10).
    3. P / τ0 = −ln(1 − τ0)/τ0; for τ0 < 0.05 by its series Σ_{n<6} τ0^n / (n + 1) (remainder below 1e-8).
       P = τ0 (P / τ0); P / (e^P − 1) = (P / τ0)(1 − τ0).
    4. 3-point Gauss-Legendre on [0, L]; M(1/2, 2, x) by Horner with its first 10 terms (x <= P <= 3.92
       for τ0 <= 0.98). Sized for the shaders' cost (a node group evaluates every step as nodes; render times in
       docs/benchmarks.md): 6 points and 14 terms would give 1e-5 relative with 84 Horner steps instead of 30.

    Measured against ``smith_lambda`` for θ <= 89°, τ0 in [0, 0.98], β in [1e-3, 1]: within 2.6e-3 relative,
    G1 = 1/(1 + Λ) within 2.1e-4, in float64 and in float32 alike (float32 rounding of cos θ adds less). Only
    + − × ÷, abs, sqrt, exp, log, max and a select, with fixed loop counts: the Cycles mapping
    (nodes/micrograin.py) runs the same ``lambda_scheme`` on its OSL and node-group backends.
    """
    c = np.abs(cos_theta)
    ops = _DtypeOps(np.result_type(c, tau0, beta))
    tau0, beta = np.asarray(tau0, ops.dtype), np.asarray(beta, ops.dtype)
    lam = lambda_scheme(ops, ops.maximum(c.astype(ops.dtype), 1e-18), tau0, beta)  # 1e-18: tan² finite in float32
    return np.where(c == 0, ops.dtype.type(np.inf), lam)


def lambda_scheme(b, c, tau0, beta):
    """The steps of ``smith_lambda_float32`` on an ``expr`` backend ``b`` (+ − × ÷ on values, ``b.exp``, ``b.log``,
    ``b.sqrt``, ``b.maximum``, ``b.step_below``), for cos θ = ``c`` > 0: branches become arithmetic selects of
    two finite values."""
    a2 = beta * beta * ((1.0 - c) * (1.0 + c)) / (c * c)
    r = b.sqrt(1.0 + a2)
    z = a2 / ((r + 1.0) * (r + 1.0))
    z2 = z * z
    near = b.step_below(a2, 0.25)
    ell = near * (2.0 * z * (1.0 + z2 * (1.0 / 3.0 + z2 * (1.0 / 5.0 + z2 / 7.0)))) \
        + (1.0 - near) * b.log(b.maximum(r, 1.0))
    t = tau0
    small = b.step_below(t, 0.05)
    p_over_tau = small * (1.0 + t * (1.0 / 2.0 + t * (1.0 / 3.0 + t * (1.0 / 4.0 + t * (1.0 / 5.0 + t / 6.0))))) \
        + (1.0 - small) * (-b.log(1.0 - t) / b.maximum(t, 0.05))
    p = t * p_over_tau
    total = 0.0
    for x_n, w_n in zip(SCHEME_NODES, SCHEME_WEIGHTS):
        e = b.exp(ell * x_n)
        y = p * (1.0 - 1.0 / (e * e))
        m = KUMMER_COEFFICIENTS[-1]
        for coefficient in KUMMER_COEFFICIENTS[-2::-1]:
            m = coefficient + y * m
        total = total + w_n * e * m
    return 0.5 * p_over_tau * (1.0 - t) * ell * total


class _DtypeOps:
    """numpy ``expr`` operations that keep a dtype (float32 for the scheme's rounding tests)."""

    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)

    def sqrt(self, x):
        return np.sqrt(x)

    def exp(self, x):
        return np.exp(x)

    def log(self, x):
        return np.log(x)

    def maximum(self, a, b):
        return np.maximum(a, self.dtype.type(b))

    def step_below(self, x, edge):
        return (x < edge).astype(self.dtype)


def lambda_numeric(cos_theta, tau0: float, beta: float, n: int = 64):
    """Brute-force Smith Λ from ``ndf`` alone, for tests: Λ = (1/μ) ∫_{x>μ} (x − μ) ∫ P22(x, y) dy dx.

    μ = cot θ, P22 = D(m) cos⁴θm the slope density. Gauss-Legendre n x n after x = β cot δ,
    δ ∈ (0, δ0], δ0 = atan(β tan θ) (x − μ = β sin(δ0 − δ) / (sin δ sin δ0), no cancellation), and
    y = sqrt(β² + x²) tan φ (both integrands smooth and bounded). inf at grazing, 0 at normal incidence.
    """
    c = np.abs(np.asarray(cos_theta, dtype=float)).ravel()
    inside = (c > 0) & (c < 1)
    tan_theta = np.sqrt(_sin2(c[inside])) / c[inside]
    x_n, w_n = np.polynomial.legendre.leggauss(n)
    delta0 = np.arctan(beta * tan_theta)[:, None, None]  # (N, 1, 1)
    delta = delta0 * (0.5 * (1.0 - x_n))[None, :, None]  # (N, n, 1)
    phi = (0.25 * np.pi * (x_n + 1.0))[None, None, :]  # (1, 1, n): y >= 0, doubled below
    x, y = np.broadcast_arrays(beta / np.tan(delta), beta / np.sin(delta) * np.tan(phi))
    m = normalize(np.stack([-x, -y, np.ones_like(x)], axis=-1).reshape(-1, 3))
    p22 = (ndf(m, tau0, beta) * m[:, 2] ** 4).reshape(x.shape)
    jacobian = (beta / np.sin(delta) ** 2) * (beta / np.sin(delta) / np.cos(phi) ** 2)
    x_minus_mu = beta * np.sin(delta0 - delta) / (np.sin(delta) * np.sin(delta0))
    weights = (0.5 * delta0 * w_n[None, :, None]) * (0.25 * np.pi * w_n[None, None, :])
    lam = np.where(c == 0, np.inf, 0.0)
    lam[inside] = 2.0 * tan_theta * np.sum(x_minus_mu * p22 * jacobian * weights, axis=(1, 2))
    return lam


def _lambda_gaf(w, tau0, beta, gaf):
    if gaf == "series":
        return smith_lambda(w, tau0, beta)
    if gaf == "ggx":
        return microfacet.smith_lambda(w, np.vectorize(equivalent_roughness)(tau0, beta))
    raise ValueError(f"unknown gaf {gaf!r}")


def g1(w, tau0, beta, gaf="series"):
    """Smith masking 1 / (1 + Λ(w)): the micrograin Λ (``series``) or GGX's with α̃ of Eq. 18 (``ggx``)."""
    return 1.0 / (1.0 + _lambda_gaf(as_directions(w), tau0, beta, gaf))


def g2(wi, wo, tau0, beta, gaf="series"):
    """Height-correlated masking-shadowing 1 / (1 + Λ(wi) + Λ(wo)); 0 at grazing."""
    wi, wo = as_directions(wi), as_directions(wo)
    return 1.0 / (1.0 + _lambda_gaf(wi, tau0, beta, gaf) + _lambda_gaf(wo, tau0, beta, gaf))


# ------------------------------------------------------------------------------------------- grains

def _specular(params: Params, wi, wo, fresnel):
    """D(h) G(i, o) F(i·h) / (4 cos i cos o) (Eq. 2) for both directions above; ``fresnel(cos)`` -> (N,) or (N, 3)."""
    h = normalize(wi + wo)
    value = (ndf(h, params.filling_factor, params.anfractuosity)
             * g2(wi, wo, params.filling_factor, params.anfractuosity, params.gaf) / (4.0 * wi[:, 2] * wo[:, 2]))
    f = fresnel(dot(wi, h))
    return (f if f.ndim == 2 else f[:, None]) * value[:, None]


def _ndf_cdf(theta_m, tau0, beta):
    """C(θm) = (1 − (1 − τ0)^{tan²θm / (β² + tan²θm)}) / τ0 (Eq. 19); tan²/(β² + tan²) at τ0 = 0."""
    s2, c2 = np.sin(theta_m) ** 2, np.cos(theta_m) ** 2
    t = s2 / (s2 + beta * beta * c2)
    tau0 = float(tau0)
    return -np.expm1(-_log_porosity(tau0) * t) / tau0 if tau0 > 0 else t


def _graded_nodes(n, both_ends):
    """Gauss-Legendre nodes and weights on [0, 1] graded towards 1 (s = 1 − (1 − x)²) or towards both ends
    (s = 3x² − 2x³), where the reflected direction reaches the horizon and G varies fastest."""
    x, v = np.polynomial.legendre.leggauss(n)
    x, v = 0.5 * (x + 1.0), 0.5 * v
    if both_ends:
        return x * x * (3.0 - 2.0 * x), v * 6.0 * x * (1.0 - x)
    return 1.0 - (1.0 - x) ** 2, v * 2.0 * (1.0 - x)


def specular_albedo(cos_theta, tau0: float, beta: float, ior=None, gaf="series", n=32):
    """Directional albedo E(θ) = ∫ D G F / (4 cos i cos o) cos o dωo of a specular micrograin lobe (dielectric
    Fresnel of ``ior``, or F = 1 when ``ior`` is None), (N,).

    Integrated over the NDF's sampling variables (m = ``sample_ndf(ξ1, ξ2)`` has density D cos θm):
    E = ∫∫ G F (i·m) / (cos i cos θm) dξ1 dξ2 over the normals that reflect wi above the horizon. Those are
    all azimuths for θm < (90° − θi)/2, |φm| < φmax(θm) up to (90° + θi)/2 (cos φmax = −cot θi cot 2θm),
    none beyond: n x n graded Gauss-Legendre nodes on each of the two pieces.
    """
    c = np.clip(np.asarray(cos_theta, dtype=float).ravel(), 1e-12, 1.0)
    theta_i = np.arccos(c)
    sin_i = np.sqrt(1.0 - c * c)
    cot_i = np.divide(c, sin_i, out=np.zeros_like(c), where=sin_i > 0)  # the second piece is empty at θi = 0
    wi = np.repeat(spherical(c, np.zeros_like(c)), n * n, axis=0)
    bounds = [_ndf_cdf(a, tau0, beta) for a in (0.0 * theta_i, 0.25 * np.pi - 0.5 * theta_i,
                                                  0.25 * np.pi + 0.5 * theta_i)]
    total = np.zeros_like(c)
    for lo, hi, full in ((bounds[0], bounds[1], True), (bounds[1], bounds[2], False)):
        x, v = _graded_nodes(n, both_ends=not full)
        xi = lo[:, None] + (hi - lo)[:, None] * x  # (N, n)
        m = sample_ndf(tau0, beta, xi.ravel(), np.zeros(xi.size))
        cos_m, sin_m = m[:, 2].reshape(xi.shape), m[:, 0].reshape(xi.shape)
        if full:
            phi_max = np.full_like(xi, np.pi)
        else:
            cot_2m = np.divide(cos_m * cos_m - sin_m * sin_m, 2.0 * sin_m * cos_m, out=np.zeros_like(xi),
                               where=sin_m * cos_m > 0)
            phi_max = np.arccos(np.clip(-cot_i[:, None] * cot_2m, -1.0, 1.0))
        y, u = _graded_nodes(n, both_ends=False)
        phi = phi_max[:, :, None] * y  # (N, n, n)
        m = np.stack(np.broadcast_arrays(sin_m[:, :, None] * np.cos(phi), sin_m[:, :, None] * np.sin(phi),
                                         cos_m[:, :, None]), axis=-1).reshape(-1, 3)
        wo = reflect(wi, m)
        cos_im = dot(wi, m)
        ok = wo[:, 2] > 0
        f = np.ones_like(cos_im) if ior is None else microfacet.fresnel_dielectric(cos_im, ior)
        value = np.zeros_like(cos_im)
        value[ok] = g2(wi[ok], wo[ok], tau0, beta, gaf) * f[ok] * cos_im[ok] / (wi[ok, 2] * m[ok, 2])
        weights = (hi - lo)[:, None, None] * v[:, None] * (phi_max[:, :, None] * u) / np.pi
        total += np.sum(value.reshape(weights.shape) * weights, axis=(1, 2))
    return total


@lru_cache(maxsize=64)
def _albedo_table(tau0: float, beta: float, ior: float, gaf: str):
    """Cosines (cell centres of [0, 1]) and the specular albedo there, per parameter set."""
    mu = (np.arange(TABLE_SIZE) + 0.5) / TABLE_SIZE
    return mu, specular_albedo(mu, tau0, beta, ior, gaf)


def _coat_albedo(params: Params, cos):
    """E_spec(θ) of a dielectric coat, interpolated from its table (0 for diffuse grains, 1 for conductors)."""
    grain = params.grain
    if grain.type != "dielectric":
        return np.full(np.shape(cos), 1.0 if grain.type == "conductor" else 0.0)
    mu, albedo = _albedo_table(float(params.filling_factor), float(params.anfractuosity), float(grain.ior),
                               params.gaf)
    return np.interp(np.abs(cos), mu, albedo)


def _grain_bsdf(params: Params, wi, wo):
    """f_S of Eq. 2 (N, 3) for both directions above."""
    grain = params.grain
    if grain.type == "conductor":
        return _specular(params, wi, wo, lambda c: microfacet.fresnel_conductor(c, grain.ior, grain.k))
    diffuse = np.asarray(grain.albedo) / np.pi * np.ones((len(wi), 1))
    if grain.type == "diffuse":
        return diffuse
    coat = (1.0 - _coat_albedo(params, wi[:, 2])) * (1.0 - _coat_albedo(params, wo[:, 2]))
    return diffuse * coat[:, None] + _specular(params, wi, wo, lambda c: microfacet.fresnel_dielectric(c, grain.ior))


# --------------------------------------------------------------------------------------------- bulk

def _bulk_model(bulk: Bulk):
    return importlib.import_module(f".{bulk.type}", __package__)


def _bulk_eval(bulk: Bulk, wi, wo):
    """A dielectric bulk is a glass as renderers see it: Walter et al.'s f with ωi and ωo exchanged, so the
    transmitted throughput seen from the viewer's side is 1 − F without the 1/η² of radiance entering a denser
    medium (a pane's two interfaces cancel it; Cycles' Glass BSDF does the same, ``nodes.closures_np``)."""
    if bulk.type == "dielectric":
        return spongecake.substrate_bsdf(bulk.params, wo, wi)
    if bulk.type in SIMPLE_BULKS:
        return spongecake.substrate_bsdf(bulk.params, wi, wo)
    return _bulk_model(bulk).eval(bulk.params, wi, wo)


def samples_from_view(model) -> bool:
    """Whether a model bulk's reference samples the light direction given the view (its module sets
    ``SAMPLES_FROM_VIEW = True``: ``sample(p, wo, u) -> Sample(wi, ...)``, ``pdf(p, wi, wo)`` the density of wi
    given wo, e.g. the thin coat, which is built from the view) instead of the other models' ``sample(p, wi, u)
    -> Sample(wo, ...)`` with ``pdf(p, wi, wo)`` the density of wo given wi. This layer samples "the other
    direction given the one it holds" either way: a view-built bulk gets the held direction as its view and its
    pdf with the arguments exchanged, so the density is always that of what was drawn."""
    return bool(getattr(model, "SAMPLES_FROM_VIEW", False))


def _bulk_pdf(bulk: Bulk, wi, wo):
    """Density of ``_bulk_sample``'s wo given wi."""
    if bulk.type in SIMPLE_BULKS:
        return spongecake.substrate_pdf(bulk.params, wi, wo)
    model = _bulk_model(bulk)
    if samples_from_view(model):
        return model.pdf(bulk.params, wo, wi)
    return model.pdf(bulk.params, wi, wo)


def _bulk_sample(bulk: Bulk, wi, u):
    """Directions wo from the bulk's own sampler given wi, and which of them are Diracs (model bulks only); a bulk
    that samples from the view (``samples_from_view``) is handed wi as its view."""
    if bulk.type in SIMPLE_BULKS:
        return spongecake.substrate_sample(bulk.params, wi, u[:, 0], u[:, 1], u[:, 2]), np.zeros(len(wi), bool)
    model = _bulk_model(bulk)
    s = model.sample(bulk.params, wi, u)
    drawn = s.wi if samples_from_view(model) else s.wo
    return drawn, getattr(s, "is_delta", np.zeros(len(wi), bool))


# --------------------------------------------------------------------------------------------- public

def _pore_weight(params: Params, wi, wo, blend):
    """1 − w for both directions above: the share of light that reaches the bulk (Eq. 1)."""
    tau0, beta = params.filling_factor, params.anfractuosity
    if blend == "ours":
        return 1.0 - w_plus(wi, wo, tau0, beta)
    if blend == "linear":
        return np.full(len(wi), 1.0 - tau0)
    return (1.0 - tau0) * microfacet.g2(wi, wo, params.roughness)


def _pore_transmittance(params: Params, w, blend):
    """Share of light crossing the layer along w (the direction above) and the bulk's far side: the bulk's weight
    for reflection, 1 − w(i, o), with the other direction's factor averaged over the hemisphere (cosine-weighted).
    The pores seen along w, 1 − τ⁺ = g(θ) sqrt(1 − τ0), would count twice the pore area that w⁺ already gives to
    the grains (pores shadowed from the light): white grains over a clear glass would reflect and transmit more
    than they receive. ``ours`` g(θ) ḡ (g = sqrt(1 − τβ), ``hemispherical_mean``); ``linear`` 1 − τ0; ``deon``
    (1 − τ0) G1(θ) Ḡ1 (GGX(α̃); G1 G1 ≤ G2, so it stays below the bulk's reflection weight)."""
    tau0, beta = params.filling_factor, params.anfractuosity
    if blend == "linear":
        return np.full(len(w), 1.0 - tau0)
    if blend == "ours":
        def g(c):
            return np.sqrt(1.0 - tau_beta(c, tau0, beta))
    else:
        def g(c):
            return 1.0 / (1.0 + microfacet.smith_lambda(spherical(c, np.zeros_like(c)), params.roughness))
    scale = 1.0 if blend == "ours" else 1.0 - tau0
    return scale * g(w[:, 2]) * hemispherical_mean(g)


def hemispherical_mean(g, n: int = 32) -> float:
    """Cosine-weighted hemispherical mean 2 ∫ g(μ) μ dμ of a function of cos θ (Gauss-Legendre)."""
    x, weights = np.polynomial.legendre.leggauss(n)
    mu = 0.5 * (x + 1.0)
    return float(np.sum(weights * mu * g(mu)))


def eval(params: Params, wi, wo, blend="ours"):
    """Micrograin BSDF f(wi, wo) (N, 3), no cosine (Eq. 1); 0 at grazing.

    Both directions above: w f_S + (1 − w) f_B. One below (transmission through the bulk): f_B times the
    share of light through the layer (``_pore_transmittance``), no grain term. Both below: f_B.

    ``blend`` picks w: ``ours`` w⁺ (Eq. 24); ``linear`` w = τ0 (the paper's Fig. 14 "linear mix by τ0");
    ``deon`` the weighting of d'Eon et al. 2023 matched by Eq. 26 with w_A = τ0: 1 − w = (1 − τ0) G2_GGX(α̃)(i, o),
    the bulk seen through the grain layer's GGX(α̃) masking-shadowing. Eq. 26 as printed, (1 − w_A) / G, would
    grow towards grazing, contradicting the paper's Fig. 11: this is our reading.
    """
    if blend not in BLENDS:
        raise ValueError(f"unknown blend {blend!r}; expected one of {', '.join(BLENDS)}")
    wi, wo = as_directions(wi), as_directions(wo)
    f = _bulk_eval(params.bulk, wi, wo)
    up_i, up_o = wi[:, 2] > 0, wo[:, 2] > 0
    both = up_i & up_o
    if both.any():
        keep = _pore_weight(params, wi[both], wo[both], blend)[:, None]
        f[both] = (1.0 - keep) * _grain_bsdf(params, wi[both], wo[both]) + keep * f[both]
    through = up_i ^ up_o
    if through.any():
        above = np.where(up_i[through, None], wi[through], wo[through])
        f[through] = f[through] * _pore_transmittance(params, above, blend)[:, None]
    return np.where(((wi[:, 2] != 0) & (wo[:, 2] != 0))[:, None], f, 0.0)


def reflection_terms(params: Params, wi, wo):
    """The terms Eq. 1 blends for directions both above: (f_S, f_B), each (N, 3), so that other weights than w⁺
    can be measured (docs/accuracy.md: view-only stand-ins for w⁺)."""
    wi, wo = as_directions(wi), as_directions(wo)
    return _grain_bsdf(params, wi, wo), _bulk_eval(params.bulk, wi, wo)


def _lobe_probabilities(params: Params, wi):
    """(N, 3) probabilities of the specular grain lobe, the diffuse grain lobe and the bulk: grains with
    τ⁺(θi) (0 from below), split by the grains' specular share E_spec / (E_spec + mean(Kd) t(θi))."""
    up = wi[:, 2] >= 0
    grains = np.where(up, tau_plus(wi[:, 2], params.filling_factor, params.anfractuosity), 0.0)
    e = _coat_albedo(params, wi[:, 2])
    diffuse = 0.0 if params.grain.type == "conductor" else float(np.mean(params.grain.albedo)) * (1.0 - e)
    total = e + diffuse
    share = np.divide(e, total, out=np.full_like(e, 0.5), where=total > 0)
    return np.stack([grains * share, grains * (1.0 - share), 1.0 - grains], axis=1)


def _specular_pdf(params: Params, wi, wo):
    """Density of wo = reflect(wi, m), m ~ D(m) cos θm: D(m) cos θm / (4 |wi·m|), m the upper half vector."""
    h = normalize(wi + wo)
    h = h * np.where(h[:, 2] < 0, -1.0, 1.0)[:, None]
    jacobian = 4.0 * np.abs(dot(wi, h))
    density = ndf(h, params.filling_factor, params.anfractuosity) * h[:, 2]
    return np.divide(density, jacobian, out=np.zeros_like(density), where=jacobian > 0)


def pdf(params: Params, wi, wo):
    """Solid-angle density (N,) of ``sample`` (it integrates to 1 minus the probability of a bulk's Dirac)."""
    wi, wo = as_directions(wi), as_directions(wo)
    p = _lobe_probabilities(params, wi)
    return (p[:, 0] * _specular_pdf(params, wi, wo) + p[:, 1] * lobes.cosine_pdf(1.0, wo)
            + p[:, 2] * _bulk_pdf(params.bulk, wi, wo))


def sample(params: Params, wi, u) -> Sample:
    """Sample wo for each wi from u in [0, 1)^3: u0 picks the lobe (then reused by the bulk), u1 and u2 the
    direction. Grain lobes: a normal of ``sample_ndf`` reflecting wi, or a cosine lobe above."""
    wi, u = as_directions(wi), as_directions(u)
    lobe, _, u0 = lobes.choose(_lobe_probabilities(params, wi), u[:, 0])
    wo = np.empty_like(wi)
    delta = np.zeros(len(wi), bool)
    m = lobe == 0
    wo[m] = reflect(wi[m], sample_ndf(params.filling_factor, params.anfractuosity, u[m, 1], u[m, 2]))
    m = lobe == 1
    wo[m] = lobes.cosine_sample(1.0, u[m, 1], u[m, 2])
    m = lobe == 2
    if m.any():
        wo[m], delta[m] = _bulk_sample(params.bulk, wi[m], np.stack([u0[m], u[m, 1], u[m, 2]], axis=1))
    density = np.where(delta, 0.0, pdf(params, wi, wo))
    value = eval(params, wi, wo) * np.abs(wo[:, 2:])
    weight = np.divide(value, density[:, None], out=np.zeros_like(value), where=density[:, None] > 0)
    return Sample(wo, weight, density)


def directional_albedo(params: Params, wo, n: int = 16384, seed: int = 0, blend="ours"):
    """∫ f(wi, wo) |cos wi| dwi (N, 3), reflection and transmission: seeded Monte Carlo with the balance
    heuristic over the sampler from wo (7/8 of the samples) and uniform directions on the sphere."""
    wo = as_directions(wo)
    rng = np.random.default_rng(seed)
    albedo = np.zeros((len(wo), 3))
    n_b, n_u = (7 * n) // 8, n // 8
    for row, w in enumerate(wo):
        s = sample(params, np.repeat(w[None], n_b, axis=0), rng.random((n_b, 3)))
        x = np.concatenate([s.wo, spherical(2.0 * rng.random(n_u) - 1.0, 2.0 * np.pi * rng.random(n_u))])
        ws = np.repeat(w[None], len(x), axis=0)
        q = n_b * pdf(params, ws, x) + n_u / (4.0 * np.pi)
        albedo[row] = np.sum(eval(params, x, ws, blend) * np.abs(x[:, 2:]) / q[:, None], axis=0)
    return albedo


def furnace_albedo(params: Params, wo, n: int = 4096, seed: int = 0, blend="ours"):
    """What a white furnace returns towards wo (N, 3): the directional albedo plus a model bulk's straight-through
    Dirac (SpongeCake's delta transmission), passing the layer like the bulk's other transmission
    (``_pore_transmittance``). ``sample`` and ``pdf`` leave the Dirac out."""
    wo = as_directions(wo)
    albedo = directional_albedo(params, wo, n=n, seed=seed, blend=blend)
    model = _bulk_model(params.bulk) if params.bulk.type not in SIMPLE_BULKS else None
    if model is None or not hasattr(model, "delta_transmittance"):
        return albedo
    delta = model.delta_transmittance(params.bulk.params, wo)
    up = wo[:, 2] > 0
    if up.any():
        delta[up] = delta[up] * _pore_transmittance(params, wo[up], blend)[:, None]
    return albedo + delta
