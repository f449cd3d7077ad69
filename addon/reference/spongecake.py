"""SpongeCake single scattering (Wang et al. 2022, Sec. 4): the exact float64 reference.

Conventions (local frame, z = macro normal; ``wi`` points to the light, ``wo`` to the viewer; f has no cosine):

* ``params.layers[0]`` is the top layer. Each layer is a slab of optical thickness T rho (Sec. 4.1); flake
  layers use the SGGX matrix of their orientation, HG layers an isotropic extinction (sigma = 1).
* Layer k's lobe is attenuated along wi and along wo by the layers between it and the side each direction
  points to: the layers above for directions above the horizon, below for directions below (Sec. 4.3). Light
  may arrive from either side when there is no substrate.
* A substrate (Sec. 4.4) closes the stack from below: then the layers contribute only when wi and wo are both
  above. Diffuse and conductor substrates are opaque (f = 0 whenever a direction is below). The dielectric
  substrate is a rough interface to a dielectric half-space: its reflection above, its transmission into the
  half-space (wo below) and back, and its internal reflection (both below), attenuated by the stack along the
  directions above. Refraction follows Walter et al. 2007 Eq. 21 as printed, without 1/eta^2 radiance scaling
  (transmitted throughput integrates to 1 - F; f(i, o) / eta_o^2 = f(o, i) / eta_i^2).
* Delta transmission is a Dirac along -wi with weight prod_k tau_k(wi), only when the flag is on and there is
  no substrate (every substrate blocks or refracts it); it is not part of ``eval`` or ``pdf``.
* With ``multiple_scattering``, ``eval`` adds the network's lobes (Sec. 5, and a forward lobe of ours, scaled by
  the layers' projected areas where the network predicts exponents for them: ``area_scale``), and
  ``sample``/``pdf`` sample them too (not in the paper, whose Sec. 4.5 samples single scattering only): the lobes of
  the prediction of wi's side by their own samplers, W2r and W2t cosine-weighted on wi's side and the other.
* Energy (``energy_tables``; not in the paper): the network's lobes are scaled per view by
  s(ωo) = min((left(ωo) − m) / E(ωo), limit), tabulated on ``ENERGY_KNOTS`` view cosines and, where a layer is
  oriented off the normal, ``ENERGY_AZIMUTHS`` view azimuths, interpolated bilinearly in √|μo| and the azimuth
  less the interpolation's error bound where the table is convex (``energy_at``). left = 1 − A_ss − T_δ is what
  single scattering and the Dirac leave (whether the Dirac is rendered or not), E the directional albedo of the
  network's lobes, m = ``ENERGY_MARGIN`` (0.3%) a margin for the noise of their estimates: single plus multiple
  scattering never return more than they receive.
  For 1 or 2 layers without a substrate the limit is q left / E: the energy network's fraction q(ωo) of what is left
  (``bake.spongecake.energy_fraction``, ``fraction_limit``; q taken to 1 for white stacks that conserve energy).
  Otherwise it is 1 (the network's energy wherever it fits in), except for stacks that conserve energy once
  white (``models.spongecake.conserving``: no Fresnel flakes, no substrate or a diffuse one), where it moves towards
  left_white / E_white, the scale that gives the white stack exactly its leftover, by the stack's whiteness
  (``bake.spongecake.whiteness_of``): a white isotropic stack returns what it receives less m at the knots. The
  scale follows the view alone, as a Cycles closure weight does, so the scaled lobes are reciprocal only where it
  is the same at both directions. [named: ms-energy]
* Sampling picks a lobe with P(first collision in layer k) = (1 - tau_k(wi)) prod_{j between} tau_j(wi), the
  substrate (or the Dirac) with prod_k tau_k(wi), renormalised (uniform over the continuous lobes when all
  vanish, where f = 0 anyway); multiple scattering's lobes take their rough share of the light returned
  (``_lobe_probabilities``). ``pdf`` is the exact density of the continuous samples; a Dirac sample has
  wo = -wi, pdf = P(delta) and weight = delta_transmittance / P(delta).
"""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from ..models.spongecake import Layer, Params, Substrate, energy_cosines, params_from_dict
from . import frames, hg, lobes, microfacet, sggx
from .frames import as_directions, dot, spherical

__all__ = ["Params", "Sample", "params_from_dict", "eval", "eval_multiple", "pdf", "sample", "delta_transmittance",
           "directional_albedo", "furnace_albedo", "ground_truth", "ground_truth_albedo"]


class Sample(NamedTuple):
    """Sampled directions with weight f |cos wo| / pdf (Dirac: transmittance / P), pdf and a Dirac flag."""

    wo: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray
    is_delta: np.ndarray


# ---------------------------------------------------------------------------------------------- layers

def _sggx(layer: Layer) -> sggx.SGGX:
    make = sggx.surface if layer.type == "surface" else sggx.fiber
    return make(layer.orientation, layer.roughness)


def _sigma(layer: Layer, w):
    """Projected area of the layer's scatterers along w (1 for HG media)."""
    return sggx.sigma(_sggx(layer), w) if layer.is_flake else np.ones(len(w))


def area_scale(params: Params, exponents, wi, wo):
    """Π_k (σ_k(wi) σ_k(wo))^p_k (N,): the projected areas of the stack's layers (1 for hg layers) along both
    directions to the ``exponents`` (one per layer, top first), the forward lobe's scale (``bake.spongecake``).
    Reciprocal; exponents 0 (or none) give 1. σ is even in the direction, so the stack's own layers serve the
    prediction for either side."""
    log_scale = np.zeros(len(wi))
    for layer, p in zip(params.layers, exponents):
        if p > 0.0 and layer.is_flake:
            log_scale += p * np.log(np.maximum(_sigma(layer, wi) * _sigma(layer, wo), 1e-300))
    return np.exp(log_scale)


def _optical_depths(params: Params, w):
    """(L, N) optical depths T rho sigma(w) / |cos w| of each layer along w: inf at grazing, 0 for T rho = 0."""
    c = np.abs(w[:, 2])
    rows = []
    for layer in params.layers:
        if layer.thickness == 0.0:
            rows.append(np.zeros(len(w)))
            continue
        rows.append(np.divide(layer.thickness * _sigma(layer, w), c, out=np.full(len(w), np.inf), where=c > 0))
    return np.array(rows)


