"""Extreme parameters and directions: every output of the micrograin reference finite and non-negative, without
a numpy warning (τ0 in {0, 1e-6, 0.98}, β in {1e-3, 1}, grazing directions, grain IOR 1)."""
import itertools

import numpy as np
import pytest

from addon.reference import frames
from addon.reference import micrograin as mg

COSINES = (1.0, 0.5, 1e-7, 0.0, -0.0, -1e-7, -1.0)
DIRECTIONS = frames.spherical(np.repeat(COSINES, 2), np.tile([0.0, 2.2], len(COSINES)))
WI = np.repeat(DIRECTIONS, len(DIRECTIONS), 0)
WO = np.tile(DIRECTIONS, (len(DIRECTIONS), 1))
U = np.array(list(itertools.product((0.0, 0.5, np.nextafter(1.0, 0.0)), repeat=3)))

GRAINS = {
    "diffuse": {"type": "diffuse", "albedo": [1, 1, 1]},
    "ior 1": {"type": "dielectric", "albedo": [1, 1, 1], "ior": 1.0},
    "ior 1.0001": {"type": "dielectric", "albedo": [0, 0, 0], "ior": 1.0001},
    "ior 3": {"type": "dielectric", "ior": 3.0},
    "conductor": {"type": "conductor", "ior": [0.01, 1.0, 10.0], "k": [0.0, 20.0, 3.0]},
}
BULKS = {
    "diffuse": {"type": "diffuse"},
    "smooth conductor": {"type": "conductor", "roughness": 1e-4},
    "smooth dielectric": {"type": "dielectric", "roughness": 1e-4, "ior": 1.0001},
    "rough dielectric": {"type": "dielectric", "roughness": 1.0, "ior": 3.0},
    "spongecake": {"type": "spongecake", "preset": "plastic"},
}


def _check(*arrays):
    for a in arrays:
        assert np.all(np.isfinite(a)) and np.all(a >= 0)


@pytest.mark.parametrize("gaf", ("series", "ggx"))
@pytest.mark.parametrize("beta", (1e-3, 1.0))
@pytest.mark.parametrize("tau0", (0.0, 1e-6, 0.98))
@pytest.mark.parametrize("grain", GRAINS)
def test_bsdf_outputs_are_finite_and_non_negative(grain, tau0, beta, gaf):
    for bulk in BULKS.values():
        p = mg.params_from_dict(dict(filling_factor=tau0, anfractuosity=beta, grain=GRAINS[grain], bulk=bulk,
                                     gaf=gaf))
        with np.errstate(divide="raise", over="raise", invalid="raise"):
            for blend in mg.BLENDS:
                _check(mg.eval(p, WI, WO, blend))
            _check(mg.pdf(p, WI, WO))
            s = mg.sample(p, np.repeat(DIRECTIONS, len(U), 0), np.tile(U, (len(DIRECTIONS), 1)))
            _check(s.weight, s.pdf)
            assert np.allclose(np.linalg.norm(s.wo, axis=1), 1.0, atol=1e-9)


@pytest.mark.parametrize("beta", (1e-3, 1.0))
@pytest.mark.parametrize("tau0", (0.0, 1e-6, 0.98))
def test_geometric_terms_are_finite_and_non_negative(tau0, beta):
    c = np.array([1.0, 1.0 - 1e-16, np.cos(1e-4), 0.5, 1e-7, 1e-30, 1e-300, 0.0])
    w = frames.spherical(c, 0.3)
    with np.errstate(divide="raise", over="raise", invalid="raise"):
        for gaf in ("series", "ggx"):
            _check(mg.g2(WI, WO, tau0, beta, gaf), mg.g1(w, tau0, beta, gaf))
        lam = mg.smith_lambda(w, tau0, beta)
        _check(lam[:-1], mg.lambda_numeric(c[:-1], tau0, beta), mg.ndf(DIRECTIONS, tau0, beta))
        _check(mg.tau_beta(c, tau0, beta), mg.tau_plus(c, tau0, beta), mg.w_plus(WI, WO, tau0, beta))
        c32 = c.astype(np.float32)  # 1e-300 is grazing in float32
        lam32 = mg.smith_lambda_float32(c32, np.float32(tau0), np.float32(beta))
        _check(lam32[c32 > 0])
        m = mg.sample_ndf(tau0, beta, U[:, 0], U[:, 1])
        _check(m[:, 2], mg.specular_albedo(c, tau0, beta, 1.5))
    assert lam[-1] == np.inf and np.all(lam32[c32 == 0] == np.inf) and lam[0] == 0.0 and lam32[0] == 0.0
    assert np.allclose(np.linalg.norm(m, axis=1), 1.0, atol=1e-12)


def test_lambda_at_the_largest_density_and_grazing():
    """τ0 = 0.98, β = 1: Λ is large but finite up to 1e-300 from grazing, and the float32 scheme's G1 agrees (its
    Λ is 5% low at 89.99°, where G1 is below 0.03)."""
    c = np.array([1e-2, 1e-4, 1e-8, 1e-300])
    lam = mg.smith_lambda(frames.spherical(c, 0.0), 0.98, 1.0)
    assert np.all(np.isfinite(lam)) and np.all(np.diff(lam) > 0) and lam[-1] > 1e298
    assert np.allclose(1 / (1 + mg.smith_lambda_float32(c[:2], 0.98, 1.0)), 1 / (1 + lam[:2]), rtol=0, atol=3e-4)
