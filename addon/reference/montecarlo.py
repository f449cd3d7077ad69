"""Batched Monte Carlo estimates shared by the ground truths (``*_truth.py``): independent seeded batches, their
mean and standard error, Beer-Lambert transmittance along a direction, the checked view direction; and what
ground-truth images share: the sampled pixels of a scene, the nearest sampled pixel, the truth's relative noise."""
from __future__ import annotations

import math

import numpy as np

from . import scenes as ref_scenes


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


def sampled_pixels(spec: ref_scenes.Scene, stride: int) -> np.ndarray:
    """H x W bool: the mask's pixels at rows and columns = stride // 2 (mod stride); the whole mask when the
    grid misses it (tiny images)."""
    mask = ref_scenes.scene_mask(spec)
    rows, cols = np.indices(mask.shape)
    grid = mask & (rows % stride == stride // 2) & (cols % stride == stride // 2)
    return grid if grid.any() else mask


def nearest(rc_to: np.ndarray, rc_from: np.ndarray, block: int = 4096) -> np.ndarray:
    """Index into rc_from of the nearest point for every point of rc_to (both (N, 2) pixel coordinates)."""
    out = np.empty(len(rc_to), dtype=int)
    for s0 in range(0, len(rc_to), block):
        d = ((rc_to[s0:s0 + block, None, :] - rc_from[None, :, :]) ** 2).sum(-1)
        out[s0:s0 + block] = np.argmin(d, axis=1)
    return out


def relative_noise(truth_image: np.ndarray, noise: np.ndarray, samples: np.ndarray) -> float:
    """RMS standard error of the ground truth over ``samples`` / its mean there (scale of a relative RMSE)."""
    mean = float(np.mean(truth_image[samples]))
    if not samples.any() or mean <= 0:
        return float("nan")
    return float(np.sqrt(np.mean(noise[samples] ** 2)) / mean)
