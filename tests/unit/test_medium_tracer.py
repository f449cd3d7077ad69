"""The photon tracer of the neural participating media (training/medium_tracer.py): energy per scattering order,
first-collision depth, HG scattering, an independent closed form for isotropic double scattering, extremes, the
sign of the final phase function, the far-photon bias probe, and the resumable dataset (training/medium_dataset.py).
Small grids and seeded runs: every test takes seconds."""
import json
import math

import numpy as np
import pytest

from stats import chi2_sf
from training import medium_dataset as md
from training import medium_tracer as mt

# rho up to 4 mfp, z in [-3, 5]: small and fast, with cells away from the axis on both sides of the source
SMALL = mt.Grid(rho_edges=(0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0),
                z_edges=(-3.0, -2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0))


def _batches(fn, n_batches, seed):
    """Mean and standard error over independent seeded batches of fn(rng)."""
    values = np.array([fn(np.random.default_rng([seed, b])) for b in range(n_batches)])
    return values.mean(axis=0), values.std(axis=0, ddof=1) / math.sqrt(n_batches)


# ------------------------------------------------------------------------------------------ (a) energy per order

@pytest.mark.parametrize("roulette", [None, 1.0])  # the default (alpha^2) and analog absorption
def test_order_k_carries_alpha_to_the_k_minus_1(roulette):
    alpha, n = 0.9, 20000
    t = mt.trace(alpha, 0.5, SMALL, n, np.random.default_rng(7), roulette=roulette, far=1e9)
    w_rr = alpha ** 2 if roulette is None else roulette
    assert t.dropped == 0 and len(t.order_weight) > 30
    for k in range(1, 31):
        p_k = min(1.0, alpha ** (k - 1) / w_rr)
        w_k = alpha ** (k - 1) / p_k
        sigma = w_k * math.sqrt(p_k * (1.0 - p_k) / n)
        got = t.order_weight[k - 1] / n
        assert abs(got - alpha ** (k - 1)) <= 3.0 * sigma + 1e-12, (k, got, alpha ** (k - 1), sigma)
        if p_k == 1.0:
            assert t.order_count[k - 1] == n  # no roulette before w_rr: the weight is exact
    # the measured cost is the predicted one
    assert abs(t.order_count.sum() / n - mt.expected_collisions(alpha, roulette)) < 0.05 * mt.expected_collisions(alpha, roulette)


@pytest.mark.parametrize("alpha,g", [(0.9, 0.5), (0.7, -0.6), (0.97, 0.9)])
def test_total_weight_of_all_orders_is_one_over_one_minus_alpha(alpha, g):
    """Counting every collision, inside the (small) table or not: Sum_k alpha^(k-1) = 1 / (1 - alpha)."""
    captured = []

    def total(rng):
        t = mt.trace(alpha, g, SMALL, 1000, rng, far=1e9)
        captured.append(t.hist.sum() / t.order_weight.sum())
        return t.order_weight.sum() / t.photons

    mean, se = _batches(total, 40, seed=11)
    assert abs(mean - 1.0 / (1.0 - alpha)) <= 3.0 * se, (mean, se)
    assert max(captured) < 1.0  # collisions outside the table were counted too


# ------------------------------------------------------------------------------------------ (b) first collisions

def test_first_collision_depth_follows_exp_minus_z():
    n = 40000
    t = mt.trace(0.5, 0.0, SMALL, n, np.random.default_rng(3), max_order=1)
    counts = t.hist[0].reshape(len(SMALL.rho_edges) - 1, len(SMALL.z_edges) - 1, -1)
    assert counts[1:].sum() == 0  # on the axis
    per_z = counts[0].sum(axis=1)
    z = np.asarray(SMALL.z_edges)
    assert per_z[z[:-1] < 0].sum() == 0  # nothing behind the source
    front = z[:-1] >= 0
    expected = n * (np.exp(-z[:-1][front]) - np.exp(-z[1:][front]))
    observed = per_z[front]
    observed = np.append(observed, n - observed.sum())  # beyond the table
    expected = np.append(expected, n * math.exp(-z[-1]))
    assert expected.min() > 5
    chi2 = float(np.sum((observed - expected) ** 2 / expected))
    assert chi2_sf(chi2, len(expected) - 1) > 1e-3, (observed, expected)
    # the test can fail: depths that follow e^(-z / 1.05) (a 5 % wrong mean free path) are rejected
    wrong = np.append(n * (np.exp(-z[:-1][front] / 1.05) - np.exp(-z[1:][front] / 1.05)), n * math.exp(-z[-1] / 1.05))
    assert chi2_sf(float(np.sum((observed - wrong) ** 2 / wrong)), len(wrong) - 1) < 1e-6


