"""Image metrics and comparison pictures for Cycles-vs-reference renders (numpy, no bpy).

All functions take H x W x C float images in linear radiance (row 0 = top) and an optional H x W bool
``mask`` (True = pixel counts); without a mask every pixel counts. Errors are taken over all colour
channels of the masked pixels.

* ``rmse``            sqrt(mean((a - b)^2)).
* ``rel_rmse``        rmse / mean(reference) (the mean of the reference over the mask, all channels).
* ``max_abs_error``   max |a - b|.
* ``worst_pixels``    the k pixels with the largest |a - b| (max over channels), as
                      (row, col, cycles_rgb, reference_rgb).
* ``heat_map``        |a - b| (max over channels) through a fixed colormap (black -> purple -> red ->
                      yellow -> white, an "inferno"-like ramp) with full scale ``vmax``; by default
                      vmax = ``HEAT_SCALE`` (50%, chosen there) x the reference mean, so the same colour means
                      the same relative error in every picture. Masked-out pixels are dark grey.
* ``tonemap``         linear -> 8-bit sRGB: v * 2^exposure, clipped to [0, 1], sRGB transfer function.
* ``side_by_side``    Cycles | reference | heat map, uint8, with the same stated exposure for both
                      renders (default ``auto_exposure``: the 99th percentile of the reference maps to 1).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = [
    "rmse", "rel_rmse", "max_abs_error", "worst_pixels", "heat_map", "HEAT_STOPS", "HEAT_SCALE", "srgb_encode",
    "tonemap", "auto_exposure", "side_by_side", "summary",
]

# Fixed colormap stops: (position in [0, 1], RGB in [0, 1]).
HEAT_STOPS = (
    (0.00, (0.0, 0.0, 0.0)),
    (0.25, (0.34, 0.06, 0.43)),
    (0.50, (0.80, 0.16, 0.20)),
    (0.75, (0.98, 0.60, 0.05)),
    (1.00, (1.0, 1.0, 0.85)),
)
MASKED_GREY = (0.15, 0.15, 0.15)

# Full scale of every error map, relative to the reference's mean over the object: a pixel off by half that mean is
# at the top of the ramp (pale yellow), 10% of it is dark purple, 25% red. Relative to the mean, not to the pixel, so
# dark pixels do not light up and a highlight ten times the mean shows a 5% error of its own at full scale.
# Why 50%: the comparisons must show the approximations, not saturate on noise. At the demo's 64 samples, Cycles'
# noise alone (a preset whose mapping is exact to 1%, plastic, OSL, furnace) is within 3.5% of the mean at 90% of
# the pixels and 18% at 99%, and the presets' systematic errors range from a few % to well over 100% (leaf, backlit
# fabrics, dirt on glass); with the former 10% scale noise reached full scale and several maps were a solid yellow;
# at 50% noise stays in the dark end and the ramp separates 5%, 25% and 50% errors.
HEAT_SCALE = 0.5


def _prep(a, b, mask):
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    if mask is None:
        mask = np.ones(a.shape[:2], dtype=bool)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != a.shape[:2]:
        raise ValueError(f"mask shape {mask.shape} does not match image {a.shape[:2]}")
    return a, b, mask


def rmse(a, b, mask=None) -> float:
    a, b, mask = _prep(a, b, mask)
    if not mask.any():
        return float("nan")
    d = a[mask] - b[mask]
    return float(np.sqrt(np.mean(d * d)))


def rel_rmse(cycles, reference, mask=None) -> float:
    """RMSE divided by the mean of ``reference`` over the mask (all channels); inf if that mean is 0."""
    a, b, mask = _prep(cycles, reference, mask)
    if not mask.any():
        return float("nan")
    mean = float(np.mean(b[mask]))
    e = rmse(a, b, mask)
    if mean <= 0.0:
        return 0.0 if e == 0.0 else float("inf")
    return e / mean


def max_abs_error(a, b, mask=None) -> float:
    a, b, mask = _prep(a, b, mask)
    if not mask.any():
        return float("nan")
    return float(np.max(np.abs(a[mask] - b[mask])))


def worst_pixels(cycles, reference, mask=None, k: int = 10):
    """The ``k`` masked pixels with the largest max-over-channels |cycles - reference|, worst first:
    a list of (row, col, cycles_rgb tuple, reference_rgb tuple) with row 0 = top."""
    a, b, mask = _prep(cycles, reference, mask)
    err = np.max(np.abs(a - b), axis=-1)
    err = np.where(mask, err, -np.inf)
    flat = err.ravel()
    k = int(min(k, int(mask.sum())))
    if k <= 0:
        return []
    idx = np.argpartition(-flat, k - 1)[:k]
    idx = idx[np.argsort(-flat[idx], kind="stable")]
    w = a.shape[1]
    out = []
    for i in idx:
        r, c = divmod(int(i), w)
        out.append((r, c, tuple(float(v) for v in a[r, c]), tuple(float(v) for v in b[r, c])))
    return out


def _colormap(x):
    x = np.clip(x, 0.0, 1.0)
    pos = np.array([s[0] for s in HEAT_STOPS])
    cols = np.array([s[1] for s in HEAT_STOPS])
    return np.stack([np.interp(x, pos, cols[:, c]) for c in range(3)], axis=-1)


def heat_map(cycles, reference, mask=None, vmax: float | None = None, relative: float = HEAT_SCALE):
    """H x W x 3 float RGB in [0, 1]: max-over-channels |cycles - reference| / vmax through the fixed
    colormap ``HEAT_STOPS``. ``vmax`` None: ``relative`` x mean(reference over the mask).
    Returns (rgb, vmax)."""
    a, b, mask = _prep(cycles, reference, mask)
    if vmax is None:
        mean = float(np.mean(b[mask])) if mask.any() else 0.0
        vmax = relative * mean if mean > 0 else 1.0
    vmax = float(vmax) if vmax > 0 else 1.0
    err = np.max(np.abs(a - b), axis=-1)
    rgb = _colormap(err / vmax)
    rgb[~mask] = MASKED_GREY
    return rgb, vmax


def srgb_encode(x):
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def tonemap(image, exposure: float = 0.0):
    """Linear radiance -> uint8 sRGB: value * 2**exposure, clipped to [0, 1], sRGB transfer, rounded.
    NaN/inf become 0 (black) so a bad pixel never breaks the picture."""
    a = np.asarray(image, dtype=np.float64)
    a = np.where(np.isfinite(a), a, 0.0)
    if a.ndim == 2:
        a = a[..., None]
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, axis=-1)
    a = a[..., :3] * (2.0 ** exposure)
    return np.round(srgb_encode(a) * 255.0).astype(np.uint8)


def auto_exposure(reference, mask=None, percentile: float = 99.0) -> float:
    """Exposure (stops) that maps the ``percentile`` of the masked reference (max over channels) to 1."""
    b = np.asarray(reference, dtype=np.float64)
    if b.ndim == 2:
        b = b[..., None]
    v = np.max(b, axis=-1)
    if mask is not None:
        v = v[np.asarray(mask, dtype=bool)]
    v = v[np.isfinite(v)]
    if v.size == 0:
        return 0.0
    p = float(np.percentile(v, percentile))
    return 0.0 if p <= 0 else -math.log2(p)


def side_by_side(cycles, reference, mask=None, exposure: float | None = None, vmax: float | None = None,
                 gap: int = 2, scale: int = 1):
    """Cycles | reference | heat map as one uint8 H x (3W + 2 gap) x 3 picture (each panel optionally
    enlarged ``scale`` times, nearest neighbour). Returns (picture, {"exposure": ..., "heat_vmax": ...})."""
    a, b, mask = _prep(cycles, reference, mask)
    if exposure is None:
        exposure = auto_exposure(b, mask)
    heat, vmax = heat_map(a, b, mask, vmax)
    panels = [tonemap(a, exposure), tonemap(b, exposure), np.round(heat * 255).astype(np.uint8)]
    if scale > 1:
        panels = [np.repeat(np.repeat(p, scale, 0), scale, 1) for p in panels]
    h = panels[0].shape[0]
    sep = np.full((h, gap, 3), 255, dtype=np.uint8)
    pic = np.concatenate([panels[0], sep, panels[1], sep, panels[2]], axis=1)
    return pic, {"exposure": float(exposure), "heat_vmax": float(vmax)}


def summary(cycles, reference, mask=None, k: int = 10) -> dict:
    """rmse, rel_rmse, max_abs_error, worst_pixels and the number of masked pixels, as plain Python."""
    _, _, m = _prep(cycles, reference, mask)
    return {
        "rmse": rmse(cycles, reference, mask),
        "rel_rmse": rel_rmse(cycles, reference, mask),
        "max_abs_error": max_abs_error(cycles, reference, mask),
        "worst_pixels": worst_pixels(cycles, reference, mask, k),
        "pixels": int(m.sum()),
    }
