"""von Mises-Fisher kit: normalisation, A3 and its inverse (against mpmath), moment-matched convolution (against
quadrature and Monte Carlo), sampling (chi-square against the density) and the Beckmann stand-in."""
import mpmath
import numpy as np
import pytest

from addon.reference import frames, vmf
from stats import chi2_sf, chi2_test, sphere_directions

KAPPAS = [1e-3, 0.1, 1.0, 10.0, 1e3, 1e5, 1e6]
PAIRS = [(1.0, 1.0), (10.0, 1e4), (1e4, 10.0), (0.1, 50.0), (100.0, 100.0), (50.0, 200.0), (1e3, 1e6)]
mpmath.mp.dps = 50


def _lobe_edges(kappa):
    """Panel edges in w = 1 - cos theta over [0, 2]: width 1/kappa over the lobe core, eighths of the range beyond."""
    core = np.arange(41) / kappa if kappa > 0 else np.zeros(1)
    return np.unique(np.minimum(2.0, np.concatenate([core, np.linspace(0.0, 2.0, 9)])))


def _rule(edges, order=16):
    """Composite Gauss-Legendre nodes and weights on the panels between ``edges``."""
    x, wt = np.polynomial.legendre.leggauss(order)
    half = 0.5 * np.diff(edges)[:, None]
    return (edges[:-1, None] + half * (x + 1.0)).ravel(), (half * wt).ravel()


def _lobe_rule(kappa):
    """Nodes w = 1 - cos theta in [0, 2] and weights for integrals against a vMF lobe."""
    return _rule(_lobe_edges(kappa))


def _mp_a3(kappa):
    k = mpmath.mpf(kappa)
    return mpmath.coth(k) - 1 / k


# ------------------------------------------------------------------------------------------ density

@pytest.mark.parametrize("kappa", [0.0] + KAPPAS)
def test_density_integrates_to_one(kappa):
    w, wt = _lobe_rule(kappa)
    # cos theta = 1 - w rounds by 1e-16, which the density amplifies by kappa: 1e-10 relative at kappa = 1e6
    assert 2.0 * np.pi * np.sum(wt * vmf.density(1.0 - w, kappa)) == pytest.approx(1.0, abs=1e-15 * max(1e3, kappa))


def test_density_matches_the_sinh_form_in_high_precision():
    for kappa in [1e-3, 0.3, 1.0, 40.0, 800.0, 1e6]:
        for cos in [-1.0, 0.0, 0.7, 1.0 - 3.0 / kappa, 1.0]:
            k = mpmath.mpf(kappa)
            exact = k / (4 * mpmath.pi * mpmath.sinh(k)) * mpmath.exp(k * cos)
            assert vmf.density(cos, kappa) == pytest.approx(float(exact), rel=1e-12, abs=1e-300)


def test_density_is_finite_and_non_negative_everywhere():
    cos = np.concatenate([[-1.0, 0.0, 1.0], np.linspace(-1.0, 1.0, 1001)])[:, None]
    kappa = np.array([0.0, 1e-300, 1e-3, 1.0, 700.0, 720.0, 1e3, 1e5, 1e6])[None, :]
    d = vmf.density(cos, kappa)
    assert np.all(np.isfinite(d)) and np.all(d >= 0.0)
    assert np.all(d[:, :2] == pytest.approx(0.25 / np.pi, rel=1e-15))
    assert vmf.density(1.0, 1e6) == pytest.approx(1e6 / (2.0 * np.pi), rel=1e-15)


# --------------------------------------------------------------------------------------- A3, inverse

def test_a3_and_complement_match_mpmath():
    for kappa in [1e-3, 0.01, 0.0499, 0.05, 0.051, 0.3, 1.0, 5.0, 10.0, 100.0, 1e3, 1e6]:
        exact = _mp_a3(kappa)
        assert vmf.a3(kappa) == pytest.approx(float(exact), rel=1e-13)
        assert vmf.mean_cosine_complement(kappa) == pytest.approx(float(1 - exact), rel=1e-15)


def test_inverse_round_trips_over_the_whole_range():
    kappa = np.logspace(-3, 6, 4001)
    from_u = vmf.kappa_from_complement(vmf.mean_cosine_complement(kappa))
    from_r = vmf.kappa_from_a3(vmf.a3(kappa))
    assert np.max(np.abs(from_u / kappa - 1.0)) < 1e-12  # measured 3.0e-13
    assert np.max(np.abs(from_r / kappa - 1.0)) < 1e-9  # measured 5.3e-11 (A3 = 1 - 1e-6 holds 10 digits of u)