def _between(depths, up):
    """(L, N) optical depth of the layers between each layer and the side w points to (above if ``up``)."""
    zero = np.zeros_like(depths[:1])
    above = np.concatenate([zero, np.cumsum(depths, axis=0)[:-1]])
    below = np.concatenate([np.cumsum(depths[::-1], axis=0)[::-1][1:], zero])
    return np.where(up, above, below)


def _above(w):
    """Directions on the upper side; exactly grazing ones count as above (their BSDF value is 0 anyway)."""
    return w[:, 2] >= 0


def _slab_g(trho, lam_i, lam_o):
    """G of Eqs. 12 and 14 without overflow: (e^{T rho E-} - e^{-T rho E+}) / (Lambda_i + Lambda_o).

    E+ and E- sum the positive and negative Lambdas; the expm1 form is exact when Lambda_i + Lambda_o -> 0,
    where G -> T rho e^{T rho E-}.
    """
    e_neg = np.minimum(lam_i, 0.0) + np.minimum(lam_o, 0.0)
    e_pos = np.maximum(lam_i, 0.0) + np.maximum(lam_o, 0.0)
    x = trho * np.abs(e_pos + e_neg)
    safe = np.where(x > 0, x, 1.0)
    one_minus_exp_over_x = np.where(x > 0, -np.expm1(-safe) / safe, 1.0)
    return trho * np.exp(trho * np.maximum(e_neg, -e_pos)) * one_minus_exp_over_x


def _phase_value(layer: Layer, wi, wo):
    """F(h) f_p(wi -> wo), (N, 3): the flake phase function D(h) / (4 sigma(wi)) (Eq. 4) with Schlick's F on
    |wi . h| (f0 = 1 gives F = 1), or Henyey-Greenstein."""
    p = _phase_pdf(layer, wi, wo)[:, None]
    if not layer.has_fresnel:
        return p * np.ones(3)
    return microfacet.schlick(layer.f0, dot(wi, sggx.half_vector(wi, wo)[0])) * p


def _phase_pdf(layer: Layer, wi, wo):
    """Normalised phase function f_p(wi -> wo), the density of ``_phase_sample``."""
    if layer.is_flake:
        return sggx.phase_pdf(_sggx(layer), wi, wo)
    return hg.eval(layer.roughness, -dot(wi, wo))


def _phase_sample(layer: Layer, wi, u1, u2):
    """Scattered directions and the Fresnel factor of the flake that scattered them ((N, 3), 1 for HG)."""
    if not layer.is_flake:
        return hg.sample(layer.roughness, -wi, u1, u2), np.ones((len(wi), 3))
    wo, m = sggx.sample_phase(_sggx(layer), wi, u1, u2)
    return wo, microfacet.schlick(layer.f0, dot(wi, m))


def _stack_eval(params: Params, wi, wo):
    """Sum over layers of the single-scattering lobes (Eqs. 10-14), each attenuated by the layers in between."""
    ci, co = wi[:, 2], wo[:, 2]
    grazing = (ci == 0) | (co == 0)
    ci, co = np.where(grazing, 1.0, ci), np.where(grazing, 1.0, co)
    between = _between(_optical_depths(params, wi), _above(wi)) + _between(_optical_depths(params, wo), _above(wo))
    att = np.exp(-between)
    total = np.zeros((len(wi), 3))
    for k, layer in enumerate(params.layers):
        sigma_i = _sigma(layer, wi)
        g = _slab_g(layer.thickness, sigma_i / ci, _sigma(layer, wo) / co)
        # reduced phase function over rho, sigma(wi) F f_p (Eq. 5), integrated over the depth (Eqs. 10, 11)
        scale = sigma_i * g * att[k] / np.abs(ci * co)
        total += np.asarray(layer.albedo) * _phase_value(layer, wi, wo) * scale[:, None]
    if params.substrate is not None:
        total *= ((ci > 0) & (co > 0))[:, None]
    return np.where(grazing[:, None], 0.0, total)


# ------------------------------------------------------------------------------------------- substrate

def _stack_transmittance(params: Params, w):
    """Transmittance of the whole stack along w for directions above; 1 below (inside the substrate)."""
    return np.where(_above(w), np.exp(-_optical_depths(params, w).sum(axis=0)), 1.0)


def substrate_bsdf(sub: Substrate, wi, wo):
    """The bare substrate BSDF (N, 3), no cosine."""
    if sub.type == "diffuse":
        both_above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return np.where(both_above[:, None], np.asarray(sub.albedo) / np.pi, 0.0)
    if sub.type == "conductor":
        return microfacet.conductor_eval(wi, wo, sub.roughness, sub.eta, sub.k)
    return microfacet.dielectric_eval(wi, wo, sub.roughness, sub.ior)[:, None] * np.ones(3)


def substrate_pdf(sub: Substrate, wi, wo):
    """Density of ``substrate_sample``: cosine on wi's side, or GGX visible normals (mirrored when wi is below)."""
    if sub.type == "dielectric":
        return microfacet.dielectric_pdf(wi, wo, sub.roughness, sub.ior)
    side = np.where(_above(wi), 1.0, -1.0)
    if sub.type == "diffuse":
        return lobes.cosine_pdf(side, wo)
    return microfacet.reflection_pdf(side[:, None] * wi, side[:, None] * wo, sub.roughness)


def substrate_sample(sub: Substrate, wi, u0, u1, u2):
    """Cosine-weighted directions (diffuse), reflected GGX visible normals (conductor), Walter 2007 (dielectric)."""
    if sub.type == "dielectric":
        return microfacet.dielectric_sample(wi, sub.roughness, sub.ior, u0, u1, u2)
    side = np.where(_above(wi), 1.0, -1.0)
    if sub.type == "diffuse":
        return lobes.cosine_sample(side, u1, u2)
    return side[:, None] * microfacet.conductor_sample(side[:, None] * wi, sub.roughness, u1, u2)


