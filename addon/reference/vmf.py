"""Von Mises-Fisher (vMF) lobes on the unit sphere, numerically stable for kappa from 0 to 1e6.

Conventions: float64, vectorised numpy (arguments broadcast); ``kappa`` >= 0 is the concentration, ``cos_theta``
the cosine to the mean direction mu; densities are per unit solid angle and integrate to 1 over the sphere (the
paper's M(x; mu, kappa), Eq. 5, not the NDF D = M / A3 of Eq. 6). Lobes are carried by the complement of the mean
cosine u = 1 - A3(kappa) rather than by A3 itself: u keeps full relative precision for sharp lobes (u ~ 1/kappa),
where A3 rounds to 1. The stable forms follow the research notes, section 2 (thin transparent coat with ENDF).

Exact (to rounding): ``density``, ``mean_cosine_complement``, ``a3``, their limits at kappa = 0 and infinity,
``sample`` (inverse CDF of w = 1 - cos theta) and ``sample_around``. Iterative: ``kappa_from_complement`` and
``kappa_from_a3`` (Newton to rounding, ~1e-13 relative). Approximations by design: ``convolve`` (moment matching,
Eq. 18: exact in the mean cosine, not in shape) and ``beckmann_alpha`` (a Beckmann lobe standing in for a vMF lobe).
"""
from __future__ import annotations

import numpy as np

from .frames import as_directions, basis, from_frame

SERIES_BELOW = 0.05  # below this kappa, A3 comes from its Taylor series (1 - u cancels there)
INVERSE_BELOW = 1e-3  # below this u, kappa = 1/u exactly in float64 (u = 1/kappa - O(e^-2000))


def _kappa_over_one_minus_exp(kappa):
    """kappa / (1 - e^{-2 kappa}), written with expm1; its limit 1/2 at kappa = 0."""
    kappa = np.asarray(kappa, dtype=float)
    safe = np.where(kappa > 0.0, kappa, 1.0)
    return np.where(kappa > 0.0, safe / -np.expm1(-2.0 * safe), 0.5)


def density(cos_theta, kappa):
    """vMF density kappa / (2 pi (1 - e^{-2 kappa})) e^{kappa (cos - 1)} (Eq. 5 with sinh expanded; notes sec. 2).

    The paper's C3 = kappa / (4 pi sinh kappa) times e^{kappa cos} overflows to inf / inf = NaN from kappa ~ 710;
    this form only ever underflows to 0. kappa = 0 gives the uniform 1 / (4 pi)."""
    cos_theta = np.asarray(cos_theta, dtype=float)
    kappa = np.asarray(kappa, dtype=float)
    return _kappa_over_one_minus_exp(kappa) / (2.0 * np.pi) * np.exp(kappa * (cos_theta - 1.0))


def density_around(x, mu, kappa):
    """M(x; mu, kappa) for unit rows x and mean directions mu, with 1 - x . mu from |x - mu|^2 / 2 (no cancellation
    at the peak of sharp lobes, where 1 - cos theta is far below float64's epsilon)."""
    d = np.asarray(x, dtype=float) - np.asarray(mu, dtype=float)
    return density(1.0 - 0.5 * np.einsum("...i,...i->...", d, d), kappa)


def _a3_series(kappa):
    """Langevin series A3 = k/3 - k^3/45 + 2 k^5/945 - k^7/4725 (next term < 3e-15 relative below 0.05)."""
    k2 = kappa * kappa
    return kappa * (1.0 / 3.0 + k2 * (-1.0 / 45.0 + k2 * (2.0 / 945.0 - k2 / 4725.0)))


def _complement_direct(kappa):
    """1 - A3 = 1/kappa - 2 / expm1(2 kappa), the second term as 2 e^{-2k} / (1 - e^{-2k}) so it cannot overflow."""
    e = np.exp(-2.0 * kappa)
    return 1.0 / kappa - 2.0 * e / -np.expm1(-2.0 * kappa)


def mean_cosine_complement(kappa):
    """u = 1 - A3(kappa) = 1 - E[cos theta] (Eq. 6's A3 = coth kappa - 1/kappa, notes sec. 2); 1 at kappa = 0,
    0 at infinity. Below kappa = 0.05 it is 1 - (series), where the direct form would cancel."""
    kappa = np.asarray(kappa, dtype=float)
    small = kappa < SERIES_BELOW
    direct = _complement_direct(np.where(small, 1.0, kappa))
    return np.where(small, 1.0 - _a3_series(np.where(small, kappa, 0.0)), direct)


def a3(kappa):
    """A3(kappa) = coth kappa - 1/kappa, the mean cosine (mean resultant length) of a vMF lobe (Eq. 6)."""
    kappa = np.asarray(kappa, dtype=float)
    small = kappa < SERIES_BELOW
    return np.where(small, _a3_series(np.where(small, kappa, 0.0)), 1.0 - mean_cosine_complement(kappa))


