"""The analytic single scattering against an independent random walk, and its exact identities.

Ground-truth error metric: per colour channel, mean |reference - walk| / mean(walk) over a 16 x 16 grid of
(wi, wo) pairs (polar angles 15-72 degrees, four azimuths each), with the walk's order-1 estimate.
"""
import numpy as np
import pytest

from addon import presets
from addon.models import spongecake as model
from addon.reference import frames, microfacet, spongecake
from stats import sphere_directions, unit


def _params(**stack):
    return spongecake.params_from_dict(stack)


def _grid(side=1.0):
    theta, phi = np.meshgrid(np.radians([15, 35, 55, 72]), np.radians([10, 100, 190, 280]), indexing="ij")
    return frames.spherical(side * np.cos(theta).ravel(), phi.ravel())


def _midpoint_sphere(n_theta, n_phi):
    """Centres of equal-area (cos theta, phi) cells: a midpoint rule with weight 4 pi / (n_theta n_phi)."""
    c = -1 + (np.arange(n_theta) + 0.5) * 2 / n_theta
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    c, phi = np.meshgrid(c, phi, indexing="ij")
    return frames.spherical(c.ravel(), phi.ravel())


def _pairs(wi_side, wo_side):
    """All 16 x 16 pairs of the grid, wi and wo on the given sides (+1 above, -1 below)."""
    wi, wo = _grid(wi_side), _grid(wo_side)
    return np.repeat(wi, len(wi), axis=0), np.tile(wo, (len(wo), 1))


REFLECTION, TRANSMISSION, FROM_BELOW, BELOW_TO_ABOVE = (1, 1), (1, -1), (-1, -1), (-1, 1)
THREE_LAYERS = [dict(type="surface", roughness=0.3, thickness=0.3), dict(type="hg", roughness=-0.3, thickness=0.5),
                dict(type="fiber", roughness=0.6, orientation=[0, 0.6, 0.8])]
FLAKES_OVER_GLASS = dict(layers=[dict(type="surface", roughness=0.3, thickness=0.4)],
                         substrate=dict(type="dielectric", roughness=0.3, ior=1.5))
GROUND_TRUTH_CASES = {
    "surface tilted, Fresnel": (dict(layers=[dict(type="surface", roughness=0.4, albedo=[0.9, 0.6, 0.3],
                                                  f0=[0.5, 0.2, 1], orientation=[0.2, 0.1, 0.97])]), REFLECTION),
    "fiber": (dict(layers=[dict(type="fiber", roughness=0.3, thickness=2.0, orientation=[1, 0, 0])]), REFLECTION),
    "hg transmission": (dict(layers=[dict(type="hg", roughness=0.5, albedo=[0.9, 0.9, 0.9], thickness=0.7)]),
                        TRANSMISSION),
    "2 layers transmission": (dict(layers=[dict(type="fiber", roughness=0.5, orientation=[0.6, 0.8, 0]),
                                           dict(type="surface", roughness=0.5, thickness=0.5)]), TRANSMISSION),
    "3 layers": (dict(layers=THREE_LAYERS), REFLECTION),
    "3 layers from below": (dict(layers=THREE_LAYERS), FROM_BELOW),
    "diffuse substrate": (dict(layers=[dict(type="surface", roughness=0.3, thickness=0.4)],
                               substrate=dict(type="diffuse", albedo=[0.6, 0.3, 0.1])), REFLECTION),
    "conductor substrate": (dict(layers=[dict(type="fiber", roughness=0.5, thickness=0.4)],
                                 substrate=dict(type="conductor", roughness=0.3)), REFLECTION),
    "dielectric substrate transmission": (FLAKES_OVER_GLASS, TRANSMISSION),
    "dielectric substrate from inside": (FLAKES_OVER_GLASS, BELOW_TO_ABOVE),
}


SHARP_TILTED_FLAKES = dict(layers=[dict(type="surface", roughness=1e-4, f0=[0.3, 0.5, 1], orientation=[0.3, 0, 1]),
                                   dict(type="fiber", roughness=1e-4, thickness=0.5, orientation=[0, 1, 0.2])])


@pytest.mark.parametrize("stack", [GROUND_TRUTH_CASES["surface tilted, Fresnel"][0], dict(layers=THREE_LAYERS),
                                   GROUND_TRUTH_CASES["diffuse substrate"][0], FLAKES_OVER_GLASS, SHARP_TILTED_FLAKES])
