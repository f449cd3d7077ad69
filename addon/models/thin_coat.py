"""Thin transparent coat with the extended normal distribution function (Guo et al. 2018; paper: thin_layers_endf).

Declared once here; the reference, the node group, the OSL shader, the UI, presets and the CLI read it.
A transparent layer of relative IOR η (Sec. 5) whose top and bottom interfaces are rough with vMF normal
distributions of concentration κ1 (top) and κ2 (bottom) (Eqs. 5-6), absorbing σa per unit length over its depth
d (Eq. 27), over a base: an opaque rough dielectric (the paper's case: light is only reflected at the bottom),
a conductor, a Lambertian diffuse base, or ``slab``: no base, the coat is a free-standing thin slab that also
transmits (Sec. 4.3, Eq. 23). ``bounces`` (0-4) is how many subsurface reflections are modelled (Sec. 5.2,
Table 2's speed/accuracy knob); 0 is the top interface alone.

Roughness and κ: the artist's roughness α of an interface is the Beckmann roughness whose lobe matches the vMF
lobe (research notes §2): κ = 2 / α², α = sqrt(2 / κ). So α = 0.1 is κ = 200, α = 0.01 is κ = 2e4; κ is kept
in [1e-3, 1e6], α = 0 (a mirror) is κ = 1e6. A dict gives either ``kappa_top`` or ``roughness_top`` (and the same
for the bottom).

IORs of the base are absolute (in air, as tables give them); at the bottom interface the coat's η divides them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .params import METADATA_KEYS, Param, ParamError, Validated, read_fields

ID = "thin_coat"
LABEL = "Thin Coat"
MIN_KAPPA, MAX_KAPPA = 1e-3, 1e6
MAX_BOUNCES = 4
BASE_TYPES = ("dielectric_rough", "conductor", "diffuse", "slab")
BASE_LABELS = {"dielectric_rough": "Rough dielectric", "conductor": "Conductor", "diffuse": "Diffuse",
               "slab": "None (thin slab)"}
INTERFACES = ("top", "bottom")

LAYER = (
    Param("kappa_top", "Top Kappa", "float", 1e4, MIN_KAPPA, MAX_KAPPA,
          description="vMF concentration of the top interface's normals (Eq. 5); roughness = sqrt(2 / kappa)"),
    Param("kappa_bottom", "Bottom Kappa", "float", 1e3, MIN_KAPPA, MAX_KAPPA,
          description="vMF concentration of the bottom interface's normals; no effect over a diffuse base"),
    Param("eta", "Coat IOR", "float", 1.5, 1.0001, 3.0,
          description="Index of refraction of the coat relative to the air above it"),
    Param("sigma_a", "Absorption", "color", (0.0, 0.0, 0.0), 0.0, 1000.0, texturable=True,
          description="Absorption coefficient sigma_a of the coat per unit depth, RGB (Eq. 27)"),
    Param("depth", "Depth", "float", 0.5, 0.0, 100.0, texturable=True,
          description="Thickness d of the coat, in the units of the absorption (only sigma_a x d matters)"),
)

# The artist's alternative to each kappa: the Beckmann roughness of the same lobe (module docstring).
ROUGHNESS = {
    side: Param(f"roughness_{side}", f"{side.capitalize()} Roughness", "float", math.sqrt(2.0 / default.default),
                0.0, math.sqrt(2.0 / MIN_KAPPA), texturable=True,
                description=f"Beckmann roughness of the {side} interface, sqrt(2 / kappa) (0: a mirror, kappa 1e6)")
    for side, default in zip(INTERFACES, LAYER[:2])
}

BASE = {
    "dielectric_rough": (
        Param("ior", "Base IOR", "float", 2.25, 1.0001, 3.0,
              description="Absolute IOR of the opaque base; the bottom interface reflects by Fresnel at base IOR / "
                          "coat IOR (2.25 under a 1.5 coat is the paper's relative 1.5)"),
    ),
    "conductor": (
        Param("eta", "Base IOR", "color", (0.143, 0.374, 1.442), 0.01, 10.0,
              description="Real part of the metal's complex IOR in air (RGB); divided by the coat IOR at the bottom"),
        Param("k", "Base Extinction", "color", (3.983, 2.385, 1.603), 0.0, 20.0,
              description="Imaginary part of the metal's complex IOR in air (RGB)"),
    ),
    "diffuse": (
        Param("albedo", "Base Color", "color", (0.8, 0.8, 0.8), 0.0, 1.0, texturable=True,
              description="Lambertian albedo of the base under the coat"),
    ),
    "slab": (),
}

STACK = (
    Param("bounces", "Bounces", "int", 2, 0, MAX_BOUNCES,
          description="Subsurface reflections modelled (Sec. 5.2): 0 is the top interface alone; each adds a "
                      "lobe, the first carries most of the energy"),
    Param("merge_orders", "Merge orders ≥ 2", "bool", False,
          description="Cycles forms only: render the reflection (and slab transmission) orders from the second on "
                      "as one lobe each, cheaper with 3-4 bounces; the reference keeps every order"),
)


def _default(base: str, name: str):
    return next(prm.default for prm in BASE[base] if prm.name == name)


@dataclass(frozen=True)
class Base:
    """The base under the coat; only the fields its type declares (``BASE``) matter, the others keep defaults."""

    type: str
    ior: float = _default("dielectric_rough", "ior")
    eta: tuple = _default("conductor", "eta")
    k: tuple = _default("conductor", "k")
    albedo: tuple = _default("diffuse", "albedo")


@dataclass(frozen=True)
class Params:
    kappa_top: float
    kappa_bottom: float
    eta: float
    sigma_a: tuple
    depth: float
    base: Base
    bounces: int = 2
    merge_orders: bool = False

    @property
    def roughness_top(self) -> float:
        return roughness_from_kappa(self.kappa_top)

    @property
    def roughness_bottom(self) -> float:
        return roughness_from_kappa(self.kappa_bottom)

    @property
    def transmits(self) -> bool:
        return self.base.type == "slab"

    def to_dict(self) -> dict:
        return {
            **{p.name: _plain(getattr(self, p.name)) for p in LAYER + STACK},
            "base": {"type": self.base.type, **{p.name: _plain(getattr(self.base, p.name))
                                                for p in BASE[self.base.type]}},
        }


def _plain(v):
    return list(v) if isinstance(v, tuple) else v


def kappa_from_roughness(alpha: float) -> float:
    """κ = 2 / α² (the Beckmann lobe of roughness α matches the vMF lobe of κ), kept in [1e-3, 1e6]; rounded to 12
    significant digits so that round numbers stay round (α 0.1 is κ 200, not 199.99999999999997)."""
    return float(f"{min(max(2.0 / max(alpha * alpha, 1e-300), MIN_KAPPA), MAX_KAPPA):.12g}")


def roughness_from_kappa(kappa: float) -> float:
    return math.sqrt(2.0 / kappa)


def validate(data: dict) -> Validated:
    """Clean a Thin Coat dict: clamp out-of-range numbers (with messages), refuse what cannot be clamped."""
    if not isinstance(data, dict):
        raise ParamError(f"thin_coat: expected a dict, got {type(data).__name__}")
    names = {p.name for p in LAYER + STACK} | {p.name for p in ROUGHNESS.values()}
    unknown = sorted(set(data) - names - {"base", *METADATA_KEYS})
    if unknown:
        raise ParamError(f"thin_coat: unknown key(s) {', '.join(unknown)}")
    warnings: list[str] = []
    fields = {k: data[k] for k in data if k in {p.name for p in LAYER + STACK}}
    for side in INTERFACES:
        alt = ROUGHNESS[side]
        if alt.name in data:
            if f"kappa_{side}" in data:
                raise ParamError(f"thin_coat: give either kappa_{side} or {alt.name} (sqrt(2 / kappa)), not both")
            fields[f"kappa_{side}"] = kappa_from_roughness(alt.clamp(data[alt.name], "thin_coat: ", warnings))
    values = read_fields(LAYER + STACK, fields, "thin_coat: ", warnings)
    base = _read_base(data.get("base", {"type": "dielectric_rough"}), warnings)
    return Validated(Params(base=base, **values), warnings)


def params_from_dict(data: dict) -> Params:
    """The Python API entry point: a Thin Coat dict (see docs/api.md) to reference parameters."""
    return validate(data).params


def _read_base(d, warnings: list[str]) -> Base:
    if not isinstance(d, dict) or d.get("type") not in BASE_TYPES:
        raise ParamError(f"base: expected a dict with type in {', '.join(BASE_TYPES)}, got {d!r}")
    rest = {k: v for k, v in d.items() if k != "type"}
    return Base(d["type"], **read_fields(BASE[d["type"]], rest, "base: ", warnings))


def default_params() -> Params:
    return params_from_dict({})