def _a3_derivative(kappa):
    """dA3/dkappa = 1 - A3^2 - 2 A3 / kappa (1/3 at kappa = 0)."""
    r = a3(kappa)
    return np.where(kappa > 0.0, 1.0 - r * r - 2.0 * r / np.where(kappa > 0.0, kappa, 1.0), 1.0 / 3.0)


def _invert(r, u):
    """kappa with A3 = r, 1 - A3 = u (both given so that neither loses digits): kappa = 1/u for u < 1e-3, else
    Banerjee et al.'s r (3 - r^2) / (1 - r^2) (within 5 %) refined by 3 Newton steps in float64 (notes sec. 2).
    Newton runs on log f against log kappa, f being whichever of A3 or u is the small one (full relative
    precision); both are near power laws of kappa there, so 3 steps reach rounding (2 steps: 2e-8)."""
    r, u = np.broadcast_arrays(np.asarray(r, dtype=float), np.asarray(u, dtype=float))
    solve = (u >= INVERSE_BELOW) & (r > 0.0)
    rs, us = np.where(solve, r, 0.5), np.where(solve, u, 0.5)
    on_a3 = rs < 0.5
    target = np.where(on_a3, rs, us)
    kappa = rs * (3.0 - rs * rs) / (us * (1.0 + rs))  # 1 - r^2 = u (1 + r)
    for _ in range(3):
        f = np.where(on_a3, a3(kappa), mean_cosine_complement(kappa))
        slope = np.where(on_a3, 1.0, -1.0) * kappa * _a3_derivative(kappa) / f  # d log f / d log kappa
        kappa = kappa * np.exp(-np.log(f / target) / slope)
    with np.errstate(divide="ignore"):
        sharp = 1.0 / u
    return np.where(solve, kappa, np.where(r > 0.0, sharp, 0.0))


def kappa_from_complement(u):
    """Inverse of ``mean_cosine_complement``: u = 1 gives 0, u = 0 gives inf."""
    u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    return _invert(1.0 - u, u)


def kappa_from_a3(r):
    """Inverse of ``a3`` (the paper's A3^{-1}, Eq. 18): r = 0 gives 0, r = 1 gives inf."""
    r = np.clip(np.asarray(r, dtype=float), 0.0, 1.0)
    return _invert(r, 1.0 - r)


def convolve(kappa1, kappa2):
    """Concentration of the vMF lobe matching the spherical convolution of two lobes (Eq. 18, [MJ00]).

    Matches the first moment: A3(k) = A3(k1) A3(k2), i.e. u = u1 + u2 - u1 u2 on the complements (notes sec. 2),
    which stays exact for sharp lobes (k ~ k1 k2 / (k1 + k2)) where A3(k1) A3(k2) would round to 1."""
    u1, u2 = mean_cosine_complement(kappa1), mean_cosine_complement(kappa2)
    return kappa_from_complement(u1 + u2 - u1 * u2)


def sample(kappa, u1, u2):
    """Unit rows drawn from a vMF lobe around +z, by inversion of the CDF of w = 1 - cos theta (notes sec. 2).

    w = -ln(xi + (1 - xi) e^{-2 kappa}) / kappa with xi = 1 - u1, written as -log1p(u1 expm1(-2 kappa)) / kappa:
    u1 -> 0 lands on the peak with full relative precision in w, and kappa -> 0 gives w = 2 u1 (uniform)."""
    kappa, u1, u2 = np.broadcast_arrays(np.asarray(kappa, dtype=float), np.asarray(u1, dtype=float),
                                        np.asarray(u2, dtype=float))
    safe = np.where(kappa > 0.0, kappa, 1.0)
    w = np.where(kappa > 0.0, -np.log1p(u1 * np.expm1(-2.0 * safe)) / safe, 2.0 * u1)
    w = np.clip(w, 0.0, 2.0)
    sin_theta = np.sqrt(w * (2.0 - w))
    phi = 2.0 * np.pi * u2
    return np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), 1.0 - w], axis=-1)


def sample_around(mu, kappa, u1, u2):
    """Unit rows drawn from vMF lobes around the unit mean directions ``mu`` ((3,) or (N, 3))."""
    mu = as_directions(mu)
    return from_frame(sample(kappa, u1, u2), *basis(mu), mu)


def beckmann_alpha(kappa):
    """Beckmann roughness alpha = sqrt(2 / kappa) that renders a vMF lobe (notes sec. 2: vMF -> Cycles).

    Both lobes are e^{-theta^2 kappa / 2} to second order in theta, so the peaks agree (Beckmann / vMF =
    1 - e^{-2 kappa}) and so do the widths. Lobe-core ratio, measured in tests/unit/test_vmf.py: where the vMF is
    above 10 % of its peak, Beckmann / vMF lies in [1, 1 + 8 / (3 kappa)] (1.013 at kappa = 200, alpha = 0.1) and
    the Beckmann half-maximum angle is wider by 1.5 / kappa (0.75 % at kappa = 200); further out the Beckmann tail
    is lighter (0.93 at 1 % of the peak, kappa = 200). The error vanishes as alpha -> 0; use for kappa >= 200.
    """
    return np.sqrt(2.0 / np.asarray(kappa, dtype=float))