def test_next_event_blocks_equal_the_pair_by_pair_estimate(stack):
    """The walk's next-event estimate, a vertices x directions block in closed form (quadratic forms in the SGGX
    axis frame, transmittance as matrix products), equals the phase function and transmittance evaluated pair by
    pair, sharp tilted flakes and h = wi + wo at or near 0 included."""
    p = _params(**stack)
    n_layers, rng = len(p.layers), np.random.default_rng(4)
    z = rng.uniform(0.0, n_layers, 40)
    layer = np.minimum(z.astype(int), n_layers - 1)
    wi = sphere_directions(40, seed=5)
    beta = rng.uniform(0.1, 1.0, (40, 3))
    surface = (rng.random(40) < 0.3) & (p.substrate is not None)
    z[surface] = n_layers
    wi[surface, 2] = np.abs(wi[surface, 2])
    opposite, nearly = -wi[:3], np.nextafter(-wi[3:6], 1.0)  # h = 0; h in the last bits
    wo = np.concatenate([sphere_directions(12, seed=6), opposite, nearly, frames.spherical(np.ones(1), np.zeros(1))])
    kappa = spongecake._exit_depths(p, wo)
    block = spongecake._vertex_block(p, z, wi, beta, layer, surface, wo, kappa)
    pairwise = np.zeros((len(wo), 3))
    for v in range(len(z)):
        for q, w in enumerate(wo):
            up = w[2] > 0
            overlap = np.clip(z[v] - np.arange(n_layers), 0, 1) if up else np.clip(np.arange(n_layers) + 1 - z[v], 0, 1)
            transmittance = np.exp(-np.sum(kappa[:, q] * overlap))
            if surface[v]:
                value = spongecake.substrate_bsdf(p.substrate, wi[v:v + 1], w[None])[0]
            elif p.substrate is not None and not up:
                value = np.zeros(3)
            else:
                lay = p.layers[layer[v]]
                value = np.asarray(lay.albedo) * spongecake._phase_value(lay, wi[v:v + 1], w[None])[0] / abs(w[2])
            pairwise[q] += beta[v] * value * transmittance
    assert pairwise.max() > 0
    np.testing.assert_allclose(block, pairwise, rtol=1e-6, atol=1e-300)  # the block's transmittance is float32


@pytest.mark.parametrize("name", GROUND_TRUTH_CASES)
def test_single_scattering_matches_the_random_walk(name):
    stack, sides = GROUND_TRUTH_CASES[name]
    p = _params(**stack)
    wi, wo = _pairs(*sides)
    reference = spongecake.eval(p, wi, wo)
    walk, _ = spongecake.ground_truth(p, wi, wo, n_paths=20000, seed=1, max_depth=1)
    error = np.abs(reference - walk).mean(axis=0) / walk.mean(axis=0)
    assert error.max() < 0.01, error


@pytest.mark.parametrize("wi", [unit(0.6, 0.2, 0.75), unit(0.6, 0.2, -0.75)])
def test_the_walk_conserves_energy_without_absorption(wi):
    p = _params(layers=[dict(type="fiber", roughness=0.3, albedo=[1, 1, 1], thickness=0.5, orientation=[0.6, 0, 0.8]),
                        dict(type="hg", roughness=0.6, albedo=[1, 1, 1], thickness=0.3)])
    wo = _midpoint_sphere(24, 48)
    single, multiple = spongecake.ground_truth(p, np.repeat(wi, len(wo), 0), wo, n_paths=4000, seed=2)
    scattered = np.sum((single + multiple)[:, 0] * np.abs(wo[:, 2])) * 4 * np.pi / len(wo)
    unscattered = np.exp(-spongecake._optical_depths(p, wi).sum())
    assert scattered + unscattered == pytest.approx(1.0, abs=0.02)


