"""SpongeCake multiple scattering (Wang et al. 2022, Sec. 5): network inputs, outputs and numpy inference.

The multiple-scattering part of f for a stack of 1 or 2 layers (no substrate, light from above; deeper stacks below) is modelled as

    f_ms(wi, wo) = W1 f_ss(params', wi, wo) + W2r / pi [wi, wo on one side] + W2t / pi [opposite sides]
                   + f_ss(forward, wi, wo)

where params' has the same layer types, count and Fresnel structure as params, and ``forward`` is one HG layer
(mean cosine g, RGB albedo carrying its weight, thickness; not in the paper). The forward lobe is there for the
even orders of low-roughness flakes: two mirror reflections about one flake normal undo each other, so that light
continues close to its own direction, where the flake-shaped lobe puts nothing (docs/training.md measures what it
wins). A network without its outputs (``FORWARD_OUTPUTS``) predicts none (albedo 0). A network trained with
``training.train --area`` also scales it by the layers' projected areas, Π_k (σ_k(wi) σ_k(wo))^p_k with one
exponent p_k ≥ 0 per layer (σ of the input stack's layer k, 1 for hg layers; ``reference.spongecake.area_scale``):
the chance of each of the two reflections grows with the area the flakes show along the light; a network without
them has p = 0. The paper's single Lambertian weight W2 is split into reflection and transmission weights, because a
thick layer sends far more multiply scattered light back than through, and each is RGB, because multiple
scattering is more saturated than single scattering (γ^n) and grey Lambert weights cannot follow it
(docs/training.md).

The prediction is chosen by the side of the viewer: for wo above, the network's prediction for the stack;
for wo below, its prediction for the flipped stack (layers reversed, orientations mirrored). Reflection above
is what the network was trained on; transmission with the light below and the viewer above is, by reciprocity
of the true BSDF, the training case with wi and wo swapped, and the predicted lobe is itself reciprocal
(f_ss and the Lambert terms are). Choosing by the viewer's side is also what Cycles can do: closure weights
depend on the view only, so the rendered material and ``eval`` agree for light from either side.
W1 is folded into the lobe's albedo (f_ss is linear in it), so a prediction is a lobe ``Params`` plus W2r and W2t.

Encoding (per layer, ``FEATURES`` = 14 inputs): type one-hot (3); roughness as log alpha mapped from
[0.01, 1] to [-1, 1] for flakes, g / 0.95 for hg; 2 albedo - 1 (3); log T rho mapped from [0.01, 10] to [-1, 1];
2 f0 - 1 (3); orientation with z >= 0 (3; zero for hg). Inputs beyond the training ranges are clamped.
Decoding (per layer, ``OUTPUTS`` = 11 raw values, then ``WEIGHT_OUTPUTS`` = 7 for W1, W2r RGB, W2t RGB, then
``FORWARD_OUTPUTS`` = 5 for the forward lobe: g = ``FORWARD_G_MAX`` tanh(.), albedo softplus(.) RGB, T rho moved
from 1 like the layers' thickness, then optionally one area exponent per layer, softplus(.)): each
lobe parameter is a residual on the layer's own (``decode``): alpha' in [0.01, 1], g' in (-0.95, 0.95),
albedo' and f0' in (0, 1) (f0' = 1 for layers without Fresnel), T rho' in [0.01, 20],
orientation' = normalize(orientation + tanh(.)); W = softplus(.). ``decode`` is written against an
array namespace so training (torch) and inference (numpy) share it.

Stacks of 3 or 4 layers (no network is trained for them) go through the two-layer network, grouped (an
approximation of the model itself, not of a Cycles form): the layers are split into a top and a bottom group where
the optical thickness is most even; each group is lumped into one layer (its thickest layer's type, roughness, f0
and orientation, its summed thickness, the thickness-weighted albedo); the network's outputs for the two lumped
layers are applied, as residuals, to every layer of their group (``grouped_raw``). Its error against Monte Carlo is
measured on held-out 3- and 4-layer stacks (docs/training.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..models import spongecake as model
from ..reference.frames import spherical
from . import layer_rows as rows_
from . import mlp

WEIGHTS = Path(__file__).parent / "weights"
FEATURES = 14
OUTPUTS = 11
WEIGHT_OUTPUTS = 7  # W1, W2r RGB, W2t RGB
FORWARD_OUTPUTS = 5  # the forward lobe's g, albedo RGB, T rho
FORWARD_G_MAX = 0.98
# The decoded weights' columns (``decode``): W2r RGB, W2t RGB, then the forward lobe's g, albedo RGB and T rho.
W2R, W2T, FORWARD_G, FORWARD_ALBEDO, FORWARD_THICKNESS = slice(0, 3), slice(3, 6), 6, slice(7, 10), 10
AREA = slice(11, None)  # then the area exponents p_k, one per layer (0 for a network without them)
ALPHA_RANGE = (0.01, 1.0)
G_MAX = 0.95
THICKNESS_IN = (0.01, 10.0)
THICKNESS_OUT = (0.01, 20.0)
MS_VERSION = 13  # what a bake holds: 2 adds the energy scale (the ``MS Energy`` inputs), 3 its margin, 4 an oriented
# stack's scale over the view's azimuth too (``nodes.spongecake.view_inputs``), 5 the energy budget (``energy_budget``),
# 6 its view tables made safe along the view cosine too (``budget_rows``), 7 the forward lobe (``decode``), 8 each
# form's budget on its own prediction (the node group's merged fiber lobes: ``nodes.spongecake._FiberLobes``), 9 one
# ``MS Energy`` input fed from a view table for every stack (``nodes.spongecake.budget_table``), 10 the energy
# fraction's network for stacks of 1 or 2 layers without a substrate (``energy_fraction``), with budget tables
# that follow a texture-driven input (``driven_budget_rows``), 11 the forward lobe scaled by the layers' projected
# areas (``AREA``; the Cycles forms' along the normal: ``cycles_weights``), 12 the reference's energy table on twice
# the knots (``models.spongecake.ENERGY_KNOTS``: what fits with multiple scattering match), 13 the energy fraction for
# stacks of 3 and 4 layers too (``takes_fraction``)
NETWORK_LAYERS = 2  # lobe networks are trained for 1 and 2 layers; more go through the two-layer one, grouped
ENERGY_NETWORK_LAYERS = model.MAX_LAYERS  # an energy fraction network per layer count, each on its own data


def weights_path(n_layers: int) -> Path:
    return WEIGHTS / f"spongecake_ms_{n_layers}layer.npz"


def network(n_layers: int) -> mlp.MLP:
    """The network that predicts stacks of ``n_layers`` (deeper ones: the two-layer network, grouped)."""
    if not 1 <= n_layers <= model.MAX_LAYERS:
        raise ValueError(f"stacks have 1 to {model.MAX_LAYERS} layers, got {n_layers}")
    return mlp.load(weights_path(min(n_layers, NETWORK_LAYERS)))


def scales_forward_by_area(n_layers: int) -> bool:
    """Whether the network for stacks of ``n_layers`` predicts the area exponents (``decode``)."""
    return network(n_layers).weights[-1].shape[1] == output_widths(min(n_layers, NETWORK_LAYERS))[2]


def energy_weights_path(n_layers: int) -> Path:
    return WEIGHTS / f"spongecake_ms_energy_{n_layers}layer.npz"


def energy_network(n_layers: int) -> mlp.MLP:
    """The network that predicts the energy fraction (``energy_fraction``) of stacks of ``n_layers`` (1 to
    ``ENERGY_NETWORK_LAYERS``)."""
    if not 1 <= n_layers <= ENERGY_NETWORK_LAYERS:
        raise ValueError(f"energy fraction networks are trained for 1 to {ENERGY_NETWORK_LAYERS} layers, "
                         f"got {n_layers}")
    return mlp.load(energy_weights_path(n_layers))


# A manifest's records of how its network scores (``train --rescore`` rewrites them): not what the network predicts.
SCORE_RECORDS = ("held_out_validation", "held_out_per_config", "held_out_scored_by")


def ms_identity(n_layers: int) -> list:
    """What a stack's multiple scattering comes from: the manifests of the networks that predict it (lobes and
    energy fraction) without their ``SCORE_RECORDS``, and the version of what is made from the prediction
    (``MS_VERSION``, e.g. the energy scale); part of bake keys and fit keys, so that scoring the same weights on
    another held-out set asks for no re-bake and no refit."""
    return [{k: v for k, v in net.manifest.items() if k not in SCORE_RECORDS}
            for net in (network(n_layers), energy_network(n_layers))] + [MS_VERSION]


# ------------------------------------------------------------------------------------------- encoding

def _log_unit(x, lo, hi, xp=np):
    """log x mapped from [lo, hi] to [-1, 1] (clamped)."""
    t = (xp.log(xp.clip(x, lo, hi)) - math.log(lo)) / (math.log(hi) - math.log(lo))
    return 2.0 * t - 1.0


def features(rows: np.ndarray) -> np.ndarray:
    """(N, L, ROW) layer rows → (N, L * FEATURES) network inputs (see the module docstring)."""
    rows = np.asarray(rows, dtype=np.float64)
    kind = np.rint(rows[..., rows_.TYPE]).astype(int)
    is_hg = kind == 2
    one_hot = np.eye(3)[kind]
    rough = np.where(is_hg, np.clip(rows[..., rows_.ROUGHNESS] / G_MAX, -1.0, 1.0),
                     _log_unit(rows[..., rows_.ROUGHNESS], *ALPHA_RANGE))
    orientation = rows[..., rows_.ORIENTATION] * np.where(rows[..., rows_.ORIENTATION.stop - 1:] < 0, -1.0, 1.0)
    orientation = np.where(is_hg[..., None], 0.0, orientation)
    parts = [one_hot, rough[..., None], 2.0 * rows[..., rows_.ALBEDO] - 1.0,
             _log_unit(np.maximum(rows[..., rows_.THICKNESS], 1e-12), *THICKNESS_IN)[..., None],
             2.0 * rows[..., rows_.F0] - 1.0, orientation]
    x = np.concatenate(parts, axis=-1)
    return x.reshape(x.shape[0], -1)


# ------------------------------------------------------------------------------------------- decoding

class NumpyOps:
    exp, tanh, sqrt, log = np.exp, np.tanh, np.sqrt, np.log
    where = staticmethod(np.where)

    @staticmethod
    def sigmoid(x):
        return 0.5 * (1.0 + np.tanh(0.5 * x))

    @staticmethod
    def softplus(x):
        return np.logaddexp(x, 0.0)

    clip = staticmethod(np.clip)

    @staticmethod
    def any_last(x):
        return x.any(axis=-1, keepdims=True)

    @staticmethod
    def sum_last(x):
        return x.sum(axis=-1, keepdims=True)

    @staticmethod
    def stack(parts, axis):
        return np.stack(parts, axis=axis)

    @staticmethod
    def concat(parts, axis):
        return np.concatenate(parts, axis=axis)


def _logit(x, ops, eps=1e-4):
    x = ops.clip(x, eps, 1.0 - eps)
    return ops.log(x) - ops.log(1.0 - x)


def _log_range(x, lo, hi, ops, r):
    """x moved by r in the logit of its log-position in [lo, hi]: x itself at r = 0, always inside (lo, hi)."""
    u = (ops.log(ops.clip(x, lo, hi)) - math.log(lo)) / (math.log(hi) - math.log(lo))
    return ops.exp(math.log(lo) + ops.sigmoid(_logit(u, ops) + r) * (math.log(hi) - math.log(lo)))


def decode(raw, rows, ops=NumpyOps):
    """Raw network outputs (N, L * OUTPUTS + 7 [+ 5 [+ L]]) and the input rows (N, L, ROW) → (lobe rows (N, L, ROW)
    with W1 folded into the albedo, weights (N, 11 + L): W2r RGB, W2t RGB, the forward lobe's g, albedo RGB, Tρ and
    the area exponents (columns ``W2R`` ... ``AREA``; albedo 0 without ``FORWARD_OUTPUTS``, exponents 0 without
    theirs)). ``ops`` is the array namespace (numpy or torch). Every lobe parameter is a residual on the layer's own
    value (a zero output keeps it), moved in an unbounded coordinate: the logit of albedo and f0, of the
    log-position of α and Tρ in their ranges, atanh of g."""
    n_layers = rows.shape[1]
    known = output_widths(n_layers)
    if raw.shape[1] not in known:
        raise ValueError(f"raw outputs for {n_layers} layers are {', '.join(map(str, known))} wide, these "
                         f"{raw.shape[1]}")
    layers = []
    weights = ops.softplus(raw[:, n_layers * OUTPUTS:n_layers * OUTPUTS + WEIGHT_OUTPUTS])
    for k in range(n_layers):
        r = raw[:, k * OUTPUTS:(k + 1) * OUTPUTS]
        row = rows[:, k]
        kind = row[:, rows_.TYPE:rows_.TYPE + 1]
        is_hg = kind > 1.5
        rough_in = row[:, rows_.ROUGHNESS:rows_.ROUGHNESS + 1]
        g = G_MAX * ops.tanh(0.5 * _logit(0.5 + 0.5 * rough_in / G_MAX, ops) + r[:, 0:1])
        rough = ops.where(is_hg, g, _log_range(rough_in, *ALPHA_RANGE, ops, r[:, 0:1]))
        albedo = ops.sigmoid(_logit(row[:, rows_.ALBEDO], ops) + r[:, 1:4]) * weights[:, 0:1]
        thickness = _log_range(row[:, rows_.THICKNESS:rows_.THICKNESS + 1], *THICKNESS_OUT, ops, r[:, 4:5])
        has_fresnel = ops.any_last(row[:, rows_.F0] < 1.0) & ~is_hg
        f0 = ops.where(has_fresnel, ops.sigmoid(_logit(row[:, rows_.F0], ops) + r[:, 5:8]), 1.0 + 0.0 * r[:, 5:8])
        o = row[:, rows_.ORIENTATION] + ops.tanh(r[:, 8:11])
        o = o / ops.sqrt(ops.sum_last(o * o) + 1e-12)
        layers.append(ops.concat([kind, rough, albedo, thickness, f0, o], axis=1))
    return ops.stack(layers, axis=1), ops.concat([weights[:, 1:7], _forward(raw, n_layers, ops),
                                                  _area_exponents(raw, n_layers, ops)], axis=1)


def cycles_weights(rows, weights) -> np.ndarray:
    """Decoded weights (N, 11 + L) of stacks ``rows`` (N, L, ROW) as the Cycles forms take them (N, 11): the
    forward lobe's albedo times its area scale for both directions along the normal (``normal_area_scale``; the
    forms' multiple-scattering closure weights are those of the view along the normal), the exponents dropped."""
    out = np.array(weights[:, :AREA.start], dtype=np.float64)
    out[:, FORWARD_ALBEDO] *= normal_area_scale(rows, weights[:, AREA])[:, None]
    return out


