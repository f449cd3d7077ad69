"""Importance sampling of the micrograin reference: the NDF sampler (corrected Eq. 20) and the BSDF sampler."""
import zlib

import numpy as np
import pytest

from addon.reference import frames
from addon.reference import micrograin as mg
from stats import cell_integrals, chi2_test, unit

N = 200_000
NDF_CASES = [(0.0, 0.5), (0.3, 0.5), (0.9, 0.3), (0.98, 1.0), (0.98, 0.15)]


def _uniforms(n, seed):
    return np.random.default_rng(seed).random((n, 3))


def _ndf_density(tau0, beta):
    return lambda m: mg.ndf(m, tau0, beta) * np.maximum(m[:, 2], 0.0)


@pytest.mark.parametrize("tau0, beta", NDF_CASES)
def test_sample_ndf_follows_d_cos(tau0, beta):
    u = _uniforms(N, zlib.crc32(f"ndf {tau0} {beta}".encode()))
    m = mg.sample_ndf(tau0, beta, u[:, 0], u[:, 1])
    assert np.allclose(np.linalg.norm(m, axis=1), 1.0, atol=1e-12) and np.all(m[:, 2] >= 0)
    result = chi2_test(m, _ndf_density(tau0, beta), n_theta=48, res=10)
    assert result.p_value > 0.01, result
    assert result.integral == pytest.approx(1.0, abs=2e-3)


def test_sample_ndf_reduces_to_ggx_sampling():
    u = _uniforms(1000, 1)
    beta = 0.4
    tan2 = beta ** 2 * u[:, 0] / (1.0 - u[:, 0])
    ggx = np.stack([np.sqrt(tan2 / (1 + tan2)) * np.cos(2 * np.pi * u[:, 1]),
                    np.sqrt(tan2 / (1 + tan2)) * np.sin(2 * np.pi * u[:, 1]), 1 / np.sqrt(1 + tan2)], axis=1)
    assert np.allclose(mg.sample_ndf(0.0, beta, u[:, 0], u[:, 1]), ggx, rtol=0, atol=1e-13)
    assert np.allclose(mg.sample_ndf(1e-12, beta, u[:, 0], u[:, 1]), ggx, rtol=0, atol=1e-12)
    assert not np.allclose(mg.sample_ndf(1e-3, beta, u[:, 0], u[:, 1]), ggx, rtol=0, atol=1e-6)


def test_sample_ndf_is_the_corrected_eq_20():
    u = np.linspace(0.01, 0.99, 99)
    for tau0, beta in ((0.3, 0.5), (0.98, 1.0)):
        corrected = beta ** 2 * np.log(1 - u * tau0) / (np.log(1 - tau0) - np.log(1 - u * tau0))
        m = mg.sample_ndf(tau0, beta, u, 0 * u)
        assert np.allclose((m[:, 0] / m[:, 2]) ** 2, corrected, rtol=1e-10)


def test_printed_eq_20_has_no_real_solution():
    """As printed, the radicand ln(1 − ξτ0) / (ln(1 − ξτ0) − ln(1 − τ0)) is negative for every ξ and τ0 in
    (0, 1): the inverse CDF gives no angle at all (the sign error of research notes §3)."""
    xi, tau0 = np.meshgrid(np.linspace(0.001, 0.999, 200), np.linspace(0.001, 0.98, 50))
    radicand = np.log(1 - xi * tau0) / (np.log(1 - xi * tau0) - np.log(1 - tau0))
    assert np.all(radicand < 0)
    with np.errstate(invalid="ignore"):
        assert np.all(np.isnan(np.arctan(0.5 * np.sqrt(radicand))))


def test_chi2_rejects_a_wrong_ndf_sampler():
    """GGX(β) or GGX(α̃) samples are not micrograin samples at τ0 = 0.9: the test can tell."""
    tau0, beta = 0.9, 0.5
    u = _uniforms(N, 2)
    for wrong in (mg.sample_ndf(0.0, beta, u[:, 0], u[:, 1]),
                  mg.sample_ndf(0.0, mg.params_from_dict(dict(filling_factor=tau0, anfractuosity=beta)).roughness,
                                u[:, 0], u[:, 1])):
        assert chi2_test(wrong, _ndf_density(tau0, beta), n_theta=48, res=10).p_value < 1e-6


# ------------------------------------------------------------------------------------------- BSDF