@pytest.mark.parametrize("alpha", [1e-4, 0.05, 0.3, 1.0])
def test_thick_surface_layer_is_half_ggx_with_height_correlated_smith(alpha):
    p = _params(layers=[dict(type="surface", roughness=alpha, albedo=[1, 1, 1], thickness=1e4, f0=[1, 1, 1])])
    wi, wo = sphere_directions(2000, 1, side=1), sphere_directions(2000, 2, side=1)
    h = frames.normalize(wi + wo)
    ggx = microfacet.ggx_d(h, alpha) * microfacet.g2(wi, wo, alpha) / (4 * wi[:, 2] * wo[:, 2])
    f = spongecake.eval(p, wi, wo)
    keep = ggx > 1e-300
    assert np.allclose(f[keep], 0.5 * ggx[keep, None], rtol=1e-9, atol=0)


RECIPROCITY_CASES = [
    dict(layers=[dict(type="surface", roughness=0.2, f0=[0.04, 0.5, 0.9], orientation=[0.3, 0, 0.95])]),
    dict(layers=[dict(type="fiber", roughness=0.4, orientation=[1, 0, 0]),
                 dict(type="hg", roughness=0.7, thickness=2.0),
                 dict(type="surface", roughness=0.8, thickness=0.1)]),
    dict(layers=[dict(type="hg", roughness=-0.5, thickness=3.0)], substrate=dict(type="diffuse")),
    dict(layers=[dict(type="surface", roughness=0.1, thickness=0.3)], substrate=dict(type="conductor")),
    dict(layers=[dict(type="surface", roughness=0.1, thickness=0.3)], substrate=dict(type="dielectric")),
]


@pytest.mark.parametrize("stack", RECIPROCITY_CASES)
def test_reflection_is_reciprocal(stack):
    p = _params(**stack)
    for side in (1, -1):
        wi, wo = sphere_directions(3000, 3, side=side), sphere_directions(3000, 4, side=side)
        assert np.allclose(spongecake.eval(p, wi, wo), spongecake.eval(p, wo, wi), rtol=1e-9, atol=0)


def test_transmission_without_substrate_is_reciprocal_and_dielectric_obeys_eta_squared():
    p = _params(**RECIPROCITY_CASES[1])
    wi, wo = sphere_directions(3000, 5, side=1), sphere_directions(3000, 6, side=-1)
    assert np.allclose(spongecake.eval(p, wi, wo), spongecake.eval(p, wo, wi), rtol=1e-9, atol=0)
    p = _params(**RECIPROCITY_CASES[4])
    forward, backward = spongecake.eval(p, wi, wo) / 1.5 ** 2, spongecake.eval(p, wo, wi)
    assert np.allclose(forward, backward, rtol=1e-9, atol=1e-12 * forward.max())


THICK_MIRROR = dict(layers=[dict(type="surface", roughness=0.05, thickness=1e4)])


@pytest.mark.parametrize("stack", RECIPROCITY_CASES[:2] + [THICK_MIRROR])
def test_single_scattering_albedo_is_at_most_one(stack):
    for layer in stack["layers"]:
        layer.update(albedo=[1, 1, 1], f0=[1, 1, 1])
    p = _params(**stack)
    wo = frames.spherical(np.array([1.0, 0.7, 0.3, 0.05, -0.5]), np.array([0.0, 1.0, 2.0, 3.0, 4.0]))
    albedo = spongecake.directional_albedo(p, wo, n=8192)
    assert np.all(albedo + spongecake.delta_transmittance(p, wo) <= 1.0 + 5e-3), albedo


def test_directional_albedo_matches_a_brute_force_quadrature_and_splits():
    p = _params(layers=[dict(type="fiber", roughness=0.6, thickness=0.8, orientation=[0.6, 0, 0.8])])
    wo = unit(0.3, -0.4, 0.6)
    wi = _midpoint_sphere(400, 800)
    value = spongecake.eval(p, wi, np.repeat(wo, len(wi), 0)) * np.abs(wi[:, 2:]) * 4 * np.pi / len(wi)
    reflection, transmission = spongecake.directional_albedo(p, wo, split=True)
    assert reflection[0] == pytest.approx(value[wi[:, 2] > 0].sum(axis=0), rel=5e-3)
    assert transmission[0] == pytest.approx(value[wi[:, 2] < 0].sum(axis=0), rel=5e-3)


