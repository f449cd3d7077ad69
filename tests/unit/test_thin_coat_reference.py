"""The analytic thin-coat reference (ENDF model, thin_layers_endf Sec. 5): its lobes, sampling and limits."""
import zlib

import numpy as np
import pytest

from addon.models.thin_coat import params_from_dict
from addon.reference import microfacet, vmf, warping
from addon.reference import thin_coat as tc
from addon.reference.frames import spherical
from stats import chi2_test, sphere_directions

CASES = {
    "paper": {"kappa_top": 1e4, "kappa_bottom": 1e3, "bounces": 2},
    "rough": {"kappa_top": 30, "kappa_bottom": 10, "bounces": 3},
    "metal": {"kappa_top": 300, "kappa_bottom": 200, "sigma_a": [0.2, 0.8, 0.8], "depth": 0.5,
              "base": {"type": "conductor", "eta": [1.657, 0.880, 0.521], "k": [9.224, 6.270, 4.837]}},
    "diffuse": {"kappa_top": 300, "bounces": 3, "sigma_a": [0.3, 0.6, 1.2], "depth": 0.3,
                "base": {"type": "diffuse", "albedo": [0.8, 0.5, 0.3]}},
    "slab": {"kappa_top": 100, "kappa_bottom": 300, "bounces": 2, "base": {"type": "slab"}},
}
N = 200_000


def _view(cos_o, n=1):
    return np.repeat(spherical(np.array([cos_o]), np.array([0.3])), n, axis=0)


@pytest.mark.parametrize("name, cos_o", [(name, 0.85) for name in sorted(CASES)]
                         + [(name, 0.35) for name in sorted(CASES) if name != "paper"])  # κ1 1e4: too sharp
def test_sampled_directions_follow_the_pdf(name, cos_o):
    """Chi-square over the sphere; at the oblique view over the upper hemisphere only (the rest is the remainder
    cell): reflecting wo about half vectors orthogonal to it gives −wo, a spike the cell quadrature cannot
    integrate (``tc._reflection_pdf``), below the horizon where reflection lobes are zero."""
    p = params_from_dict(CASES[name])
    wo = _view(cos_o, N)
    s = tc.sample(p, wo, np.random.default_rng(zlib.crc32(f"{name} {cos_o}".encode())).random((N, 3)))
    assert np.all(np.isfinite(s.weight)) and np.all(s.weight >= 0)
    keep = (lambda wi: wi[:, 2] > 0) if cos_o < 0.5 else (lambda wi: np.ones(len(wi), bool))
    result = chi2_test(s.wi[keep(s.wi)], lambda wi: tc.pdf(p, wi, _view(cos_o, len(wi))) * keep(wi), n_total=N,
                       res=10)
    assert result.p_value > 0.01, result
    if cos_o > 0.5:
        assert result.integral == pytest.approx(1.0, abs=2e-3)


def test_chi2_catches_a_wrong_endf_kappa():
    """The sampler test can fail: halving κ̂ of the first reflection lobe in the pdf is detected."""
    p = params_from_dict(CASES["rough"])
    wo = _view(0.85, N)
    s = tc.sample(p, wo, np.random.default_rng(5).random((N, 3)))
    found = tc.lobes_at(p, wo[:1])
    prob = tc._lobe_probabilities(p, wo[:1], found)[0]

    def wrong(wi):
        w = _view(0.85, len(wi))
        return sum(prob[c] * tc._reflection_pdf(lobe.kappa * (0.5 if lobe.order == 1 else 1.0), wi, w)
                   for c, lobe in enumerate(found))
    assert chi2_test(s.wi, wrong, res=10).p_value < 1e-6


def test_smooth_interfaces_give_the_fresnel_series():
    """κ1 = κ2 = 1e6 (mirrors): order k carries (1 − F)² F_b^k F^{k−1} e^{−2kσd / cos θt} (G1 → 1), F at the
    macro angles (Eq. 9), F_b at base IOR / coat IOR; the lobes integrate to it."""
    p = params_from_dict({"kappa_top": 1e6, "kappa_bottom": 1e6, "bounces": 4, "sigma_a": [0.1, 0.5, 2.0],
                          "depth": 0.4})
    cos_o = 0.6
    ct = np.sqrt(1 - (1 - cos_o ** 2) / p.eta ** 2)
    f = microfacet.fresnel_dielectric(np.array([cos_o]), p.eta)[0]
    f_b = microfacet.fresnel_dielectric(np.array([ct]), p.base.ior / p.eta)[0]
    a = np.exp(-np.array(p.sigma_a) * p.depth / ct)
    albedo = tc.directional_albedo(p, _view(cos_o), n=20000, orders=True)[:, 0]
    for k in range(1, 5):
        expected = (1 - f) ** 2 * f_b ** k * f ** (k - 1) * a ** (2 * k)
        assert albedo[k] == pytest.approx(expected, rel=2e-3)
    assert albedo[0] == pytest.approx(np.full(3, f), rel=2e-3)


