"""SGGX microflake distributions (Heitz et al. 2015) with an axially symmetric matrix S.

S = a I + (b - a) v v^T: eigenvalue b along the unit axis v, a across it. Surface flakes (normal n):
S = alpha^2 I + (1 - alpha^2) n n^T; fibers (tangent t): S = I + (alpha^2 - 1) t t^T (Sec. 3.3). Quadratic
forms use the coordinates (x1, x2, x3) of x in an orthonormal frame (e1, e2, v) of the axis:
x^T S y = a (x1 y1 + x2 y2) + b x3 y3, free of cancellation, so alpha = 1e-4 is safe.
D is normalised as in Heitz et al. 2015: the projected area int D(m) <w, m> dm equals sigma(w) = sqrt(w^T S w).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .frames import basis, dot, from_frame, normalize, reflect


class SGGX(NamedTuple):
    """Axially symmetric SGGX matrix: unit ``axis``, eigenvalue ``a`` across it and ``b`` along it."""

    axis: np.ndarray
    a: float
    b: float


def surface(normal, alpha) -> SGGX:
    """Surface-like flakes around ``normal``: S = alpha^2 I + (1 - alpha^2) n n^T."""
    return SGGX(_unit(normal), alpha * alpha, 1.0)


def fiber(tangent, alpha) -> SGGX:
    """Fiber-like flakes (fibers along ``tangent``): S = I + (alpha^2 - 1) t t^T."""
    return SGGX(_unit(tangent), 1.0, alpha * alpha)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def matrix(s: SGGX):
    """The 3x3 matrix S."""
    return s.a * np.eye(3) + (s.b - s.a) * np.outer(s.axis, s.axis)


def coords(s: SGGX, x):
    """Coordinates of the rows x in the orthonormal frame (e1, e2, axis)."""
    e1, e2 = basis(s.axis)
    return x @ np.stack([e1, e2, s.axis], axis=1)


def _forms(s: SGGX, x, y):
    """x1 y1 + x2 y2 and x3 y3: the pieces of every quadratic form of S across and along the axis."""
    cx = coords(s, x)
    cy = cx if y is x else coords(s, y)
    return cx[:, 0] * cy[:, 0] + cx[:, 1] * cy[:, 1], cx[:, 2] * cy[:, 2]


def quad(s: SGGX, x, y):
    """Bilinear form x^T S y, row-wise."""
    across, along = _forms(s, x, y)
    return s.a * across + s.b * along


def quad_inv(s: SGGX, x, y):
    """Bilinear form x^T S^-1 y, row-wise."""
    across, along = _forms(s, x, y)
    return across / s.a + along / s.b


def det(s: SGGX) -> float:
    """det S."""
    return s.a * s.a * s.b


def D(s: SGGX, m):
    """Microflake normal distribution D(m) = 1 / (pi sqrt(det S) (m^T S^-1 m)^2) (Eq. 7)."""
    q = quad_inv(s, m, m)
    return 1.0 / (np.pi * np.sqrt(det(s)) * q * q)


def sigma(s: SGGX, w):
    """Projected area sigma(w) = sqrt(w^T S w) (Eqs. 3 and 7)."""
    return np.sqrt(quad(s, w, w))


def vndf_pdf(s: SGGX, wi, m):
    """Visible-normal density D_wi(m) = <wi, m> D(m) / sigma(wi)."""
    return np.maximum(dot(wi, m), 0.0) * D(s, m) / sigma(s, wi)


def half_vector(wi, wo):
    """normalize(wi + wo) and where it exists (wo != -wi); undefined rows hold an arbitrary unit vector."""
    h = normalize(wi + wo)
    valid = np.any(h != 0, axis=1)
    return np.where(valid[:, None], h, [0.0, 0.0, 1.0]), valid


def phase_pdf(s: SGGX, wi, wo):
    """Specular microflake phase function D(h) / (4 sigma(wi)) (Eq. 4), also the density of ``sample_phase``."""
    h, valid = half_vector(wi, wo)
    return np.where(valid, D(s, h) / (4.0 * sigma(s, wi)), 0.0)


def sample_vndf(s: SGGX, wi, u1, u2):
    """Visible normal for unit rows wi (Heitz et al. 2015, supplemental): S projected on the frame rows (k, j, wi).

    The projected entries S_kk... are x^T S y with x, y frame vectors (R S R^T, not R^T S R: see the research
    notes on Mitsuba's transposed frame). Cofactors use det S (S^-1)_xy so thin lobes need no subtraction.
    """
    wk, wj = basis(wi)
    s_ii = quad(s, wi, wi)
    d = det(s)
    inv_kk = quad_inv(s, wk, wk)
    minor = np.sqrt(d * inv_kk)  # sqrt(S_jj S_ii - S_ji^2)
    root_ii = np.sqrt(s_ii)
    zero = np.zeros_like(s_ii)
    m_k = np.stack([1.0 / np.sqrt(inv_kk), zero, zero], axis=1)  # sqrt(det S) / minor
    m_j = np.stack([-d * quad_inv(s, wk, wj) / (minor * root_ii), minor / root_ii, zero], axis=1)
    m_i = np.stack([quad(s, wk, wi), quad(s, wj, wi), s_ii], axis=1) / root_ii[:, None]
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    u, v = r * np.cos(phi), r * np.sin(phi)
    w = np.sqrt(np.maximum(0.0, 1.0 - u * u - v * v))
    m_local = normalize(u[:, None] * m_k + v[:, None] * m_j + w[:, None] * m_i)
    return normalize(from_frame(m_local, wk, wj, wi))


def sample_phase(s: SGGX, wi, u1, u2):
    """Scatter direction of a two-sided mirror flake (wi reflected about a visible normal) and that normal."""
    m = sample_vndf(s, wi, u1, u2)
    return reflect(wi, m), m