def _substrate_eval(params: Params, wi, wo):
    """Substrate BSDF attenuated by the stack along wi and wo (Sec. 4.4)."""
    if params.substrate is None:
        return np.zeros((len(wi), 3))
    att = _stack_transmittance(params, wi) * _stack_transmittance(params, wo)
    return substrate_bsdf(params.substrate, wi, wo) * att[:, None]


# ---------------------------------------------------------------------------------------------- public

def eval(params: Params, wi, wo):
    """SpongeCake BSDF f(wi, wo) (N, 3), reflection and transmission, no cosine, no Dirac: single scattering,
    plus the network's multiple-scattering lobes (``addon.bake.spongecake``) when ``params.multiple_scattering``."""
    wi, wo = as_directions(wi), as_directions(wo)
    f = _stack_eval(params, wi, wo) + _substrate_eval(params, wi, wo)
    if params.multiple_scattering:
        f = f + eval_multiple(params, wi, wo)
    return np.where(((wi[:, 2] != 0) & (wo[:, 2] != 0))[:, None], f, 0.0)


def eval_multiple(params: Params, wi: np.ndarray, wo: np.ndarray, prediction=None):
    """The predicted multiple-scattering part of f(wi, wo), (N, 3), no cosine. With a substrate, the layers' own
    prediction (trained without one) closes at the substrate: reflection above only (the "ms-over-substrate"
    approximation, measured against the random walk in docs/accuracy.md), scaled per view by ``energy_tables``.
    ``prediction``: a given network's lobes (``bake.spongecake.predict_with``), unscaled; the shipped network's,
    scaled, when not given."""
    from ..bake.spongecake import predict

    pred = prediction or predict(params)
    above, below = energy_tables(params) if prediction is None else (None, None)
    f = _network_lobes(params, pred, wi, wo)
    if above is not None:
        f = f * np.where((wo[:, 2] > 0)[:, None], energy_at(above, wo), energy_at(below, wo))
    return f


def _network_lobes(params: Params, pred, wi, wo):
    """The network's multiple-scattering lobes as predicted, before the energy scale (``eval_multiple``)."""
    up = (wo[:, 2] > 0)[:, None]  # the viewer's side picks the prediction (module docstring)
    same = (wi[:, 2] > 0) == (wo[:, 2] > 0)
    f = np.where(up, eval(pred.lobe, wi, wo) + _forward_lobe(params, pred.forward, pred.forward_area, wi, wo),
                 eval(pred.lobe_below, wi, wo) + _forward_lobe(params, pred.forward_below, pred.forward_area_below,
                                                               wi, wo))
    w2r = np.where(up, pred.reflection, pred.reflection_below)
    w2t = np.where(up, pred.transmission, pred.transmission_below)
    f = f + np.where(same[:, None], w2r, w2t) / np.pi
    if params.substrate is not None:
        f = f * ((wi[:, 2] > 0) & (wo[:, 2] > 0))[:, None]
    grazing = (wi[:, 2] == 0) | (wo[:, 2] == 0)
    return np.where(grazing[:, None], 0.0, f)


def _forward_lobe(params: Params, forward: Params, exponents, wi, wo):
    """The network's forward lobe (one hg layer) scaled by the stack's projected areas (``area_scale``)."""
    return eval(forward, wi, wo) * area_scale(params, exponents, wi, wo)[:, None]


ENERGY_SAMPLES = 4096  # directions per view of the albedos behind the energy tables (``directional_albedo``)


def energy_at(table, w):
    """A table over ``energy_cosines`` and the azimuths of ``bake.spongecake.energy_azimuths`` (K, P, 3) at
    directions w (N, 3): bilinear in √|cos θ| (clamped at the ends) and the azimuth, less an estimate of linear
    interpolation's error where the table is convex, f (1 − f) / 2 times its largest second difference at the
    view's four knots in each coordinate (f the view's place between two knots; exact for a quadratic in √|cos θ|),
    so that a view between knots takes no more than the scale there allows."""
    knots = np.sqrt(energy_cosines())
    n_phi = table.shape[1]
    u = np.sqrt(np.abs(w[:, 2]))
    k = np.clip(np.searchsorted(knots, u) - 1, 0, len(knots) - 2)
    g = np.clip((u - knots[k]) / (knots[k + 1] - knots[k]), 0.0, 1.0)[:, None]
    x = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2.0 * np.pi) * (n_phi / (2.0 * np.pi))
    j = np.floor(x).astype(int) % n_phi
    f = (x - np.floor(x))[:, None]
    corners = [(k, j, (1.0 - g) * (1.0 - f)), (k, (j + 1) % n_phi, (1.0 - g) * f),
               (k + 1, j, g * (1.0 - f)), (k + 1, (j + 1) % n_phi, g * f)]
    bend_u, bend_phi = _second_differences(table)
    value = sum(weight * table[a, b] for a, b, weight in corners)
    convex_u = np.maximum.reduce([bend_u[a, b] for a, b, _ in corners] + [np.zeros_like(value)])
    convex_phi = np.maximum.reduce([bend_phi[a, b] for a, b, _ in corners] + [np.zeros_like(value)])
    return np.maximum(value - 0.5 * g * (1.0 - g) * convex_u - 0.5 * f * (1.0 - f) * convex_phi, 0.0)


def _second_differences(table):
    """(along the view cosine's knots, along the azimuths) second differences of a (K ≥ 4, P, 3) table: linearly
    extrapolated to the first and last knots; the azimuths wrap around (0 where P = 1)."""
    along_u = np.zeros_like(table)
    along_u[1:-1] = table[:-2] - 2.0 * table[1:-1] + table[2:]
    along_u[0], along_u[-1] = 2.0 * along_u[1] - along_u[2], 2.0 * along_u[-2] - along_u[-3]
    along_phi = np.roll(table, 1, axis=1) - 2.0 * table + np.roll(table, -1, axis=1)
    return along_u, along_phi


def energy_tables(params: Params):
    """The energy scale of the network's lobes (module docstring) on ``energy_cosines`` and, where a layer is
    oriented off the normal, on the view azimuths of ``bake.spongecake.energy_azimuths``, for views above and below
    ((K, P, 3) each; P = 1 for isotropic stacks). Seen from below a stack on a substrate has no multiple scattering
    (scale 0). Cached per stack and weights folder."""
    from ..bake import spongecake as bake

    return _energy_tables(params, str(bake.WEIGHTS))


