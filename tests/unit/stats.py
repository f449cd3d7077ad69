"""Chi-square goodness of fit for direction samplers, without scipy.

Bins are equal-area cells of (cos theta, phi) on the sphere. Expected counts integrate the claimed pdf over
each cell with a Gauss-Legendre rule; cells expecting fewer than ``min_expected`` samples are pooled. The
remainder cell (samples drawn but not passed in, e.g. Dirac samples, against 1 - integral of the pdf) keeps
an unnormalised pdf honest. The p-value is the regularised upper incomplete gamma Q(dof / 2, chi2 / 2).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np


def gammaincc(a: float, x: float) -> float:
    """Regularised upper incomplete gamma Q(a, x): series below a + 1, Lentz continued fraction above."""
    if x <= 0.0:
        return 1.0
    log_prefix = a * math.log(x) - x - math.lgamma(a)
    if x < a + 1.0:
        term = total = 1.0 / a
        n = a
        while abs(term) > 1e-16 * abs(total):
            n += 1.0
            term *= x / n
            total += term
        return max(0.0, 1.0 - total * math.exp(log_prefix))
    tiny = 1e-300
    b = x + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    h = d
    for i in range(1, 10000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return math.exp(log_prefix) * h


def chi2_sf(statistic: float, dof: int) -> float:
    """Probability that a chi-square variable with ``dof`` degrees of freedom exceeds ``statistic``."""
    return gammaincc(0.5 * dof, 0.5 * statistic)


class Chi2(NamedTuple):
    p_value: float
    statistic: float
    dof: int
    integral: float  # the pdf integrated over the sphere by the same quadrature


def cell_index(dirs, n_theta: int, n_phi: int):
    """Flat (cos theta, phi) cell index of unit rows."""
    i = np.clip(((dirs[:, 2] + 1.0) * 0.5 * n_theta).astype(int), 0, n_theta - 1)
    phi = np.arctan2(dirs[:, 1], dirs[:, 0]) % (2.0 * np.pi)
    j = np.clip((phi / (2.0 * np.pi) * n_phi).astype(int), 0, n_phi - 1)
    return i * n_phi + j


def cell_integrals(pdf, n_theta: int, n_phi: int, res: int):
    """Integral of ``pdf`` (callable on (K, 3) unit rows) over each cell, flat, Gauss-Legendre res x res per cell."""
    x, w = np.polynomial.legendre.leggauss(res)
    dc, dp = 2.0 / n_theta, 2.0 * np.pi / n_phi
    c = (-1.0 + dc * (np.arange(n_theta)[:, None] + 0.5 * (x + 1.0))).ravel()  # (n_theta * res)
    p = (dp * (np.arange(n_phi)[:, None] + 0.5 * (x + 1.0))).ravel()  # (n_phi * res)
    cc, pp = np.meshgrid(c, p, indexing="ij")
    s = np.sqrt(np.maximum(0.0, 1.0 - cc * cc))
    dirs = np.stack([s * np.cos(pp), s * np.sin(pp), cc], axis=-1).reshape(-1, 3)
    values = np.concatenate([pdf(chunk) for chunk in np.array_split(dirs, max(1, len(dirs) // 65536))])
    weights = np.outer(np.tile(w, n_theta), np.tile(w, n_phi)) * (0.25 * dc * dp)
    cells = (values.reshape(n_theta * res, n_phi * res) * weights).reshape(n_theta, res, n_phi, res)
    return cells.sum(axis=(1, 3)).ravel()


def chi2_test(dirs, pdf, n_total: int | None = None, n_theta: int = 24, n_phi: int = 48, res: int = 8,
              min_expected: float = 5.0) -> Chi2:
    """Test that the unit rows ``dirs`` (out of ``n_total`` draws, default all) are distributed with density ``pdf``."""
    n_total = len(dirs) if n_total is None else n_total
    integrals = cell_integrals(pdf, n_theta, n_phi, res)
    observed = np.bincount(cell_index(dirs, n_theta, n_phi), minlength=n_theta * n_phi).astype(float)
    expected = integrals * n_total
    observed = np.append(observed, n_total - len(dirs))
    expected = np.append(expected, max(0.0, n_total - expected.sum()))
    if np.any((expected <= 0.0) & (observed > 0)):
        return Chi2(0.0, math.inf, 0, float(integrals.sum()))
    statistic, dof = _pooled_statistic(observed, expected, min_expected)
    return Chi2(chi2_sf(statistic, dof) if dof > 0 else 1.0, statistic, dof, float(integrals.sum()))


def _pooled_statistic(observed, expected, min_expected):
    low = expected < min_expected
    o, e = list(observed[~low]), list(expected[~low])
    pooled_o, pooled_e = observed[low].sum(), expected[low].sum()
    if pooled_e >= min_expected or (pooled_e > 0 and not e):
        o.append(pooled_o)
        e.append(pooled_e)
    elif pooled_e > 0:  # too small to stand alone: fold the pool into the smallest regular cell
        k = int(np.argmin(e))
        o[k] += pooled_o
        e[k] += pooled_e
    o, e = np.array(o), np.array(e)
    return float(np.sum((o - e) ** 2 / e)), len(e) - 1


def sphere_directions(n: int, seed: int = 0, side: int = 0):
    """n random unit rows, uniform on the sphere (side = 0), or on the upper (1) / lower (-1) hemisphere."""
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if side:
        v[:, 2] = side * np.abs(v[:, 2])
    return v


def unit(*xyz):
    """One unit direction as a (1, 3) row."""
    v = np.array([xyz], dtype=float)
    return v / np.linalg.norm(v)
