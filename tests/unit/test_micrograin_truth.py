"""Explicit-grain Monte Carlo (reference.micrograin_truth) against the micrograin closed forms (Lucas et al. 2023).

The simulation casts rays into Poisson fields of half-ellipsoid grains; it never uses Eqs. 16-25.
"""
import math

import numpy as np
import pytest

from addon.reference.micrograin import ndf, tau_plus
from addon.reference.micrograin_truth import ground_truth, visible_filling, visible_normals
from stats import chi2_test

GRID = [(tau0, beta, theta) for tau0 in (0.2, 0.5, 0.9) for beta in (0.3, 1.0) for theta in (0, 30, 60, 80)]


@pytest.mark.parametrize("tau0,beta,theta", GRID)
def test_visible_filling_matches_eq22(tau0, beta, theta):
    c = math.cos(math.radians(theta))
    estimate, stderr = visible_filling(tau0, beta, c, n_rays=200_000, seed=theta)
    expected = float(tau_plus(c, tau0, beta))
    assert stderr <= 0.002
    assert abs(estimate - expected) < 0.01, (estimate, stderr, expected)
    assert abs(estimate - expected) < 5.0 * max(stderr, 1e-4), (estimate, stderr, expected)


@pytest.mark.parametrize("tau0,beta", [(0.2, 0.5), (0.2, 1.0), (0.9, 0.5), (0.9, 1.0)])
def test_normal_view_normals_follow_ndf(tau0, beta):
    """Seen from above, the first hit is on the closest grain: visible normals have density D(m) cos theta_m."""
    normals, fraction = visible_normals(tau0, beta, 1.0, n_rays=400_000, seed=7)
    assert abs(fraction - tau0) < 5.0 * math.sqrt(tau0 * (1.0 - tau0) / 400_000)

    def pdf(m):
        return np.where(m[:, 2] > 0.0, ndf(m, tau0, beta) * np.maximum(m[:, 2], 0.0), 0.0)

    result = chi2_test(normals, pdf, n_theta=200, n_phi=4)
    assert abs(result.integral - 1.0) < 1e-3, result
    assert result.p_value > 1e-3, result


def test_flat_grains_and_monotonicity():
    flat, stderr = visible_filling(0.5, 1e-3, 0.5, n_rays=100_000, seed=3)
    assert abs(flat - 0.5) < 5.0 * stderr  # beta -> 0: discs, tau+ = tau0 at every angle
    truth = ground_truth((0.5, 1.0), angles_deg=(0, 30, 45, 60, 75, 85), n_rays=100_000, seed=1)
    assert np.all(np.diff(truth["tau_plus"]) > 0.0), truth["tau_plus"]
    assert abs(truth["tau_plus"][0] - 0.5) < 5.0 * truth["stderr"][0]
    assert truth["tau_plus"][-1] > 0.95  # towards 1 at grazing (Fig. 9)
