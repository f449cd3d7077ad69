"""SpongeCake → Cycles closures (both forms: OSL and node group), written once with ``expr`` backends.

Each layer k becomes closures whose weights depend on the view direction ωo only. Light-direction factors
are evaluated at the mirror configuration ωi = reflect(ωo) ("mirror approximation", exact when the
layer is optically thick or the lobe is narrow); docs/accuracy.md names and measures each one:

* surface flakes: reflection = γ · ½(1 − τ²) · GGX(α) around the flake normal, with Schlick F(f0).
  Exact for Tρ → ∞ with the normal along n (research notes §1: thick surface flakes = ½ GGX with
  height-correlated Smith); the (1 − τ²) factor is G of Eq. 12 at Λi = Λo. [approx: mirror-G]
  A flake normal below the tangent plane is flipped up (S is the same for ±n; Cycles would render almost
  nothing around it). A tilted flake normal keeps the GGX lobe around it [approx: tilted-flakes], and
  Cycles renders that lobe its own way, which the numpy prediction models (``closures_np``; read in Cycles'
  kernel, measured in both forms on 4.2 and 5.0): it foreshortens light with the closure's normal,
  cos(n, ωi) instead of cos θi, and where the mirror direction of ωo about n falls below the surface it
  turns n towards the shading normal (``ensure_valid_specular_reflection``: the material's Bump Map
  Correction, on by default; with it off Cycles keeps n and the prediction is off at those views). Light
  below the surface gives nothing. Limitation, Blender 4.2 only: its GGX sampling keeps reflections below a
  tilted closure normal (above the surface) that its evaluation gives 0, so under environment light reached
  by BSDF sampling it renders more than any BSDF predicts (rel. RMSE 1.5–2.5 % in the white furnace for
  tilted flakes, whose uniform world Cycles reaches by BSDF sampling alone; ``NumpyBackend.
  sampling_leak_blender42`` gives that excess; a light-sampled world weights it by the BSDF's MIS weight).
  5.0 rejects those samples. Suns are unaffected.
* fiber layers: the same with an anisotropic GGX, exact for in-plane fibers (see ``_fiber_lobe``).
* transmission (no substrate): Lambert translucency carrying a single-scattering transmittance estimate
  γ · p · path · G_t: p the share of scattering that leaves downwards for light along the normal, path the
  layer's scattering depth along ωo (``_layer_terms``), G_t Eq. 14 with the light leaving at cos θ = 1/2
  (``_slab_transmission``). [approx: translucent-lobe]
  Cycles' GGX refraction with IOR 1 evaluates exactly Eq. 13's form under lamps, but samples it as a
  straight-through refraction: under environment light it renders as transparency (tests/blender/
  test_cycles_facts.py), so it is not used. Flakes' Schlick F is evaluated at h = n in transmission, in both
  forms. [approx: schlick-at-view]
* hg layers (and fibers along n): Lambert reflection carrying γ · p_back · path · G_r likewise.
  [approx: lambert-hg]
* attenuation by the layers above is ∏ τ_j(ωo)² for reflection (Sec. 4.3 with τ(ωi) ≈ τ(ωo)), and
  ∏ τ_j(ωo) · ∏ τ_j(60°) for transmission (layers above, layers below). [approx: mirror-attenuation]
* substrate: its closure × ∏ τ_j(ωo) × ∏ τ_j(ωi), with ωi the mirror direction for glossy substrates and
  cos θi = 1/2 for a diffuse one (Sec. 4.4). [approx: substrate-attenuation]
* delta transmission: transparent × ∏ τ_j(ωo) — exact (ωi = −ωo and σ is symmetric); none over a substrate.
* multiple scattering (Sec. 5): the network's lobe mapped like the layers, with the closure weights of the view
  along the normal (computed from the inputs alone: constants Cycles folds) [approx: ms-weights-at-normal], plus
  Lambert lobes, all scaled per view by the baked ``MS Energy`` input: an energy budget e (``bake.spongecake.
  energy_budget``), 1 + the reference's energy scale built on this form's own numpy prediction (``budget_table``);
  multiple scattering takes max(e − 1, 0). Where the form's own single scattering and Dirac return more than 1 − m
  (thin, very rough layers near grazing), e < 1 and they are scaled by min(e, 1). The material feeds the input from
  a packed float image of e over asin(√μ) (the view's angle near the normal, √μ near grazing), and over the view's
  azimuth too where a layer is oriented off the normal, looked up bilinearly at the view (``view_inputs``,
  ``view_table``, ``view_wiring``): one texture lookup, where a chain of mixes between knots cost the node group
  more (docs/training.md). Where a texture drives one layer input of an isotropic stack (a thickness, roughness or
  albedo), the table's columns are that input's values instead (``TexelEnergy``: 9 of them over the texels' range,
  made safe between them; greys for an albedo, each channel looked up at its own) and the lookup takes the
  texture's value; other texture-driven materials keep one table and leave the energy fraction out of it (each
  texel then keeps its baked lobes' own energy). [approx: ms-energy]
  In the node group each fiber layer's GGX lobe and the network's lobe for that layer are one Glossy BSDF (colours
  summed, α_x mixed harmonically: ``_FiberLobes``), and its budget is computed on that. [approx: ms-merged-fiber-lobe]

The node-group form also evaluates Schlick's F at h = flake normal [approx: schlick-at-view];
the OSL form evaluates it per microfacet (generalized_schlick_bsdf).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache, partial

import numpy as np

from ..models import spongecake as model
from ..models.params import Param
from .closures_np import SHARP_ALBEDO
from .expr import LAMBERT_CLOSURES, NumpyBackend, closure_furnace, schlick, schlick_at_view


# Every approximation the mapping makes, with a configuration that isolates it (docs/accuracy.md measures
# each against the reference on the comparison scenes; ``make bench`` regenerates the table).
def _one(**layer):
    return {"layers": [{"albedo": [1, 1, 1], **layer}]}


# The fitted mapping (``fitted``) rescales these closures per view and may add a few: offered here.
FITTABLE = True

APPROXIMATIONS = {
    "mirror-G": ("Eq. 12's G evaluated at Λi = Λo (thin layers; exact when thick)",
                 _one(type="surface", roughness=0.3, thickness=0.3)),
    "tilted-flakes": ("a tilted flake normal keeps an isotropic GGX lobe around it (Cycles foreshortens it with "
                      "that normal)",
                      _one(type="surface", roughness=0.3, thickness=1e4, orientation=[0.5, 0, 0.866])),
    "tilted-fiber": ("fibers leaving the tangent plane mix the in-plane GGX lobe and the along-normal Lambert lobe",
                     _one(type="fiber", roughness=0.3, thickness=1e4, orientation=[0.707, 0, 0.707])),
    "fiber-along-normal": ("fibers along the normal (sheen) become a Lambert lobe: the grazing sheen is lost",
                           _one(type="fiber", roughness=0.3, thickness=1e4, orientation=[0, 0, 1])),
    "diffusivity-exit": ("Lambert lobes: scattered light leaves the layer at cos θ = 1/2 (Eqs. 12, 14)",
                         _one(type="hg", roughness=0.0, thickness=1.0)),
    "translucent-lobe": ("every layer's transmission as Lambert translucency (no lobe shape)",
                         _one(type="surface", roughness=0.5, thickness=1.0)),
    "scattering-share": ("the share of light scattered downwards taken from normal incidence",
                         _one(type="surface", roughness=0.5, thickness=0.1)),
    "fiber-transmission-share": ("in-plane fibers transmit a fitted share of light along the normal",
                                 _one(type="fiber", roughness=0.5, thickness=1.0, orientation=[1, 0, 0])),
    "lambert-hg": ("HG layers as Lambert reflection and translucency (forward-scattering shape lost)",
                   _one(type="hg", roughness=0.7, thickness=1.0)),
    "mirror-attenuation": ("attenuation by other layers along ωi taken equal to that along ωo (reflection)",
                           {"layers": [{"type": "surface", "roughness": 0.3, "thickness": 0.3, "albedo": [1, 1, 1]},
                                       {"type": "surface", "roughness": 0.6, "thickness": 1e4,
                                        "albedo": [1, 1, 1]}]}),
    "substrate-attenuation": ("the substrate's light-side attenuation at the mirror direction (glossy) or 60° (diffuse)",
                              {**_one(type="surface", roughness=0.05, thickness=0.2),
                               "substrate": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}}),
    "conductor-f0-blender-4.2": ("Blender 4.2 node group only (no Metallic BSDF node): Principled metal with the "
                                "complex IOR's F0; not measured here (bpy 5.0)",
                                {**_one(type="surface", roughness=0.3, thickness=0.1),
                                 "substrate": {"type": "conductor"}}),
    "dielectric-substrate-adjoint": ("Cycles' glass transmits light from inside the substrate without the 1/η² of "
                                    "the reference's half-space (Cycles evaluates the adjoint BSDF)",
                                    {**_one(type="surface", roughness=0.3, thickness=0.3),
                                     "substrate": {"type": "dielectric", "roughness": 0.3, "ior": 1.5}}),
    "ms-energy": ("multiple scattering's energy scale on the form's own single scattering (not the reference's; "
                  "where that exceeds 1, it is scaled down), in a table over asin(√μ) (32 rows; by 64 azimuths "
                  "where a layer is oriented), bilinear (the reference bounds the interpolation's error; the table "
                  "does not); in a texture-driven bake by 9 values of one driven input (per channel at greys for "
                  "an albedo), else one per material without the energy fraction",
                  {**_one(type="surface", roughness=0.5, thickness=1.0), "multiple_scattering": True}),
    "ms-weights-at-normal": ("the multiple-scattering closures' weights are the layer math's for the view along "
                             "the normal (constants Cycles folds), their total restored per view by the energy "
                             "scale: only their split between the closures is that of normal incidence",
                             {**_one(type="fiber", roughness=0.3, thickness=0.5, orientation=[1, 0, 0]),
                              "multiple_scattering": True}),
    "ms-merged-fiber-lobe": ("node group only: each fiber layer's GGX lobe and the network's lobe for that layer are "
                             "one closure (colours summed, α_x mixed harmonically by the network lobe's share, about "
                             "the single-scattering lobe's tangent)",
                             {**_one(type="fiber", roughness=0.1, thickness=1.0, orientation=[1, 0, 0]),
                              "multiple_scattering": True}),
    "ms-forward-area": ("the multiple-scattering forward lobe's scale by the flakes' projected areas "
                        "(Π (σ(ωi) σ(ωo))^p) taken along the normal for both directions, as the other "
                        "multiple-scattering weights (the energy scale restores the total per view)",
                        {**_one(type="surface", roughness=0.1, thickness=0.5, orientation=[0.5, 0, 0.866]),
                         "multiple_scattering": True}),
    "schlick-at-view": ("Schlick F at h = flake normal, not per microfacet (node group reflection; both forms' "
                        "transmission)",
                        _one(type="surface", roughness=0.3, thickness=1e4, f0=[0.2, 0.2, 0.2])),
}


def cheaper_variants(p: model.Params) -> list[tuple[str, model.Params]]:
    """What Fit to budget may build instead (``budget``): the stack without its multiple-scattering lobes."""
    return [("no multiple scattering", replace(p, multiple_scattering=False))] if p.multiple_scattering else []


def approximations_used(p: model.Params) -> list[str]:
    """The names of the ``APPROXIMATIONS`` the mapping makes for ``p``, in that table's order (an approximation
    marked for Blender 4.2 is listed whenever its configuration occurs: it says so itself). The transmission
    lobes' approximations only where light passes (``p.transmits``: the lobes of a thick stack carry nothing)."""
    translucent = p.substrate is None and p.transmits
    used = set()
    for layer in p.layers:
        along_normal = abs(layer.orientation[2])  # |cos| between the flake normal or fiber tangent and n
        glossy = layer.type == "surface" or (layer.type == "fiber" and along_normal < 1.0)
        lambert = layer.type == "hg" or (layer.type == "fiber" and along_normal > 0.0)
        if glossy and layer.thickness < model.OPAQUE_THICKNESS:
            used.add("mirror-G")
        if layer.type == "surface" and along_normal < 1.0:
            used.add("tilted-flakes")
        if layer.type == "fiber" and 0.0 < along_normal < 1.0:
            used.add("tilted-fiber")
        if layer.type == "fiber" and along_normal > 0.0:
            used.add("fiber-along-normal")
        if layer.type == "fiber" and along_normal < 1.0 and translucent:
            used.add("fiber-transmission-share")
        if layer.type == "hg":
            used.add("lambert-hg")
        if lambert:
            used |= {"diffusivity-exit", "scattering-share"}
        if layer.has_fresnel:
            used.add("schlick-at-view")
    if translucent:
        used |= {"translucent-lobe", "diffusivity-exit", "scattering-share"}
    if p.substrate is not None:
        used.add("substrate-attenuation")
        if p.substrate.type == "conductor":
            used.add("conductor-f0-blender-4.2")
        if p.substrate.type == "dielectric":
            used.add("dielectric-substrate-adjoint")
    if len(p.layers) > 1:
        used.add("mirror-attenuation")
    if p.multiple_scattering:
        used |= {"ms-energy", "ms-weights-at-normal", "lambert-hg", "diffusivity-exit", "scattering-share"}
        if any(layer.type == "fiber" for layer in p.layers):
            used.add("ms-merged-fiber-lobe")
        from ..bake.spongecake import scales_forward_by_area

        if any(layer.is_flake for layer in p.layers) and scales_forward_by_area(len(p.layers)):
            used.add("ms-forward-area")
    return [name for name in APPROXIMATIONS if name in used]


