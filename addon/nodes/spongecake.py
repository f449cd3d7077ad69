"""SpongeCake → Cycles closures (both forms: OSL and node group), written once with ``expr`` backends.

Each layer k becomes closures whose weights depend on the view direction ωo only. Light-direction factors
are evaluated at the mirror configuration ωi = reflect(ωo) ("mirror approximation", exact when the
layer is optically thick or the lobe is narrow); docs/accuracy.md names and measures each one:

* surface flakes: reflection = γ · ½(1 − τ²) · GGX(α) around the flake normal, with Schlick F(f0).
  Exact for Tρ → ∞ with the normal along n (research notes §1: thick surface flakes = ½ GGX with
  height-correlated Smith); the (1 − τ²) factor is G of Eq. 12 at Λi = Λo. [approx: mirror-G]
  A tilted flake normal keeps the GGX lobe around it. [approx: tilted-flakes]
* fiber layers: the same with an anisotropic GGX, exact for in-plane fibers (see ``_fiber_lobe``).
* transmission (every layer): Lambert translucency carrying the single-scattering transmittance estimate
  γ · p · (Tρ/cos θo) · G_t, with p the share of scattering that leaves downwards for light along the normal
  and G_t Eq. 14 with the light at normal incidence (``_transmission_g``). [approx: translucent-lobe]
  Cycles' GGX refraction with IOR 1 evaluates exactly Eq. 13's form under lamps, but samples it as a
  straight-through refraction: under environment light it renders as transparency (measured: furnace
  albedo 1.0 instead of 0.15 for α = 0.3), so it is not used. Flakes' Schlick F is evaluated at h = n.
* hg layers: Lambert reflection carrying γ · (1 − p) · ½(1 − τ²), p the forward share of HG scattering.
  [approx: lambert-hg]
* attenuation by the layers above is ∏ τ_j(ωo)² for reflection (Sec. 4.3 with τ(ωi) ≈ τ(ωo)), and
  ∏ τ_j(ωo) · ∏ τ_j(n) for transmission (layers above, layers below). [approx: mirror-attenuation]
* substrate: its closure × ∏ τ_j(ωo)² (Sec. 4.4). [approx: substrate-attenuation]
* delta transmission: transparent × ∏ τ_j(ωo) — exact (ωi = −ωo and σ is symmetric).

The node-group form also evaluates Schlick's F at h = flake normal [approx: schlick-at-view];
the OSL form evaluates it per microfacet (generalized_schlick_bsdf).
"""
from __future__ import annotations

from dataclasses import dataclass

from ..models import spongecake as model
from ..models.params import Param
from .expr import schlick_at_view


# Every approximation the mapping makes, with a configuration that isolates it (docs/accuracy.md measures
# each against the reference on the comparison scenes; ``make bench`` regenerates the table).
def _one(**layer):
    return {"layers": [{"albedo": [1, 1, 1], **layer}]}


APPROXIMATIONS = {
    "mirror-G": ("Eq. 12's G evaluated at Λi = Λo (thin layers; exact when thick)",
                 _one(type="surface", roughness=0.3, thickness=0.3)),
    "tilted-flakes": ("a tilted flake normal keeps an isotropic GGX lobe around it",
                      _one(type="surface", roughness=0.3, thickness=1e4, orientation=[0.5, 0, 0.866])),
    "tilted-fiber": ("fibers leaving the tangent plane blend towards an isotropic α = 1 lobe",
                     _one(type="fiber", roughness=0.3, thickness=1e4, orientation=[0.707, 0, 0.707])),
    "fiber-along-normal": ("fibers along the normal (sheen) become an isotropic α = 1 lobe",
                           _one(type="fiber", roughness=0.3, thickness=1e4, orientation=[0, 0, 1])),
    "transmission-normal-light": ("transmission weight (Eq. 14) with the light at normal incidence",
                                  _one(type="surface", roughness=0.3, thickness=0.1)),
    "translucent-lobe": ("every layer's transmission as Lambert translucency (no lobe shape)",
                         _one(type="surface", roughness=0.5, thickness=1.0)),
    "flake-transmission-share": ("flakes transmit the share of light along the normal they scatter downwards",
                                 _one(type="fiber", roughness=0.1, thickness=1.0, orientation=[1, 0, 0])),
    "lambert-hg": ("HG layers as Lambert reflection and translucency with single-scattering albedo estimates",
                   _one(type="hg", roughness=0.7, thickness=1.0)),
    "mirror-attenuation": ("attenuation by other layers along ωi taken equal to that along ωo (reflection)",
                           {"layers": [{"type": "surface", "roughness": 0.3, "thickness": 0.3, "albedo": [1, 1, 1]},
                                       {"type": "surface", "roughness": 0.6, "thickness": 1e4,
                                        "albedo": [1, 1, 1]}]}),
    "substrate-attenuation": ("the substrate is attenuated by ∏ τ(ωo)² instead of ∏ τ(ωi) τ(ωo)",
                              {**_one(type="surface", roughness=0.05, thickness=0.2),
                               "substrate": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}}),
    "conductor-f0-blender-4.2": ("Blender 4.2 node group only (no Metallic BSDF node): Principled metal with the "
                                "complex IOR's F0; not measured here (bpy 5.0)",
                                {**_one(type="surface", roughness=0.3, thickness=0.1),
                                 "substrate": {"type": "conductor"}}),
    "schlick-at-view": ("node group only: Schlick F at h = flake normal instead of per microfacet",
                        _one(type="surface", roughness=0.3, thickness=1e4, f0=[0.2, 0.2, 0.2])),
}