# ------------------------------------------------------------------------------------------ (c) HG scattering

def _hg_cdf(g, c):
    """P(cos <= c) of Henyey-Greenstein, written out independently of addon.reference.hg."""
    if g == 0.0:
        return 0.5 * (c + 1.0)
    return (1.0 - g * g) / (2.0 * g) * (1.0 / np.sqrt(1.0 + g * g - 2.0 * g * c) - 1.0 / (1.0 + g))


def _hg_chi2_p(cosines, g, bins=40):
    """Chi-square p-value of the cosines against HG(g) on bins of equal probability."""
    fine = np.linspace(-1.0, 1.0, 200001)
    edges = np.interp(np.linspace(0.0, 1.0, bins + 1), _hg_cdf(g, fine), fine)
    edges[0], edges[-1] = -1.0 - 1e-12, 1.0 + 1e-12
    observed = np.histogram(cosines, edges)[0]
    expected = np.diff(_hg_cdf(g, np.clip(edges, -1.0, 1.0))) * len(cosines)
    return chi2_sf(float(np.sum((observed - expected) ** 2 / expected)), bins - 1)


@pytest.mark.parametrize("g", [-0.9, -0.3, 0.0, 0.5, 0.9])
def test_scattering_cosines_follow_hg(g):
    rng = np.random.default_rng(5)
    n = 100000
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    out = mt.scatter(d, g, rng)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)
    cosines = np.einsum("ij,ij->i", d, out)
    assert _hg_chi2_p(cosines, g) > 1e-3
    assert _hg_chi2_p(cosines, -g if g else 0.3) < 1e-6  # the test can fail: the mirrored lobe is rejected
    # azimuth about a fixed incoming direction is uniform
    d0 = np.tile(np.array([[0.6, 0.0, 0.8]]), (n, 1))
    out0 = mt.scatter(d0, g, rng)
    e1, e2 = np.array([0.8, 0.0, -0.6]), np.array([0.0, 1.0, 0.0])
    phi = np.arctan2(out0 @ e2, out0 @ e1) % (2 * np.pi)
    observed = np.histogram(phi, np.linspace(0, 2 * np.pi, 25))[0]
    expected = n / 24
    assert chi2_sf(float(np.sum((observed - expected) ** 2 / expected)), 23) > 1e-3


# ------------------------------------------------------------------------------------------ (d) isotropic closed form

def _second_collision_density(alpha, rho, z):
    """Integral_0^inf e^-s alpha e^-r / (4 pi r^2) ds, r = |x - s e_z| (first collision at depth s, then an
    isotropic flight to x): Gauss-Legendre on [0, 40] in 160 panels."""
    x, w = np.polynomial.legendre.leggauss(8)
    edges = np.linspace(0.0, 40.0, 161)
    s = (0.5 * (edges[:-1, None] + edges[1:, None]) + 0.5 * np.diff(edges)[:, None] * x).ravel()
    ws = (0.5 * np.diff(edges)[:, None] * w).ravel()
    r2 = rho[..., None] ** 2 + (z[..., None] - s) ** 2
    return alpha * np.sum(ws * np.exp(-s - np.sqrt(r2)) / (4.0 * np.pi * r2), axis=-1)


