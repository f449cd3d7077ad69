"""Building blocks of the reference: frames, GGX, Fresnel, SGGX, Henyey-Greenstein, and the chi-square helper."""
import math

import numpy as np
import pytest

from addon.reference import frames, hg, microfacet, sggx
from stats import cell_integrals, chi2_test, gammaincc, sphere_directions, unit

RNG = np.random.default_rng(7)


def _u(n):
    return RNG.random(n), RNG.random(n)


# ------------------------------------------------------------------------------------------- frames

def test_basis_is_orthonormal_including_the_poles():
    n = np.concatenate([sphere_directions(1000, 1), [[0, 0, 1.0], [0, 0, -1.0], [0, 0, -0.0 - 1.0]]])
    s, t = frames.basis(n)
    for a, b in ((s, t), (s, n), (t, n)):
        assert np.abs(frames.dot(a, b)).max() < 1e-12
    for a in (s, t):
        assert np.abs(np.linalg.norm(a, axis=1) - 1).max() < 1e-12


# -------------------------------------------------------------------------------------------- GGX

def _composite_gauss(a, b, panels=500, order=16):
    """Nodes and weights of a composite Gauss-Legendre rule on [a, b]."""
    x, w = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(a, b, panels + 1)
    half = 0.5 * np.diff(edges)[:, None]
    return ((edges[:-1, None] + half * (x + 1)).ravel(), (half * w).ravel())


def _graded_gauss():
    """Composite Gauss-Legendre on [-1, 1] with panels refined geometrically towards both ends (peaked HG)."""
    x, w = np.polynomial.legendre.leggauss(16)
    ends = 1.0 - np.geomspace(1e-9, 1.0, 120)
    edges = np.unique(np.concatenate([ends, -ends, np.linspace(-1, 1, 101)]))
    half = 0.5 * np.diff(edges)[:, None]
    return (edges[:-1, None] + half * (x + 1)).ravel(), (half * w).ravel()


def _hemisphere_integral(f):
    """int over the upper hemisphere of an isotropic f(cos theta), in theta."""
    theta, w = _composite_gauss(0.0, 0.5 * np.pi)
    return np.sum(w * f(np.cos(theta)) * np.sin(theta)) * 2 * np.pi


@pytest.mark.parametrize("alpha", [0.02, 0.3, 1.0])
def test_ggx_d_is_normalised_in_projected_area(alpha):
    def d_cos(c):
        m = frames.spherical(c, np.zeros_like(c))
        return microfacet.ggx_d(m, alpha) * c
    assert _hemisphere_integral(d_cos) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("alpha", [0.2, 0.7])
def test_visible_normals_integrate_to_one_which_validates_smith_lambda(alpha):
    for wi in (unit(0.2, 0.1, 1), unit(1, -0.5, 0.3), unit(1, 0, 0.02)):
        pdf = lambda m: microfacet.vndf_pdf(np.repeat(wi, len(m), 0), m, alpha)
        assert cell_integrals(pdf, 32, 64, 12).sum() == pytest.approx(1.0, abs=2e-3)


def test_smith_lambda_closed_form_and_grazing():
    w = sphere_directions(100, 2, side=1)
    tan2 = (w[:, 0] ** 2 + w[:, 1] ** 2) / w[:, 2] ** 2
    expected = (np.sqrt(1 + 0.09 * tan2) - 1) / 2
    assert np.allclose(microfacet.smith_lambda(w, 0.3), expected, rtol=1e-12, atol=0)
    grazing = np.array([[1.0, 0.0, 0.0]])
    assert microfacet.smith_lambda(grazing, 0.3)[0] == np.inf
    assert microfacet.g2(grazing, unit(0, 0, 1), 0.3)[0] == 0.0


def test_ggx_visible_normal_sampler_matches_its_density():
    alpha, wi = 0.35, unit(0.8, 0.3, 0.5)
    n = 200_000
    m = microfacet.sample_vndf(np.repeat(wi, n, 0), alpha, *_u(n))
    result = chi2_test(m, lambda x: microfacet.vndf_pdf(np.repeat(wi, len(x), 0), x, alpha), res=10)
    assert result.p_value > 0.01, result


# ---------------------------------------------------------------------------------------- Fresnel