@lru_cache(maxsize=256)
def _energy_tables(params: Params, weights: str):
    from ..bake.spongecake import energy_table

    above = energy_table(params, single_leftover, lobes_albedo)
    below = (np.zeros_like(above) if params.substrate is not None
             else energy_table(params, single_leftover, lobes_albedo, -1.0))
    return above, below


def single_leftover(params: Params, wo):
    """``leftover`` of the stack's single scattering alone (what the energy scale shares out)."""
    return leftover(replace(params, multiple_scattering=False), wo)


def lobes_albedo(params: Params, wo):
    """``network_albedo`` of the shipped network's unscaled lobes for the stack."""
    from ..bake.spongecake import predict

    return network_albedo(params, predict(params), wo)


def leftover(params: Params, wo, n: int | None = None):
    """1 - A_ss - T_delta towards wo (N, 3): what single scattering and the Dirac (rendered or not) leave; A_ss by
    ``directional_albedo`` with ``n`` directions per view (``ENERGY_SAMPLES`` as it is at the call)."""
    through = np.exp(-_optical_depths(params, wo).sum(axis=0))[:, None] * (params.substrate is None)
    return 1.0 - directional_albedo(params, wo, n=ENERGY_SAMPLES if n is None else n) - through


def network_albedo(params: Params, pred, wo):
    """Directional albedo (N, 3) of the network's unscaled lobes ``pred`` (``bake.spongecake.predict``) towards wo
    (all on one side): the extra single-scattering lobe's and the forward lobe's plus W2r + W2t (Lambert, exact);
    over a substrate reflection only."""
    up = wo[0, 2] > 0
    lobe, forward, exponents = ((pred.lobe, pred.forward, pred.forward_area) if up
                                else (pred.lobe_below, pred.forward_below, pred.forward_area_below))
    reflection, transmission = (
        a + b for a, b in zip(directional_albedo(lobe, wo, n=ENERGY_SAMPLES, split=True),
                              directional_albedo(forward, wo, n=ENERGY_SAMPLES, split=True,
                                                 weight_of=lambda x, w: area_scale(params, exponents, x, w))))
    w2r = np.asarray(pred.reflection if up else pred.reflection_below)
    w2t = np.asarray(pred.transmission if up else pred.transmission_below)
    if params.substrate is not None:
        return reflection + w2r
    return reflection + transmission + w2r + w2t


def delta_transmittance(params: Params, wi):
    """Weight (N, 3) of the unscattered Dirac along -wi: prod_k tau_k(wi) (Sec. 4.4); 0 if off or with a substrate."""
    wi = as_directions(wi)
    if not params.delta_transmission or params.substrate is not None:
        return np.zeros((len(wi), 3))
    return np.exp(-_optical_depths(params, wi).sum(axis=0))[:, None] * np.ones(3)


def _single_weights(params: Params, wi):
    """(N, lobes) unnormalised selection weights of single scattering: P(first collision in layer k) per layer, then
    the substrate or the Dirac when present (Sec. 4.5)."""
    depths = _optical_depths(params, wi)
    up = _above(wi)
    through = np.exp(-depths.sum(axis=0))
    columns = list(-np.expm1(-depths) * np.exp(-_between(depths, up)))
    if params.substrate is not None:
        columns = [c * up for c in columns] + [np.where(up, through, 1.0)]
    elif params.delta_transmission:
        columns.append(through)
    return np.stack(columns, axis=1)


def _normalised(p, n_continuous):
    """Rows of p divided by their sums; uniform over the first ``n_continuous`` lobes where a row is all 0."""
    fallback = np.zeros(p.shape[1])
    fallback[:n_continuous] = 1.0 / n_continuous
    total = p.sum(axis=1, keepdims=True)
    return np.where(total > 0, p / np.where(total > 0, total, 1.0), fallback)


def _intercepted(params: Params, wi, weights=None):
    """(N,) the light a stack scatters once from wi, roughly: P(first collision in layer k) times the layer's mean
    albedo, summed (the substrate and the Dirac at full weight). ``weights``: ``_single_weights``, when known."""
    albedo = [np.mean(layer.albedo) for layer in params.layers] + [1.0] * (params.substrate is not None)
    weights = _single_weights(params, wi) if weights is None else weights
    return weights[:, : len(albedo)] @ np.asarray(albedo) + weights[:, len(albedo):].sum(axis=1)


MS_LOBES = 4  # the network's extra lobe, its forward lobe, W2r's Lambert on wi's side, W2t's on the other


def _multiple_weights(params: Params, wi):
    """(N, ``MS_LOBES``) unnormalised selection weights of multiple scattering's lobes, by their rough albedos
    (``_intercepted``, W2r, W2t) times the view's mean energy scale; the prediction of wi's side. wi is the view of
    ``eval_multiple`` (its wo): the sampler starts from the viewer, as ``directional_albedo`` uses it."""
    from ..bake.spongecake import predict

    pred = predict(params)
    up = _above(wi)
    above, below = energy_tables(params)
    scale = np.where(up, energy_at(above, wi).mean(axis=1), energy_at(below, wi).mean(axis=1))
    transmits = params.substrate is None
    columns = [np.where(up, _intercepted(pred.lobe, wi), _intercepted(pred.lobe_below, wi)),
               np.where(up, _intercepted(pred.forward, wi) * area_scale(params, pred.forward_area, wi, wi),
                        _intercepted(pred.forward_below, wi) * area_scale(params, pred.forward_area_below, wi, wi)),
               np.where(up, np.mean(pred.reflection), np.mean(pred.reflection_below)),
               np.where(up, np.mean(pred.transmission), np.mean(pred.transmission_below)) * transmits]
    return np.stack(columns, axis=1) * scale[:, None]