PLASTIC = {"type": "spongecake", "preset": "plastic"}
CASES = {
    "diffuse grains on diffuse": dict(grain={"type": "diffuse"}, bulk={"type": "diffuse"}),
    "coated grains on diffuse": dict(grain={"type": "dielectric", "ior": 1.5}, bulk={"type": "diffuse"}),
    "metal grains on diffuse": dict(grain={"type": "conductor"}, bulk={"type": "diffuse"}),
    "coated grains on metal": dict(grain={"type": "dielectric", "ior": 2.0},
                                   bulk={"type": "conductor", "roughness": 0.2}),
    "metal grains on glass": dict(grain={"type": "conductor"}, bulk={"type": "dielectric", "roughness": 0.3}),
    "coated grains on plastic": dict(grain={"type": "dielectric", "ior": 1.5}, bulk=PLASTIC),
    "diffuse grains on plastic": dict(grain={"type": "diffuse"}, bulk=PLASTIC),
    "dense sharp metal grains on glass": dict(filling_factor=0.98, anfractuosity=0.3, grain={"type": "conductor"},
                                              bulk={"type": "dielectric", "roughness": 0.3}),
}
SIDES = {"above": unit(0.5, 0.3, 0.6), "grazing": unit(0.95, 0.0, 0.1), "below": unit(-0.4, 0.5, -0.7)}
RUNS = [(name, side) for name in CASES for side in SIDES
        if side != "below" or CASES[name]["bulk"]["type"] in ("dielectric", "spongecake")]


def _params(name):
    return mg.params_from_dict(dict(dict(filling_factor=0.6, anfractuosity=0.5), **CASES[name]))


def _pdf_of(p, wi):
    return lambda wo: mg.pdf(p, np.repeat(wi, len(wo), 0), wo)


@pytest.mark.parametrize("name, side", RUNS)
def test_mean_sample_weight_is_the_albedo(name, side):
    """E[weight] = ∫ f(wi, wo) |cos θo| dωo, the integral taken by deterministic quadrature of ``eval``
    (independent of the sampler); finite, non-negative weights with pdf > 0 almost everywhere."""
    from addon.reference import scenes

    p, wi = _params(name), SIDES[side]
    s = mg.sample(p, np.repeat(wi, 40_000, 0), _uniforms(40_000, 3))
    assert np.all(np.isfinite(s.weight)) and np.all(s.weight >= 0) and (s.pdf > 0).mean() > 0.99
    assert np.allclose(np.linalg.norm(s.wo, axis=1), 1.0, atol=1e-12)
    albedo = scenes.directional_albedo(lambda a, b: mg.eval(p, b, a), wi[None], quadrature=(128, 256))[0]
    mean, err = s.weight.mean(axis=0), s.weight.std(axis=0) / np.sqrt(len(s.weight))
    assert np.all(np.abs(mean - albedo) <= 4 * err + 0.01 * albedo), (mean, albedo, err)


@pytest.mark.parametrize("name, side", RUNS)
def test_sampled_directions_follow_the_pdf(name, side):
    """From grazing wi, the specular lobe's density D cos θm / (4 |wi·m|) is singular at wo = −wi (every
    m ⊥ wi maps there), which the cells' quadrature cannot integrate: there only the upper hemisphere is
    binned, and the rest of the samples go to the remainder cell."""
    p, wi = _params(name), SIDES[side]
    s = mg.sample(p, np.repeat(wi, N, 0), _uniforms(N, zlib.crc32(f"{name} {side}".encode())))
    density = _pdf_of(p, wi)
    if side == "grazing":
        result = chi2_test(s.wo[s.wo[:, 2] > 0], lambda wo: density(wo) * (wo[:, 2] > 0), n_total=N, res=10)
    else:
        result = chi2_test(s.wo, density, res=10)
        assert result.integral == pytest.approx(1.0, abs=5e-3)
    assert result.p_value > 0.01, result


def test_chi2_catches_a_missing_reflection_jacobian():
    """Dropping 1 / (4 |wi·m|) from the specular lobe's density fails even once renormalised."""
    p, wi = _params("metal grains on diffuse"), SIDES["above"]
    s = mg.sample(p, np.repeat(wi, N, 0), _uniforms(N, 4))

    def wrong(wo):
        wis = np.repeat(wi, len(wo), 0)
        probabilities = mg._lobe_probabilities(p, wis)
        spec = mg._specular_pdf(p, wis, wo) * 4 * np.abs(frames.dot(wis, frames.normalize(wis + wo)))
        return probabilities[:, 0] * spec + probabilities[:, 2] * np.maximum(wo[:, 2], 0) / np.pi

    total = cell_integrals(wrong, 24, 48, 10).sum()
    assert chi2_test(s.wo, _pdf_of(p, wi), res=10).p_value > 0.01
    assert chi2_test(s.wo, lambda wo: wrong(wo) / total, res=10).p_value < 1e-6
