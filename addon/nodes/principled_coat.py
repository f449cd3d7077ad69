"""Blender's Principled BSDF coat set up like a Lamina thin coat: what an artist would otherwise use, rendered
beside the thin coat in comparisons (``compare --principled``, the compare panel's *Principled BSDF*; declared by
``nodes.thin_coat.PRINCIPLED``, whose line is ``MAPPING``).

The mapping (``settings``; every number comes from the thin-coat parameters, nothing is fitted):

* **Coat Weight** 1. **Coat IOR** = the coat's η.
* **Coat Roughness** from the top interface's κ1: the vMF lobe of κ is the Beckmann lobe of α = sqrt(2 / κ)
  (models.thin_coat); we take GGX α = that Beckmann α, and Principled's roughness r has α = r², so
  r = sqrt(α) = (2 / κ1)^(1/4), capped at 1 (κ1 = 200: α 0.1, r 0.316; κ1 = 1e6: r 0.038).
* **Coat Tint** from the absorption: Cycles multiplies what is under the coat once by Tint^(1 / cos θt) (θt the
  view refracted into the coat; intern/cycles/kernel/osl/shaders/node_principled_bsdf.osl), so Tint is the
  transmittance of one straight pass at normal incidence. Light reflected by the base crosses the thin coat
  twice (down and up, e^(−σa d / cos θt) each, Eq. 27), so Tint = e^(−2 σa d): equal at normal incidence.
  A slab's transmitted light crosses once: Tint = e^(−σa d).
* The base, from the thin coat's base seen through the coat (its IORs divided by the coat's η, as the thin coat's
  bottom interface has them; Cycles does not divide them by the Coat IOR itself):
  ``diffuse``: Base Color = the albedo, Metallic 0, Specular IOR Level 0 (no specular base: the diffuse base of
  the thin coat has none). ``conductor``: Metallic 1, Base Color = the metal's exact Fresnel reflectance at normal
  incidence, Specular Tint = its reflectance at 82° (cos = 1/7) over the Schlick curve's (Cycles' F82-tint metal
  then matches the exact conductor at 0° and 82°), Roughness from κ2 as above. ``dielectric_rough``: Base Color
  black (the opaque base absorbs what it refracts), Metallic 0, IOR = base IOR / η (its inverse below 1: the same
  reflectance at normal incidence), Roughness from κ2. ``slab``: a coated glass, Transmission Weight 1 with IOR η
  and Roughness from κ2 (its reflection stands for the slab's bottom interface; a single glass interface bends
  the transmitted light, which the slab does not: the backlit scene shows it), Base Color white. (IOR 1, the
  usual thin-sheet trick, renders as transparency: nothing under a sun.)
* Everything else is Principled's default (multiscatter GGX).

The thin coat's bounces have no counterpart: Principled has no light reflected inside the coat.
"""
from __future__ import annotations

import math

import numpy as np

from ..models import thin_coat
from ..reference import microfacet

MAPPING = ("Coat Weight 1; Coat Roughness (2 / kappa_top)^(1/4) (GGX alpha = Beckmann alpha = sqrt(2 / kappa), "
           "roughness = sqrt(alpha)); Coat IOR eta; Coat Tint exp(-2 sigma_a depth) (a slab: exp(-sigma_a depth)); "
           "base: diffuse colour (no specular) / metal with the conductor's exact colours at 0 and 82 degrees / "
           "black dielectric of IOR base/eta / glass of IOR eta (slab), Roughness (2 / kappa_bottom)^(1/4)")
F82_COS = 1.0 / 7.0  # Cycles' F82-tint model pins the metal's colour at cos θ = 1/7 (about 82°)


def roughness(kappa: float) -> float:
    """Principled's roughness for an interface of concentration κ: (2 / κ)^(1/4) (module docstring), ≤ 1."""
    return min(math.sqrt(thin_coat.roughness_from_kappa(kappa)), 1.0)


def _conductor_colors(p) -> tuple[tuple, tuple]:
    """(Base Color, Specular Tint) of Cycles' F82-tint metal matching the base metal under the coat exactly at
    normal incidence and at cos θ = 1/7."""
    eta = np.asarray(p.base.eta, dtype=float) / p.eta
    k = np.asarray(p.base.k, dtype=float) / p.eta
    f0 = microfacet.fresnel_conductor(np.array([1.0]), eta, k)[0]
    f82 = microfacet.fresnel_conductor(np.array([F82_COS]), eta, k)[0]
    schlick = f0 + (1.0 - f0) * (1.0 - F82_COS) ** 5
    return tuple(float(c) for c in f0), tuple(float(c) for c in np.clip(f82 / schlick, 0.0, 1.0))


def settings(p) -> dict:
    """The Principled BSDF input values (by socket name) for thin-coat parameters ``p`` (module docstring)."""
    passes = 1.0 if p.transmits else 2.0
    out = {
        "Coat Weight": 1.0,
        "Coat Roughness": roughness(p.kappa_top),
        "Coat IOR": float(p.eta),
        "Coat Tint": tuple(math.exp(-passes * s * p.depth) for s in p.sigma_a),
        "Roughness": roughness(p.kappa_bottom),
    }
    base = p.base.type
    if base == "diffuse":
        out.update({"Base Color": tuple(p.base.albedo), "Metallic": 0.0, "Specular IOR Level": 0.0})
    elif base == "conductor":
        color, tint = _conductor_colors(p)
        out.update({"Base Color": color, "Specular Tint": tint, "Metallic": 1.0})
    elif base == "dielectric_rough":
        relative = p.base.ior / p.eta
        out.update({"Base Color": (0.0, 0.0, 0.0), "Metallic": 0.0, "IOR": max(relative, 1.0 / relative)})
    else:  # slab
        out.update({"Base Color": (1.0, 1.0, 1.0), "Metallic": 0.0, "Transmission Weight": 1.0, "IOR": float(p.eta)})
    return out