def _lobe_probabilities(params: Params, wi):
    """(N, lobes) selection probabilities: the layers, then with multiple scattering its ``MS_LOBES`` lobes, then the
    substrate or the Dirac when present (last). Single scattering keeps its own proportions (Sec. 4.5); multiple
    scattering takes its rough share of the light returned, W_ms / (W_ms + ``_intercepted``)."""
    weights = _single_weights(params, wi)
    n_layers = len(params.layers)
    n_continuous = n_layers + (params.substrate is not None)
    single = _normalised(weights, n_continuous)
    if not params.multiple_scattering:
        return single
    multiple = _multiple_weights(params, wi)
    total = multiple.sum(axis=1, keepdims=True)
    share = total / np.maximum(total + _intercepted(params, wi, weights)[:, None], 1e-300)
    multiple = share * np.divide(multiple, total, out=np.zeros_like(multiple), where=total > 0)
    single = (1.0 - share) * single
    return np.concatenate([single[:, :n_layers], multiple, single[:, n_layers:]], axis=1)


def _multiple_pdfs(params: Params, wi, wo):
    """(N, ``MS_LOBES``) densities of multiple scattering's lobes' samplers (``_sample_multiple``)."""
    from ..bake.spongecake import predict

    pred = predict(params)
    up = _above(wi)
    side = np.where(up, 1.0, -1.0)
    return np.stack([np.where(up, pdf(pred.lobe, wi, wo), pdf(pred.lobe_below, wi, wo)),
                     np.where(up, pdf(pred.forward, wi, wo), pdf(pred.forward_below, wi, wo)),
                     lobes.cosine_pdf(side, wo),
                     lobes.cosine_pdf(-side, wo)], axis=1)


def _sample_multiple(params: Params, wi, lobe, u):
    """Directions (N, 3) from multiple scattering's lobe ``lobe`` (0 .. ``MS_LOBES`` - 1) of each row: the network's
    lobes by their own samplers (they have no Dirac), the Lambert lobes cosine-weighted."""
    from ..bake.spongecake import predict

    pred = predict(params)
    up = _above(wi)
    wo = np.zeros_like(wi)
    for k, (lobe_above, lobe_below) in enumerate(((pred.lobe, pred.lobe_below), (pred.forward, pred.forward_below))):
        for side, stack in ((up, lobe_above), (~up, lobe_below)):
            m = (lobe == k) & side
            wo[m] = sample(stack, wi[m], u[m]).wo
    side = np.where(up, 1.0, -1.0)
    wo = np.where((lobe == 2)[:, None], lobes.cosine_sample(side, u[:, 1], u[:, 2]), wo)
    return np.where((lobe == 3)[:, None], lobes.cosine_sample(-side, u[:, 1], u[:, 2]), wo)


def _lobe_pdfs(params: Params, wi, wo):
    """(N, continuous lobes) densities of each continuous lobe's sampler, in ``_lobe_probabilities``' order."""
    columns = [_phase_pdf(layer, wi, wo) for layer in params.layers]
    if params.multiple_scattering:
        columns.extend(_multiple_pdfs(params, wi, wo).T)
    if params.substrate is not None:
        columns.append(substrate_pdf(params.substrate, wi, wo))
    return np.stack(columns, axis=1)


def pdf(params: Params, wi, wo):
    """Solid-angle density (N,) of the continuous samples of ``sample`` (it integrates to 1 - P(delta))."""
    wi, wo = as_directions(wi), as_directions(wo)
    lobes = _lobe_pdfs(params, wi, wo)
    return np.sum(_lobe_probabilities(params, wi)[:, : lobes.shape[1]] * lobes, axis=1)


def sample(params: Params, wi, u) -> Sample:
    """Sample wo for each wi from u in [0, 1)^3: u0 picks the lobe (then reused), u1 and u2 the direction."""
    wi, u = as_directions(wi), as_directions(u)
    probabilities = _lobe_probabilities(params, wi)
    lobe, chosen, u0 = lobes.choose(probabilities, u[:, 0])
    wo = -wi.copy()
    for k, layer in enumerate(params.layers):
        m = lobe == k
        wo[m] = _phase_sample(layer, wi[m], u[m, 1], u[m, 2])[0]
    n_layers, last = len(params.layers), probabilities.shape[1] - 1
    if params.multiple_scattering:
        m = (lobe >= n_layers) & (lobe < n_layers + MS_LOBES)
        wo[m] = _sample_multiple(params, wi[m], lobe[m] - n_layers, np.column_stack([u0[m], u[m, 1:]]))
    if params.substrate is not None:
        m = lobe == last
        wo[m] = substrate_sample(params.substrate, wi[m], u0[m], u[m, 1], u[m, 2])
    is_delta = (lobe == last) & (params.substrate is None) & params.delta_transmission
    density = np.where(is_delta, chosen, pdf(params, wi, wo))
    value = np.where(is_delta[:, None], delta_transmittance(params, wi), eval(params, wi, wo) * np.abs(wo[:, 2:]))
    weight = np.divide(value, density[:, None], out=np.zeros_like(value), where=density[:, None] > 0)
    return Sample(wo, weight, density, is_delta)


# ------------------------------------------------------------------------------------- directional albedo