def principled_settings(p: model.Params) -> dict:
    """Principled BSDF inputs (by socket name) with about as many lobes as the stack: specular + coat for more
    than one layer, sheen for fibers, transmission when it transmits (the render-time baseline of the benchmarks
    and the demo)."""
    out = {"Roughness": 0.5}
    if len(p.layers) > 1:
        out["Coat Weight"] = 1.0
    if any(layer.type == "fiber" for layer in p.layers):
        out["Sheen Weight"] = 1.0
    if p.transmits:
        out["Transmission Weight"] = 0.5
    return out


@dataclass(frozen=True)
class Socket:
    name: str  # node-group socket name; OSL parameter name is its identifier form
    kind: str  # "float" | "color" | "vector"
    param: Param
    layer: int | None  # 0-based layer index, None for the substrate (or the MS weights)
    group: str = ""  # interface panel; the layer's or the substrate's when empty
    baked: bool = False  # written by Lamina's bake (network prediction), not a model parameter

    @property
    def per_texel(self) -> bool:
        """Baked per texel by a texture-driven bake: every baked input but the energy scale (the material's own)."""
        return self.baked and self.param.texturable

    @property
    def panel(self) -> str:
        if self.group:
            return self.group
        return "Substrate" if self.layer is None else f"Layer {self.layer + 1}"


