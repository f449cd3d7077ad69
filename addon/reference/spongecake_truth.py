"""Monte Carlo ground truth of the multiple-scattering part on the comparison scenes (numpy, no bpy).

The closed-form single scattering is exact, so a ground-truth image of a stack is the single-scattering
reference image plus the orders >= 2 of the reference's independent random walk
(``reference.spongecake.ground_truth(...)[1]``; for the furnace ``ground_truth_albedo(...)[2]``).

Cost control: the walk runs at *sampled pixels* only, every ``stride``-th row and column of the scene's mask
(sphere pixels each have their own light direction, so every sampled pixel costs ``paths`` walks; the plane
scenes share one sun direction, so ``paths`` walks serve all their pixels). Metrics against the ground truth
use the sampled pixels only (no interpolation error); the other pixels of the returned image copy the
nearest sampled pixel's BSDF value (times their own cosine), for pictures only.

Noise: every estimate is the mean of ``batches`` independent batches of the paths; their spread gives the
standard error of the mean per pixel (``noise``; several batches, because the pixels of a plane scene share
their paths, so two halves would give one nearly common draw for all of them). ``montecarlo.relative_noise`` turns it
into the scale of a relative RMSE (RMS standard error / mean of the ground-truth image), the floor of any error
measured against it (errors add in quadrature: measured² ≈ true² + noise²).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from . import scenes as ref_scenes
from . import spongecake as reference
from .montecarlo import nearest, sampled_pixels

__all__ = ["TruthSettings", "multiple_scattering_truth", "single_scattering"]


@dataclass(frozen=True)
class TruthSettings:
    """How much Monte Carlo the ground truth gets (see the module docstring)."""

    paths: int = 2000  # random-walk paths per light direction (all batches together)
    albedo_paths: int = 4000  # furnace: paths per sampled pixel's view direction
    stride: int = 2  # ground truth at every stride-th row and column
    max_depth: int = 64  # scattering orders followed
    seed: int = 0
    chunk: int = 512  # sampled pixels per walk (bounds memory: chunk x paths / batches live paths)
    batches: int = 8  # independent batches of the paths (their spread is the noise estimate)

    def __post_init__(self):
        if (min(self.paths, self.albedo_paths) < 2 * self.batches or self.batches < 2 or self.stride < 1
                or self.max_depth < 2 or self.chunk < 1):
            raise ValueError(f"bad ground-truth settings {self!r}: batches >= 2, paths >= 2 x batches, stride >= 1")


def single_scattering(p):
    """The same stack without the network's lobes (what ``eval`` is in closed form)."""
    return replace(p, multiple_scattering=False)


def _seed(base: int, chunk: int, half: int) -> int:
    return int(np.random.SeedSequence([int(base), int(chunk), int(half)]).generate_state(1)[0])


def _batches(fn, n_items: int, settings: TruthSettings):
    """fn(slice, seed) -> (m, 3) over chunks and batches: (mean, standard error of the mean), each (n_items, 3)."""
    out = np.zeros((settings.batches, n_items, 3))
    for c, s0 in enumerate(range(0, n_items, settings.chunk)):
        sl = slice(s0, min(n_items, s0 + settings.chunk))
        for h in range(settings.batches):
            out[h, sl] = fn(sl, _seed(settings.seed, c, h))
    return out.mean(axis=0), out.std(axis=0, ddof=1) / np.sqrt(settings.batches)


def multiple_scattering_truth(p, spec: ref_scenes.Scene, settings: TruthSettings = TruthSettings()) -> dict:
    """The orders >= 2 of the random walk rendered into ``spec`` (direct light, like ``reference_image``).

    Returns ``image`` (H x W x 3: the multiple-scattering radiance; exact Monte Carlo at ``samples``, copied
    from the nearest sample elsewhere), ``noise`` (H x W x 3 standard error, 0 off the samples), ``samples``
    (H x W bool), ``seconds``. Add it to the single-scattering reference image for the ground truth of SS + MS.
    The network's flag in ``p`` is irrelevant: the walk never uses the closed form or the network."""
    t0 = time.perf_counter()
    g = ref_scenes.pixel_geometry(spec)
    h, w = spec.height, spec.width
    samples = sampled_pixels(spec, settings.stride)
    flat = lambda a: a.reshape(h * w, -1)  # noqa: E731
    hit = g["hit"].ravel()
    t, b, n, wo = (flat(g[k]) for k in ("t", "b", "n", "wo"))
    wo_l = ref_scenes.to_local(wo, t, b, n)
    idx = np.flatnonzero(samples.ravel())
    k = len(idx)
    walk_p = single_scattering(p)

    image = np.zeros((h * w, 3))
    noise = np.zeros((h * w, 3))
    if spec.kind == "furnace":
        wo_s = wo_l[idx]
        mean, se = _batches(lambda sl, seed: reference.ground_truth_albedo(
            walk_p, wo_s[sl], n_paths=settings.albedo_paths // settings.batches, seed=seed, max_depth=settings.max_depth)[2],
            k, settings)
        per_sample = [(mean * spec.environment, None)]
        noise[idx] = se * spec.environment
    else:
        if spec.environment > 0:
            raise ValueError(f"scene {spec.name!r}: ground truth of environment light is only done for the furnace")
        per_sample = []
        var = np.zeros((k, 3))
        for s_i, sun in enumerate(spec.suns):
            d = np.broadcast_to(np.asarray(sun.direction), wo_l.shape)
            wi_l = ref_scenes.to_local(d, t, b, n)
            cos_i = np.abs(wi_l[:, 2]) * sun.irradiance
            if spec.kind == "sphere":  # closed sphere: light from below the local horizon is blocked
                cos_i = np.where(wi_l[:, 2] > 0.0, cos_i, 0.0)
            lit = idx[cos_i[idx] > 0]
            f = np.zeros((k, 3))
            if len(lit):
                wi_s, wo_s = wi_l[lit], wo_l[lit]
                mean, se = _batches(lambda sl, seed: reference.ground_truth(
                    walk_p, wi_s[sl], wo_s[sl], n_paths=settings.paths // settings.batches,
                    seed=seed + 7919 * s_i, max_depth=settings.max_depth)[1], len(lit), settings)
                pos = np.searchsorted(idx, lit)
                f[pos] = mean
                var[pos] += (se * cos_i[lit, None]) ** 2
            per_sample.append((f, cos_i))
        noise[idx] = np.sqrt(var)

    # the picture: every hit pixel takes its nearest sample's value (own cosine), samples keep their own
    targets = np.flatnonzero(hit)
    rc = lambda ii: np.stack(np.divmod(ii, w), axis=1).astype(np.float64)  # noqa: E731
    near = nearest(rc(targets), rc(idx)) if k else np.zeros(len(targets), int)
    for f, cos_i in per_sample:
        if k:
            image[targets] += f[near] * (1.0 if cos_i is None else cos_i[targets, None])
    return {"image": image.reshape(h, w, 3), "noise": noise.reshape(h, w, 3), "samples": samples,
            "seconds": time.perf_counter() - t0, "settings": settings}
