"""Direction helpers: rows of (N, 3) float64 arrays in the local frame (x tangent, z macro normal)."""
from __future__ import annotations

import numpy as np


def dot(a, b):
    """Row-wise dot product of two (..., 3) arrays."""
    return np.einsum("...i,...i->...", a, b)


def normalize(v):
    """Rows of ``v`` scaled to unit length; zero rows stay zero."""
    n = np.sqrt(dot(v, v))[..., None]
    return np.divide(v, n, out=np.zeros_like(v, dtype=float), where=n > 0)


def basis(n):
    """Two unit tangents (s, t) completing unit rows ``n`` to an orthonormal frame (Duff et al. 2017)."""
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    s = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    t = np.stack([b, sign + y * y * a, -y], axis=-1)
    return s, t


def from_frame(local, s, t, n):
    """Directions with coordinates ``local`` in the frame (s, t, n) expressed in the ambient frame."""
    return local[..., :1] * s + local[..., 1:2] * t + local[..., 2:3] * n


def spherical(cos_theta, phi):
    """Unit directions from the cosine of the polar angle (to +z) and the azimuth."""
    cos_theta = np.asarray(cos_theta, dtype=float)
    sin_theta = np.sqrt(np.maximum(0.0, 1.0 - cos_theta * cos_theta))
    return np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta * np.ones_like(phi)], axis=-1)


def reflect(w, m):
    """Mirror reflection of the directions ``w`` about the unit normals ``m``."""
    return 2.0 * dot(w, m)[..., None] * m - w


def as_directions(w):
    """``w`` as a float64 (N, 3) array (a single direction becomes one row)."""
    return np.atleast_2d(np.asarray(w, dtype=float))