def normal_area_scale(rows, exponents) -> np.ndarray:
    """Π_k σ_k(n)^(2 p_k) (N,): ``reference.spongecake.area_scale`` at wi = wo = n for stacks of layer rows (N, L,
    ROW) and exponents (N, L). Along the normal σ² is α² + (1 − α²) cos² for flakes about a normal at cos to n,
    1 + (α² − 1) cos² for fibers along a tangent at cos to n (the SGGX matrices of ``reference.sggx``), 1 for hg."""
    rows = np.asarray(rows, dtype=np.float64)
    o = rows[..., rows_.ORIENTATION]
    cos2 = o[..., 2] ** 2 / np.maximum(np.sum(o * o, axis=-1), 1e-300)
    sigma2 = projected_area2(rows[..., rows_.TYPE], rows[..., rows_.ROUGHNESS] ** 2, cos2)
    return np.exp(np.sum(np.asarray(exponents) * np.log(np.maximum(sigma2, 1e-300)), axis=-1))


def projected_area2(kind, alpha2, cos2):
    """σ² of layers of type ``kind`` (row codes) and roughness² ``alpha2`` along a direction at cos² ``cos2`` to their
    orientation: α² + (1 − α²) cos² for flakes, 1 + (α² − 1) cos² for fibers (the SGGX matrices of ``reference.sggx``),
    1 for hg."""
    flakes, fibers = alpha2 + (1.0 - alpha2) * cos2, np.maximum(1.0 + (alpha2 - 1.0) * cos2, 0.0)
    return np.where(kind < 0.5, flakes, np.where(kind < 1.5, fibers, 1.0))


