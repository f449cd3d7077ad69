"""Micrograin porous layer → Cycles closures (both forms), written once with ``expr`` backends.

The node takes the material under the grains as a Shader input (``Bulk``), so it wraps anything. Eq. 1 mixes
the grains' BRDF f_S and the bulk's f_B with the weight w⁺(i, o) of Eq. 24, whose complement factorises as
1 − w⁺ = g(θi) g(θo), g = sqrt(1 − τβ) (research notes §3). A closure weight cannot depend on the light, so
g(θi) is taken at the mirror configuration θi = θo: the bulk gets 1 − τβ(θo) and the grains τβ(θo), exact at
the specular configuration (docs/accuracy.md compares it with the hemispherical mean). [approx: view-only-weight]
The bulk's transmission (glass) gets that weight too, where the reference has g(θo) ḡ (ḡ the hemispherical mean
of g). [approx: bulk-transmission-weight] Seen from below the surface (the inner side of a glass's far face,
where Cycles flips the normal towards the viewer) the layer is its bulk, as in the reference.

The grains' specular lobe is Cycles' GGX with the equivalent roughness α̃ of Eq. 18, whose D equals the
micrograin D (Eq. 17) at h = n, i.e. at every mirror configuration. [approx: grains-as-ggx] With the
series GAF (Eq. 25) the lobe is scaled by G_micrograin / G_GGX(α̃) at the mirror configuration,
(1 + 2Λ_GGX) / (1 + 2Λ), with Λ evaluated in float32 without cancellation (``_micrograin_lambda``).
[approx: gaf-at-mirror] The specular Fresnel is exact per microfacet: a conductor closure, with k = 0 for
dielectric grains (the complex Fresnel then equals the dielectric one). So over a reflecting bulk, diffuse and
conductor grains are exact at every mirror configuration (Blender 5.0; 4.2's node group and conductor Fresnel
are approximate). The diffuse part of dielectric grains is weighted by T̄(i, o) = t(θi) t(θo) taken at the
mirror configuration, t = 1 − E_spec, with the specular lobe's albedo E_spec fitted (``ALBEDO_FIT``) where the
reference tabulates it. [approx: grain-transmittance-fit]
"""
from __future__ import annotations

from dataclasses import replace

from ..models import micrograin as model
from ..models.params import Param
from ..reference.micrograin import lambda_scheme
from .expr import BULK_INPUT, fresnel_dielectric
from .spongecake import Socket


def _one(**kw) -> dict:
    grain = kw.pop("grain", {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]})
    return {"filling_factor": 0.5, "anfractuosity": 0.5, "grain": grain,
            "bulk": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}, **kw}


APPROXIMATIONS = {
    "view-only-weight": ("w⁺(i, o) taken at the mirror configuration θi = θo (τβ of the view only)",
                         _one(filling_factor=0.5, anfractuosity=1.0)),
    "bulk-transmission-weight": ("the bulk's transmission weighted g(θo)² = 1 − τβ(θo) instead of g(θo) ḡ",
                                 _one(filling_factor=0.3, bulk={"type": "dielectric", "roughness": 0.1,
                                                                "ior": 1.5},
                                      grain={"type": "conductor", "ior": [1.5] * 3, "k": [0.0] * 3})),
    "grains-as-ggx": ("micrograin D (Eq. 17) rendered as GGX with the equivalent roughness (Eq. 18)",
                      _one(filling_factor=0.9, anfractuosity=0.5, gaf="ggx",
                           grain={"type": "conductor", "ior": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.1]},
                           bulk={"type": "diffuse", "albedo": [0.0, 0.0, 0.0]})),
    "gaf-at-mirror": ("the micrograin G (Eq. 25) applied as the ratio to GGX's at the mirror configuration",
                      _one(filling_factor=0.9, anfractuosity=0.5,
                           grain={"type": "conductor", "ior": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.1]},
                           bulk={"type": "diffuse", "albedo": [0.0, 0.0, 0.0]})),
    "grain-transmittance-fit": ("dielectric grains' diffuse part under t(θo)², t = 1 − E_spec by a fit, not "
                                "(1 − E_spec(θi))(1 − E_spec(θo)) tabulated",
                                   _one(filling_factor=0.98, anfractuosity=1.0,
                                        grain={"type": "dielectric", "albedo": [0.8] * 3, "ior": 1.5},
                                        bulk={"type": "diffuse", "albedo": [0.0, 0.0, 0.0]})),
}


