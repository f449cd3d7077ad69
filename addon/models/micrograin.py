"""Micrograin porous layer (Lucas et al. 2023): opaque half-ellipsoid grains scattered over any bulk material.

Declared once here; the reference, the node group, the OSL shader, the UI, presets and the CLI read it.
Names follow the paper's Table 1: filling factor τ0 (share of the surface covered by grains seen from above,
Eq. 13), anfractuosity β (grain height over radius, Sec. 3). The equivalent GGX roughness α̃ (Eq. 18) is the
artist-friendly alternative to β: a dict may give ``roughness`` instead of ``anfractuosity``.

The grains' micro-BRDF is diffuse, diffuse + specular dielectric, or a specular conductor (Sec. 3). The bulk
is a simple BSDF declared like SpongeCake's substrates, or any other Lamina model (``{"type": "spongecake",
...}`` with that model's dict, or ``"preset"``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from . import spongecake
from .metals import METALS
from .params import METADATA_KEYS, Param, ParamError, Validated, read_fields

ID = "micrograin"
LABEL = "Micrograin"
MAX_FILLING = 0.98  # Sec. 4.2: keeps the largest equivalent roughness above 0.5
MIN_ANFRACTUOSITY = 1e-3
GRAIN_TYPES = ("diffuse", "dielectric", "conductor")
GRAIN_LABELS = {"diffuse": "Diffuse", "dielectric": "Diffuse + specular", "conductor": "Conductor"}
SIMPLE_BULKS = ("diffuse", "conductor", "dielectric")
WRAPPED = "shader"  # the bulk is a material's own shader (Add Porous Layer): Cycles only, no reference
GAF_TYPES = ("series", "ggx")

LAYER = (
    Param("filling_factor", "Filling Factor", "float", 0.5, 0.0, MAX_FILLING, texturable=True, subtype="FACTOR",
          description="Share of the surface covered by grains seen from above (tau0, Eq. 13); linear, so "
                      "textures and mipmaps average it correctly"),
    Param("anfractuosity", "Anfractuosity", "float", 0.5, MIN_ANFRACTUOSITY, 1.0, texturable=True, subtype="FACTOR",
          description="Grain height over radius (beta): flat discs at 0, spheres at 1; the grains' GGX roughness "
                      "as the filling factor goes to 0"),
)

GRAIN = {
    "diffuse": (
        Param("albedo", "Grain Albedo", "color", (0.8, 0.8, 0.8), 0.0, 1.0, texturable=True,
              description="Lambertian albedo Kd of the grains"),
    ),
    "dielectric": (
        Param("albedo", "Grain Albedo", "color", (0.5, 0.5, 0.5), 0.0, 1.0, texturable=True,
              description="Albedo Kd of the grains' diffuse part under their specular coat"),
        Param("ior", "Grain IOR", "float", 1.5, 1.0, 3.0, description="Index of refraction of the grains' coat"),
    ),
    "conductor": (
        Param("ior", "Grain IOR", "color", (0.143, 0.374, 1.442), 0.01, 10.0,
              description="Real part of the grains' complex IOR (RGB)"),
        Param("k", "Grain Extinction", "color", (3.983, 2.385, 1.603), 0.0, 20.0,
              description="Imaginary part of the grains' complex IOR (RGB)"),
    ),
}

# Complex IORs (R, G, B at about 650, 550, 450 nm) of what conductor grains are made of: metals and two oxides.
CONDUCTORS = {
    **{name: METALS[name] for name in ("gold", "aluminium", "copper", "silver")},
    "copper_oxide": ((2.80, 3.00, 2.85), (0.08, 0.25, 0.75)),
    "soot": ((1.75, 1.75, 1.75), (0.45, 0.45, 0.45)),
}

# The artist's alternative to the anfractuosity (Eq. 18); converted to β by ``validate``.
ROUGHNESS = Param("roughness", "Equivalent Roughness", "float", 0.4, 0.0, 1.0, subtype="FACTOR",
                  description="GGX roughness alpha of the grains' highlight (Eq. 18: anfractuosity x "
                              "sqrt(-tau0 / ln(1 - tau0))); capped where the anfractuosity reaches 1")

STACK = (
    Param("gaf", "Geometric Term", "enum", "series", items=GAF_TYPES,
          description="series: the micrograin Lambda of Eq. 25 (exact); ggx: GGX Lambda of the equivalent "
                      "roughness (cheaper, darker at grazing)"),
)


@dataclass(frozen=True)
class Grain:
    type: str
    albedo: tuple = (0.8, 0.8, 0.8)
    ior: object = 1.5  # float (dielectric) or RGB (conductor)
    k: tuple = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Bulk:
    """The material under the grains: a simple BSDF (``spongecake.Substrate``) or another model's parameters."""

    type: str
    params: object