def output_widths(n_layers: int) -> tuple:
    """The raw output widths a network for ``n_layers`` may have: without the forward lobe, with it, and with the
    area exponents too."""
    plain = n_layers * OUTPUTS + WEIGHT_OUTPUTS
    return plain, plain + FORWARD_OUTPUTS, plain + FORWARD_OUTPUTS + n_layers


def _area_exponents(raw, n_layers: int, ops):
    """The area exponents p_k (N, L): softplus of the last L raw outputs; 0 for a network without them."""
    start = output_widths(n_layers)[1]
    if raw.shape[1] < start + n_layers:
        return 0.0 * raw[:, :n_layers]
    return ops.softplus(raw[:, start:start + n_layers])


def _forward(raw, n_layers: int, ops):
    """The forward lobe's (g, albedo RGB, Tρ) (N, 5) from the last ``FORWARD_OUTPUTS`` raw outputs; (0, 0, 0, 0, 1)
    for a network without them."""
    start = n_layers * OUTPUTS + WEIGHT_OUTPUTS
    zero = 0.0 * raw[:, :1]
    if raw.shape[1] < start + FORWARD_OUTPUTS:
        return ops.concat([zero, zero, zero, zero, zero + 1.0], axis=1)
    r = raw[:, start:start + FORWARD_OUTPUTS]
    return ops.concat([FORWARD_G_MAX * ops.tanh(r[:, 0:1]), ops.softplus(r[:, 1:4]),
                       _log_range(zero + 1.0, *THICKNESS_OUT, ops, r[:, 4:5])], axis=1)