def cheaper_variants(p: model.Params) -> list[tuple[str, model.Params]]:
    """What Fit to budget may build instead (``budget``): GGX's geometric term instead of the grains' series."""
    return [("GGX geometric term", replace(p, gaf="ggx"))] if p.gaf == "series" else []


def approximations_used(p: model.Params) -> list[str]:
    """The names of the ``APPROXIMATIONS`` the mapping makes for ``p``, in that table's order (none without
    grains; the bulk's own mapping has its own)."""
    if p.filling_factor <= 0.0:
        return []
    used = {"view-only-weight"}
    if p.transmits:
        used.add("bulk-transmission-weight")
    if p.grain.type != "diffuse":
        used.add("grains-as-ggx")
        if p.gaf == "series":
            used.add("gaf-at-mirror")
    if p.grain.type == "dielectric":
        used.add("grain-transmittance-fit")
    return [name for name in APPROXIMATIONS if name in used]


# A Principled BSDF's roughness standing for grains over a bulk (the render-time baseline; the benchmark also
# plugs it into the layer's Bulk input).
PRINCIPLED_ROUGHNESS = 0.4


def principled_settings(p: model.Params) -> dict:
    """Principled BSDF inputs (by socket name) of about the porous layer's lobe count: one diffuse and one
    specular lobe (the render-time baseline of the benchmarks and the demo)."""
    return {"Roughness": PRINCIPLED_ROUGHNESS}


GRAINS_PANEL = "Grains"
BULK_PARAM = Param("bulk", "Bulk", "shader", None,
                   description="The material under the grains (any shader: Principled, a Lamina material, ...)")


def structure_key(p: model.Params) -> tuple:
    return p.grain.type, p.gaf


def sockets(p: model.Params) -> list[Socket]:
    """The Bulk shader input, then the layer's and the grains' parameters, from the model declaration."""
    out = [Socket(BULK_INPUT, "shader", BULK_PARAM, None, GRAINS_PANEL)]
    out += [Socket(prm.label, prm.kind, prm, None, GRAINS_PANEL) for prm in model.LAYER + model.GRAIN[p.grain.type]]
    return out


def _target(p: model.Params, s: Socket):
    return p.grain if s.param in model.GRAIN[p.grain.type] else p


def input_values(p: model.Params) -> dict:
    return {s.name: getattr(_target(p, s), s.param.name) for s in sockets(p) if s.kind != "shader"}


def with_values(p: model.Params, values: dict) -> model.Params:
    data = p.to_dict()
    for s in sockets(p):
        if s.kind != "shader":
            target = data["grain"] if _target(p, s) is p.grain else data
            target[s.param.name] = values[s.name]
    return model.params_from_dict(data)


def bulk_shader(p: model.Params) -> tuple[str, object] | None:
    """The mapping id and parameters of what renders the reference bulk; None for a wrapped shader."""
    if p.bulk.type == model.WRAPPED:
        return None
    return ("bulk" if p.bulk.type in model.SIMPLE_BULKS else p.bulk.type), p.bulk.params


def numpy_bulk(p: model.Params, form: str):
    """``wo -> NumpyBackend`` holding what the bulk renders as (the Cycles form of a reference bulk)."""
    from . import _backend

    shader = bulk_shader(p)
    if shader is None:
        raise ValueError(model.reference_refusal(p))
    return lambda wo: _backend(*shader, form, wo)


