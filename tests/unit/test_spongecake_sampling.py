"""Importance sampling of the reference: weights, pdf normalisation, chi-square goodness of fit."""
import zlib

import numpy as np
import pytest

from addon.reference import frames, sggx, spongecake
from stats import cell_integrals, chi2_test, unit

N = 200_000
CASES = {
    "surface tilted": dict(layers=[dict(type="surface", roughness=0.3, f0=[0.04, 0.5, 1.0],
                                        orientation=[0.4, 0.2, 0.9])]),
    "fiber tilted": dict(layers=[dict(type="fiber", roughness=0.4, thickness=1.5, orientation=[0.6, 0.3, 0.74])]),
    "hg with delta": dict(layers=[dict(type="hg", roughness=0.6, thickness=0.8)], delta_transmission=True),
    "2 layers": dict(layers=[dict(type="fiber", roughness=0.5, thickness=0.7, orientation=[1, 0, 0]),
                             dict(type="surface", roughness=0.4, thickness=2.0)]),
    "3 layers with delta": dict(layers=[dict(type="surface", roughness=0.35, thickness=0.3),
                                        dict(type="hg", roughness=-0.4),
                                        dict(type="fiber", roughness=0.6, orientation=[0, 0.6, 0.8])],
                                delta_transmission=True),
    "diffuse substrate": dict(layers=[dict(type="surface", roughness=0.3, thickness=0.4)],
                              substrate=dict(type="diffuse")),
    "conductor substrate": dict(layers=[dict(type="fiber", roughness=0.5, thickness=0.3)],
                                substrate=dict(type="conductor", roughness=0.4)),
    "dielectric substrate": dict(layers=[dict(type="hg", roughness=0.3, thickness=0.3)],
                                 substrate=dict(type="dielectric", roughness=0.4, ior=1.5)),
    "multiple scattering with delta": dict(layers=[dict(type="fiber", roughness=0.5, thickness=0.7,
                                                        orientation=[1, 0, 0]),
                                                   dict(type="hg", roughness=0.4, thickness=1.0)],
                                           delta_transmission=True, multiple_scattering=True),
    "multiple scattering on a substrate": dict(layers=[dict(type="surface", roughness=0.4, thickness=1.5)],
                                               substrate=dict(type="diffuse"), multiple_scattering=True),
}
INCIDENT = {"above": unit(0.5, 0.3, 0.6), "below": unit(-0.4, 0.5, -0.7)}
# What is checked here (sample, pdf and eval agree) holds for any energy table: the multiple-scattering cases take
# conftest's coarse tables (each lobe keeps its share within 6%), not 20 s of the full ones.
pytestmark = pytest.mark.usefixtures("coarse_energy_tables")


def _draw(p, wi, n, seed=0):
    return spongecake.sample(p, np.repeat(wi, n, 0), np.random.default_rng(seed).random((n, 3)))


def _delta_probability(p, wi):
    """P(delta): the Dirac is the last lobe, so u0 just below 1 selects it whenever it has probability."""
    s = spongecake.sample(p, wi, np.array([[np.nextafter(1.0, 0.0), 0.5, 0.5]]))
    return s.pdf[0] if s.is_delta[0] else 0.0


def _pdf_of(p, wi):
    return lambda wo: spongecake.pdf(p, np.repeat(wi, len(wo), 0), wo)


@pytest.mark.parametrize("side", INCIDENT)
@pytest.mark.parametrize("name", CASES)
def test_weight_is_eval_cosine_over_pdf(name, side):
    p, wi = spongecake.params_from_dict(CASES[name]), INCIDENT[side]
    s = _draw(p, wi, 20_000)
    wis = np.repeat(wi, len(s.wo), 0)
    cont = ~s.is_delta & (s.pdf > 0)
    assert np.allclose(s.pdf[cont], spongecake.pdf(p, wis, s.wo)[cont], rtol=1e-12, atol=0)
    expected = spongecake.eval(p, wis, s.wo) * np.abs(s.wo[:, 2:]) / np.where(cont, s.pdf, 1.0)[:, None]
    assert np.allclose(s.weight[cont], expected[cont], rtol=1e-9, atol=0)
    assert np.all(np.isfinite(s.weight)) and np.all(s.weight >= 0)
    assert np.allclose(np.linalg.norm(s.wo, axis=1), 1.0, atol=1e-12)
    if s.is_delta.any():
        assert np.all(s.wo[s.is_delta] == -wi)
        dirac = spongecake.delta_transmittance(p, wi)[0] / s.pdf[s.is_delta][:, None]
        assert np.allclose(s.weight[s.is_delta], dirac, rtol=1e-12)


@pytest.mark.parametrize("side", INCIDENT)
@pytest.mark.parametrize("name", CASES)
def test_pdf_integrates_to_one_minus_the_delta_probability(name, side):
    p, wi = spongecake.params_from_dict(CASES[name]), INCIDENT[side]
    total = cell_integrals(_pdf_of(p, wi), 48, 96, 10).sum()
    assert total == pytest.approx(1.0 - _delta_probability(p, wi), abs=0.01)


@pytest.mark.parametrize("side", INCIDENT)
@pytest.mark.parametrize("name", CASES)
def test_sampled_directions_follow_the_pdf(name, side):
    p, wi = spongecake.params_from_dict(CASES[name]), INCIDENT[side]
    s = _draw(p, wi, N, seed=zlib.crc32(f"{name} {side}".encode()))
    result = chi2_test(s.wo[~s.is_delta], _pdf_of(p, wi), n_total=N, res=10)
    assert result.p_value > 0.01, result


def test_chi2_catches_the_half_vector_jacobian_bug():
    """Using the density of h (D_wi(h)) for wo, or dividing by 4 |wi.h| twice, fails even once renormalised."""
    p = spongecake.params_from_dict(CASES["surface tilted"])
    wi = INCIDENT["above"]
    s = _draw(p, wi, N)
    right = _pdf_of(p, wi)

    def scaled(power):
        def pdf(wo):
            wis = np.repeat(wi, len(wo), 0)
            jacobian = 4 * np.abs(frames.dot(wis, sggx.half_vector(wis, wo)[0]))
            return right(wo) * jacobian ** power
        total = cell_integrals(pdf, 24, 48, 10).sum()
        return lambda wo: pdf(wo) / total

    assert chi2_test(s.wo, right, res=10).p_value > 0.01
    for power in (1, -1):
        assert chi2_test(s.wo, scaled(power), res=10).p_value < 1e-6


MS_LOBES = ("extra lobe", "forward lobe", "W2r Lambert", "W2t Lambert")


@pytest.mark.parametrize("side", INCIDENT)
@pytest.mark.parametrize("lobe", range(len(MS_LOBES)), ids=MS_LOBES)
def test_each_multiple_scattering_lobe_follows_its_pdf(lobe, side):
    """Each of multiple scattering's lobes alone: in the mixture a wrong density of a lobe with a small share
    hides in the others' (a W2t density of 1.5 cos² / π instead of cos / π passed the mixture's test)."""
    p, wi = spongecake.params_from_dict(CASES["multiple scattering with delta"]), INCIDENT[side]
    n = 50_000
    u = np.random.default_rng(lobe).random((n, 3))
    wis = np.repeat(wi, n, 0)
    wo = spongecake._sample_multiple(p, wis, np.full(n, lobe), u)
    result = chi2_test(wo, lambda w: spongecake._multiple_pdfs(p, np.repeat(wi, len(w), 0), w)[:, lobe], res=10)
    assert result.p_value > 0.01, result