def _cell_average(alpha, r0, r1, z0, z1):
    x, w = np.polynomial.legendre.leggauss(6)
    rho = 0.5 * (r0 + r1) + 0.5 * (r1 - r0) * x
    zz = 0.5 * (z0 + z1) + 0.5 * (z1 - z0) * x
    f = _second_collision_density(alpha, rho[:, None] * np.ones((1, 6)), np.ones((6, 1)) * zz[None, :])
    integral = np.sum(w[:, None] * w[None, :] * f * 2.0 * np.pi * rho[:, None]) * 0.25 * (r1 - r0) * (z1 - z0)
    return integral / (np.pi * (r1 * r1 - r0 * r0) * (z1 - z0))


# (rho index, z index) of SMALL: rho in [1, 1.5] or [1.5, 2]; z behind, beside and in front of the source
CELLS = [(3, 2), (3, 4), (4, 5), (3, 7), (4, 8)]


def test_isotropic_second_collision_density_matches_the_closed_form():
    alpha, n = 0.8, 200000
    idx = np.array(CELLS)
    vol = SMALL.volumes()[idx[:, 0], idx[:, 1]]

    def dens(rng):
        t = mt.trace(alpha, 0.0, SMALL, n, rng, max_order=2, roulette=0.0)
        d = t.hist[1].sum(axis=1).reshape(SMALL.shape[:2]) / n
        return d[idx[:, 0], idx[:, 1]] / vol

    mean, se = _batches(dens, 12, seed=21)
    exact = np.array([_cell_average(alpha, SMALL.rho_edges[i], SMALL.rho_edges[i + 1], SMALL.z_edges[j],
                                    SMALL.z_edges[j + 1]) for i, j in CELLS])
    assert np.all(se < 0.05 * mean)  # the comparison has power
    # the cells' average (independent batches give the noise of the average), and each cell at 4 sigma
    avg, avg_exact = mean.mean(), exact.mean()
    assert abs(avg - avg_exact) <= 3.0 * np.sqrt(np.sum(se ** 2)) / len(CELLS), (avg, avg_exact)
    np.testing.assert_array_less(np.abs(mean - exact), 4.0 * se)
    # the test can fail: the same closed form without the albedo of the first scattering is rejected
    assert abs(avg - avg_exact / alpha) > 10.0 * np.sqrt(np.sum(se ** 2)) / len(CELLS)


def test_isotropic_emission_is_alpha_density_over_four_pi():
    """For g = 0 the final phase function is 1 / (4 pi): Phi_2 = alpha * (order-2 density) / (4 pi) in every
    direction (the emission step and the density agree)."""
    alpha = 0.8
    r = mt.simulate(alpha, 0.0, SMALL, mt.Settings(photons=2000, double_photons=40000, batches=2, sub=4), seed=2)
    expected = alpha * r["density_double"] / (4.0 * np.pi)
    np.testing.assert_allclose(r["double"], np.broadcast_to(expected[..., None, None], r["double"].shape),
                               rtol=1e-10, atol=1e-15)


# ------------------------------------------------------------------------------------------ (e) extremes

TINY = mt.Grid(rho_edges=(0.0, 0.5, 1.0, 2.0), z_edges=(-2.0, -1.0, 0.0, 1.0, 2.0), n_theta=6, n_phi=6)


@pytest.mark.parametrize("alpha", [0.0, 1.0])
@pytest.mark.parametrize("g", [-0.99, 0.99])
def test_extreme_media_give_finite_non_negative_tables(alpha, g):
    s = mt.Settings(photons=400, double_photons=4000, batches=2, far=3.0, sub=4)
    r = mt.simulate(alpha, g, TINY, s, seed=4)
    for key in ("single", "double", "multiple", "double_se", "multiple_se"):
        assert np.all(np.isfinite(r[key])) and np.all(r[key] >= 0.0), key
    if alpha == 0.0:
        assert not r["double"].any() and not r["multiple"].any()
        assert len(r["order_weight"]) == 1
    else:
        assert r["double"].max() > 0 and r["multiple"].max() > 0


# ------------------------------------------------------------------------------------------ (f) phase sign