def shade(b, p: model.Params) -> None:
    """Build the closure mix on backend ``b`` (see the module docstring)."""
    mu = b.cos_view()
    tau0 = b.minimum(b.maximum(b.input("Filling Factor", "float"), 0.0), model.MAX_FILLING)
    beta = b.minimum(b.maximum(b.input("Anfractuosity", "float"), model.MIN_ANFRACTUOSITY), 1.0)
    log_pores = b.log(1.0 - tau0)  # −P = ln(1 − τ0) (Eq. 13)
    pores = b.exp(log_pores * b.sqrt(mu * mu + beta * beta * (1.0 - mu * mu)) / mu)  # 1 − τβ(θo) (Eq. 21)
    grains = (1.0 - pores) * (1.0 - b.backfacing())  # seen from inside (a glass's far face), no grains
    b.bulk(1.0 - grains)
    alpha = beta * _roughness_factor(b, tau0, log_pores)
    if p.grain.type == "diffuse":
        b.diffuse(b.scale(b.input("Grain Albedo", "color"), grains))
        return
    specular = grains if p.gaf == "ggx" else grains * _gaf_ratio(b, mu, tau0, beta, alpha)
    if p.grain.type == "conductor":
        b.conductor(b.scale((1.0, 1.0, 1.0), specular), alpha, b.input("Grain IOR", "color"),
                    b.input("Grain Extinction", "color"))
        return
    ior = b.input("Grain IOR", "float")
    b.conductor(b.scale((1.0, 1.0, 1.0), specular), alpha, b.scale((1.0, 1.0, 1.0), ior), (0.0, 0.0, 0.0))
    t = 1.0 - specular_albedo_fit(b, mu, ior, alpha)
    b.diffuse(b.scale(b.input("Grain Albedo", "color"), grains * t * t))


def _roughness_factor(b, tau0, log_pores):
    """sqrt(−τ0 / ln(1 − τ0)) of Eq. 18; its series 1 − τ0/4 below τ0 = 1e-3 (0/0 at τ0 = 0)."""
    small = b.step_below(tau0, 1e-3)
    exact = b.sqrt(tau0 / (small - log_pores))  # + small keeps the unused branch finite
    return exact * (1.0 - small) + (1.0 - 0.25 * tau0) * small


# E_spec(μ) ≈ F(μ + (1 − μ) min(1, a α̃^q)) (1 − s α̃²): the rough lobe's Fresnel seen at a cosine pulled towards
# normal incidence, and its single-scattering loss. (a, q, s) minimise the largest error over τ0 in [0.05, 0.98],
# β in [0.1, 1], η in [1.3, 2.5], μ in [0.02, 1] (``bench_micrograin.grain_albedo_fit``: 0.074, against 0.83
# for the smooth interface's F(μ)); exact as α̃ → 0.
ALBEDO_FIT = (0.9, 0.85, 0.3)


def specular_albedo_fit(b, mu, eta, alpha):
    """The directional albedo E_spec of dielectric grains' specular lobe by the fit ``ALBEDO_FIT``."""
    a, q, s = ALBEDO_FIT
    pulled = mu + (1.0 - mu) * b.minimum(a * b.exp(q * b.log(alpha)), 1.0)
    return fresnel_dielectric(b, pulled, eta) * (1.0 - s * alpha * alpha)


def _gaf_ratio(b, mu, tau0, beta, alpha):
    """G_micrograin / G_GGX(α̃) at the mirror configuration, where the height-correlated G2 = 1 / (1 + Λi + Λo)
    (Heitz 2014, Eq. 99) is 1 / (1 + 2 Λ(θo)): (1 + 2 Λ_GGX(θo)) / (1 + 2 Λ(θo))."""
    tan2 = (1.0 - mu * mu) / (mu * mu)
    lambda_ggx = 0.5 * (b.sqrt(1.0 + alpha * alpha * tan2) - 1.0)
    return (1.0 + 2.0 * lambda_ggx) / (1.0 + 2.0 * _micrograin_lambda(b, mu, tau0, beta))


def _micrograin_lambda(b, mu, tau0, beta):
    """Λ of the micrograin NDF at cos θ = μ in float32 without cancellation (``reference.micrograin.
    smith_lambda_float32``: within 1.1e-4 of the exact Λ for θ ≤ 89°, never negative)."""
    return lambda_scheme(b, mu, tau0, beta)
