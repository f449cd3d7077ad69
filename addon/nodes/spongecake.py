"""SpongeCake → Cycles closures (both forms: OSL and node group), written once with ``expr`` backends.

Each layer k becomes closures whose weights depend on the view direction ωo only. Light-direction factors
are evaluated at the mirror configuration ωi = reflect(ωo) ("mirror approximation", exact when the
layer is optically thick or the lobe is narrow); docs/accuracy.md names and measures each one:

* surface flakes: reflection = γ · ½(1 − τ²) · GGX(α) around the flake normal, with Schlick F(f0).
  Exact for Tρ → ∞ with the normal along n (research notes §1: thick surface flakes = ½ GGX with
  height-correlated Smith); the (1 − τ²) factor is G of Eq. 12 at Λi = Λo. [approx: mirror-G]
  A tilted flake normal keeps the GGX lobe around it. [approx: tilted-flakes]
* fiber layers: the same with an anisotropic GGX, exact for in-plane fibers (see ``_fiber_lobe``).
* hg layers: reflection = Lambert with the single-scattering albedo estimate γ · p_up · ½(1 − τ²).
  [approx: lambert-lobe]
* every layer: transmission = Lambert translucency with albedo γ · p_down · x e^{−x}, x = Tρ σ(ωo)/cos θo
  (Eq. 14 integrated at ωi = −ωo). [approx: translucent-lobe]
* attenuation by the layers above (below) is ∏ τ_j(ωo)² for reflection, ∏ τ_j(ωo) both ways for
  transmission (Sec. 4.3 with τ(ωi) ≈ τ(ωo)). [approx: mirror-attenuation]
* substrate: its closure × ∏ τ_j(ωo)² (Sec. 4.4). [approx: mirror-attenuation]
* delta transmission: transparent × ∏ τ_j(ωo) — exact (ωi = −ωo and σ is symmetric).

The node-group form also evaluates Schlick's F at h = flake normal [approx: schlick-at-view];
the OSL form evaluates it per microfacet (generalized_schlick_bsdf).
"""
from __future__ import annotations

from dataclasses import dataclass

from ..models import spongecake as model
from ..models.params import Param

# Share of a layer's single scattering that leaves downwards, for light arriving along the normal
# (hemispherical split of the phase function; surface flakes: smooth flakes only reflect, α = 1 is isotropic).
P_DOWN = {
    "surface": lambda b, a: 0.5 * a * a,
    "fiber": lambda b, a: 0.5,
    "hg": lambda b, g: 0.5 * (1.0 + g),
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
        below = _prod(*taus[k + 1:]) if k + 1 < len(taus) else None
        reflected = _prod(0.5 * (1.0 - t["tau"] * t["tau"]), above, above)  # Eq. 12 at Λi = Λo, Sec. 4.3
        if layer.is_flake:
            b.glossy(b.scale(t["albedo"], reflected), t["alpha_x"], t["alpha_y"], t["normal"], t.get("tangent"),
                     t.get("f0"))
        else:
            b.diffuse(b.scale(t["albedo"], (1.0 - t["p_down"]) * reflected))
        x = t["x"]
        b.translucent(b.scale(t["albedo"], _prod(t["p_down"] * x * b.exp(-x), above, below)))  # Eq. 14 at ωi = −ωo
    stack = _prod(*taus)
    if p.substrate is not None:
        _substrate(b, p.substrate, stack * stack)
    if p.delta_transmission:
        b.transparent(b.scale((1.0, 1.0, 1.0), stack))


def _layer_terms(b, k: int, layer: model.Layer, mu) -> dict:
    name = f"L{k + 1} "
    rough = b.input(name + ("Roughness" if layer.is_flake else "Mean Cosine g"), "float")
    t = {"albedo": b.input(name + "Albedo", "color"), "p_down": P_DOWN[layer.type](b, rough)}
    thickness = b.input(name + "Thickness", "float")
    sigma = 1.0
    if layer.is_flake:
        direction = b.direction(b.input(name + "Orientation", "vector"))
        c = b.dot_view(direction)
        a2 = rough * rough
        # σ(ωo) = sqrt(ωoᵀ S ωo) for S of Sec. 3.3 rotated to the orientation (research notes §1)
        if layer.type == "surface":
            sigma = b.sqrt(a2 + (1.0 - a2) * c * c)
            t.update(alpha_x=rough, alpha_y=rough, normal=direction)
        else:
            sigma = b.sqrt(1.0 + (a2 - 1.0) * c * c)
            t.update(_fiber_lobe(b, rough, direction))
        if layer.has_fresnel:
            t["f0"] = b.input(name + "F0", "color")
    t["x"] = thickness * sigma / mu
    t["tau"] = b.exp(-t["x"])
    return t


def _fiber_lobe(b, alpha, tangent) -> dict:
    """Fibers along an in-plane tangent t: S = diag(α², 1, 1) in (t, n×t, n), so D is the anisotropic GGX with
    (α_t, α_b) = (α, 1) and Λ_sggx = 1 + 2Λ_smith — exact, like surface flakes. Tilting t out of the plane
    blends α_t towards 1 (isotropic GGX α = 1 for fibers along n, whose exact lobe, GGX with α = 1/α > 1,
    Cycles cannot express). [approx: tilted-fiber]"""
    c = b.dot(tangent, b.normal())
    in_plane = 1.0 - c * c
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
