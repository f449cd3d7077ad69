"""Picking one lobe of a mixture per sample (shared by the models' samplers)."""
from __future__ import annotations

import numpy as np


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