@dataclass(frozen=True)
class Socket:
    name: str  # node-group socket name; OSL parameter name is its identifier form
    kind: str  # "float" | "color" | "vector"
    param: Param
    layer: int | None  # 0-based layer index, None for the substrate

    @property
    def panel(self) -> str:
        return "Substrate" if self.layer is None else f"Layer {self.layer + 1}"


def structure_key(p: model.Params) -> tuple:
    """What decides the shape of the generated shader (parameter values are inputs, not structure)."""
    return (
        tuple((layer.type, layer.has_fresnel) for layer in p.layers),
        None if p.substrate is None else p.substrate.type,
        p.delta_transmission,
    )


def _layer_params(layer: model.Layer) -> tuple[Param, ...]:
    skip = {"type"}
    if not layer.has_fresnel:
        skip.add("f0")
    if not layer.is_flake:
        skip.add("orientation")
    return tuple(p for p in model.LAYER if p.name not in skip)


def sockets(p: model.Params) -> list[Socket]:
    """The inputs of the generated shader, in panel order, from the model declaration."""
    out = []
    for k, layer in enumerate(p.layers):
        for prm in _layer_params(layer):
            label = "Mean Cosine g" if (prm.name == "roughness" and not layer.is_flake) else prm.label
            out.append(Socket(f"L{k + 1} {label}", prm.kind, prm, k))
    if p.substrate is not None:
        for prm in model.SUBSTRATE[p.substrate.type]:
            out.append(Socket(f"Substrate {prm.label}", prm.kind, prm, None))
    return out


def input_values(p: model.Params) -> dict:
    """Socket name → value for these parameters (what the material's group node or script node is set to)."""
    values = {}
    for s in sockets(p):
        source = p.substrate if s.layer is None else p.layers[s.layer]
        values[s.name] = getattr(source, s.param.name)
    return values


def shade(b, p: model.Params) -> None:
    """Build the closure mix for the stack structure of ``p`` on backend ``b`` (see module docstring)."""
    mu = b.cos_view()
    terms = [_layer_terms(b, k, layer, mu) for k, layer in enumerate(p.layers)]
    taus = [t["tau"] for t in terms]
    for k, (layer, t) in enumerate(zip(p.layers, terms)):
        above = _prod(*taus[:k]) if k else None
        below = _prod(*[u["tau_n"] for u in terms[k + 1:]]) if k + 1 < len(terms) else None
        reflected = _prod(0.5 * (1.0 - t["tau"] * t["tau"]), above, above)  # Eq. 12 at Λi = Λo, Sec. 4.3
        transmitted = b.scale(t["albedo"], _prod(t["p_down"] * t["depth"] * _transmission_g(b, t), above, below))
        if layer.is_flake:
            b.glossy(b.scale(t["albedo"], reflected), t["alpha_x"], t["alpha_y"], t["normal"], t.get("tangent"),
                     t.get("f0"))
            if "f0" in t:
                transmitted = schlick_at_view(b, transmitted, t["f0"], t["normal"])
        else:
            b.diffuse(b.scale(t["albedo"], (1.0 - t["p_down"]) * reflected))
        b.translucent(transmitted)
    stack = _prod(*taus)
    if p.substrate is not None:
        _substrate(b, p.substrate, stack * stack)
    if p.delta_transmission:
        b.transparent(b.scale((1.0, 1.0, 1.0), stack))


def _transmission_g(b, t):
    """Eq. 14's G / Tρ with the light at normal incidence on the far side: with x = Tρ|Λ(ωo)| and
    a = Tρ|Λ(n)|, (e^{−x} − e^{−a}) / (a − x), which tends to e^{−x} as x → a. [approx: transmission-normal-light]"""
    a, x = t["x_n"], t["x"]
    d = a - x
    near = b.step_below(b.abs(d), 1e-4)
    exact = (b.exp(-x) - b.exp(-a)) / (d + near)  # the + near keeps the unused branch finite
    return exact * (1.0 - near) + b.exp(-x) * near


