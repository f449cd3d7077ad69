"""Cycles' random-walk subsurface scattering as a medium (bpy-free): the Principled BSDF settings under which Cycles'
random walk (``subsurface_method = 'RANDOM_WALK'``) walks in a given homogeneous medium.

What Cycles does with a Principled BSDF's subsurface inputs, read in its kernel (Blender 4.2 and 5.0 alike:
closure/bssrdf.h ``bssrdf_setup``, integrator/subsurface_random_walk.h ``subsurface_random_walk_remap``): the radius
is Subsurface Radius x Subsurface Scale per channel, the anisotropy g is clamped to [0, 0.9], and the walk's medium is

    sigma_t = 1 / (radius (1 - g)),    single-scattering albedo = remap(Base Color, g)

where ``remap`` is a fitted curve (below: the same coefficients as Cycles') that turns the colour an artist sees
(roughly the multiple-scattering albedo of a half-space) into the single-scattering albedo, clamped to 0.999999.
The walk enters through the surface at the Principled IOR (clamped to >= 1.01), and light leaves where it exits as
a Lambertian (diffuse) closure at the exit point: not the medium's radiance there. Below a single-scattering albedo
of 0.2 Cycles walks with 0.2 and scales the path's weight by albedo / 0.2.

So: a medium (sigma_t, albedo, g) is rendered by Cycles' random walk with radius = 1 / (sigma_t (1 - g')),
g' = clamp(g, 0, 0.9), and the Base Color whose remap is the albedo (``base_color``, by bisection). Media with g < 0
or g > 0.9 walk with g' instead of g: ``subsurface_settings`` says so.
"""
from __future__ import annotations

import numpy as np

MAX_ANISOTROPY = 0.9  # bssrdf_setup clamps the anisotropy to [0, 0.9]
MAX_ALBEDO = 0.999999  # subsurface_random_walk_remap clamps the single-scattering albedo here

# subsurface_random_walk_remap: six polynomials in g (degree 7) of the curve
# albedo(A) = (1 - A^(1/4)) a atan(b A)^c + A^(1/4) d atan(e A)^f; for b and e: 4.98511194385 + 0.127355959438 e^P(g)
# and 4.23190299701 + 0.00310603949088 e^P(g) with the polynomials' constant term 0.
_POLY = {
    "a": (1.8260523782, -1.28451056436, -1.79904629312, 9.19393289202, -22.8215585862, 32.0234874259,
          -23.6264803333, 7.21067002658),
    "b": (0.0, 31.1491581433, -201.847017512, 841.576016723, -2018.09288505, 2731.71560286, -1935.41424244,
          559.009054474),
    "c": (1.09686102424, -0.394704063468, 1.05258115941, -8.83963712726, 28.8643230661, -46.8802913581,
          38.5402837518, -12.7181042538),
    "d": (0.496310210422, 0.360146581622, -2.15139309747, 17.8896899217, -55.2984010333, 82.065982243,
          -58.5106008578, 15.8478295021),
    "e": (0.0, 76.7316253952, -594.356773233, 2448.8834203, -5576.68528998, 7116.60171912, -4763.54467887,
          1303.5318055),
    "f": (2.40602999408, -2.51814844609, 9.18494908356, -79.2191708682, 259.082868209, -403.613804597,
          302.85712436, -87.4370473567),
}


def _poly(name: str, g: float) -> float:
    return float(sum(c * g ** k for k, c in enumerate(_POLY[name])))


def walk_anisotropy(g: float) -> float:
    """The anisotropy Cycles' random walk uses for a requested ``g``."""
    return min(max(float(g), 0.0), MAX_ANISOTROPY)


def single_scattering_albedo(color, g: float) -> np.ndarray:
    """Cycles' remap from a Base Color channel (0..1) to the random walk's single-scattering albedo, for the
    walk's anisotropy ``g`` (already clamped: ``walk_anisotropy``)."""
    A = np.clip(np.asarray(color, dtype=np.float64), 0.0, 1.0)
    a, c, d, f = (_poly(k, g) for k in "acdf")
    b = 4.98511194385 + 0.127355959438 * np.exp(_poly("b", g))
    e = 4.23190299701 + 0.00310603949088 * np.exp(_poly("e", g))
    blend = A ** 0.25
    alpha = (1.0 - blend) * a * np.arctan(b * A) ** c + blend * d * np.arctan(e * A) ** f
    return np.clip(alpha, 0.0, MAX_ALBEDO)


def base_color(albedo, g: float, iterations: int = 60) -> np.ndarray:
    """The Base Color whose remap is ``albedo`` (per channel), by bisection on [0, 1] (the remap rises
    monotonically there; tests/unit/test_neural_medium_subsurface.py). An albedo above what colour 1 gives
    returns 1."""
    target = np.asarray(albedo, dtype=np.float64)
    lo, hi = np.zeros_like(target), np.ones_like(target)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        below = single_scattering_albedo(mid, g) < target
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def subsurface_settings(sigma_t, albedo, g: float) -> dict:
    """Principled BSDF inputs (Blender 4.2 and 5.0 names) under which Cycles' random walk walks in the medium of
    extinction ``sigma_t`` per scene unit and single-scattering ``albedo`` (per channel) with HG ``g``; ``notes``
    lists what it cannot match. No specular layer (Specular IOR Level 0) and IOR 1 (the walk enters at 1.01): an
    index-matched boundary as near as the Principled BSDF allows."""
    walk_g = walk_anisotropy(g)
    sigma_t = np.maximum(np.asarray(sigma_t, dtype=np.float64), 1e-12)
    notes = []
    if walk_g != g:
        notes.append(f"Cycles' random walk clamps the anisotropy to [0, {MAX_ANISOTROPY:g}]: it walks with g = "
                     f"{walk_g:g}, not {g:g}")
    if np.min(albedo) < 0.2:
        notes.append("below a single-scattering albedo of 0.2 Cycles walks with 0.2 and scales the light down")
    return {"inputs": {"Base Color": (*base_color(albedo, walk_g).tolist(), 1.0), "Subsurface Weight": 1.0,
                       "Subsurface Radius": tuple((1.0 / (sigma_t * (1.0 - walk_g))).tolist()),
                       "Subsurface Scale": 1.0, "Subsurface Anisotropy": walk_g, "IOR": 1.0,
                       "Specular IOR Level": 0.0, "Roughness": 0.0},
            "method": "RANDOM_WALK", "notes": notes}