# ------------------------------------------------------------------------------------------ inference

def predict_rows(rows: np.ndarray, net: mlp.MLP | None = None):
    """Per row set (N, L, ROW) with light from above: (lobe rows (N, L, ROW), (N, 6) Lambert weights W2r, W2t);
    the shipped network for L layers, or ``net``; more than ``NETWORK_LAYERS`` layers grouped (module docstring)."""
    rows = np.asarray(rows, dtype=np.float64)
    if rows.shape[1] <= NETWORK_LAYERS:
        return decode((net or network(rows.shape[1]))(features(rows)), rows)
    lumped, groups = lumped_rows(rows)
    return decode(grouped_raw((net or network(rows.shape[1]))(features(lumped)), groups, rows), rows)


def lumped_rows(rows: np.ndarray):
    """(N, L, ROW) rows of L > 2 layers → (N, 2, ROW) rows of their top and bottom groups, and the group of each layer
    (N, L) (0 top, 1 bottom). The split leaves the most even optical thickness on both sides; a group is lumped into
    its thickest layer with the group's summed thickness and thickness-weighted albedo (a summed thickness above the
    network's input range acts as its end, as for any layer: ``features``)."""
    n, n_layers = rows.shape[:2]
    thickness = rows[..., rows_.THICKNESS]
    above = np.cumsum(thickness, axis=1)[:, :-1]  # thickness of the top group for splits after layer 0 .. L-2
    split = 1 + np.argmin(np.abs(2.0 * above - thickness.sum(axis=1, keepdims=True)), axis=1)
    groups = (np.arange(n_layers)[None, :] >= split[:, None]).astype(int)
    lumped = np.empty((n, 2, rows.shape[2]))
    for g in (0, 1):
        member = groups == g
        t = np.where(member, thickness, 0.0)
        thickest = _thickest(thickness, member)
        lumped[:, g] = rows[np.arange(n), thickest]
        total = t.sum(axis=1)
        lumped[:, g, rows_.THICKNESS] = total
        weights = np.where(total[:, None] > 0, t / np.maximum(total, 1e-300)[:, None],
                           np.arange(n_layers)[None, :] == thickest[:, None])  # all empty: the thickest's albedo
        lumped[:, g, rows_.ALBEDO] = np.einsum("nl,nlc->nc", weights, rows[..., rows_.ALBEDO])
    return lumped, groups


def _thickest(thickness: np.ndarray, member: np.ndarray) -> np.ndarray:
    """(N,) the index of the thickest layer among the ``member`` ones (N, L): the layer a lumped group stands for."""
    return np.argmax(np.where(member, thickness, -1.0), axis=1)


