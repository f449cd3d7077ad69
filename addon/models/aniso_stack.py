"""Anisotropic layered stacks (Belcour 2018's atomic operators extended to 2×2 covariances; paper:
anisotropic_layered).

Declared once here; the reference, the node group, the OSL shader, the UI, presets and the CLI read it.
A stack of 1-4 rough interfaces, top first, with air above the first. Each interface is a ``dielectric`` (the
absolute IOR of what lies below it, scalar or RGB) or a ``conductor`` (complex IOR n + ik in air, RGB; it ends the
stack: the model divides it by the IOR of the medium above). Each has its own anisotropic GGX roughness
(αx, αy) along its own tangent, rotated by ``rotation`` degrees about the normal from the surface's tangent.
Between interfaces j and j + 1 lies ``media[j]``: absorption σa and scattering σs per unit depth over ``depth``,
with a Henyey-Greenstein mean cosine g (Belcour's forward-scattering medium operator: g in [0, 0.999]).

A dict (docs/api.md)::

    {"interfaces": [{"type": "dielectric", "ior": 1.49, "alpha": [0.10, 0.02], "rotation": 30.0},
                    {"type": "conductor", "ior": [r, g, b], "k": [r, g, b], "alpha": [0.2, 0.05]}],
     "media": [{"sigma_a": [r, g, b], "depth": 0.0, "sigma_s": [0, 0, 0], "g": 0.0}]}

``alpha`` may be one number (isotropic). ``media`` may be left out (clear, empty gaps). Refused with one message:
no interface or more than 4, a conductor above another interface, an IOR ≤ 0, an extinction k < 0, a media list
whose length is not the number of gaps, an unknown key or type. Clamped with a warning: α outside [1e-4, 1], IORs
and media values outside their ranges, NaN (the default).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .params import METADATA_KEYS, Param, ParamError, Validated, read_fields

ID = "aniso_stack"
LABEL = "Anisotropic Stack"
MAX_INTERFACES = 4
MIN_ALPHA = 1e-4
INTERFACE_TYPES = ("dielectric", "conductor")
INTERFACE_LABELS = {"dielectric": "Dielectric", "conductor": "Conductor"}
GLOSSY_MAX_ANISOTROPY = 0.99  # Blender's Glossy BSDF clamps its Anisotropy to ±0.99

ROUGHNESS = (
    Param("alpha_x", "Alpha X", "float", 0.1, MIN_ALPHA, 1.0, texturable=True, subtype="FACTOR",
          description="GGX roughness alpha along the interface's tangent"),
    Param("alpha_y", "Alpha Y", "float", 0.1, MIN_ALPHA, 1.0, texturable=True, subtype="FACTOR",
          description="GGX roughness alpha along the interface's bitangent"),
    Param("rotation", "Rotation", "float", 0.0, -360.0, 360.0, unit="°", texturable=True,
          description="Angle of the interface's tangent about the normal from the surface tangent, in degrees"),
)

INTERFACE = {
    "dielectric": (
        Param("ior", "IOR", "color", (1.49, 1.49, 1.49), 1.0001, 3.0,
              description="Absolute index of refraction of what lies below the interface (RGB for dispersion)"),
    ),
    "conductor": (
        Param("ior", "IOR", "color", (0.143, 0.374, 1.442), 0.01, 10.0,
              description="Real part n of the conductor's complex IOR in air (RGB)"),
        Param("k", "Extinction", "color", (3.983, 2.385, 1.603), 0.0, 20.0,
              description="Imaginary part k of the conductor's complex IOR in air (RGB)"),
    ),
}

MEDIUM = (
    Param("sigma_a", "Absorption", "color", (0.0, 0.0, 0.0), 0.0, 1000.0, texturable=True,
          description="Absorption coefficient per unit depth of the medium between two interfaces (RGB)"),
    Param("depth", "Depth", "float", 0.0, 0.0, 100.0, texturable=True,
          description="Thickness of the medium, in the units of its coefficients (only sigma x depth matters)"),
    Param("sigma_s", "Scattering", "color", (0.0, 0.0, 0.0), 0.0, 1000.0,
          description="Scattering coefficient per unit depth (RGB); 0 is a clear, absorbing medium"),
    Param("g", "Mean Cosine", "float", 0.0, 0.0, 0.999,
          description="Henyey-Greenstein mean cosine of the scattering (forward only, Belcour's medium operator)"),
)


@dataclass(frozen=True)
class Interface:
    """One rough interface; ``k`` matters for conductors only."""

    type: str
    ior: tuple
    alpha_x: float
    alpha_y: float
    rotation: float = 0.0
    k: tuple = (0.0, 0.0, 0.0)

    @property
    def alpha(self) -> tuple:
        return self.alpha_x, self.alpha_y


@dataclass(frozen=True)
class Medium:
    sigma_a: tuple = (0.0, 0.0, 0.0)
    depth: float = 0.0
    sigma_s: tuple = (0.0, 0.0, 0.0)
    g: float = 0.0

    @property
    def optical_depth(self) -> tuple:
        """(σa + σs)·depth per channel: the extinction along the normal."""
        return tuple((a + s) * self.depth for a, s in zip(self.sigma_a, self.sigma_s))


@dataclass(frozen=True)
class Params:
    interfaces: tuple
    media: tuple

    @property
    def transmits(self) -> bool:
        """Light passes below the stack where its last interface is a dielectric (into that dielectric)."""
        return self.interfaces[-1].type == "dielectric"

    def to_dict(self) -> dict:
        return {"interfaces": [_interface_dict(i) for i in self.interfaces],
                "media": [{p.name: _plain(getattr(m, p.name)) for p in MEDIUM} for m in self.media]}


def _plain(v):
    return list(v) if isinstance(v, tuple) else v


def _interface_dict(i: Interface) -> dict:
    out = {"type": i.type, "alpha": [i.alpha_x, i.alpha_y], "rotation": i.rotation}
    return {**out, **{p.name: _plain(getattr(i, p.name)) for p in INTERFACE[i.type]}}


def validate(data: dict) -> Validated:
    """Clean an Anisotropic Stack dict: clamp out-of-range numbers (with messages), refuse what cannot be clamped
    (module docstring)."""
    if not isinstance(data, dict):
        raise ParamError(f"{ID}: expected a dict, got {type(data).__name__}")
    unknown = sorted(set(data) - {"interfaces", "media", *METADATA_KEYS})
    if unknown:
        raise ParamError(f"{ID}: unknown key(s) {', '.join(unknown)}; expected interfaces, media")
    raw = data.get("interfaces", [default_interface("dielectric"), default_interface("conductor")])
    if not isinstance(raw, (list, tuple)) or not 1 <= len(raw) <= MAX_INTERFACES:
        count = len(raw) if isinstance(raw, (list, tuple)) else type(raw).__name__
        raise ParamError(f"{ID}: interfaces: expected a list of 1 to {MAX_INTERFACES} interfaces, got {count}")
    warnings: list[str] = []
    interfaces = tuple(_read_interface(d, j, warnings) for j, d in enumerate(raw))
    for j, interface in enumerate(interfaces[:-1]):
        if interface.type == "conductor":
            raise ParamError(f"{ID}: interface {j + 1} is a conductor: a conductor ends the stack (no light passes "
                             f"it), so it must be the last of the {len(interfaces)}")
    gaps = len(interfaces) - 1
    media = data.get("media", [{}] * gaps)
    if not isinstance(media, (list, tuple)) or len(media) != gaps:
        count = len(media) if isinstance(media, (list, tuple)) else type(media).__name__
        raise ParamError(f"{ID}: media: expected {gaps} (one between each two of the {len(interfaces)} interfaces), "
                         f"got {count}")
    media = tuple(_read_medium(d, j, warnings) for j, d in enumerate(media))
    return Validated(Params(interfaces, media), warnings)


def params_from_dict(data: dict) -> Params:
    """The Python API entry point: an Anisotropic Stack dict (docs/api.md) to reference parameters."""
    return validate(data).params


def alpha_from_glossy(roughness: float, anisotropy: float) -> tuple[float, float]:
    """(αx, αy) of Blender's Glossy BSDF at Roughness r and Anisotropy a (its OSL and SVM code, Blender 4.2 to 5.0):
    α = r², a clamped to ±0.99; a ≥ 0 stretches the highlight across the tangent (αx = α(1 − a), αy = α / (1 − a)),
    a < 0 along it (αx = α / (1 + a), αy = α(1 + a))."""
    alpha = min(max(roughness, 0.0), 1.0) ** 2
    a = min(max(anisotropy, -GLOSSY_MAX_ANISOTROPY), GLOSSY_MAX_ANISOTROPY)
    return (alpha * (1.0 - a), alpha / (1.0 - a)) if a >= 0.0 else (alpha / (1.0 + a), alpha * (1.0 + a))


def glossy_from_alpha(alpha_x: float, alpha_y: float) -> tuple[float, float]:
    """The inverse of ``alpha_from_glossy``: (Roughness, Anisotropy) with r⁴ = αx·αy and the aspect sqrt(αx / αy)
    (an anisotropy beyond ±0.99, αx/αy outside [1/39601, 39601], is clamped there)."""
    roughness = (alpha_x * alpha_y) ** 0.25
    a = 1.0 - math.sqrt(alpha_x / alpha_y) if alpha_x <= alpha_y else math.sqrt(alpha_y / alpha_x) - 1.0
    return roughness, min(max(a, -GLOSSY_MAX_ANISOTROPY), GLOSSY_MAX_ANISOTROPY)


def default_interface(kind: str) -> dict:
    """The dict of an interface of type ``kind`` with every declared default."""
    return {"type": kind, **{p.name: _plain(p.default) for p in INTERFACE[kind]},
            "alpha": [ROUGHNESS[0].default, ROUGHNESS[1].default], "rotation": ROUGHNESS[2].default}


def default_params() -> Params:
    return params_from_dict({})


def _read_interface(d, j: int, warnings: list[str]) -> Interface:
    where = f"interface {j + 1}: "
    if not isinstance(d, dict) or d.get("type") not in INTERFACE_TYPES:
        raise ParamError(f"{ID}: {where}expected a dict with type in {', '.join(INTERFACE_TYPES)}, got {d!r}")
    kind = d["type"]
    fields = {k: v for k, v in d.items() if k not in ("type", "alpha")}
    if "alpha" in d:
        if "alpha_x" in d or "alpha_y" in d:
            raise ParamError(f"{ID}: {where}give either alpha or alpha_x / alpha_y, not both")
        fields["alpha_x"], fields["alpha_y"] = _alpha_pair(d["alpha"], where)
    _refuse_non_positive(fields, kind, where)
    values = read_fields(ROUGHNESS + INTERFACE[kind], fields, f"{ID}: {where}", warnings)
    return Interface(type=kind, **values)


def _alpha_pair(value, where: str) -> tuple:
    """``alpha`` as (αx, αy): one number is isotropic."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return value, value
    if isinstance(value, (list, tuple)) and len(value) == 2:
        return tuple(value)
    raise ParamError(f"{ID}: {where}alpha: expected one number or [alpha_x, alpha_y], got {value!r}")


def _refuse_non_positive(fields: dict, kind: str, where: str) -> None:
    """An IOR ≤ 0 or an extinction k < 0 is not a material: refused rather than clamped."""
    for name, bad, words in (("ior", lambda v: v <= 0.0, "must be > 0"), ("k", lambda v: v < 0.0, "must be ≥ 0")):
        if name not in fields:
            continue
        value = fields[name]
        values = value if isinstance(value, (list, tuple)) else [value]
        if any(isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isnan(v) and bad(v)
               for v in values):
            raise ParamError(f"{ID}: {where}{name}: {value!r} {words} (a {kind})")


def _read_medium(d, j: int, warnings: list[str]) -> Medium:
    where = f"medium {j + 1}: "
    if not isinstance(d, dict):
        raise ParamError(f"{ID}: {where}expected a dict, got {d!r}")
    return Medium(**read_fields(MEDIUM, d, f"{ID}: {where}", warnings))