def test_inverse_of_high_precision_values():
    for kappa in [1e-3, 0.2, 3.0, 999.0, 1001.0, 1e5]:
        exact = _mp_a3(kappa)
        assert vmf.kappa_from_complement(float(1 - exact)) == pytest.approx(kappa, rel=1e-12)
        assert vmf.kappa_from_a3(float(exact)) == pytest.approx(kappa, rel=1e-9)


def test_limits():
    assert vmf.a3(0.0) == 0.0 and vmf.mean_cosine_complement(0.0) == 1.0
    assert vmf.a3(np.inf) == 1.0 and vmf.mean_cosine_complement(np.inf) == 0.0
    assert vmf.kappa_from_complement(1.0) == 0.0 and vmf.kappa_from_complement(0.0) == np.inf
    assert vmf.kappa_from_a3(0.0) == 0.0 and vmf.kappa_from_a3(1.0) == np.inf
    assert vmf.kappa_from_a3(1e-300) == pytest.approx(3e-300, rel=1e-15)
    assert vmf.kappa_from_complement(1e-4) == 1e4


# ---------------------------------------------------------------------------------------- convolution

def _convolved_complement(kappa1, kappa2, n_phi=16):
    """1 - E[y . z] for x ~ vMF(z, kappa1), y ~ vMF(x, kappa2), by quadrature of the two densities (x in the xz plane
    by symmetry, y in the frame of x)."""
    w1, a1 = _lobe_rule(kappa1)
    w2, a2 = _lobe_rule(kappa2)
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    x = frames.spherical(1.0 - w1, np.zeros_like(w1))
    local = frames.spherical(1.0 - w2[:, None], phi[None, :])  # (n2, n_phi, 3)
    s, t = frames.basis(x)
    y_z = frames.from_frame(local[None], s[:, None, None], t[:, None, None], x[:, None, None])[..., 2]
    weight = (2.0 * np.pi * a1 * vmf.density(1.0 - w1, kappa1))[:, None, None] \
        * (a2 * vmf.density(1.0 - w2, kappa2))[None, :, None] * (2.0 * np.pi / n_phi)
    weight = np.broadcast_to(weight, y_z.shape)
    return np.sum(weight * (1.0 - y_z)) / np.sum(weight)


@pytest.mark.parametrize("kappa1, kappa2", PAIRS)
def test_convolution_matches_quadrature(kappa1, kappa2):
    kappa = vmf.convolve(kappa1, kappa2)
    numerical = vmf.kappa_from_complement(_convolved_complement(kappa1, kappa2))
    assert kappa == pytest.approx(numerical, rel=1e-9)  # measured 1e-13: moment matching is exact in the mean cosine
    assert vmf.convolve(kappa2, kappa1) == kappa


@pytest.mark.parametrize("kappa1, kappa2", PAIRS)
def test_convolution_matches_monte_carlo(kappa1, kappa2):
    n = 400_000
    u = np.random.default_rng(int(kappa1 * 7 + kappa2)).random((4, n))
    x = vmf.sample(kappa1, u[0], u[1])
    y = vmf.sample_around(x, kappa2, u[2], u[3])
    d = y - np.array([0.0, 0.0, 1.0])
    w = 0.5 * frames.dot(d, d)  # 1 - y_z without cancellation for sharp lobes
    u = vmf.mean_cosine_complement(vmf.convolve(kappa1, kappa2))
    assert abs(w.mean() - u) < 5.0 * w.std() / np.sqrt(n)


# ------------------------------------------------------------------------------------------- sampling

@pytest.mark.parametrize("kappa", [0.0, 0.01, 1.0, 30.0])
def test_sampled_directions_follow_the_density(kappa):
    n = 200_000
    u = np.random.default_rng(11 + int(100 * kappa)).random((2, n))
    dirs = vmf.sample(kappa, u[0], u[1])
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    n_theta = 24 if kappa <= 1.0 else 480  # cells of 1/16 lobe width in cos theta for kappa = 30
    result = chi2_test(dirs, lambda d: vmf.density(d[:, 2], kappa), n_theta=n_theta, n_phi=24)
    assert result.p_value > 0.01, result
    assert result.integral == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("kappa", [30.0, 1e3, 1e5, 1e6])