def grouped_raw(raw: np.ndarray, groups: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The two-layer network's raw outputs (N, 2 OUTPUTS + 7 [+ 5 [+ 2]]) spread to the L layers of ``rows`` (N, L
    OUTPUTS + 7 [+ 5 [+ L]]): each layer takes its group's residuals, the weights and the forward lobe stay; a
    group's area exponent goes to the layer whose projected area the lumped layer has (its thickest), the others
    get none (raw −∞: exponent 0)."""
    n, n_layers = groups.shape
    layer_part = raw[:, :2 * OUTPUTS].reshape(n, 2, OUTPUTS)
    per_layer = np.take_along_axis(layer_part, groups[:, :, None], axis=1)
    shared = raw[:, 2 * OUTPUTS:output_widths(2)[1]]
    if raw.shape[1] < output_widths(2)[2]:
        return np.concatenate([per_layer.reshape(n, -1), shared], axis=1)
    area = np.full((n, n_layers), -np.inf)
    thickness = rows[..., rows_.THICKNESS]
    for g in (0, 1):
        thickest = _thickest(thickness, groups == g)
        area[np.arange(n), thickest] = raw[:, output_widths(2)[1] + g]
    return np.concatenate([per_layer.reshape(n, -1), shared, area], axis=1)


@dataclass(frozen=True)
class Prediction:
    """The multiple-scattering lobes of one stack seen from above and from below (the flipped stack's)."""

    lobe: model.Params
    reflection: tuple  # W2r, RGB
    transmission: tuple  # W2t, RGB
    forward: model.Params  # the forward lobe: one hg layer
    lobe_below: model.Params
    reflection_below: tuple
    transmission_below: tuple
    forward_below: model.Params
    # the forward lobe's area exponents per layer, top first (``AREA``, ``reference.spongecake.area_scale``)
    forward_area: tuple
    forward_area_below: tuple


def predict(params: model.Params) -> Prediction:
    """The shipped network's prediction for the stack (cached per stack and weights folder, ``WEIGHTS``)."""
    return _predict(params, str(WEIGHTS))


@lru_cache(maxsize=256)
def _predict(params: model.Params, weights: str) -> Prediction:
    return _prediction(*predict_rows(_both_sides(params)))


def forget_networks() -> None:
    """Drop the loaded networks and their cached predictions (after a weights file changed in place)."""
    mlp.load.cache_clear()
    _predict.cache_clear()


def predict_with(net: mlp.MLP, params: model.Params) -> Prediction:
    """``predict`` with a given network (e.g. one being exported), uncached."""
    return _prediction(*predict_rows(_both_sides(params), net))


def _both_sides(params: model.Params) -> np.ndarray:
    rows = rows_.stack_rows(params)
    return np.stack([rows, rows_.flipped(rows)])


def _prediction(lobes, weights) -> Prediction:
    above = rows_.params_from_rows(lobes[0])
    below = rows_.params_from_rows(rows_.flipped(lobes[1]))
    return Prediction(above, tuple(weights[0, W2R]), tuple(weights[0, W2T]), forward_params(weights[0]),
                      below, tuple(weights[1, W2R]), tuple(weights[1, W2T]), forward_params(weights[1]),
                      tuple(map(float, weights[0, AREA])), tuple(map(float, weights[1, AREA][::-1])))


# ------------------------------------------------------------------------------------ energy fraction

def channel_rows(rows: np.ndarray, c: int) -> np.ndarray:
    """Rows (N, L, ROW) whose albedo and f0 are channel ``c``'s in all three channels: the channels are independent
    random-walk experiments, so the energy network sees one channel at a time."""
    out = np.array(rows, dtype=np.float64)
    out[..., rows_.ALBEDO] = out[..., rows_.ALBEDO][..., c:c + 1]
    out[..., rows_.F0] = out[..., rows_.F0][..., c:c + 1]
    return out


ENERGY_FEATURES = FEATURES + 3  # per layer: ``features``, √(1 − albedo), √(1 − f0), log(albedo f0) of the channel
LOG_ENERGY_FLOOR = 1e-3  # the least albedo f0 the last of them tells apart


ENERGY_VIEW_FEATURES = 3  # per layer, after w: what the view meets (``view_features``)


def energy_input_count(n_layers: int, view: bool) -> int:
    """The energy network's inputs for ``n_layers`` layers, with ``view_features`` or without (the first format)."""
    return n_layers * (ENERGY_FEATURES + ENERGY_VIEW_FEATURES * view) + 3


def energy_inputs(rows: np.ndarray, w: np.ndarray, view: bool = True) -> np.ndarray:
    """(N, 3, ``energy_input_count``) inputs of the energy network for stacks (N, L, ROW) seen along w (N, 3)
    from above, per channel: per layer ``features`` of the channel's rows, √(1 − albedo) and √(1 − f0) (multiply
    scattered light falls like √(1 − albedo) near white: similarity theory), log(albedo f0) / |log floor| (each
    bounce multiplies by about albedo f0, so the share left after a few is a power of it), then w in the stack's
    frame, then (``view``) each layer's ``view_features``."""
    rows, w = np.asarray(rows, dtype=np.float64), np.asarray(w, dtype=np.float64)
    n, n_layers = rows.shape[:2]
    seen = [view_features(rows, w)] if view else []

    def of_channel(c):
        one = channel_rows(rows, c)
        albedo, f0 = one[..., rows_.ALBEDO.start], one[..., rows_.F0.start]
        near_white = np.sqrt(np.clip(1.0 - np.stack([albedo, f0], axis=-1), 0.0, 1.0))
        per_bounce = np.log(np.maximum(albedo * f0, LOG_ENERGY_FLOOR)) / -math.log(LOG_ENERGY_FLOOR)
        per_layer = np.concatenate([features(one).reshape(n, n_layers, FEATURES), near_white, per_bounce[..., None]],
                                   axis=2)
        return np.concatenate([per_layer.reshape(n, -1), w, *seen], axis=1)

    return np.stack([of_channel(c) for c in range(3)], axis=1)


def view_features(rows: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N, L * ENERGY_VIEW_FEATURES) what the view w (N, 3) meets in each layer of stacks (N, L, ROW): c² for c = w·o
    (o the unit orientation), the projected area σ(w) of the layer's SGGX distribution (``projected_area2``;
    research notes §1), and for surface flakes the z of w's
    mirror image about o, 2 c o_z − w_z (where a smooth flake sends the light: back up, or down into the stack; 0
    for other layers). What the network would have to learn from products of its inputs, given: the light a tilted
    smooth layer multiply scatters follows these, not the azimuth alone. Unchanged by turns and mirrors about the
    normal (``training.energy_train.rotated``)."""
    kind = np.rint(rows[..., rows_.TYPE]).astype(int)
    o = rows[..., rows_.ORIENTATION]
    o = o / np.maximum(np.linalg.norm(o, axis=-1, keepdims=True), 1e-12)
    c = np.einsum("nlk,nk->nl", o, w)
    sigma = np.sqrt(projected_area2(kind, np.clip(rows[..., rows_.ROUGHNESS], *ALPHA_RANGE) ** 2, c * c))
    surface, flake = kind == 0, kind <= 1
    mirror_z = np.where(surface, 2.0 * c * o[..., 2] - w[:, None, 2], 0.0)
    out = np.stack([np.where(flake, c * c, 0.0), sigma, mirror_z], axis=-1)
    return out.reshape(len(rows), -1)


def fraction_rows(rows: np.ndarray, w: np.ndarray, net: mlp.MLP | None = None) -> np.ndarray:
    """The energy fraction (N, 3) of stacks (N, L, ROW) seen along w (N, 3) from above: the share of what single
    scattering and the Dirac leave that multiple scattering returns (``energy_fraction``); the shipped network for L
    layers, or ``net`` (with ``view_features`` where its inputs count them)."""
    rows = np.asarray(rows, dtype=np.float64)
    net = net or energy_network(rows.shape[1])
    x = energy_inputs(rows, w, view=net.weights[0].shape[0] == energy_input_count(rows.shape[1], True))
    raw = net(x.reshape(-1, x.shape[-1])).reshape(len(rows), 3)
    return 1.0 / (1.0 + np.exp(-np.clip(raw, -60.0, 60.0)))


def energy_fraction(params: model.Params, w: np.ndarray, net: mlp.MLP | None = None) -> np.ndarray:
    """(N, 3) the share q(ω) of left = 1 − A_ss − T_δ (what single scattering and the Dirac leave of the light
    arriving along ω) that multiple scattering returns, predicted for the stack's layers without a substrate: views
    above by the stack, views below by the flipped stack (as the lobes). By reciprocity q at a view is q for light
    from that direction, what the network was trained on (``training.energy_train``)."""
    w = np.asarray(w, dtype=np.float64)
    up = w[:, 2] > 0
    rows = np.where(up[:, None, None], rows_.stack_rows(params)[None], rows_.flipped(rows_.stack_rows(params))[None])
    seen_from_above = w.copy()
    seen_from_above[:, 2] = np.abs(w[:, 2])
    return fraction_rows(rows, seen_from_above, net)


def forward_params(weights) -> model.Params:
    """The forward lobe of one row of decoded weights (``decode``) as a one-layer hg stack."""
    return model.Params((model.Layer("hg", float(weights[FORWARD_G]), tuple(map(float, weights[FORWARD_ALBEDO])),
                                     float(weights[FORWARD_THICKNESS]), (1.0, 1.0, 1.0), (0.0, 0.0, 1.0)),))


# ------------------------------------------------------------------------------------ energy scale

def energy_scale(left, lobes, limit=1.0):
    """Multiple scattering's energy scale (..., 3) from what single scattering and the Dirac leave of the stack
    (``left``) and the albedo of the network's lobes (``lobes``): (left − ``ENERGY_MARGIN``) / lobes, so that single
    plus multiple scattering never return more than they receive, even where the estimates of ``left`` and
    ``lobes`` err by their noise; at most ``limit`` (1: the network's lobes as predicted wherever they fit in;
    ``white_limit`` for stacks that conserve energy once white)."""
    share = np.where(lobes > 1e-9, np.maximum(left - model.ENERGY_MARGIN, 0.0) / np.maximum(lobes, 1e-9), np.inf)
    return np.minimum(share, limit)


def energy_budget(left, lobes, limit=1.0):
    """The Cycles forms' energy budget (..., 3): 1 + ``energy_scale`` where single scattering and the Dirac leave at
    least ``ENERGY_MARGIN``, else (1 − m) / (1 − left) < 1. A form's single scattering can return more than the
    layers intercept (thin, very rough layers seen near grazing: the mirror approximation's G and the Lambert
    translucency each take much of it); the forms scale their single scattering and Dirac by min(budget, 1), which
    brings them down to 1 − m there, and multiple scattering by max(budget − 1, 0). One non-negative value carries
    both, so it fits the colour inputs and images that carry the scale."""
    room = np.maximum(1.0 - left, 1e-9)
    return np.where(left < model.ENERGY_MARGIN, (1.0 - model.ENERGY_MARGIN) / room,
                    1.0 + energy_scale(left, lobes, limit))


WHITENESS_POWER = 16  # the whiteness of a stack: its smallest albedo to this power (``whiteness_of``)


def whiteness_of(params: model.Params, power: int = WHITENESS_POWER) -> np.ndarray:
    """(3,) how close a stack is to white, per channel: its smallest albedo (layers and a diffuse substrate) to the
    ``power`` (``WHITENESS_POWER``: 1 for white, 0.44 at 0.95, 0.03 at 0.8): light scattered many times has met the
    darkest scatterer."""
    albedos = [layer.albedo for layer in params.layers]
    if params.substrate is not None and params.substrate.type == "diffuse":
        albedos.append(params.substrate.albedo)
    return np.min(np.asarray(albedos, dtype=np.float64), axis=0) ** power


def budget_rows(params: model.Params, left_of, lobes_of, rows: int, phi, substeps: int,
                phi_substeps: int = 1, fraction: bool = True) -> np.ndarray:
    """The Cycles forms' energy budget (``energy_budget``; rows, len(phi), 3) on the view tables' cosines
    (``models.spongecake.view_table_cosines(rows)``) and the azimuths ``phi`` (uniform over the circle from 0 where
    there are several), interpolated linearly between them and made safe between them (``safe_between``), computed
    ``substeps`` times finer along the rows' coordinate. With ``phi_substeps`` 1 (isotropic stacks, whose budget is
    smooth; one azimuth) the rows are lowered only where the budget caps single scattering. With ``phi_substeps`` > 1
    (oriented stacks) the budget is as many times finer in the azimuth too, and rows and columns are lowered wherever
    interpolation would return more light than the finer budget by ``SAFE_TOLERANCE`` (``furnace_weights``): a tilted
    closure normal that Cycles bends makes the budget leap within a few degrees, near the normal view as well as near
    grazing. ``fraction``: as ``energy_grid``'s."""
    fine_mu = _fine_cosines(rows, substeps)
    phi = np.asarray(phi, dtype=np.float64)
    if phi_substeps == 1:
        return safe_between(energy_grid(params, left_of, lobes_of, fine_mu, phi, scale_of=energy_budget,
                                        fraction=fraction), substeps)
    budget_and_weights, weights = _recording_furnace_weights()
    fine_phi = np.asarray(model.uniform_azimuths(len(phi) * phi_substeps))
    fine = energy_grid(params, left_of, lobes_of, fine_mu, fine_phi, scale_of=budget_and_weights, fraction=fraction)
    weight = weights[0].reshape(fine.shape)
    table = safe_between(fine, substeps, weight)

    def wrapped(a):  # the azimuth wraps around: the first column again at the end, columns first
        return np.concatenate([a, a[:, :1]], axis=1).swapaxes(0, 1)

    return safe_between(wrapped(table), phi_substeps, wrapped(weight[::substeps])).swapaxes(0, 1)[:, :-1]