def _layer_terms(b, k: int, layer: model.Layer, mu) -> dict:
    name = f"L{k + 1} "
    rough = b.input(name + ("Roughness" if layer.is_flake else "Mean Cosine g"), "float")
    t = {"albedo": b.input(name + "Albedo", "color")}
    thickness = b.input(name + "Thickness", "float")
    sigma = sigma_n = 1.0
    if layer.is_flake:
        direction = b.direction(b.input(name + "Orientation", "vector"))
        c, c_n = b.dot_view(direction), b.dot(direction, b.normal())
        a2 = rough * rough
        # σ(ω) = sqrt(ωᵀ S ω) for S of Sec. 3.3 rotated to the orientation (research notes §1)
        if layer.type == "surface":
            sigma, sigma_n = b.sqrt(a2 + (1.0 - a2) * c * c), b.sqrt(a2 + (1.0 - a2) * c_n * c_n)
            t.update(alpha_x=rough, alpha_y=rough, normal=direction)
        else:
            sigma, sigma_n = b.sqrt(1.0 + (a2 - 1.0) * c * c), b.sqrt(1.0 + (a2 - 1.0) * c_n * c_n)
            t.update(_fiber_lobe(b, rough, c_n, direction))
        if layer.has_fresnel:
            t["f0"] = b.input(name + "F0", "color")
        # light along the normal leaves downwards off flakes tilted beyond 45°: P(tan² θm > 1) = α²/(1 + α²)
        # for GGX (α² = α_x α_y for fibers) [approx: flake-transmission-share]
        ax2 = t["alpha_x"] * t["alpha_y"]
        t["p_down"] = ax2 / (1.0 + ax2)
    else:
        t["p_down"] = 1.0 - _hg_back_share(b, rough)
    t["depth"] = thickness / mu  # Tρ / cos θo
    t["x"] = t["depth"] * sigma
    t["x_n"] = thickness * sigma_n
    t["tau"] = b.exp(-t["x"])
    t["tau_n"] = b.exp(-t["x_n"])
    return t


def _hg_back_share(b, g):
    """Share of Henyey–Greenstein scattering into the backward hemisphere for light along the normal:
    (1 − g)/(2g) · ((1 + g)/sqrt(1 + g²) − 1), → 1/2 as g → 0 (the series 1/2 − 3g/4 + … below |g| = 1e-3)."""
    small = b.step_below(b.abs(g), 1e-3)
    safe_g = g + small  # keeps the unused branch finite at g = 0
    exact = (1.0 - g) / (2.0 * safe_g) * ((1.0 + g) / b.sqrt(1.0 + g * g) - 1.0)
    return exact * (1.0 - small) + (0.5 - 0.75 * g) * small


def _fiber_lobe(b, alpha, c_n, tangent) -> dict:
    """Fibers along an in-plane tangent t: S = diag(α², 1, 1) in (t, n×t, n), so D is the anisotropic GGX with
    (α_t, α_b) = (α, 1) and Λ_sggx = 1 + 2Λ_smith — exact, like surface flakes. Tilting t out of the plane
    (c_n = t·n) blends α_t towards 1 (isotropic GGX α = 1 for fibers along n, whose exact lobe, GGX with
    α = 1/α > 1, Cycles cannot express). [approx: tilted-fiber] [approx: fiber-along-normal]"""
    in_plane = 1.0 - c_n * c_n
    return {"alpha_x": 1.0 + (alpha - 1.0) * in_plane, "alpha_y": 1.0, "normal": b.normal(),
            "tangent": b.tangent_plane(tangent)}


def _substrate(b, s: model.Substrate, weight) -> None:
    white = b.scale((1.0, 1.0, 1.0), weight)
    if s.type == "diffuse":
        b.diffuse(b.scale(b.input("Substrate Albedo", "color"), weight))
    elif s.type == "conductor":
        b.conductor(white, b.input("Substrate Roughness", "float"),
                    b.input("Substrate IOR", "color"), b.input("Substrate Extinction", "color"))
    else:
        b.dielectric(white, b.input("Substrate Roughness", "float"), b.input("Substrate IOR", "float"))


def _prod(*factors):
    """Product of the factors that are not None (None stands for "no attenuation", so no node is made)."""
    present = [f for f in factors if f is not None]
    if not present:
        return 1.0
    out = present[0]
    for f in present[1:]:
        out = out * f
    return out
