"""SpongeCake (Wang et al. 2022): stacks of volumetric layers of SGGX microflakes or Henyey–Greenstein media.

Declared once here; the reference, the node group, the OSL shader, the UI, presets and the CLI read it.
Parameter names follow the paper's Table 2: albedo γ, roughness α (the mean cosine g for ``hg``),
Schlick reflectance f0, optical thickness Tρ (the model only depends on the product, Sec. 4.1),
and orientation ω_p (flake normal for ``surface``, fiber tangent for ``fiber``; tangent space).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

from .params import METADATA_KEYS, Param, ParamError, Validated, read_fields

ID = "spongecake"
LABEL = "SpongeCake"
MAX_LAYERS = 4
LAYER_TYPES = ("surface", "fiber", "hg")
SUBSTRATE_TYPES = ("none", "diffuse", "conductor", "dielectric")

# Optical thickness (Tρ summed over the stack) beyond which no light crosses it: e^-30 ≈ 1e-13 along the normal,
# and flakes along the normal or fibers in the tangent plane are at least as thick along every other direction.
OPAQUE_THICKNESS = 30.0
# Multiple scattering's energy scale in the reference (``energy_tables``): a table over
# the view cosine on ENERGY_KNOTS knots uniform in √μ from MIN_ENERGY_COS to 1 (dense near grazing, where the scale
# changes fastest; views closer to grazing take the first knot's value). 16 knots rather than 8 bring the light
# returned by one-layer held-out stacks from 3.6% to 2.5% off the walk (docs/training.md), for twice the table's time.
ENERGY_KNOTS = 16
MIN_ENERGY_COS = 0.02
ENERGY_AZIMUTHS = 32  # view azimuths per knot where a layer is oriented off the normal (``energy_tables``)
# The Cycles forms' table of the energy budget (``nodes.spongecake.budget_table``): rows uniform in asin(√μ) from
# MIN_ENERGY_COS to 1 by azimuths (``view_energy_grid``: one where no layer is oriented off the normal), looked up
# bilinearly as a float image (``nodes.view_table``).
VIEW_ENERGY_GRID = (32, 64)
# The share of the received light the scale leaves unreturned (``bake.spongecake.energy_scale``): twice the largest
# standard deviation (0.16%) of the tables' 4096-sample estimates of what single scattering leaves, measured over the
# 32 azimuths of the normal view of the white furnace bench's oriented stacks (measured once during development).
ENERGY_MARGIN = 0.003
OPAQUE_SUBSTRATES = ("diffuse", "conductor")  # a dielectric substrate refracts light through the stack

# Flake roughness below this makes the SGGX matrix singular in float32; HG |g| above this is a delta.
MIN_FLAKE_ROUGHNESS = 1e-4
MAX_ABS_G = 0.999

LAYER = (
    Param("type", "Type", "enum", "surface", items=LAYER_TYPES,
          description="surface: flake normals around the orientation; fiber: fibers along it; hg: Henyey-Greenstein medium"),
    Param("roughness", "Roughness", "float", 0.3, -MAX_ABS_G, 1.0, texturable=True,
          description="SGGX roughness alpha of the flakes or fibers; for hg layers the mean cosine g"),
    Param("albedo", "Albedo", "color", (0.8, 0.8, 0.8), 0.0, 1.0, texturable=True,
          description="Single-scattering albedo gamma of each scattering event"),
    Param("thickness", "Thickness", "float", 1.0, 0.0, 1e4, unit="optical depth", texturable=True,
          description="Optical thickness T*rho (density times thickness, unitless)"),
    Param("f0", "F0", "color", (1.0, 1.0, 1.0), 0.0, 1.0,
          description="Schlick reflectance of the flakes at normal incidence; (1,1,1) means no Fresnel"),
    Param("orientation", "Orientation", "vector", (0.0, 0.0, 1.0), texturable=True, subtype="DIRECTION",
          description="Flake normal (surface) or fiber tangent (fiber) in tangent space (x tangent, z normal)"),
)

SUBSTRATE = {
    "none": (),
    "diffuse": (
        Param("albedo", "Albedo", "color", (0.5, 0.5, 0.5), 0.0, 1.0, texturable=True,
              description="Lambertian substrate reflectance"),
    ),
    "conductor": (
        Param("roughness", "Roughness", "float", 0.2, 1e-4, 1.0, description="GGX alpha of the metal substrate"),
        Param("eta", "IOR", "color", (0.2, 0.92, 1.1), 0.01, 10.0, description="Real part of the complex IOR"),
        Param("k", "Extinction", "color", (3.9, 2.45, 2.14), 0.0, 20.0, description="Imaginary part of the complex IOR"),
    ),
    "dielectric": (
        Param("roughness", "Roughness", "float", 0.1, 1e-4, 1.0, description="GGX alpha of the dielectric substrate"),
        Param("ior", "IOR", "float", 1.5, 1.0001, 3.0, description="Relative index of refraction of the substrate"),
    ),
}

STACK = (
    Param("delta_transmission", "Delta transmission", "bool", False,
          description="Let unscattered light pass straight through the stack (Sec. 4.4)"),
    Param("multiple_scattering", "Multiple scattering", "bool", False,
          description="Add the network-predicted multiple-scattering lobes (Sec. 5; networks for 1 and 2 layers, "
                      "deeper stacks grouped into two)"),
)


@dataclass(frozen=True)
class Layer:
    type: str
    roughness: float
    albedo: tuple
    thickness: float
    f0: tuple
    orientation: tuple

    @property
    def is_flake(self) -> bool:
        return self.type != "hg"

    @property
    def has_fresnel(self) -> bool:
        return self.is_flake and tuple(self.f0) != (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Substrate:
    type: str
    albedo: tuple = (0.5, 0.5, 0.5)
    roughness: float = 0.2
    eta: tuple = (1.5, 1.5, 1.5)
    k: tuple = (0.0, 0.0, 0.0)
    ior: float = 1.5


@dataclass(frozen=True)
class Params:
    layers: tuple
    substrate: Substrate | None = None
    delta_transmission: bool = False
    multiple_scattering: bool = False

    @property
    def transmits(self) -> bool:
        """Whether light passes through the stack: no opaque substrate, and layers thinner than
        ``OPAQUE_THICKNESS`` in all."""
        opaque = self.substrate is not None and self.substrate.type in OPAQUE_SUBSTRATES
        return not opaque and sum(layer.thickness for layer in self.layers) < OPAQUE_THICKNESS

    def to_dict(self) -> dict:
        return {
            "layers": [asdict(layer) for layer in self.layers],
            "substrate": None if self.substrate is None else _substrate_dict(self.substrate),
            "delta_transmission": self.delta_transmission,
            "multiple_scattering": self.multiple_scattering,
        }


def _substrate_dict(s: Substrate) -> dict:
    return {"type": s.type, **{p.name: getattr(s, p.name) for p in SUBSTRATE[s.type]}}


def validate(data: dict) -> Validated:
    """Clean a SpongeCake dict: clamp out-of-range numbers (with messages), refuse what cannot be clamped."""
    if not isinstance(data, dict):
        raise ParamError(f"spongecake: expected a dict, got {type(data).__name__}")
    stack_keys = tuple(p.name for p in STACK)
    unknown = sorted(set(data) - {"layers", "substrate", *METADATA_KEYS, *stack_keys})
    if unknown:
        raise ParamError(f"spongecake: unknown key(s) {', '.join(unknown)}")
    layers_in = data.get("layers") or []
    if not 1 <= len(layers_in) <= MAX_LAYERS:
        raise ParamError(f"spongecake: needs 1 to {MAX_LAYERS} layers, got {len(layers_in)}")
    warnings: list[str] = []
    layers = tuple(_read_layer(d, i, warnings) for i, d in enumerate(layers_in))
    substrate = _read_substrate(data.get("substrate"), warnings)
    stack = read_fields(STACK, {k: data[k] for k in stack_keys if k in data}, "spongecake: ", warnings)
    return Validated(Params(layers, substrate, **stack), warnings)


def params_from_dict(data: dict) -> Params:
    """The Python API entry point: a SpongeCake dict (see docs/api.md) to reference parameters."""
    return validate(data).params


def _read_layer(d: dict, index: int, warnings: list[str]) -> Layer:
    where = f"layer {index + 1}: "
    if not isinstance(d, dict):
        raise ParamError(f"{where}expected a dict, got {d!r}")
    kind = LAYER[0].clamp(d.get("type", LAYER[0].default), where, warnings)
    return Layer(**read_fields(layer_declaration(kind), d, where, warnings))


def layer_declaration(kind: str) -> tuple:
    """``LAYER`` with the roughness range of a layer of type ``kind`` (flakes and fibers: α in [1e-4, 1];
    media: the mean cosine g in [-0.999, 0.999])."""
    lo, hi = (-MAX_ABS_G, MAX_ABS_G) if kind == "hg" else (MIN_FLAKE_ROUGHNESS, 1.0)
    return tuple(replace(p, min=lo, max=hi) if p.name == "roughness" else p for p in LAYER)


def _read_substrate(d, warnings: list[str]) -> Substrate | None:
    if d is None:
        return None
    if not isinstance(d, dict) or d.get("type") not in SUBSTRATE_TYPES:
        raise ParamError(f"substrate: expected a dict with type in {', '.join(SUBSTRATE_TYPES)}, got {d!r}")
    if d["type"] == "none":
        return None
    rest = {k: v for k, v in d.items() if k != "type"}
    return Substrate(d["type"], **read_fields(SUBSTRATE[d["type"]], rest, "substrate: ", warnings))


def default_params() -> Params:
    return params_from_dict({"layers": [{}]})


def energy_cosines(count: int = ENERGY_KNOTS):
    """``count`` view cosines uniform in √μ from √MIN_ENERGY_COS to 1 (by default the energy tables' knots,
    ``ENERGY_KNOTS``), as a list; the last is exactly 1."""
    lo = MIN_ENERGY_COS ** 0.5
    return [(lo + (1.0 - lo) * k / (count - 1)) ** 2 for k in range(count - 1)] + [1.0]


def view_table_cosines(count: int):
    """``count`` view cosines uniform in asin(√μ) from the first knot's (``energy_cosines``) to π/2 (the view tables'
    rows, ``nodes.view_table``): near the normal uniform in the view's angle (asin(√cos θ) ≈ π/2 − θ/√2), near
    grazing in √μ, as a list; the last is exactly 1."""
    lo = view_table_lowest()
    return [math.sin(lo + (0.5 * math.pi - lo) * k / (count - 1)) ** 2 for k in range(count - 1)] + [1.0]


def view_table_lowest() -> float:
    """asin(√μ) of the view tables' first row: the energy tables' first knot."""
    return math.asin(MIN_ENERGY_COS ** 0.5)


def view_energy_grid(params: Params) -> tuple[int, int]:
    """(rows, azimuths) of the Cycles forms' energy table of ``params``: ``VIEW_ENERGY_GRID`` where a layer is
    oriented off the normal, else its rows of one azimuth."""
    rows, azimuths = VIEW_ENERGY_GRID
    return rows, azimuths if anisotropic(params) else 1


def uniform_azimuths(count: int):
    """``count`` view azimuths uniform over the circle from 0 (the energy tables' columns), as a list."""
    return [2.0 * math.pi * k / count for k in range(count)]


def anisotropic(params: Params) -> bool:
    """Whether the stack's BSDF depends on the view's azimuth: a flake or fiber layer oriented off the normal."""
    return any(layer.is_flake and tuple(layer.orientation[:2]) != (0.0, 0.0) for layer in params.layers)


def conserving(params: Params) -> bool:
    """Whether the stack conserves energy once its albedos are 1: no Fresnel layer (flakes with f0 < 1 lose 1 - F),
    and no substrate or a diffuse one."""
    no_fresnel = not any(layer.has_fresnel for layer in params.layers)
    return no_fresnel and (params.substrate is None or params.substrate.type == "diffuse")


def white(params: Params) -> Params:
    """The same stack without absorption: every albedo 1 (a diffuse substrate's too), single scattering only."""
    data = params.to_dict()
    for layer in data["layers"]:
        layer["albedo"] = [1.0] * 3
    if params.substrate is not None and params.substrate.type == "diffuse":
        data["substrate"]["albedo"] = [1.0] * 3
    data["multiple_scattering"] = False
    return params_from_dict(data)

