"""Batched Monte Carlo estimates shared by the ground truths (``*_truth.py``): independent seeded batches, their
mean and standard error, Beer-Lambert transmittance along a direction, and the checked view direction."""
from __future__ import annotations

import math

import numpy as np


def batches(n_paths, n_batches, seed):
    """``n_batches`` (at least 2) independent (size, generator) pairs that share ``n_paths`` between them."""
    n_batches = max(2, int(n_batches))
    size = max(1, -(-int(n_paths) // n_batches))
    return [(size, np.random.default_rng(s)) for s in np.random.SeedSequence(seed).spawn(n_batches)]


def mean_stderr(per_batch):
    """The mean over batches (axis 0) and its standard error."""
    per_batch = np.asarray(per_batch)
    return per_batch.mean(axis=0), per_batch.std(axis=0, ddof=1) / math.sqrt(len(per_batch))


def transmittance(tau, cos_z):
    """exp(-sigma_a d / |w_z|) per RGB channel; 1 where tau = 0, 0 at grazing with tau > 0."""
    c = np.abs(cos_z)[:, None]
    with np.errstate(divide="ignore", over="ignore"):
        ratio = np.where(tau > 0.0, tau / np.maximum(c, 1e-300), 0.0)
    return np.exp(-ratio)


def view_direction(wo):
    """``wo`` as one unit vector above the surface (ValueError below it)."""
    wo = np.asarray(wo, dtype=float).reshape(3)
    wo = wo / np.linalg.norm(wo)
    if wo[2] <= 0.0:
        raise ValueError("wo must be above the surface (wo_z > 0)")
    return wo