def _stratified(n, rng):
    """k^2 <= n points of [0, 1)^3 (k = floor(sqrt(n))): u0 in k^2 jittered strata, (u1, u2) one per cell of a
    jittered k x k grid, the two stratifications randomly paired."""
    side = int(np.sqrt(n))
    n = side * side
    cells = rng.permutation(n)
    u0 = (rng.permutation(n) + rng.random(n)) / n
    u1 = (cells // side + rng.random(n)) / side
    u2 = (cells % side + rng.random(n)) / side
    return np.minimum(np.stack([u0, u1, u2], axis=1), np.nextafter(1.0, 0.0))


def directional_albedo(params: Params, wo, n: int = 16384, seed: int = 0, split: bool = False, weight_of=None):
    """Continuous-part albedo int f(wi, wo) |cos wi| dwi (N, 3); with ``split``, (reflection, transmission); with
    ``weight_of`` (a function of (wi, wo) arrays, (N,)), the albedo of f times it (sampled as f is).

    Deterministic (seeded) stratified estimate with two techniques combined by the balance heuristic: the
    sampler from wo (f is reciprocal up to the dielectric's eta^2) for 7/8 of the samples, uniform directions
    for the rest. The Dirac part is excluded: add ``delta_transmittance(params, wo)`` for a furnace. Each view
    draws its own stratified samples; views are evaluated together, ``ALBEDO_CHUNK`` samples at a time.
    """
    wo = as_directions(wo)
    rng = np.random.default_rng(seed)
    draws = [(_stratified((7 * n) // 8, rng), _stratified(n // 8, rng)) for _ in wo]
    reflection, transmission = np.zeros((len(wo), 3)), np.zeros((len(wo), 3))
    per_chunk = max(1, ALBEDO_CHUNK // max(n, 1))
    for start in range(0, len(wo), per_chunk):
        rows = slice(start, start + per_chunk)
        reflection[rows], transmission[rows] = _albedo_rows(params, wo[rows], draws[rows], weight_of)
    return (reflection, transmission) if split else reflection + transmission


ALBEDO_CHUNK = 1 << 18  # samples per array in ``directional_albedo``


def _albedo_rows(params: Params, wo, draws, weight_of=None):
    """``directional_albedo``'s (reflection, transmission) of the views ``wo`` (K, 3) from their draws."""
    k = len(wo)
    n_b, n_u = len(draws[0][0]), len(draws[0][1])
    row_b, row_u = np.repeat(np.arange(k), n_b), np.repeat(np.arange(k), n_u)
    s = sample(params, wo[row_b], np.concatenate([d[0] for d in draws]))
    u = np.concatenate([d[1] for d in draws])
    x = np.concatenate([s.wo[~s.is_delta], spherical(2.0 * u[:, 1] - 1.0, 2.0 * np.pi * u[:, 2])])
    row = np.concatenate([row_b[~s.is_delta], row_u])
    ws = wo[row]
    q = n_b * pdf(params, ws, x) + n_u / (4.0 * np.pi)
    value = eval(params, x, ws) * np.abs(x[:, 2:]) / q[:, None]
    if weight_of is not None:
        value = value * weight_of(x, ws)[:, None]
    same = x[:, 2] * ws[:, 2] > 0

    def per_row(mask):
        return np.stack([np.bincount(row, weights=value[:, c] * mask, minlength=k) for c in range(3)], axis=1)

    return per_row(same), per_row(~same)


def furnace_albedo(params: Params, wo, n: int = 4096, seed: int = 0):
    """What a white furnace returns towards wo: the directional albedo plus the Dirac part (N, 3)."""
    wo = as_directions(wo)
    return directional_albedo(params, wo, n=n, seed=seed) + delta_transmittance(params, wo)


# ----------------------------------------------------------------------------------- ground truth walk

def _exit_depths(params: Params, w):
    """(L, N) extinction per unit depth of each unit-thickness layer along w (0 for grazing w)."""
    c = np.abs(w[:, 2])
    return np.array([np.divide(layer.thickness * _sigma(layer, w), c, out=np.zeros(len(w)), where=c > 0)
                     for layer in params.layers])


def _free_flight(params: Params, z, d, rng):
    """Exponential free flight through the piecewise-constant extinction T_k rho_k sigma_k(d) of layers of unit
    depth (layer k spans depths [k, k + 1]); the optical depth left at a boundary carries into the next layer
    (the same law as re-sampling there, by memorylessness). Returns the new depth, the layer, and whether the
    path collided (else it left through the top or the bottom)."""
    n_layers = len(params.layers)
    up = d[:, 2] > 0
    kappa = np.array([layer.thickness * _sigma(layer, d) for layer in params.layers])
    mu = np.abs(d[:, 2])
    kappa = np.divide(kappa, mu, out=np.where(kappa > 0, np.inf, 0.0), where=mu > 0)  # per unit depth
    tau = rng.standard_exponential(len(z))
    flying = np.ones(len(z), bool)
    collided = np.zeros(len(z), bool)
    layer = np.zeros(len(z), int)
    rows = np.arange(len(z))
    for _ in range(n_layers):
        k = np.clip(np.where(up, np.ceil(z) - 1, np.floor(z)), 0, n_layers - 1).astype(int)
        layer = np.where(flying, k, layer)
        to_boundary = np.where(up, z - k, k + 1 - z)
        depth = kappa[k, rows] * to_boundary
        hit = flying & (tau < depth)
        collided |= hit
        step = tau[hit] / kappa[k[hit], rows[hit]]
        z[hit] = np.clip(z[hit] + np.where(up[hit], -step, step), k[hit], k[hit] + 1)
        cross = flying & ~hit
        tau[cross] -= depth[cross]
        z[cross] = np.where(up[cross], k[cross], k[cross] + 1)
        flying = cross & (z > 0) & (z < n_layers)
    return z, layer, collided


BLOCK_PAIRS = 16  # a light direction with at least this many view directions gets its NEE as blocks
CHUNK = 1 << 19  # vertex-direction pairs per array
BLOCK = 1 << 15  # vertex-direction pairs per block (its arrays stay in the cache)
NEAR_OPPOSITE = 1e-12  # |wi + wo|^2 below which ``_phase_block`` forms h as the exact sum


def _nee(params: Params, state, wo_pairs, kappa_o, slots, sums):
    """Next-event estimation from every vertex to each wo of its group (light direction), added to ``sums`` (N, 3)
    per pair: per group as vertices x directions blocks (``_vertex_block``) where groups have many directions (the
    dataset: every wo of a wi), pair by pair (``_vertex_to``) where they have few (a scene's pixels, each with its own
    light direction)."""
    z, d, beta, layer, surface, group = state
    if slots.shape[1] < BLOCK_PAIRS:
        vertex, slot = np.nonzero(slots[group] >= 0)
        for start in range(0, len(vertex), CHUNK):
            v = vertex[start:start + CHUNK]
            pair = slots[group[v], slot[start:start + CHUNK]]
            contribution = beta[v] * _vertex_to(params, z[v], -d[v], layer[v], surface[v], wo_pairs[pair],
                                                kappa_o[:, pair])
            for c in range(3):
                sums[:, c] += np.bincount(pair, weights=contribution[:, c], minlength=len(sums))
        return
    order = np.argsort(group, kind="stable")
    bounds = np.searchsorted(group[order], np.arange(len(slots) + 1))
    for g in np.flatnonzero(np.diff(bounds)):
        pairs = slots[g][slots[g] >= 0]
        step = max(1, BLOCK // len(pairs))
        for start in range(bounds[g], bounds[g + 1], step):
            v = order[start:min(start + step, bounds[g + 1])]
            sums[pairs] += _vertex_block(params, z[v], -d[v], beta[v], layer[v], surface[v], wo_pairs[pairs],
                                         kappa_o[:, pairs])


def _vertex_to(params: Params, z, wi, layer, surface, wo, kappa_o):
    """Next-event estimate towards wo of vertices at depth z reached with unit throughput from wi, (N, 3), pair by
    pair (rows of equal length; ``_vertex_block`` is the same for every vertex x every wo)."""
    up = wo[:, 2] > 0
    j = np.arange(len(params.layers))[:, None]
    overlap = np.where(up, np.clip(z - j, 0.0, 1.0), np.clip(j + 1 - z, 0.0, 1.0))
    transmittance = np.exp(-np.sum(kappa_o * overlap, axis=0))
    value = np.zeros((len(z), 3))
    for k, lay in enumerate(params.layers):
        # volume vertex: albedo F f_p / |cos wo| (position-free form of the path integral, Guo et al. 2018)
        m = ~surface & (layer == k)
        if m.any():
            value[m] = np.asarray(lay.albedo) * _phase_value(lay, wi[m], wo[m]) / np.abs(wo[m, 2:])
    if params.substrate is not None:
        value[~surface & ~up] = 0.0  # the substrate blocks transmission out of the stack
        value[surface] = substrate_bsdf(params.substrate, wi[surface], wo[surface])
    return value * transmittance[:, None]


def _vertex_block(params: Params, z, wi, beta, layer, surface, wo, kappa_o):
    """Sum over the vertices (depth z, direction to the light wi, throughput beta) of their next-event estimates
    towards each wo, (P, 3): the transmittance to the top or bottom, and at a volume vertex albedo F f_p / |cos wo|
    (position-free form of the path integral, Guo et al. 2018), at the substrate its BSDF. The optical depths to
    either side are one matrix product (the overlaps above and below against the exit depths of the directions
    that leave on that side); the transmittance is float32 (relative 1e-7, far below the walk's noise)."""
    up = wo[:, 2] > 0
    j = np.arange(len(params.layers))
    overlaps = np.concatenate([np.clip(z[:, None] - j, 0.0, 1.0), np.clip(j + 1 - z[:, None], 0.0, 1.0)], axis=1)
    optical = overlaps @ np.concatenate([kappa_o * up, kappa_o * ~up])  # (V, P)
    transmittance = np.exp(-optical.astype(np.float32))
    out = np.zeros((len(wo), 3))
    leave = (1.0 / np.abs(wo[:, 2])).astype(np.float32)
    if params.substrate is not None:
        leave[~up] = 0.0  # the substrate blocks transmission out of the stack
    reach = transmittance * leave
    for k, lay in enumerate(params.layers):
        m = ~surface & (layer == k)
        if not m.any():
            continue
        pdf, fresnel_share = _phase_block(lay, wi[m], wo)
        weight = (beta[m] * np.asarray(lay.albedo)).T  # (3, V)
        pdf *= reach[m]
        value = weight @ pdf  # (3, P)
        if fresnel_share is not None:  # Schlick: f0 + (1 - f0) (1 - cos)^5, linear in f0
            f0 = np.asarray(lay.f0)[:, None]
            value = f0 * value + (1.0 - f0) * (weight @ (fresnel_share * pdf))
        out += value.T
    if params.substrate is not None and surface.any():
        n = int(surface.sum())
        f = substrate_bsdf(params.substrate, np.repeat(wi[surface], len(wo), axis=0), np.tile(wo, (n, 1)))
        out += np.einsum("vc,vpc->pc", beta[surface], f.reshape(n, len(wo), 3) * transmittance[surface][..., None])
    return out


@lru_cache(maxsize=64)
def _axis_frame(axis: tuple) -> tuple:
    """The orthonormal frame (e1, e2, axis) of an SGGX axis (``sggx.coords``' frame), once per axis."""
    axis = np.asarray(axis)
    return (*frames.basis(axis), axis)


def _axis_coordinates(s: sggx.SGGX, w):
    """The coordinates of the rows w in the SGGX axis frame, each an elementwise sum, so that the coordinates of -w
    are exactly the negated ones (h = wi + wo is exactly 0 at wo = -wi, as ``eval`` forms it)."""
    return [w[:, 0] * f[0] + w[:, 1] * f[1] + w[:, 2] * f[2] for f in _axis_frame(tuple(s.axis))]


def _phase_block(layer: Layer, wi, wo):
    """``_phase_pdf`` for every pair of the rows wi (V) and wo (P), (V, P), and for flakes with a Fresnel the
    Schlick factor (1 - |wi . h|)^5 (else None). D(h / |h|) = (|h|^2 / h^T S^-1 h)^2 / (pi sqrt(det S)) for the
    unnormalised h = wi + wo, whose parts across and along the axis are summed from the two directions' coordinates
    in the axis frame; where wo is within about 1e-6 of -wi, the direction of h lies in the last bits of the two, so
    h there is the exact sum wi + wo, as ``eval`` forms it (tested against ``_phase_value``). Elsewhere the Fresnel
    cosine wi . h / |h| is |h| / 2 (wi . h = |h|^2 / 2 for unit directions)."""
    if not layer.is_flake:
        return hg.eval(layer.roughness, -(wi @ wo.T)), None
    s = _sggx(layer)
    ci, co = _axis_coordinates(s, wi), _axis_coordinates(s, wo)
    h1, h2 = ci[0][:, None] + co[0], ci[1][:, None] + co[1]
    across = h1 * h1
    across += h2 * h2
    along = ci[2][:, None] + co[2]
    along *= along
    length2 = across + along
    cos = 0.5 * np.sqrt(length2) if layer.has_fresnel else None
    near = length2 < NEAR_OPPOSITE
    if near.any():
        near = np.nonzero(near)
        h = wi[near[0]] + wo[near[1]]
        exact = _axis_coordinates(s, h)
        across[near], along[near] = exact[0] ** 2 + exact[1] ** 2, exact[2] ** 2
        length2[near] = across[near] + along[near]
        if cos is not None:
            cos[near] = np.abs(dot(wi[near[0]], h)) / np.maximum(np.sqrt(length2[near]), 1e-300)
    q = across * (1.0 / s.a) + along * (1.0 / s.b)
    pdf = np.divide(length2, q, out=np.zeros_like(q), where=q > 0)
    pdf *= pdf
    sigma_i = np.sqrt(s.a * (ci[0] ** 2 + ci[1] ** 2) + s.b * ci[2] ** 2)
    pdf *= (1.0 / (np.pi * np.sqrt(sggx.det(s)) * 4.0 * sigma_i))[:, None]
    if cos is None:
        return pdf, None
    share = 1.0 - np.minimum(cos, 1.0)
    square = share * share
    return pdf, share * square * square


def _scatter(params: Params, state, rng):
    """Sample the next direction at every vertex (phase function or substrate BSDF); returns the new state."""
    z, d, beta, layer, surface, group = state
    u = rng.random((len(z), 3))
    d_new, beta = d.copy(), beta.copy()
    for k, lay in enumerate(params.layers):
        m = ~surface & (layer == k)
        d_new[m], fresnel = _phase_sample(lay, -d[m], u[m, 1], u[m, 2])
        beta[m] *= np.asarray(lay.albedo) * fresnel
    if params.substrate is not None and surface.any():
        sub, wi = params.substrate, -d[surface]
        x = substrate_sample(sub, wi, u[surface, 0], u[surface, 1], u[surface, 2])
        density = substrate_pdf(sub, wi, x)
        f = substrate_bsdf(sub, wi, x) * np.abs(x[:, 2:])
        beta[surface] *= np.divide(f, density[:, None], out=np.zeros_like(f), where=density[:, None] > 0)
        beta[surface] *= (x[:, 2:] > 0)  # light refracted or scattered into the substrate leaves the stack
        d_new[surface] = x
    keep = np.any(beta > 0, axis=1)
    return tuple(a[keep] for a in (z, d_new, beta, layer, np.zeros_like(surface), group))


def _slots(group_of_pair, pair_index, n_groups):
    """(groups, most pairs per group) table of the pair indices of each group, padded with -1."""
    counts = np.bincount(group_of_pair, minlength=n_groups)
    slots = np.full((n_groups, counts.max()), -1)
    order = np.argsort(group_of_pair, kind="stable")
    rank = np.arange(len(order)) - np.repeat(np.cumsum(counts) - counts, counts)
    slots[group_of_pair[order], rank] = pair_index[order]
    return slots


def _start(params: Params, sources, n_paths: int):
    """Walk state (depth z, direction, throughput, layer, at-substrate flag, source index) of ``n_paths`` paths
    per source direction, entering through the top (light from above) or the bottom."""
    group = np.repeat(np.arange(len(sources)), n_paths)
    d = -sources[group]
    from_below = d[:, 2] > 0
    z = np.where(from_below, float(len(params.layers)), 0.0)
    surface = from_below & (params.substrate is not None)
    return z, d, np.ones((len(z), 3)), np.zeros(len(z), int), surface, group


def _fly(params: Params, state, rng):
    """Free flight of every path not at the substrate: (paths that collided or reached the substrate,
    (throughput, source index) of the paths that left the stack)."""
    z, d, beta, layer, surface, group = state
    fly = ~surface
    z_f, layer_f, collided = _free_flight(params, z[fly], d[fly], rng)
    z[fly], layer[fly] = z_f, layer_f
    reach_substrate = np.zeros_like(surface)
    if params.substrate is not None:
        reach_substrate[fly] = ~collided & (d[fly, 2] < 0)
    alive = surface | reach_substrate
    alive[fly] |= collided
    escaped = ~alive
    state = tuple(a[alive] for a in (z, d, beta, layer, surface | reach_substrate, group))
    return state, (beta[escaped], group[escaped])


def ground_truth(params: Params, wi, wo, n_paths: int = 20000, seed: int = 0, max_depth: int = 20):
    """Independent Monte Carlo f(wi, wo) by a volumetric random walk: (order 1, orders >= 2), each (N, 3).

    Uses only the phase functions, projected areas, free-flight sampling and the substrate BSDF, never the
    closed form of ``eval``. Paths of one wi are shared by all pairs with that wi (next-event estimation).
    """
    wi, wo = as_directions(wi), as_directions(wo)
    sums = [np.zeros((len(wi), 3)), np.zeros((len(wi), 3))]
    ok = (wi[:, 2] != 0) & (wo[:, 2] != 0)  # f = 0 at grazing, as in eval
    if not ok.any():
        return tuple(sums)
    rng = np.random.default_rng(seed)
    sources, group_of_pair = np.unique(wi[ok], axis=0, return_inverse=True)
    slots = _slots(group_of_pair.ravel(), np.flatnonzero(ok), len(sources))
    kappa_o = _exit_depths(params, wo)

    state = _start(params, sources, n_paths)
    for depth in range(max_depth):
        state, _ = _fly(params, state, rng)
        if len(state[0]) == 0:
            break
        _nee(params, state, wo, kappa_o, slots, sums[min(depth, 1)])
        if depth + 1 < max_depth:
            state = _scatter(params, state, rng)
    return tuple(s / n_paths for s in sums)


def ground_truth_albedo(params: Params, wo, n_paths: int = 20000, seed: int = 0, max_depth: int = 64):
    """Independent Monte Carlo furnace albedo: the energy leaving the stack for unit light arriving from each
    wo (by reciprocity, what a white furnace shows towards wo), split into (unscattered, order 1, orders >= 2),
    each (N, 3). The same random walk as ``ground_truth``, tallying escaping throughput instead of next-event
    estimation; the unscattered part is what ``delta_transmittance`` describes (count it only with the flag)."""
    wo = as_directions(wo)
    tallies = [np.zeros((len(wo), 3)) for _ in range(3)]
    rng = np.random.default_rng(seed)
    state = _start(params, wo, n_paths)
    for depth in range(max_depth):
        state, (beta, group) = _fly(params, state, rng)
        for c in range(3):
            tallies[min(depth, 2)][:, c] += np.bincount(group, weights=beta[:, c], minlength=len(wo))
        if len(state[0]) == 0 or depth + 1 == max_depth:
            break
        state = _scatter(params, state, rng)
    return tuple(t / n_paths for t in tallies)