def _complex_conductor(cos_i, eta, k):
    """Independent conductor Fresnel for the comparison: Snell's law with the complex index n = eta + i k."""
    c = cos_i[:, None].astype(complex)
    n = eta + 1j * k
    n_cos_t = np.sqrt(n * n - (1.0 - c * c))
    rs = (c - n_cos_t) / (c + n_cos_t)
    rp = (n * n * c - n_cos_t) / (n * n * c + n_cos_t)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def test_schlick_limits():
    c = np.array([0.0, 0.3, 1.0])
    assert np.all(microfacet.schlick((1, 1, 1), c) == 1.0)
    assert np.allclose(microfacet.schlick((0.04, 0.5, 0.0), c)[2], (0.04, 0.5, 0.0))
    assert np.allclose(microfacet.schlick((0.04, 0.5, 0.0), c)[0], 1.0)


def test_dielectric_fresnel_known_values():
    eta = 1.5
    assert microfacet.fresnel_dielectric(np.array([1.0]), eta)[0] == pytest.approx(((eta - 1) / (eta + 1)) ** 2)
    brewster = np.cos(np.arctan(eta))
    rs2 = microfacet.fresnel_dielectric(np.array([brewster]), eta)[0] * 2  # rp = 0 at Brewster's angle
    ct = np.sqrt(1 - (1 - brewster ** 2) / eta ** 2)
    assert rs2 == pytest.approx(((brewster - eta * ct) / (brewster + eta * ct)) ** 2, rel=1e-12)
    assert microfacet.fresnel_dielectric(np.array([0.3]), 1 / eta)[0] == 1.0  # total internal reflection
    c = np.linspace(0.05, 1, 20)
    ct = np.sqrt(1 - (1 - c ** 2) / eta ** 2)
    assert np.allclose(microfacet.fresnel_dielectric(c, eta), microfacet.fresnel_dielectric(ct, 1 / eta), rtol=1e-12)
    assert microfacet.fresnel_dielectric(np.array([0.0]), eta)[0] == 1.0


def test_conductor_fresnel_matches_complex_snell_and_limits():
    c = np.linspace(0.0, 1.0, 101)
    for eta, k in (((0.2, 0.92, 1.1), (3.9, 2.45, 2.14)), ((1.5, 2.0, 0.3), (0.0, 0.5, 7.0)),
                   ((1.0, 0.67, 0.01), (1.0, 0.0, 0.0)), ((10.0, 1.0, 0.5), (20.0, 1e-9, 0.0))):  # TIR where k = 0
        eta, k = np.array(eta), np.array(k)
        assert np.allclose(microfacet.fresnel_conductor(c, eta, k), _complex_conductor(c, eta, k), rtol=1e-10,
                           atol=1e-14)
        normal = ((eta - 1) ** 2 + k ** 2) / ((eta + 1) ** 2 + k ** 2)
        assert np.allclose(microfacet.fresnel_conductor(np.array([1.0]), eta, k)[0], normal, rtol=1e-12)
    assert np.allclose(microfacet.fresnel_conductor(np.array([0.0]), eta, k), 1.0)
    dielectric = microfacet.fresnel_dielectric(c, 1.7)
    assert np.allclose(microfacet.fresnel_conductor(c, (1.7,) * 3, (0.0,) * 3), dielectric[:, None], rtol=1e-12)


# -------------------------------------------------------------------------------------------- SGGX

TILTED = [sggx.surface((0.5, -0.3, 0.8), 0.3), sggx.fiber((0.6, 0.7, 0.4), 0.4), sggx.surface((0, 0, 1), 0.05)]


@pytest.mark.parametrize("s", TILTED)
def test_sggx_quadratic_forms_match_the_matrix(s):
    x, y = sphere_directions(50, 3), sphere_directions(50, 4)
    S = sggx.matrix(s)
    assert np.allclose(sggx.quad(s, x, y), np.einsum("ni,ij,nj->n", x, S, y), rtol=1e-12, atol=1e-15)
    assert np.allclose(sggx.quad_inv(s, x, y), np.einsum("ni,ij,nj->n", x, np.linalg.inv(S), y), rtol=1e-9)
    assert sggx.det(s) == pytest.approx(np.linalg.det(S), rel=1e-12)