def driven_budget_rows(stacks: list, left_of, lobes_of, rows: int, substeps: int, value_substeps: int,
                       fraction: bool = True) -> np.ndarray:
    """The Cycles forms' energy budget (rows, V, 3) of an isotropic stack one of whose inputs a texture drives:
    ``stacks`` holds the stack at (V − 1) ``value_substeps`` + 1 values of that input, ascending, and column v is the
    budget of its (v ``value_substeps``)-th stack as ``budget_rows`` makes it (one azimuth), lowered where linear
    interpolation between the columns would return more light than a stack between them by ``SAFE_TOLERANCE``
    (``furnace_weights``, as an oriented stack's azimuth columns), so that a texel between two tabulated values
    gains no energy either."""
    fine_mu = _fine_cosines(rows, substeps)
    budget_and_weights, weights = _recording_furnace_weights()
    fine = np.concatenate([energy_grid(p, left_of, lobes_of, fine_mu, np.zeros(1), scale_of=budget_and_weights,
                                       fraction=fraction) for p in stacks], axis=1)
    table = safe_between(fine, substeps)  # each column's rows, as ``budget_rows``'
    weight = np.stack(weights, axis=1)[::substeps]
    return safe_between(table.swapaxes(0, 1), value_substeps, weight.swapaxes(0, 1)).swapaxes(0, 1)