@pytest.mark.parametrize("g", [0.9, -0.9])
def test_forward_scattering_emits_forward_on_the_axis(g):
    """On the axis beyond the source (rho < 0.25, 1 < z < 1.5) single scattering arrives along +z: with g = 0.9 it
    is emitted along +z (theta bin 0) far more than back (the last theta bin), with g = -0.9 the opposite. Double
    scattering there arrives mostly along +z for g = 0.9 (forward twice) and along -z for g = -0.9 (sent back
    from deeper first collisions), so both signs emit it along +z. A phase function applied with the wrong sign
    of the cosine fails every one of these."""
    r = mt.simulate(0.9, g, SMALL, mt.Settings(photons=2000, double_photons=100000, batches=2, sub=8), seed=6)
    for key, forward_wins in (("single", g > 0), ("double", True)):
        cell = r[key][0, 6]  # (theta, phi)
        forward, backward = cell[0].mean(), cell[-1].mean()
        assert forward > 0 and backward > 0
        ratio = forward / backward
        assert (ratio > 10.0) if forward_wins else (ratio < 0.1), (key, ratio)


# ------------------------------------------------------------------------------------------ far photons

def test_far_bound_and_its_bias_probe():
    alpha, g, n = 0.99, 0.0, 3000
    near = mt.trace(alpha, g, SMALL, n, np.random.default_rng(1), far=SMALL.corner * 1.01, probe=True)
    far = mt.trace(alpha, g, SMALL, n, np.random.default_rng(1), far=4 * SMALL.corner, probe=True)
    assert near.dropped == 0 and near.crossed > 0
    share_near = near.probe.sum() / near.hist.sum()
    share_far = far.probe.sum() / far.hist.sum()
    assert 0.0 < share_near < 0.5 and share_far < 0.3 * share_near
    dropped = mt.trace(alpha, g, SMALL, n, np.random.default_rng(2), far=SMALL.corner * 1.01)
    assert dropped.dropped > 0 and dropped.dropped_weight > 0
    # dropping removes (statistically) what the probe measured
    assert dropped.hist.sum() < near.hist.sum() - 0.5 * near.probe.sum()
    with pytest.raises(ValueError):
        mt.trace(alpha, g, SMALL, 10, np.random.default_rng(0), far=1.0)  # inside the table
    with pytest.raises(ValueError):
        mt.trace(1.0, g, SMALL, 10, np.random.default_rng(0), probe=True)  # nothing would end the walks


def test_default_grid_is_as_documented():
    grid = mt.default_grid()
    assert grid.shape == (40, 80, 18, 18)
    assert grid.rho_edges[-1] == 256.0 and grid.z_edges[0] == -256.0 and grid.z_edges[-1] == 256.0
    widths = np.diff(grid.rho_edges)
    assert 0.1 < widths[0] < 0.2 and np.all(np.diff(widths) > 0)
    assert mt.default_far(grid) == 1024.0
    np.testing.assert_allclose(grid.volumes().sum(), np.pi * 256.0 ** 2 * 512.0)


# ------------------------------------------------------------------------------------------ dataset

def test_dataset_writes_resumes_and_recomputes(tmp_path):
    argv = ["--out", str(tmp_path), "--albedos", "0.5", "0.9", "--gs", "0.3", "--quick", "--seed", "3"]
    assert md.main(argv) == 0
    files = sorted(p.name for p in tmp_path.glob("*.npz"))
    assert files == [md.material_name(0.5, 0.3) + ".npz", md.material_name(0.9, 0.3) + ".npz"]
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert len(manifest["materials"]) == 2
    with np.load(tmp_path / files[1]) as f:
        meta = json.loads(str(f["meta"]))
        assert f["double"].shape == f["multiple"].shape == f["double_se"].shape == tuple(meta["grid_shape"])
        assert meta["alpha"] == 0.9 and meta["photons"] > 0 and meta["seconds"] > 0
        assert np.all(f["double"] >= 0) and f["multiple"].max() > 0
        first = f["multiple"].copy()
    stamp = (tmp_path / files[1]).stat().st_mtime_ns
    assert md.main(argv) == 0  # resumed: nothing recomputed
    assert (tmp_path / files[1]).stat().st_mtime_ns == stamp
    assert md.main(argv[:-1] + ["4"]) == 0  # another configuration: recomputed
    with np.load(tmp_path / files[1]) as f:
        assert not np.array_equal(f["multiple"], first)
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary file left
