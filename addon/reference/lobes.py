"""Picking one lobe of a mixture per sample (shared by the models' samplers)."""
from __future__ import annotations

import numpy as np

from .frames import spherical


def choose(p, u0):
    """For probabilities ``p`` (N, K) and uniforms ``u0`` (N,): the lobe each u0 picks, its probability, and u0
    rescaled into [0, 1) within that lobe, so it can be reused. A lobe of probability 0 is never picked (u0 near 1
    falls to the last positive one)."""
    cdf = np.cumsum(p, axis=1)
    last = p.shape[1] - 1 - np.argmax(p[:, ::-1] > 0, axis=1)
    lobe = np.minimum(np.sum(u0[:, None] >= cdf, axis=1), last)
    rows = np.arange(len(p))
    chosen = p[rows, lobe]
    reused = np.clip((u0 - (cdf[rows, lobe] - chosen)) / chosen, 0.0, np.nextafter(1.0, 0.0))
    return lobe, chosen, reused


def cosine_sample(side, u1, u2):
    """Cosine-weighted directions (N, 3) about +z where ``side`` is 1, about -z where it is -1."""
    return np.asarray(side, float).reshape(-1, 1) * spherical(np.sqrt(1.0 - u1), 2.0 * np.pi * u2)


def cosine_pdf(side, w):
    """Density of ``cosine_sample``: max(side * cos θ, 0) / π."""
    return np.maximum(side * w[:, 2], 0.0) / np.pi
