"""Henyey-Greenstein phase function. ``cos_theta`` is the cosine between the propagation directions before
and after scattering: with the BSDF convention (wi to the light) it is -wi . wo, so g > 0 scatters forward."""
from __future__ import annotations

import numpy as np

from .frames import basis, from_frame


def eval(g, cos_theta):
    """HG phase function (1 - g^2) / (4 pi (1 + g^2 - 2 g cos)^(3/2)), normalised over the sphere."""
    return (1.0 - g * g) / (4.0 * np.pi * (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5)


def sample_cos(g, u):
    """Inverse CDF of the scattering cosine, expanded so that it is exact for every g in (-1, 1), g = 0 included."""
    e = 2.0 * u - 1.0
    d = 1.0 + g * e
    # (1 + g^2 - ((1 - g^2) / (1 - g + 2 g u))^2) / (2 g) with the 1/g cancelled analytically
    num = e + 0.5 * g * (e * e + 3.0) + g * g * e + 0.5 * g ** 3 * (e * e - 1.0)
    return np.clip(num / (d * d), -1.0, 1.0)


def sample(g, forward, u1, u2):
    """Directions scattered from the unit propagation directions ``forward`` with HG's distribution."""
    c = sample_cos(g, u1)
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    phi = 2.0 * np.pi * u2
    local = np.stack([s * np.cos(phi), s * np.sin(phi), c], axis=1)
    return from_frame(local, *basis(forward), forward)