def test_a_layer_split_in_two_identical_layers_is_unchanged():
    layer = dict(type="fiber", roughness=0.35, albedo=[0.7, 0.5, 0.2], orientation=[0.5, 0.5, 0.7])
    whole = _params(layers=[dict(layer, thickness=1.5)])
    halves = _params(layers=[dict(layer, thickness=0.4), dict(layer, thickness=1.1)])
    wi, wo = sphere_directions(2000, 7), sphere_directions(2000, 8)
    assert np.allclose(spongecake.eval(whole, wi, wo), spongecake.eval(halves, wi, wo), rtol=1e-10, atol=1e-300)
    delta = [spongecake.delta_transmittance(p, wi) for p in (whole, halves)]
    assert np.allclose(*delta, rtol=1e-12)


def test_opposite_lambdas_take_the_expm1_limit_continuously():
    p = _params(layers=[dict(type="hg", roughness=0.3, thickness=2.0)])
    wi = unit(0.3, 0.4, 0.8)
    eps = np.array([0.0, 1e-12, 1e-8, 1e-5])
    wo = frames.normalize(-wi + eps[:, None] * np.array([1.0, 0.0, 0.0]))
    f = spongecake.eval(p, np.repeat(wi, 4, 0), wo)[:, 0]
    lam = 1 / wi[0, 2]  # Lambda_i = -Lambda_o at wo = -wi: G = T rho exp(-T rho Lambda_i)
    exact = 0.8 * spongecake.hg.eval(0.3, 1.0) * 2.0 * np.exp(-2.0 * lam) / wi[0, 2] ** 2
    assert f[0] == pytest.approx(exact, rel=1e-12)
    assert np.allclose(f, f[0], rtol=1e-4)


def test_zero_thickness_is_transparent_and_substrates_are_bare():
    wi, wo = sphere_directions(500, 9, side=1), sphere_directions(500, 10, side=1)
    p = _params(layers=[dict(type="surface", thickness=0.0)], substrate=dict(type="diffuse", albedo=[0.2, 0.4, 0.6]))
    assert np.allclose(spongecake.eval(p, wi, wo), np.array([0.2, 0.4, 0.6]) / np.pi, rtol=1e-14)
    p = _params(layers=[dict(type="surface", thickness=0.0)], substrate=dict(type="conductor", roughness=0.3))
    bare = microfacet.conductor_eval(wi, wo, 0.3, p.substrate.eta, p.substrate.k)
    assert np.allclose(spongecake.eval(p, wi, wo), bare, rtol=1e-14)
    p = _params(layers=[dict(type="hg", thickness=0.0)], delta_transmission=True)
    assert np.all(spongecake.eval(p, wi, wo) == 0) and np.all(spongecake.delta_transmittance(p, wi) == 1)


def test_opaque_substrates_block_everything_below():
    for sub in (dict(type="diffuse"), dict(type="conductor")):
        p = _params(layers=[dict(type="hg", thickness=0.5)], substrate=sub, delta_transmission=True)
        up, down = sphere_directions(200, 11, side=1), sphere_directions(200, 12, side=-1)
        for wi, wo in ((up, down), (down, up), (down, down)):
            assert np.all(spongecake.eval(p, wi, wo) == 0)
        assert np.all(spongecake.delta_transmittance(p, up) == 0)


def test_delta_transmittance_is_the_product_of_layer_transmittances():
    p = _params(layers=[dict(type="fiber", roughness=0.2, thickness=0.7, orientation=[1, 0, 0]),
                        dict(type="hg", thickness=0.3)], delta_transmission=True)
    wi = sphere_directions(100, 13)
    c = np.abs(wi[:, 2])
    sigma_fiber = np.sqrt(1 - (1 - 0.04) * wi[:, 0] ** 2)
    expected = np.exp(-0.7 * sigma_fiber / c) * np.exp(-0.3 / c)
    assert np.allclose(spongecake.delta_transmittance(p, wi), expected[:, None], rtol=1e-12)
    off = _params(layers=[dict(type="hg", thickness=0.3)])
    assert np.all(spongecake.delta_transmittance(off, wi) == 0)


@pytest.mark.parametrize("name", presets.names(model.ID))
def test_presets_evaluate(name):
    p = spongecake.params_from_dict(presets.load(model.ID, name))
    wi, wo = sphere_directions(500, 14), sphere_directions(500, 15)
    f = spongecake.eval(p, wi, wo)
    assert np.all(np.isfinite(f)) and np.all(f >= 0) and f.max() > 0