def test_sggx_surface_along_z_is_ggx():
    m = sphere_directions(1000, 5, side=1)
    for alpha in (1e-4, 0.05, 0.6, 1.0):
        assert np.allclose(sggx.D(sggx.surface((0, 0, 1), alpha), m), microfacet.ggx_d(m, alpha), rtol=1e-12, atol=0)


@pytest.mark.parametrize("s", TILTED[:2])
def test_sggx_projected_area_is_the_integral_of_d(s):
    for w in (unit(0, 0, 1), unit(1, 0.2, -0.4), unit(-0.3, 0.9, 0.1)):
        integrand = lambda m: sggx.D(s, m) * np.maximum(frames.dot(m, w[0]), 0)
        assert cell_integrals(integrand, 48, 96, 8).sum() == pytest.approx(sggx.sigma(s, w)[0], rel=2e-4)


@pytest.mark.parametrize("s", TILTED[:2])
def test_sggx_phase_function_is_normalised(s):
    wi = unit(0.3, -0.2, 0.7)
    pdf = lambda wo: sggx.phase_pdf(s, np.repeat(wi, len(wo), 0), wo)
    assert cell_integrals(pdf, 48, 96, 8).sum() == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("s", TILTED[:2])
@pytest.mark.parametrize("wi", [unit(0.3, -0.2, 0.7), unit(-0.6, 0.5, -0.2)])
def test_sggx_visible_normal_sampler_matches_its_density(s, wi):
    n = 200_000
    m = sggx.sample_vndf(s, np.repeat(wi, n, 0), *_u(n))
    result = chi2_test(m, lambda x: sggx.vndf_pdf(s, np.repeat(wi, len(x), 0), x), res=10)
    assert result.p_value > 0.01, result
    assert np.abs(np.linalg.norm(m, axis=1) - 1).max() < 1e-12


# ----------------------------------------------------------------------------------- Henyey-Greenstein

@pytest.mark.parametrize("g", [-0.99, -0.4, 0.0, 0.7, 0.99])
def test_hg_is_normalised_with_mean_cosine_g(g):
    x, w = _graded_gauss()
    p = hg.eval(g, x) * 2 * np.pi
    assert np.sum(w * p) == pytest.approx(1.0, abs=1e-9)
    assert np.sum(w * p * x) == pytest.approx(g, abs=1e-9)


@pytest.mark.parametrize("g", [-0.99, -0.4, 1e-3, 0.7, 0.99])
def test_hg_inverse_cdf_inverts_the_closed_form_cdf(g):
    u = np.linspace(0.0, 1.0, 101)
    c = hg.sample_cos(g, u)
    cdf = (1 - g * g) / (2 * g) * (1 / np.sqrt(1 + g * g - 2 * g * c) - 1 / (1 + g))
    assert np.allclose(cdf, u, atol=1e-7)
    assert np.allclose(hg.sample_cos(0.0, u), 2 * u - 1, atol=1e-15)


@pytest.mark.parametrize("g", [-0.4, 0.7])
def test_hg_sampler_matches_its_density(g):
    forward = unit(0.3, 0.4, -0.8)
    n = 200_000
    wo = hg.sample(g, np.repeat(forward, n, 0), *_u(n))
    result = chi2_test(wo, lambda x: hg.eval(g, x @ forward[0]), res=10)
    assert result.p_value > 0.01, result


# ---------------------------------------------------------------------------------------- chi-square

def test_incomplete_gamma_against_closed_forms():
    for x in (0.01, 0.5, 2.0, 7.5, 40.0):
        assert gammaincc(1.0, x) == pytest.approx(math.exp(-x), rel=1e-12)
        assert gammaincc(0.5, x) == pytest.approx(math.erfc(math.sqrt(x)), rel=1e-10)
        assert gammaincc(3.0, x) == pytest.approx(math.exp(-x) * (1 + x + x * x / 2), rel=1e-12)


def test_chi2_accepts_the_truth_and_rejects_a_slightly_wrong_pdf():
    n = 200_000
    d = sphere_directions(n, 11)
    assert chi2_test(d, lambda x: np.full(len(x), 1 / (4 * np.pi))).p_value > 0.01
    assert chi2_test(d, lambda x: (1 + 0.1 * x[:, 2]) / (4 * np.pi)).p_value < 1e-6
    assert chi2_test(d[:n // 2], lambda x: np.full(len(x), 1 / (4 * np.pi)), n_total=n).p_value < 1e-6