def structure_key(p: model.Params) -> tuple:
    """What decides the shape of the generated shader (parameter values are inputs, not structure)."""
    return (
        tuple((layer.type, layer.has_fresnel) for layer in p.layers),
        None if p.substrate is None else p.substrate.type,
        p.delta_transmission,
        p.multiple_scattering,
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
            out.append(Socket(f"L{k + 1} {_label(layer, prm)}", prm.kind, prm, k))
    if p.substrate is not None:
        out += substrate_sockets(p.substrate)
    if p.multiple_scattering:
        out += _ms_sockets(p)
    return out


def substrate_sockets(s: model.Substrate) -> list[Socket]:
    return [Socket(f"Substrate {prm.label}", prm.kind, prm, None) for prm in model.SUBSTRATE[s.type]]


def _label(layer: model.Layer, prm: Param) -> str:
    return "Mean Cosine g" if (prm.name == "roughness" and not layer.is_flake) else prm.label


MS_PREFIX = "MS "
MS_PANEL = "Multiple Scattering"
MS_WEIGHTS = (
    Param("reflection", "Reflection", "color", (0.0, 0.0, 0.0), 0.0, None, texturable=True,
          description="Baked weight W2r (RGB) of the Lambertian multiple-scattering lobe on the light's side"),
    Param("transmission", "Transmission", "color", (0.0, 0.0, 0.0), 0.0, None, texturable=True,
          description="Baked weight W2t (RGB) of the Lambertian multiple-scattering lobe on the far side"),
    # the forward lobe (one hg layer, ``bake.spongecake``), mapped like an hg layer; in ``decode``'s column order
    Param("forward_g", "Forward Mean Cosine g", "float", 0.0, -1.0, 1.0, texturable=True,
          description="Baked mean cosine g of the forward multiple-scattering lobe"),
    Param("forward_albedo", "Forward Albedo", "color", (0.0, 0.0, 0.0), 0.0, None, texturable=True,
          description="Baked albedo (its weight, RGB) of the forward multiple-scattering lobe"),
    Param("forward_thickness", "Forward Thickness", "float", 1.0, 0.0, None, texturable=True,
          description="Baked optical thickness of the forward multiple-scattering lobe"),
)
MS_FORWARD = MS_PREFIX + "Forward "  # the forward lobe's inputs, named as an hg layer's (``_layer_terms``)


def _ms_sockets(p: model.Params) -> list[Socket]:
    """Baked by Lamina (addon/bake): the extra lobe's layer parameters (W1 folded into the albedo), the Lambert
    weights (reflection only over a substrate) and the forward lobe. Every one can be driven by a baked texture."""
    out = []
    for k, layer in enumerate(p.layers):
        for prm in _layer_params(layer):
            baked = replace(prm, max=None if prm.name == "albedo" else prm.max, texturable=True,
                            description="Baked multiple-scattering lobe: " + prm.description)
            out.append(Socket(f"{MS_PREFIX}L{k + 1} {_label(layer, prm)}", prm.kind, baked, k, MS_PANEL, True))
    weights = [prm for prm in MS_WEIGHTS if p.substrate is None or prm.name != "transmission"]
    out += [Socket(MS_PREFIX + prm.label, prm.kind, prm, None, MS_PANEL, True) for prm in weights]
    return out + [Socket(MS_ENERGY_INPUT, MS_ENERGY.kind, MS_ENERGY, None, MS_PANEL, True)]


# The energy budget (``bake.spongecake.energy_budget``) at the view: fed from a table over the view (``view_inputs``),
# per material, or over the view and a texture-driven input's value (``TexelEnergy``).
MS_ENERGY = Param("energy", "Energy", "color", (2.0, 2.0, 2.0), 0.0, None,
                  description="Baked energy budget at the view, fed from Lamina's view table (unlinked: its "
                              "least value): the multiple-scattering closures take what exceeds 1 (keeping them "
                              "within what single scattering leaves); below 1 it scales single scattering down")
MS_ENERGY_INPUT = MS_PREFIX + MS_ENERGY.label


def input_values(p: model.Params) -> dict:
    """Socket name → value of the model parameters (the baked inputs: ``baked_values``)."""
    values = {}
    for s in sockets(p):
        if s.baked:
            continue
        source = p.substrate if s.layer is None else p.layers[s.layer]
        values[s.name] = getattr(source, s.param.name)
    return values


def baked_values(p: model.Params, form: str) -> dict:
    """Socket name → value of the baked inputs of ``form``'s shader: with multiple scattering, the network's
    prediction as constants and the form's own energy budget (``ms_values``)."""
    return ms_values(p, form) if p.multiple_scattering else {}


def with_values(p: model.Params, values: dict) -> model.Params:
    """``p`` with the model parameters read from the shader's inputs (socket name → value)."""
    data = p.to_dict()
    for s in sockets(p):
        if not s.baked:
            target = data["substrate"] if s.layer is None else data["layers"][s.layer]
            target[s.param.name] = values[s.name]
    return model.params_from_dict(data)


def ms_values(p: model.Params, form: str) -> dict:
    """The ``MS`` socket values of ``form``'s shader: the network's prediction for light from above
    (addon.bake.spongecake) and the energy budget that keeps the form from returning more light than it receives
    (``energy_values``). Cached per stack, form and weights folder."""
    from ..bake import spongecake as bake

    return dict(_ms_values(p, form, str(bake.WEIGHTS)))


@lru_cache(maxsize=64)
def _ms_values(p: model.Params, form: str, weights: str) -> dict:
    return {**lobe_values(p), **energy_values(p, form)}


def lobe_values(p: model.Params) -> dict:
    """The network's lobes as ``MS`` socket values: every baked input but the energy budget, i.e. what a texture
    bake gives each texel (addon.bake.textures). The forward lobe's albedo carries its area scale (a network with
    the area exponents) for both directions along the normal, as the other multiple-scattering weights are taken
    at the normal view (``bake.spongecake.cycles_weights``). [approx: ms-forward-area]"""
    from ..bake.layer_rows import stack_rows
    from ..bake.spongecake import normal_area_scale, predict

    pred = predict(p)
    forward = pred.forward.layers[0]
    area = normal_area_scale(stack_rows(p)[None], np.asarray(pred.forward_area)[None])[0]
    weights = {"reflection": pred.reflection, "transmission": pred.transmission, "forward_g": forward.roughness,
               "forward_albedo": tuple(area * np.asarray(forward.albedo)), "forward_thickness": forward.thickness}
    values = {}
    for s in _ms_sockets(p):
        if s.param is MS_ENERGY:
            continue
        if s.layer is None:
            values[s.name] = weights[s.param.name]
        else:
            values[s.name] = getattr(pred.lobe.layers[s.layer], s.param.name)
    return values


# The albedos behind the energy budget: GGX reflection by its own quadrature (flakes may be near-mirrors), the other
# closures on a direction grid a quarter of the default.
ENERGY_QUADRATURE = (32, 64)
# The budget behind the view tables' rows is computed this many times finer along their coordinate (asin(√μ); and the
# azimuth where the stack is oriented) (``bake.spongecake.budget_rows``), so that it is safe between them too.
VIEW_BUDGET_SUBSTEPS = (2, 2)


def energy_values(p: model.Params, form: str) -> dict:
    """The ``MS Energy`` input's own value, what the shader uses where the input is unlinked: the least budget of
    ``view_inputs``' table over the views, so that the material gains energy at no view without its table."""
    return {MS_ENERGY_INPUT: tuple(float(v) for v in budget_table(p, form).values.min(axis=(0, 1)))}


def view_inputs(p: model.Params, form: str, texels: "TexelEnergy | None" = None) -> dict:
    """Inputs that the material feeds from a table over the view (socket name → ``view_table.ViewTable``): with
    multiple scattering, ``MS Energy`` from ``budget_table`` (following the texels as ``texels`` says)."""
    return {MS_ENERGY_INPUT: budget_table(p, form, texels)} if p.multiple_scattering else {}


@dataclass(frozen=True)
class TexelEnergy:
    """How the energy budget of a material whose layer inputs are driven by textures follows its texels (decided by
    its texture bake: ``texel_energy``). With an ``axis`` (one layer input of an isotropic stack driven), the
    budget table has a column per tabulated value of that input and is looked up at the texel's value; with one layer
    albedo driven, at greys, each channel looked up at its own value (a channel's budget follows its own albedo, all
    but the lobe network's coupling of the channels: docs/accuracy.md measures it). Without one (several inputs
    driven, an orientation, or an oriented stack, whose table already spends its columns on the azimuth), no table
    follows the texels: the budget leaves out the energy fraction (``bake.spongecake.
    energy_grid``), so that each texel keeps the energy its own baked lobes carry, as the network predicts it."""
    axis: object = None  # a ``view_table.Axis``, or None

    def note(self) -> str:
        """What the panel says about it."""
        if self.axis is None:
            return "Energy: one table for all texels (each keeps its lobes' own energy)"
        return f"Energy follows {self.axis.socket}'s texture ({len(self.axis.values)} values)"

    def to_json(self):
        return {"axis": self.axis and self.axis.to_json()}

    @classmethod
    def from_json(cls, data) -> "TexelEnergy":
        from .view_table import Axis

        return cls(data["axis"] and Axis.from_json(data["axis"]))


# A texture-driven input's budget is tabulated at this many of its values, computed ``DRIVEN_ENERGY_SUBSTEPS`` times
# finer (``bake.spongecake.driven_budget_rows``): a thickness-driven flake layer's multiple-scattering scale
# interpolated between 9 values was within 2.8% of the exact one, between 5 within 11% (docs/training.md, *What the
# ratio per texel needs*); docs/accuracy.md, *Texture-driven stacks*, measures the shipped tables.
DRIVEN_ENERGY_VALUES = 9
DRIVEN_ENERGY_SUBSTEPS = 2
# Thickness and flake roughness are tabulated uniformly in log(value + this), an albedo in log(1 + this − albedo), an
# hg layer's g (its roughness input) uniformly in the value.
DRIVEN_ENERGY_OFFSET = 0.01


def texel_energy(p: model.Params, ranges: dict) -> TexelEnergy | None:
    """How the budget of ``p`` follows its texels (``TexelEnergy``), from the least and greatest value of each driven
    layer input (``ranges``: (layer index, parameter name) → (least, greatest) over the texels (and channels),
    clamped to the parameter's range, or None for a direction: ``bake.textures.input_ranges``); None where no texture
    drives a layer."""
    from .view_table import Axis

    if not ranges:
        return None
    (layer, name), span = next(iter(ranges.items()))
    if len(ranges) > 1 or span is None or model.anisotropic(p):
        return TexelEnergy()
    socket = next(s.name for s in sockets(p) if s.layer == layer and s.param.name == name and not s.baked)
    if name == "albedo":  # uniform in log(1 + offset − albedo): dense near white, where multiple scattering grows
        return TexelEnergy(Axis.spaced(socket, *span, DRIVEN_ENERGY_VALUES, 1.0 + DRIVEN_ENERGY_OFFSET, -1.0, True))
    offset = None if name == "roughness" and p.layers[layer].type == "hg" else DRIVEN_ENERGY_OFFSET
    return TexelEnergy(Axis.spaced(socket, *span, DRIVEN_ENERGY_VALUES, offset))


def budget_table(p: model.Params, form: str, texels: TexelEnergy | None = None):
    """The energy budget (``bake.spongecake.energy_budget``: 1 + the reference's energy scale, ``reference.
    spongecake.energy_tables``) computed on what ``form`` renders (its numpy prediction): what the form's single
    scattering and Dirac leave, over the albedo of its multiple-scattering closures, so that the rendered furnace
    stays at most 1 (and is 1 less ``ENERGY_MARGIN`` for a white isotropic stack at the rows) whatever the
    single-scattering mapping's error, even where that single scattering alone exceeds 1. A ``view_table.ViewTable``
    on ``model.view_energy_grid``: over the view's angle, and its azimuth where a layer is oriented off the normal (a
    budget per view cosine, the least over the azimuths, would leave the multiple scattering short by up to 70% at
    other azimuths: docs/training.md). A texture-driven material's table follows its texels as ``texels`` says
    (``TexelEnergy``; the driven input's own value in ``p`` does not count then). Cached per stack, form, weights
    folder and ``texels``."""
    from ..bake import spongecake as bake

    if texels is not None and texels.axis is not None:
        p = with_values(p, {**input_values(p), texels.axis.socket: texels.axis.value(texels.axis.values[0])})
    return _budget_table(p, form, str(bake.WEIGHTS), texels)


@lru_cache(maxsize=64)
def _budget_table(p: model.Params, form: str, weights: str, texels: TexelEnergy | None):
    from ..bake.spongecake import budget_rows, driven_budget_rows
    from .view_table import ViewTable

    rows, azimuths = model.view_energy_grid(p)
    left_of, lobes_of = partial(_left, form=form), partial(ms_closure_albedo, form=form)
    axis = texels and texels.axis
    if axis:
        stacks = [with_values(p, {**input_values(p), axis.socket: axis.value(v)})
                  for v in axis.finer(DRIVEN_ENERGY_SUBSTEPS)]
        table = driven_budget_rows(stacks, left_of, lobes_of, rows, VIEW_BUDGET_SUBSTEPS[0], DRIVEN_ENERGY_SUBSTEPS)
        return ViewTable(table, model.view_table_lowest(), axis)
    substeps = VIEW_BUDGET_SUBSTEPS if azimuths > 1 else VIEW_BUDGET_SUBSTEPS[:1]
    table = budget_rows(p, left_of, lobes_of, rows, model.uniform_azimuths(azimuths), *substeps,
                        fraction=texels is None)
    return ViewTable(table, model.view_table_lowest())


def ms_share(p: model.Params, form: str) -> float:
    """The multiple-scattering closures' share of the energy ``form`` sends back and through for light along the
    normal (white furnace, mean over RGB; the Dirac counted as the material has it), from the numpy prediction."""
    normal = np.array([[0.0, 0.0, 1.0]])
    ss = _part_furnace(p, normal, form, single=True)
    budget = budget_table(p, form).values[-1, 0]  # the last row: μ = 1
    ms = ms_closure_albedo(p, normal, form) * np.maximum(budget - 1.0, 0.0)
    total = float(np.mean(ss + ms))
    return float(np.mean(ms)) / total if total > 0.0 else 0.0


def _left(p: model.Params, wo, form: str):
    """1 − the form's single-scattering furnace with the Dirac (rendered or not: its share is not left to MS)."""
    return 1.0 - _part_furnace(replace(p, delta_transmission=True), wo, form, single=True)


def ms_closure_albedo(p: model.Params, wo, form: str):
    """Albedo (N, 3) towards ``wo`` of the form's multiple-scattering closures before the energy scale (the E of
    ``bake.spongecake.energy_scale``)."""
    return _part_furnace(p, wo, form, single=False)


def _part_furnace(p: model.Params, wo, form: str, single: bool):
    """The white furnace (N, 3) of ``form``'s single-scattering closures with the budget's share min(e, 1) = 1
    (``single``), or of its multiple-scattering closures with max(e − 1, 0) = 1: the form's furnace is linear in
    those two (``_scattering``). ``p`` is shaded with multiple scattering whether or not it has it (the budget's
    white stack, ``model.white``, has not)."""
    p = replace(p, multiple_scattering=True)
    values = {**input_values(p), **lobe_values(p)}
    scales = (1.0, None) if single else (None, 1.0)

    def shaded(w):
        b = NumpyBackend(w, values, form)
        _scattering(b, p, b.cos_view(), *scales)
        return b

    return closure_furnace(shaded, wo, ENERGY_QUADRATURE, SHARP_ALBEDO)


def shade(b, p: model.Params) -> None:
    """Build the closure mix for the stack structure of ``p`` on backend ``b`` (see module docstring)."""
    mu = b.cos_view()
    if not p.multiple_scattering:
        _single_scattering(b, p, mu)
        return
    budget = b.input(MS_ENERGY_INPUT, "color")  # scales single scattering below 1, multiple scattering above
    _scattering(b, p, mu, b.minimum(budget, (1.0, 1.0, 1.0)), b.maximum(budget - 1.0, (0.0, 0.0, 0.0)))


def _scattering(b, p: model.Params, mu, single_scale, multiple_scale) -> None:
    """Single and multiple scattering, the colours of their closures times ``single_scale`` and ``multiple_scale``
    (None: that part's closures are not made). In the node group each fiber layer's GGX lobe and the network's lobe
    for it are one closure (``_FiberLobes``)."""
    single, multiple = _EnergyScaled(b, single_scale), _EnergyScaled(b, multiple_scale)
    fibers = any(layer.type == "fiber" for layer in p.layers)
    lobes = _FiberLobes(b, p, single, multiple) if b.form == "nodes" and fibers else None
    _single_scattering(lobes.single if lobes else single, p, mu)
    _multiple_scattering(lobes.multiple if lobes else multiple, p)
    if lobes:
        lobes.merge()
    single.flush()
    multiple.flush()


def _single_scattering(b, p: model.Params, mu) -> None:
    """The layers' closures, the substrate's and the Dirac transmission's."""
    terms = _layers(b, p, mu, "")
    stack = _prod(*[t["tau"] for t in terms])
    if p.substrate is not None:
        exit_ = stack if p.substrate.type != "diffuse" else _prod(*[t["tau_exit"] for t in terms])
        shade_substrate(b, p.substrate, stack * exit_)
    if p.delta_transmission and p.substrate is None:  # every substrate blocks or refracts it (reference)
        b.transparent(b.scale((1.0, 1.0, 1.0), stack))


def _layers(b, p: model.Params, mu, prefix: str, along_normal: bool = False, names=None) -> list[dict]:
    """Each layer's closures (inputs named ``prefix + "L<k> ..."``, or ``names[k] + "..."``); returns the per-layer
    terms. ``along_normal``: the closures' weights for the view along the normal (``_layer_terms``), whatever the
    view."""
    names = names or [prefix + f"L{k + 1} " for k in range(len(p.layers))]
    terms = [_layer_terms(b, name, layer, mu, along_normal) for name, layer in zip(names, p.layers)]
    taus = [t["tau"] for t in terms]
    for k, (layer, t) in enumerate(zip(p.layers, terms)):
        above = _prod(*taus[:k]) if k else None
        below = _prod(*[u["tau_exit"] for u in terms[k + 1:]]) if k + 1 < len(terms) else None
        reflected = _prod(0.5 * (1.0 - t["tau"] * t["tau"]), above, above)  # Eq. 12 at Λi = Λo, Sec. 4.3
        transmitted = b.scale(t["albedo"], _prod(t["p_down"] * t["path"] * _slab_transmission(b, t), above, below))
        if layer.is_flake:
            b.glossy(b.scale(t["albedo"], _prod(t.get("glossy_share"), reflected)), t["alpha_x"], t["alpha_y"],
                     t["normal"], t.get("tangent"), t.get("f0"))
            if "f0" in t:
                transmitted = schlick(b, transmitted, t["f0"], t["cos_normal"])
        if "diffuse_share" in t:
            diffuse = t["diffuse_share"] * t["path"] * _slab_reflection(b, t)
            b.diffuse(b.scale(t["albedo"], _prod(diffuse, above, above)))
        if p.substrate is None:  # a substrate closes the stack (reference convention)
            b.translucent(transmitted)
    return terms


def _multiple_scattering(b, p: model.Params) -> None:
    """Sec. 5: the network's extra single-scattering lobe (its parameters baked into the ``MS`` inputs, W1 in
    the albedo), mapped like the layers themselves but with the closure weights of the view along the normal,
    plus the Lambert lobes W2r / π and W2t / π (exact). ``shade`` passes a backend that scales these closures by
    the per-view energy scale (``_EnergyScaled``, the budget less 1), which restores the lobe's energy at each view: the weights'
    split between the closures is that of normal incidence. Computed from the inputs alone, these weights are
    constants that Cycles folds when the inputs are baked values. [approx: ms-weights-at-normal]
    The forward lobe is mapped as an hg layer: its Lambert closures add to the Lambert lobes' (no closure more).
    [approx: lambert-hg]"""
    _layers(b, p, 1.0, MS_PREFIX, along_normal=True)
    forward = model.Layer("hg", 0.0, (0.0, 0.0, 0.0), 1.0, (1.0, 1.0, 1.0), (0.0, 0.0, 1.0))  # its structure only
    _layers(b, replace(p, layers=(forward,)), 1.0, "", along_normal=True, names=[MS_FORWARD])
    b.diffuse(b.input(MS_PREFIX + "Reflection", "color"))
    if p.substrate is None:
        b.translucent(b.input(MS_PREFIX + "Transmission", "color"))


class _EnergyScaled:
    """A backend that passes everything to ``b`` but multiplies the colour of each closure by ``scale`` (None: makes
    no closure). Closures without parameters (Diffuse, Translucent, Transparent) are summed by kind and made by
    ``flush``, scaled once: the sum of the multiple-scattering colours is then a constant Cycles folds, and the view's
    scale costs one multiplication per kind, not one per closure."""

    CLOSURES = ("glossy", "diffuse", "translucent", "transparent", "conductor", "dielectric")

    def __init__(self, b, scale):
        self._b, self._scale = b, scale
        self._lamberts: dict[str, object] = {}

    def __getattr__(self, name):
        attr = getattr(self._b, name)
        if name not in self.CLOSURES:
            return attr
        if self._scale is None:
            return lambda *args, **kw: None
        if name in LAMBERT_CLOSURES:
            return lambda color: self._lamberts.update({name: _sum(self._lamberts.get(name), color)})
        return lambda color, *args, **kw: attr(self.scaled(color), *args, **kw)

    def scaled(self, color):
        """``color`` times the scale, None where there is none."""
        return None if self._scale is None else color * self._scale

    def flush(self) -> None:
        """Make the summed closures without parameters."""
        for name, color in self._lamberts.items():
            getattr(self._b, name)(self.scaled(color))
        self._lamberts.clear()


def _sum(a, b):
    """a + b, where a None stands for nothing yet."""
    return b if a is None else a + b


class _GlossyRecorder:
    """A backend that passes everything to ``b`` but records its ``glossy`` calls (what the node group's Glossy BSDF
    gets: ``NodeBackend.glossy`` applies Schlick's F at the view) instead of making them."""

    def __init__(self, b):
        self._b, self.calls = b, []

    def __getattr__(self, name):
        return getattr(self._b, name)

    def glossy(self, color, alpha_x, alpha_y, normal, tangent=None, f0=None):
        if f0 is not None:
            color = schlick_at_view(self._b, color, f0, normal)
        self.calls.append((color, alpha_x, alpha_y, normal, tangent))


class _FiberLobes:
    """Node group with multiple scattering: each fiber layer's GGX lobe and the network's lobe for that layer become
    one Glossy BSDF about the single-scattering lobe's tangent (one closure a fiber layer less to evaluate; the rest
    of the cost is the nodes evaluated per shading point, docs/training.md). Its colour is the two
    colours' sum, each times its share of the energy budget (``single`` and ``multiple``: ``_EnergyScaled``); its
    α_x mixes theirs harmonically by the network lobe's share s of the colours before those scales (channel means),
    1/α_x = (1 − s)/α_x1 + s/α_x2, which keeps the weighted peak D(h = n) = 1/(π α_x α_y) of the highlight (α_y is 1
    for both, ``_fiber_lobe``). The mix does not depend on the budget, so the node group's furnace stays linear in
    its two shares and the budget is computed on it (``_part_furnace``). Surface-flake layers keep two closures: a
    merged isotropic lobe lost the shape of sharp ones (docs/training.md, *Tried and reverted*).
    [approx: ms-merged-fiber-lobe]"""

    def __init__(self, b, p: model.Params, single, multiple):
        self._b, self._scaled = b, (single, multiple)
        self._fibers = [layer.type == "fiber" for layer in p.layers if layer.is_flake]
        self.single, self.multiple = _GlossyRecorder(single), _GlossyRecorder(multiple)

    def merge(self) -> None:
        b, (single, multiple) = self._b, self._scaled
        pairs = zip(self._fibers, self.single.calls, self.multiple.calls, strict=True)
        for fiber, (c1, *lobe1), (c2, *lobe2) in pairs:
            colors = single.scaled(c1), multiple.scaled(c2)
            if fiber:
                present = [c for c in colors if c is not None]
                lobes = [(present[0] if len(present) == 1 else present[0] + present[1],
                          *_merged_fiber_lobe(b, c1, c2, lobe1, lobe2))]
            else:  # the two lobes as they are
                lobes = [(colors[0], *lobe1), (colors[1], *lobe2)]
            for color, *lobe in lobes:
                if color is not None:
                    b.glossy(color, *lobe)


def _merged_fiber_lobe(b, c1, c2, lobe1, lobe2) -> tuple:
    """(α_x, α_y, normal, tangent) of the one lobe for two fiber lobes of colours c1, c2 (``_FiberLobes``)."""
    (ax1, ay1, normal, tangent), (ax2, *_) = lobe1, lobe2
    w2 = b.channel_mean(c2)
    share = w2 / b.maximum(b.channel_mean(c1) + w2, 1e-12)
    inverse = 1.0 / b.maximum(ax1, 1e-8)
    return 1.0 / b.multiply_add(share, 1.0 / b.maximum(ax2, 1e-8) - inverse, inverse), ay1, normal, tangent


def _slab_transmission(b, t):
    """Eq. 14's G / Tρ for light leaving the far side at cos θ = 1/2, a = 2 Tρ σ(60°) (the diffusivity
    approximation of radiative transfer): (e^{−x} − e^{−a}) / (a − x), → e^{−x} as x → a.
    [approx: diffusivity-exit]"""
    a, x = t["x_exit"], t["x"]
    d = a - x
    near = b.step_below(b.abs(d), 1e-4)
    exact = (b.exp(-x) - b.exp(-a)) / (d + near)  # the + near keeps the unused branch finite
    return exact * (1.0 - near) + b.exp(-x) * near


def _slab_reflection(b, t):
    """Eq. 12's G / Tρ for light leaving the near side at cos θ = 1/2: (1 − e^{−(x + a)}) / (x + a)."""
    s = t["x"] + t["x_exit"]
    return (1.0 - b.exp(-s)) / b.maximum(s, 1e-12)


def _layer_terms(b, name: str, layer: model.Layer, mu, along_normal: bool = False) -> dict:
    """A layer's closure terms seen at the view (cosine ``mu``), or, ``along_normal``, at the view along the
    normal (mu = 1) from the tangent-space inputs alone."""
    rough = b.input(name + ("Roughness" if layer.is_flake else "Mean Cosine g"), "float")
    t = {"albedo": b.input(name + "Albedo", "color")}
    thickness = b.input(name + "Thickness", "float")
    sigma = sigma_60 = 1.0
    if layer.is_flake:
        local = b.input(name + "Orientation", "vector")
        direction = b.direction(local)
        if layer.type == "surface":  # S is the same for ±n (two-sided flakes): the closure normal points up
            direction = b.upper_hemisphere(direction)
        if along_normal:  # c = c_n = the orientation's normalised z (|z| for the flipped-up flake normal)
            z = b.channel(local, 2) / b.sqrt(b.maximum(b.dot(local, local), 1e-24))
            c = c_n = b.abs(z) if layer.type == "surface" else z
        else:
            c, c_n = b.dot_view(direction), b.dot(direction, b.normal())
        a2 = rough * rough
        # σ(ω) = sqrt(ωᵀ S ω) for S of Sec. 3.3 rotated to the orientation (research notes §1)
        if layer.type == "surface":
            sigma, sigma2_n, trace = b.sqrt(a2 + (1.0 - a2) * c * c), a2 + (1.0 - a2) * c_n * c_n, 1.0 + 2.0 * a2
            t.update(alpha_x=rough, alpha_y=rough, normal=direction, cos_normal=c)
        else:
            sigma, sigma2_n, trace = b.sqrt(1.0 + (a2 - 1.0) * c * c), 1.0 + (a2 - 1.0) * c_n * c_n, 2.0 + a2
            t.update(_fiber_lobe(b, rough, c_n, direction), cos_normal=mu)
        # σ at 60° from n, mean over azimuth: σ² = sin²60 (tr S − S_nn)/2 + cos²60 S_nn
        sigma_60 = b.sqrt(0.375 * (trace - sigma2_n) + 0.25 * sigma2_n)
        if layer.has_fresnel:
            t["f0"] = b.input(name + "F0", "color")
        if layer.type == "surface":  # light along n leaves downwards off flakes tilted beyond 45°: P = α²/(1+α²)
            t["p_down"] = a2 / (1.0 + a2)
    else:
        t["p_down"] = 1.0 - _hg_back_share(b, rough)
        t["diffuse_share"] = 1.0 - t["p_down"]
    t["x"] = thickness * sigma / mu  # optical depth along ωo
    t["x_exit"] = 2.0 * thickness * sigma_60  # optical depth at cos θ = 1/2
    # Single-scattering path factor: Tρ σ(ωo) P_down(ωo) / cos θo ≈ x for fibers and media (P_down taken from
    # normal incidence); for surface flakes σ(ωo) P_down(ωo) is nearly view-independent (∫ D(h) dωi, measured),
    # so Tρ / cos θo. [approx: scattering-share]
    t["path"] = thickness / mu if layer.type == "surface" else t["x"]
    t["tau"] = b.exp(-t["x"])
    t["tau_exit"] = b.exp(-t["x_exit"])
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
    (α_t, α_b) = (α, 1) and Λ_sggx = 1 + 2Λ_smith — exact, like surface flakes. Fibers along n have the
    isotropic GGX lobe of α = 1/α > 1, which Cycles clamps to 1 (measured), so they become a Lambert lobe
    carrying their backward share for light along n, α²/(1 + α²); the grazing sheen this layer shows (grazing
    light is turned back even by nearly vertical fibers) is lost [approx: fiber-along-normal]. Tilted fibers
    mix the two by the in-plane share s = 1 − (t·n)². [approx: tilted-fiber]
    Downward share for light along n: α²/(1+α²) backwards → 1/(1+α²) for fibers along n; for in-plane fibers
    1 − 1/√2 at α → 0 and 1/2 at α = 1, in between (1 − 1/√2) + (√2 − 1) α²/(1+α²) (within 0.01 of the
    sampled share). [approx: fiber-transmission-share]"""
    s = 1.0 - c_n * c_n
    a2 = alpha * alpha
    back_along_n = a2 / (1.0 + a2)
    down_in_plane = (1.0 - 0.5 ** 0.5) + (2.0 ** 0.5 - 1.0) * back_along_n
    return {"alpha_x": alpha, "alpha_y": 1.0, "normal": b.normal(), "tangent": b.tangent_plane(tangent),
            "glossy_share": s, "diffuse_share": (1.0 - s) * back_along_n,
            "p_down": s * down_in_plane + (1.0 - s) * (1.0 - back_along_n)}


def shade_substrate(b, s: model.Substrate, weight=1.0) -> None:
    """The substrate's closure (inputs ``substrate_sockets``) scaled by ``weight``; also a micrograin bulk."""
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
