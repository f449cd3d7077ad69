"""Neural participating media (Ge et al., "Interactive Simulation of Scattering Effects in Participating Media Using
a Neural Network Model"; paper: neural_media): a homogeneous medium filling a closed mesh, whose double and multiple
scattering come from networks trained on Lamina's own photon tracer (training/medium_tracer.py).

A medium is not a BSDF: it has no eval/pdf/sample and no BSDF comparison scenes. This module declares its
parameters once; the ground truth (``reference/neural_medium_truth.py``) and later the bake and the Blender layer
read it. It joins the model registry with its Blender layer (issue 13's later slices).

A dict (docs/api.md)::

    {"sigma_s": [r, g, b], "sigma_a": [r, g, b], "g": 0.0, "scale": 1.0}

``sigma_s`` and ``sigma_a`` are the scattering and absorption coefficients per unit length and ``scale`` the scene
units per such unit: the coefficients per scene unit are sigma / scale (so with sigma_s + sigma_a = 1, ``scale`` is
the mean free path in scene units). ``g`` is the Henyey-Greenstein mean cosine. Refused with one message: an
unknown key, a channel whose extinction sigma_s + sigma_a is 0 (it holds nothing to scatter or absorb: no medium).
Clamped with a warning: values outside their ranges, NaN (the default). Albedo 0 and 1 and g = ±0.99 are valid.
"""
from __future__ import annotations

from dataclasses import dataclass

from .params import METADATA_KEYS, Param, ParamError, Validated, read_fields

ID = "neural_medium"
LABEL = "Neural Medium"
MAX_G = 0.99

MEDIUM = (
    Param("sigma_s", "Scattering", "color", (0.9, 0.9, 0.9), 0.0, 1e4,
          description="Scattering coefficient per unit length (RGB)"),
    Param("sigma_a", "Absorption", "color", (0.1, 0.1, 0.1), 0.0, 1e4,
          description="Absorption coefficient per unit length (RGB)"),
    Param("g", "Anisotropy", "float", 0.0, -MAX_G, MAX_G,
          description="Henyey-Greenstein mean cosine: > 0 scatters forward, < 0 backward"),
    Param("scale", "Scale", "float", 1.0, 1e-4, 1e4,
          description="Scene units per unit length of the coefficients (with sigma_s + sigma_a = 1: the mean free "
                      "path in scene units)"),
)


@dataclass(frozen=True)
class Params:
    sigma_s: tuple
    sigma_a: tuple
    g: float
    scale: float

    @property
    def sigma_t(self) -> tuple:
        """Extinction per unit length of the coefficients, per channel."""
        return tuple(s + a for s, a in zip(self.sigma_s, self.sigma_a))

    @property
    def albedo(self) -> tuple:
        """Single-scattering albedo sigma_s / sigma_t per channel."""
        return tuple(s / t for s, t in zip(self.sigma_s, self.sigma_t))

    @property
    def mean_free_path(self) -> tuple:
        """Mean free path in scene units per channel: scale / sigma_t."""
        return tuple(self.scale / t for t in self.sigma_t)

    def per_scene_unit(self) -> tuple[tuple, tuple]:
        """(sigma_s, sigma_a) per scene unit: the coefficients over ``scale``."""
        return tuple(s / self.scale for s in self.sigma_s), tuple(a / self.scale for a in self.sigma_a)

    def to_dict(self) -> dict:
        return {"sigma_s": list(self.sigma_s), "sigma_a": list(self.sigma_a), "g": self.g, "scale": self.scale}


def validate(data: dict) -> Validated:
    """Clean a Neural Medium dict: clamp out-of-range numbers (with messages), refuse what cannot be clamped (module
    docstring)."""
    if not isinstance(data, dict):
        raise ParamError(f"{ID}: expected a dict, got {type(data).__name__}")
    warnings: list[str] = []
    fields = {k: v for k, v in data.items() if k not in METADATA_KEYS}
    values = read_fields(MEDIUM, fields, f"{ID}: ", warnings)
    p = Params(**values)
    empty = [c for c, t in zip("RGB", p.sigma_t) if t <= 0.0]
    if empty:
        raise ParamError(f"{ID}: sigma_s + sigma_a is 0 in channel(s) {', '.join(empty)}: no medium there (zero "
                         f"density); give a positive scattering or absorption")
    return Validated(p, warnings)


def params_from_dict(data: dict) -> Params:
    """The Python API entry point: a Neural Medium dict (docs/api.md) to parameters."""
    return validate(data).params


def default_params() -> Params:
    return params_from_dict({})


def from_albedo_and_mean_free_path(albedo, mean_free_path, g: float, scale: float = 1.0) -> dict:
    """The dict of a medium given per channel as albedo and mean free path (the paper's Table 1): sigma_t = 1 / mfp,
    sigma_s = albedo sigma_t, sigma_a = (1 - albedo) sigma_t."""
    sigma_t = [1.0 / m for m in mean_free_path]
    return {"sigma_s": [a * t for a, t in zip(albedo, sigma_t)],
            "sigma_a": [(1.0 - a) * t for a, t in zip(albedo, sigma_t)], "g": g, "scale": scale}