def test_sharp_lobes_follow_the_density_in_w_and_phi(kappa):
    """Binned chi-square on (w = 1 - cos theta, phi); expected counts are quadratures of ``density`` over each
    w-bin (bins of equal exponential probability in kappa w, plus the tail to w = 2)."""
    n, n_w, n_phi = 200_000, 40, 16
    u = np.random.default_rng(int(kappa)).random((2, n))
    dirs = vmf.sample(kappa, u[0], u[1])
    w = 0.5 * (dirs[:, 0] ** 2 + dirs[:, 1] ** 2 + (1.0 - dirs[:, 2]) ** 2)  # 1 - cos, without cancellation
    edges = np.append(-np.log1p(-np.arange(n_w) / n_w) / kappa, 2.0)
    panels = np.union1d(edges, _lobe_edges(kappa))
    nodes, weights = _rule(panels)
    probability = np.bincount(np.repeat(np.searchsorted(edges, panels[:-1], side="right") - 1, 16),
                              weights * 2.0 * np.pi * vmf.density(1.0 - nodes, kappa), minlength=n_w)
    phi = np.arctan2(dirs[:, 1], dirs[:, 0]) % (2.0 * np.pi)
    cell = np.clip(np.searchsorted(edges, w, side="right") - 1, 0, n_w - 1) * n_phi \
        + np.minimum((phi / (2.0 * np.pi) * n_phi).astype(int), n_phi - 1)
    observed = np.bincount(cell, minlength=n_w * n_phi)
    expected = np.repeat(probability, n_phi) * (n / n_phi)
    assert probability.sum() == pytest.approx(1.0, abs=1e-15 * max(1e3, kappa))
    statistic = np.sum((observed - expected) ** 2 / expected)
    assert chi2_sf(statistic, n_w * n_phi - 1) > 0.01, statistic


@pytest.mark.parametrize("kappa", [1.0, 30.0, 1e4, 1e6])
def test_sample_around_has_mean_direction_mu(kappa):
    n = 100_000
    mus = np.concatenate([sphere_directions(3, seed=5), [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])
    u = np.random.default_rng(3).random((2, n))
    local = vmf.sample(kappa, u[0], u[1])
    for mu in mus:
        dirs = vmf.sample_around(mu, kappa, u[0], u[1])
        assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
        assert np.allclose(dirs @ mu, local[:, 2], atol=1e-12)
        spread = np.sqrt(2.0 * vmf.mean_cosine_complement(kappa) / n)  # bound on the std of each mean component
        assert np.linalg.norm(dirs.mean(axis=0) - vmf.a3(kappa) * mu) < 6.0 * spread


def test_sample_is_precise_at_the_peak():
    d = vmf.sample(1e6, np.array([1e-12, 1e-3]), np.array([0.0, 0.25]))
    w = -np.log1p(-np.array([1e-12, 1e-3])) / 1e6  # -ln(1 - u1) / kappa: e^{-2 kappa} underflows
    assert 0.5 * (d[:, 0] ** 2 + d[:, 1] ** 2) == pytest.approx(w, rel=1e-9, abs=0.0)  # sin^2 / 2 = w (1 - w / 2)


# -------------------------------------------------------------------------------------------- Beckmann

def _beckmann(cos, alpha):
    tan2 = (1.0 - cos * cos) / (cos * cos)
    return np.exp(-tan2 / (alpha * alpha)) / (np.pi * alpha * alpha * cos ** 4)


def _beckmann_half_maximum_angle(alpha):
    lo, hi = 0.0, 0.5 * np.pi
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _beckmann(np.cos(mid), alpha) > 0.5 * _beckmann(1.0, alpha) else (lo, mid)
    return lo


@pytest.mark.parametrize("kappa", [200.0, 1e3, 1e4, 1e6])
def test_beckmann_stand_in_matches_the_lobe_core(kappa):
    alpha = vmf.beckmann_alpha(kappa)
    peak = _beckmann(1.0, alpha) / vmf.density(1.0, kappa)
    width = _beckmann_half_maximum_angle(alpha) / np.arccos(1.0 - np.log(2.0) / kappa)
    cos = 1.0 - np.linspace(0.0, np.log(10.0) / kappa, 2001)  # where the vMF is above 10 % of its peak
    core = _beckmann(cos, alpha) / vmf.density(cos, kappa)
    assert peak == pytest.approx(1.0, abs=1e-12)
    assert 0.0 < width - 1.0 < 1.6 / kappa  # measured 1.49 / kappa: 1.0075 at kappa = 200
    assert core.min() > 1.0 - 1e-12 and core.max() < 1.0 + 2.7 / kappa  # measured 1 + 8 / (3 kappa)