def test_endf_kappa_is_the_joint_warp_chain():
    """κ̂ of the first reflection order equals the chain composed from the warping module's Jacobians (Eqs. 12,
    13, 19, 21, 24) with explicit directions: top refraction in, bottom reflection, top refraction out."""
    p = params_from_dict({"kappa_top": 2e3, "kappa_bottom": 150, "eta": 1.7, "bounces": 1})
    n = np.array([[0.0, 0.0, 1.0]])
    for cos_o in (0.95, 0.5, 0.1):
        o = _view(cos_o)
        t, _ = warping.refract(o, n, p.eta)  # travels down inside the coat
        up = warping.reflect(-t, n)  # after the bottom's mirror reflection, travelling up
        out_jac = warping.incident_refraction_jacobian(-up, n, 1.0 / p.eta)  # inside per outside solid angle
        entry = p.kappa_top * warping.refraction_jacobian(o, n, p.eta) * out_jac
        bottom = p.kappa_bottom * warping.reflection_jacobian(-t, n) * out_jac
        leave = p.kappa_top * warping.refraction_jacobian(-up, n, 1.0 / p.eta)
        kappa_i = vmf.convolve(vmf.convolve(entry, bottom), leave)
        expected = warping.endf_kappa_reflect(o, n, kappa_i)
        got = tc.lobes_at(p, o)[1].kappa
        assert got == pytest.approx(expected, rel=1e-10)


def test_lobes_integrate_to_their_weights_when_sharp():
    """A reflection lobe's albedo is its weight W_k times the share of its half vectors reflecting wo above the
    horizon: W_k itself for sharp lobes, less at grazing views (the lobe is cut by the horizon)."""
    p = params_from_dict(CASES["paper"])
    for cos_o, low in ((0.9, 0.998), (0.5, 0.95)):
        wo = _view(cos_o)
        albedo = tc.directional_albedo(p, wo, n=20000, orders=True)[:, 0]
        for lobe in tc.lobes_at(p, wo)[1:]:
            assert np.all(low * lobe.weight[0] <= albedo[lobe.order])
            assert np.all(albedo[lobe.order] <= 1.002 * lobe.weight[0])
    grazing = _view(0.05)
    albedo = tc.directional_albedo(p, grazing, n=20000, orders=True)[:, 0]
    assert np.all(albedo[1] <= tc.lobes_at(p, grazing)[1].weight[0] * 1.002)


def test_index_matched_coat_leaves_the_bottom():
    """η → 1: the top neither reflects nor deflects; order 1 is the bottom's own reflection, κ̂ → κ2 at normal
    view (the ENDF of a plain reflection is the NDF), weight F_b G1 G1."""
    p = params_from_dict({"eta": 1.0001, "kappa_top": 1e4, "kappa_bottom": 300, "bounces": 1,
                          "base": {"type": "dielectric_rough", "ior": 1.8}})
    found = tc.lobes_at(p, _view(1.0))
    albedo = tc.directional_albedo(p, _view(0.7), n=4096, orders=True)[:, 0, 0]
    assert albedo[0] < 1e-6 * albedo[1]
    assert found[1].kappa[0] == pytest.approx(300, rel=2e-3)
    f_b = microfacet.fresnel_dielectric(np.array([1.0]), 1.8 / 1.0001)[0]
    assert found[1].weight[0, 0] == pytest.approx(f_b, rel=1e-3)