@dataclass(frozen=True)
class Params:
    filling_factor: float
    anfractuosity: float
    grain: Grain
    bulk: Bulk
    gaf: str = "series"

    @property
    def roughness(self) -> float:
        """The equivalent GGX roughness α̃ (Eq. 18)."""
        return equivalent_roughness(self.filling_factor, self.anfractuosity)

    @property
    def transmits(self) -> bool:
        """Whether light passes through: the grains are opaque, so through the bulk only, where the bulk does (a
        dielectric, another model that transmits; a material's own shader is unknown: assumed to)."""
        return bulk_transmits(self.bulk)

    def to_dict(self) -> dict:
        return {
            "filling_factor": self.filling_factor,
            "anfractuosity": self.anfractuosity,
            "grain": {"type": self.grain.type, **{p.name: _plain(getattr(self.grain, p.name))
                                                  for p in GRAIN[self.grain.type]}},
            "bulk": _bulk_dict(self.bulk),
            "gaf": self.gaf,
        }


def _plain(v):
    return list(v) if isinstance(v, tuple) else v


def _bulk_dict(bulk: Bulk) -> dict:
    if bulk.type == WRAPPED:
        return {"type": WRAPPED}
    if bulk.type in SIMPLE_BULKS:
        return {"type": bulk.type, **{p.name: _plain(getattr(bulk.params, p.name))
                                      for p in spongecake.SUBSTRATE[bulk.type]}}
    return {"type": bulk.type, **bulk.params.to_dict()}


def bulk_transmits(bulk: Bulk) -> bool:
    """Whether light passes through the bulk (``Params.transmits``)."""
    if bulk.type in SIMPLE_BULKS:
        return bulk.type not in spongecake.OPAQUE_SUBSTRATES
    return bulk.type == WRAPPED or bulk.params.transmits


def log_porosity(tau0: float) -> float:
    """P = −ln(1 − τ0) = π ρ r_s² (Eq. 13), the grain density in units of the grain's disc."""
    return -math.log1p(-tau0)


def roughness_factor(tau0: float) -> float:
    """sqrt(−τ0 / ln(1 − τ0)) of Eq. 18 (→ 1 as τ0 → 0, by its series 1 − τ0/4 − … below 1e-6)."""
    if tau0 < 1e-6:
        return 1.0 - tau0 / 4.0
    return math.sqrt(tau0 / log_porosity(tau0))


def equivalent_roughness(tau0: float, beta: float) -> float:
    """α̃ = β sqrt(−τ0 / ln(1 − τ0)) (Eq. 18): the GGX roughness whose D matches the micrograin D at θm = 0."""
    return beta * roughness_factor(tau0)


def anfractuosity_for(tau0: float, roughness: float) -> float:
    """The β that gives the equivalent roughness α̃ at this filling factor (Eq. 18 inverted, unclamped)."""
    return roughness / roughness_factor(tau0)


