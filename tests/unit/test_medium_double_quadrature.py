"""Double scattering without a network (``reference.neural_medium.double_table``): the 1-D integral over the first
collision, checked against the photon tracer's Monte Carlo tables (independent: histograms of simulated second
collisions) and against the infinite medium's power albedo^2."""
import math

import numpy as np
import pytest

from addon.reference import neural_medium as nm
from training import medium_tracer as mt

SMALL = mt.Grid(rho_edges=(0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0),
                z_edges=(-3.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0))


def _edges(grid):
    return np.asarray(grid.rho_edges), np.asarray(grid.z_edges), grid.theta_centres(), grid.phi_centres()


def test_the_quadrature_is_the_tracers_isotropic_double_scattering():
    """g = 0 (every bin convention agrees): cell by cell and direction by direction within 4 standard errors plus
    3 %, and in all within 2 %; a wrong albedo power (albedo^1) is far outside."""
    alpha = 0.8
    r = mt.simulate(alpha, 0.0, SMALL, mt.Settings(photons=2000, double_photons=400_000, batches=4, sub=8), seed=11)
    q = nm.double_table(alpha, 0.0, *_edges(SMALL))
    mc, se = r["double"], r["double_se"]
    assert np.all(np.abs(q - mc) <= 4.0 * se + 0.03 * mc + 1e-12)
    assert q.sum() == pytest.approx(mc.sum(), rel=0.02)
    assert not (q / alpha).sum() == pytest.approx(mc.sum(), rel=0.1)


@pytest.mark.parametrize("g", [0.5, -0.5])
def test_the_quadrature_has_the_tracers_density_of_second_collisions(g):
    """Anisotropic media: the density of second collisions (the table integrated over directions, over albedo) cell
    by cell within 4 standard errors plus 3 % of the tracer's histogram, whose bins smooth the phase function
    differently (over the arrival bin, where the quadrature averages over the output bin)."""
    alpha = 0.8
    r = mt.simulate(alpha, g, SMALL, mt.Settings(photons=2000, double_photons=800_000, batches=8, sub=4), seed=12)
    q = nm.double_table(alpha, g, *_edges(SMALL))
    density = np.einsum("ijkl,kl->ij", q, nm.bin_solid_angles(*q.shape[2:])) / alpha
    mc, se = r["density_double"], r["density_double_se"]
    assert np.all(np.abs(density - mc) <= 4.0 * se + 0.03 * mc)


@pytest.mark.parametrize("g", [-0.9, 0.0, 0.8])
def test_the_quadrature_emits_the_infinite_mediums_power(g):
    """albedo^2 of a unit source is emitted by second scatterings; a 64 mfp table holds all but e^-64 of it."""
    grid = mt.default_grid(extent=64.0, n_rho=24, n_z=48)
    q = nm.double_table(0.9, g, *_edges(grid))
    assert nm.table_energy(q, grid.rho_edges, grid.z_edges) == pytest.approx(0.81, rel=0.02)


@pytest.mark.parametrize("albedo, g", [(0.0, 0.0), (1.0, 0.0), (0.5, 0.99), (0.5, -0.99)])
def test_the_quadrature_is_finite_and_non_negative_at_the_extremes(albedo, g):
    q = nm.double_table(albedo, g, *_edges(SMALL))
    assert np.all(np.isfinite(q)) and q.min() >= 0.0
    assert (q.max() > 0.0) == (albedo > 0.0)
    assert math.isfinite(nm.table_energy(q, SMALL.rho_edges, SMALL.z_edges))


def test_the_quadrature_refuses_direction_bins_it_cannot_average():
    """Each output bin is averaged over its own directions, which assumes equal bins over [0, pi]."""
    rho, z, theta, phi = _edges(SMALL)
    with pytest.raises(ValueError, match="theta"):
        nm.double_table(0.5, 0.0, rho, z, theta ** 1.1, phi)


def _direct_ring(r0, r1, z0, z1, sub, quadrature):
    """The ring's sum written out over every point and step: exp(-s - r) on the psi midpoints beyond psi0."""
    edges, psi, first, second = quadrature
    frac = (np.arange(sub) + 0.5) / sub
    R = (r0 + frac * (r1 - r0))[:, None, None, None]
    Z = (z0[:, None] + frac[None, :] * (z1 - z0)[:, None])[None, :, :, None]
    width = np.clip(np.minimum(edges[1:], math.pi) - np.maximum(edges[:-1], np.arctan2(R, Z)), 0.0, None)
    s = Z - R / np.tan(psi)
    w = np.where(s >= 0.0, np.exp(-np.maximum(s, 0.0) - R / np.sin(psi)), 0.0) * first * width
    return np.einsum("azbn,nd->zd", w, second) * 2.0 / ((r0 + r1) * sub * sub)


@pytest.mark.parametrize("g", [0.5, -0.9])
def test_the_factored_steps_are_the_direct_sum(g, monkeypatch):
    """``_double_ring`` sums the steps beyond psi0 by suffix sums of the factored integrand: the same table as the
    direct sum over every point and step, to rounding, on a grid reaching 8 mfp below the source."""
    grid = mt.Grid(rho_edges=(0.0, 0.1, 0.5, 2.0, 8.0), z_edges=(-8.0, -1.0, -0.2, 0.0, 0.3, 1.0, 8.0))
    factored = nm.double_table(0.7, g, *_edges(grid), nodes=128)
    monkeypatch.setattr(nm, "_double_ring", _direct_ring)
    direct = nm.double_table(0.7, g, *_edges(grid), nodes=128)
    np.testing.assert_allclose(factored, direct, rtol=1e-10, atol=1e-14 * direct.max())