def _fine_cosines(rows: int, substeps: int) -> np.ndarray:
    return np.asarray(model.view_table_cosines((rows - 1) * substeps + 1))


def _recording_furnace_weights():
    """``energy_budget`` as an ``energy_grid`` ``scale_of`` that also records each call's ``furnace_weights``, and
    the list it records them in."""
    weights = []

    def budget_and_weights(left, lobes, limit):
        budget = energy_budget(left, lobes, limit)
        weights.append(furnace_weights(budget, left, lobes))
        return budget

    return budget_and_weights, weights


def furnace_weights(budget, left, lobes):
    """How much a white furnace's return changes per unit of budget: below 1 the budget scales single scattering and
    the Dirac (1 − ``left``), above 1 multiple scattering (``lobes``)."""
    return np.where(budget < 1.0, 1.0 - left, lobes)


# Interpolation may exceed the budget it interpolates by this much (of the furnace's return, with weights) before
# ``safe_between`` lowers it.
SAFE_TOLERANCE = 1e-3


def safe_between(fine, substeps: int, weight=None) -> np.ndarray:
    """Every ``substeps``-th row of ``fine`` (rows along the first axis), lowered so that linear interpolation between
    the rows does not exceed ``fine`` (at its resolution) by more than ``SAFE_TOLERANCE``: there the higher end is
    lowered as far as needed, and the lower end too where that is not enough. Without ``weight``, only in the
    intervals where ``fine`` dips below 1 (where the budget caps single scattering): near grazing, a thin, very rough
    layer's budget can leap within one interval from below 1 to several, and interpolating across the leap would let
    the form's single scattering return more light than it receives; elsewhere the rows are kept, since lowering them
    wherever a smooth budget is convex costs more energy at the rows than it saves between them (docs/training.md).
    With ``weight`` (``furnace_weights`` at ``fine``'s points), in every interval where the excess times the weight,
    the light it adds to a white furnace, exceeds the tolerance."""
    rows = fine[::substeps].copy()
    t = (np.arange(substeps + 1) / substeps).reshape((-1,) + (1,) * (fine.ndim - 1))
    for k in range(len(rows) - 1):
        segment = fine[k * substeps:(k + 1) * substeps + 1]
        a, b = rows[k], rows[k + 1]
        excess = (1.0 - t) * a + t * b - segment
        if weight is None:
            unsafe = (excess.max(axis=0) > SAFE_TOLERANCE) & (segment.min(axis=0) < 1.0)
        else:
            unsafe = (excess * weight[k * substeps:(k + 1) * substeps + 1]).max(axis=0) > SAFE_TOLERANCE
        if not unsafe.any():
            continue
        first_lower = a <= b
        w = np.where(first_lower, t, 1.0 - t)  # the higher end's weight at each point
        low, high = np.minimum(a, b), np.maximum(a, b)
        inner, outer = w < 1.0, w > 0.0
        low = np.minimum(low, np.where(inner, segment / np.where(inner, 1.0 - w, 1.0), np.inf).min(axis=0))
        most = np.where(outer, (segment - (1.0 - w) * low) / np.where(outer, w, 1.0), np.inf).min(axis=0)
        high = np.minimum(high, np.maximum(most, 0.0))
        rows[k] = np.where(unsafe, np.where(first_lower, low, high), a)
        rows[k + 1] = np.where(unsafe, np.where(first_lower, high, low), b)
    return rows