def validate(data: dict) -> Validated:
    """Clean a Micrograin dict: clamp out-of-range numbers (with messages), refuse what cannot be clamped."""
    if not isinstance(data, dict):
        raise ParamError(f"micrograin: expected a dict, got {type(data).__name__}")
    known = {p.name for p in LAYER + STACK} | {"roughness", "grain", "bulk", *METADATA_KEYS}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ParamError(f"micrograin: unknown key(s) {', '.join(unknown)}")
    if "roughness" in data and "anfractuosity" in data:
        raise ParamError("micrograin: give either anfractuosity or roughness (its equivalent, Eq. 18), not both")
    warnings: list[str] = []
    fields = {p.name: data[p.name] for p in LAYER + STACK if p.name in data}
    layer = read_fields(LAYER + STACK, {k: v for k, v in fields.items() if k != "anfractuosity"},
                        "micrograin: ", warnings)
    if "roughness" in data:
        roughness = ROUGHNESS.clamp(data["roughness"], "micrograin: ", warnings)
        fields["anfractuosity"] = anfractuosity_for(layer["filling_factor"], roughness)
        if fields["anfractuosity"] > 1.0:
            warnings.append(f"micrograin: roughness {roughness:g} is above the largest equivalent roughness "
                            f"{equivalent_roughness(layer['filling_factor'], 1.0):.3g} at filling factor "
                            f"{layer['filling_factor']:g}; using that largest one (anfractuosity 1)")
            fields["anfractuosity"] = 1.0
    anfractuosity = read_fields(LAYER[1:], {k: v for k, v in fields.items() if k == "anfractuosity"},
                                "micrograin: ", warnings)["anfractuosity"]
    grain = _read_grain(data.get("grain", {"type": "diffuse"}), warnings)
    bulk = _read_bulk(data.get("bulk", {"type": "diffuse"}), warnings)
    return Validated(Params(layer["filling_factor"], anfractuosity, grain, bulk, layer["gaf"]), warnings)


def params_from_dict(data: dict) -> Params:
    """The Python API entry point: a Micrograin dict (see docs/api.md) to reference parameters."""
    return validate(data).params


def _read_grain(d, warnings: list[str]) -> Grain:
    if not isinstance(d, dict) or d.get("type") not in GRAIN_TYPES:
        raise ParamError(f"grain: expected a dict with type in {', '.join(GRAIN_TYPES)}, got {d!r}")
    rest = {k: v for k, v in d.items() if k != "type"}
    return Grain(d["type"], **read_fields(GRAIN[d["type"]], rest, "grain: ", warnings))


def bulk_types() -> tuple[str, ...]:
    from . import MODELS

    return SIMPLE_BULKS + tuple(m for m in MODELS if m != ID) + (WRAPPED,)


def _read_bulk(d, warnings: list[str]) -> Bulk:
    if not isinstance(d, dict) or d.get("type") not in bulk_types():
        raise ParamError(f"bulk: expected a dict with type in {', '.join(bulk_types())}, got {d!r}")
    rest = {k: v for k, v in d.items() if k != "type"}
    if d["type"] == WRAPPED:
        if rest:
            raise ParamError(f"bulk: a wrapped shader takes no parameters, got {', '.join(sorted(rest))}")
        return Bulk(WRAPPED, None)
    if d["type"] in SIMPLE_BULKS:
        fields = read_fields(spongecake.SUBSTRATE[d["type"]], rest, "bulk: ", warnings)
        return Bulk(d["type"], spongecake.Substrate(d["type"], **fields))
    from . import MODELS
    from .. import presets

    if "preset" in rest:
        if set(rest) != {"preset"}:
            raise ParamError("bulk: give either a preset or the model's parameters, not both")
        try:
            rest = presets.load(d["type"], rest["preset"])
        except KeyError as e:
            raise ParamError(f"bulk: {e.args[0]}") from None
    validated = MODELS[d["type"]].validate(rest)
    warnings += [f"bulk: {w}" for w in validated.warnings]
    return Bulk(d["type"], validated.params)


def reference_refusal(p: Params) -> str | None:
    """Why ``p`` has no reference to compare with (None: it has one): a layer over a material's own shader."""
    if p.bulk.type == WRAPPED:
        return ("this porous layer wraps a material's own shader, which has no reference; compare a porous layer "
                "over a reference bulk (diffuse, conductor, dielectric or another Lamina model)")
    return None


def default_params() -> Params:
    return params_from_dict({})