@pytest.mark.parametrize("base", ["dielectric_rough", "conductor", "diffuse", "slab"])
def test_extremes_are_finite_and_non_negative(base):
    """κ ∈ {1e-3, 1e6} on both sides, η ∈ {1.0001, 3}, σa d ∈ {0, 100}, views down to grazing (cos 0, 1e-6)."""
    rng = np.random.default_rng(3)
    for k1 in (1e-3, 1e6):
        for k2 in (1e-3, 1e6):
            for eta in (1.0001, 3.0):
                for sigma_d in (0.0, 100.0):
                    p = params_from_dict({"kappa_top": k1, "kappa_bottom": k2, "eta": eta, "bounces": 4,
                                          "sigma_a": [sigma_d] * 3, "depth": 1.0, "base": {"type": base}})
                    wo = spherical(np.array([1.0, 0.5, 1e-6, 0.0, -0.5]), np.zeros(5))
                    wo = np.repeat(wo, 40, axis=0)
                    wi = np.concatenate([sphere_directions(len(wo) - 5, seed=1), wo[:5] * [-1, -1, 1]])
                    f = tc.eval_orders(p, wi, wo)
                    assert np.all(np.isfinite(f)) and np.all(f >= 0), (k1, k2, eta, sigma_d)
                    s = tc.sample(p, wo, rng.random((len(wo), 3)))
                    assert np.all(np.isfinite(s.weight)) and np.all(s.weight >= 0), (k1, k2, eta, sigma_d)
                    assert np.allclose(np.linalg.norm(s.wi, axis=1), 1.0)
                    assert np.all(np.isfinite(s.pdf)) and np.all(s.pdf >= 0)


@pytest.mark.parametrize("case", [
    {"kappa_top": 1e4, "kappa_bottom": 1e3, "bounces": 4, "base": {"type": "dielectric_rough", "ior": 3.0}},
    {"kappa_top": 10, "kappa_bottom": 10, "bounces": 4, "base": {"type": "conductor", "eta": [0.2] * 3,
                                                                  "k": [20.0] * 3}},
    {"kappa_top": 1e-3, "kappa_bottom": 1e6, "bounces": 4, "base": {"type": "conductor", "eta": [0.2] * 3,
                                                                     "k": [20.0] * 3}},
    {"kappa_top": 100, "bounces": 4, "base": {"type": "diffuse", "albedo": [1.0] * 3}},
    {"kappa_top": 5, "kappa_bottom": 1e6, "eta": 3.0, "bounces": 4, "base": {"type": "slab"}},
])
def test_no_energy_gain(case):
    """White, non-absorbing coats return at most what they receive, at every view down to grazing."""
    p = params_from_dict(case)
    wo = spherical(np.array([1.0, 0.7, 0.3, 0.05]), np.zeros(4))
    assert np.all(tc.directional_albedo(p, wo, n=8192) <= 1.0 + 5e-3)


def test_surface_term_is_reciprocal():
    p = params_from_dict(CASES["rough"])
    a, b = sphere_directions(500, seed=2, side=1), sphere_directions(500, seed=3, side=1)
    f_ab, f_ba = tc.eval_orders(p, a, b)[0], tc.eval_orders(p, b, a)[0]
    assert np.allclose(f_ab, f_ba, rtol=1e-12, atol=0)


def test_slab_seen_from_below_is_the_slab_upside_down():
    p = params_from_dict(CASES["slab"])
    flipped = params_from_dict({**CASES["slab"], "kappa_top": 300, "kappa_bottom": 100})
    wi, wo = sphere_directions(200, seed=4), sphere_directions(200, seed=5, side=-1)
    z = np.array([1.0, 1.0, -1.0])
    assert np.allclose(tc.eval(p, wi, wo), tc.eval(flipped, wi * z, wo * z), rtol=1e-12, atol=0)


def test_opaque_bases_give_nothing_below():
    p = params_from_dict(CASES["metal"])
    assert np.all(tc.directional_albedo(p, _view(0.5) * [1, 1, -1], n=64) == 0)
    wi, wo = sphere_directions(100, seed=6), sphere_directions(100, seed=7, side=1)
    assert np.all(tc.eval(p, wi * [1, 1, -1] * np.sign(wi[:, 2:]), wo)[np.abs(wi[:, 2]) > 0] == 0)
    assert np.all(tc.eval(p, wo, wo * [1, 1, -1]) == 0)


def test_diffuse_means_match_closed_forms():
    """r̄_i = 1 − (1 − r̄_e) / η² with r̄_e = 0.0918 at η = 1.5 (the classic hemispherical Fresnel value, 0.092),
    and τ̄ = 2 E3(x): 1 at x = 0, 2 E3(1) = 0.2193."""
    r_i, through = tc.diffuse_means(1.5, np.array([[0.0, 1.0, 100.0]]))
    assert 1 - (1 - r_i) * 1.5 ** 2 == pytest.approx(0.0918, abs=1e-3)
    assert through[0] == pytest.approx([1.0, 0.2193839, 0.0], abs=1e-6)