def energy_table(params: model.Params, left_of, lobes_of, side: float = 1.0) -> np.ndarray:
    """The reference's energy scale (``ENERGY_KNOTS``, P, 3) on ``models.spongecake.energy_cosines`` for views above
    (side 1) or below (-1): ``energy_grid`` on those knots and, where a layer is oriented off the normal (the scale
    then depends on the view's azimuth), at ``ENERGY_AZIMUTHS`` azimuths (``energy_azimuths``; P = 1 for isotropic
    stacks)."""
    return energy_grid(params, left_of, lobes_of, np.asarray(model.energy_cosines()), energy_azimuths(params), side)


def energy_grid(params: model.Params, left_of, lobes_of, mu, phi, side: float = 1.0,
                scale_of=energy_scale, fraction: bool = True) -> np.ndarray:
    """The energy scale (len(mu), len(phi), 3) at the view cosines ``mu`` (increasing; a last 1 is the normal view)
    and azimuths ``phi``: ``scale_of`` (``energy_scale`` or ``energy_budget``) of ``left_of(params, wo)`` and
    ``lobes_of(params, wo)`` (the reference's or a Cycles form's, (N, 3) each), limited by ``fraction_limit`` where
    the stack takes the energy fraction (``takes_fraction``; unless ``fraction`` is False: a texture-driven material
    whose budget cannot follow its texels, ``nodes.spongecake.TexelEnergy``), else by ``white_limit`` where the
    stack conserves energy once white. The len(phi) estimates at the normal view, one view, are averaged."""
    wo = spherical(np.repeat(side * mu, len(phi)), np.tile(phi, len(mu)))

    def albedos(stack):
        return _normal_view_averaged(left_of(stack, wo), mu), _normal_view_averaged(lobes_of(stack, wo), mu)

    left, lobes = albedos(params)
    limit, whiteness = 1.0, whiteness_of(params)
    if fraction and takes_fraction(params):
        limit = fraction_limit(params, wo, mu, left, lobes)
    elif model.conserving(params) and whiteness.max() > NEGLIGIBLE_WHITENESS:
        if np.all(whiteness == 1.0):  # already white: the white stack is this one
            limit = white_limit(left, lobes, whiteness)
        else:
            limit = white_limit(*albedos(model.white(params)), whiteness)
    return scale_of(left, lobes, limit).reshape(len(mu), len(phi), 3)


def takes_fraction(params: model.Params) -> bool:
    """Whether the energy scale follows the energy fraction network: stacks without a substrate (over one it has no
    data). Stacks of 3 and 4 layers take it since networks of their own were trained on 15000 stacks each
    (docs/training.md, *Stacks of 3 and 4 layers*)."""
    return params.substrate is None


# A white stack's energy fraction is 1 (what single scattering leaves, multiple scattering returns); within the
# network's error of it for stacks close to white: their fraction moves to 1 by their smallest albedo to this power
# (0.77 at 0.999, 0.08 at 0.99).
FRACTION_WHITENESS_POWER = 256
MAX_SCALE = 20.0  # the most the energy fraction may scale the network's lobes by (their own energy is then tiny)


def fraction_limit(params: model.Params, wo, mu, left, lobes) -> np.ndarray:
    """The energy scale's limit (len(wo), 3) for a stack that takes the energy fraction (``takes_fraction``):
    q left / E, the scale that gives the lobes the energy fraction q (``energy_fraction``) of what single scattering
    and the Dirac leave, at most ``MAX_SCALE``; q moves to 1 for stacks that conserve energy once white, by their
    whiteness (``FRACTION_WHITENESS_POWER``), so that a white stack returns exactly what it receives less the
    margin."""
    fraction = _normal_view_averaged(energy_fraction(params, wo), mu)
    if model.conserving(params):
        white = whiteness_of(params, FRACTION_WHITENESS_POWER)
        fraction = white + (1.0 - white) * fraction
    target = fraction * np.maximum(left, 0.0)
    return np.minimum(np.divide(target, lobes, out=np.full_like(target, MAX_SCALE), where=lobes > 1e-9), MAX_SCALE)


def _normal_view_averaged(albedo, mu):
    """Albedos (len(mu) P, 3) in ``energy_grid``'s order with the P estimates at μ = 1, which all see along the
    normal, replaced by their mean (P times the samples: less noise)."""
    per_knot = albedo.reshape(len(mu), -1, 3).copy()
    if mu[-1] == 1.0:
        per_knot[-1] = per_knot[-1].mean(axis=0)
    return per_knot.reshape(albedo.shape)


# Below this whiteness the white stack's limit differs from 1 by less than this share of (ratio - 1): 1 is taken.
NEGLIGIBLE_WHITENESS = 1e-6


def energy_azimuths(params: model.Params) -> np.ndarray:
    """The view azimuths of the energy tables: ``ENERGY_AZIMUTHS`` uniform ones from 0 where a layer is oriented off
    the normal, the one azimuth 0 otherwise."""
    return np.asarray(model.uniform_azimuths(model.ENERGY_AZIMUTHS if model.anisotropic(params) else 1))


def white_limit(left_white, lobes_white, whiteness):
    """The limit of the energy scale (..., 3) of a stack that conserves energy once white
    (``models.spongecake.conserving``): left_white / lobes_white, the scale that gives the white stack exactly its
    leftover, for a white stack; 1 (the network's lobes) far from white; in between by ``whiteness``."""
    ratio = np.where(lobes_white > 1e-9, np.maximum(left_white, 0.0) / np.maximum(lobes_white, 1e-9), 1.0)
    return 1.0 + np.asarray(whiteness) * (ratio - 1.0)
