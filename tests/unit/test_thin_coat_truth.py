"""Monte Carlo ground truth of the thin coat (reference.thin_coat_truth) against brute force and closed forms.

The exact Smith masking of the vMF NDF (Eq. 7) against mpmath and a brute-force Monte Carlo of int <v, m> M dm;
the rejection sampler of visible normals against D_v (chi-square); whole paths in the limits that have closed
forms (mirror interfaces over an opaque dielectric, a conductor, a Lambertian base); next-event estimation against
sampled exits (the two estimators share no exit code); order 0's reciprocity; energy bounds at extreme settings.
"""
import math

import mpmath
import numpy as np
import pytest

from addon.models.thin_coat import params_from_dict
from addon.reference import vmf, warping
from addon.reference.frames import dot
from addon.reference.microfacet import fresnel_conductor, fresnel_dielectric
from addon.reference.thin_coat_truth import (ground_truth, ground_truth_albedo, projected_area_exact,
                                             sample_visible_normals, smith_g1, surface_reflection)
from stats import chi2_test

mpmath.mp.dps = 30


def _params(**kw):
    data = {"kappa_top": 1e6, "kappa_bottom": 1e6, "eta": 1.5, "sigma_a": [0.0, 0.0, 0.0], "depth": 0.5,
            "base": {"type": "dielectric_rough"}, "bounces": 3}
    data.update(kw)
    return params_from_dict(data)


def _direction(cos_theta, phi=0.0):
    s = math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta))
    return np.array([s * math.cos(phi), s * math.sin(phi), cos_theta])


def _hemisphere(n_mu=48, n_phi=48, sign=1.0):
    """Gauss-Legendre in mu = |cos theta| (0, 1) times the midpoint rule in phi: directions and solid angles."""
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu, w_mu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    m, p = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - m * m)
    dirs = np.stack([s * np.cos(p), s * np.sin(p), sign * m], axis=-1).reshape(-1, 3)
    return dirs, np.repeat(w_mu, n_phi) * (2.0 * np.pi / n_phi)


def _cosine_integral(f, mu_split=None, n=64):
    """2 int_0^1 f(mu) mu dmu by Gauss-Legendre, split at a kink (the critical angle)."""
    edges = [0.0, 1.0] if mu_split is None else [0.0, mu_split, 1.0]
    x, w = np.polynomial.legendre.leggauss(n)
    total = 0.0
    for a, b in zip(edges[:-1], edges[1:]):
        mu = a + 0.5 * (b - a) * (x + 1.0)
        total = total + np.sum((0.5 * (b - a) * w * 2.0 * mu)[:, None] * f(mu), axis=0)
    return total


# ------------------------------------------------------------------------------------------ Smith terms (Eq. 7)

def _mp_projected_area(c, kappa):
    """mpmath quadrature over w = 1 - cos theta_m of M times the closed-form phi integral, split at its kinks."""
    c, k = mpmath.mpf(c), mpmath.mpf(kappa)
    s = mpmath.sqrt(1 - c * c)
    norm = k / (2 * mpmath.pi * (1 - mpmath.exp(-2 * k)))

    def ring(w):
        a, b = c * (1 - w), s * mpmath.sqrt(w * (2 - w))
        if a >= b:
            return 2 * mpmath.pi * a
        if a <= -b:
            return mpmath.mpf(0)
        r = -a / b
        return 2 * (a * mpmath.acos(r) + b * mpmath.sqrt(1 - r * r))

    w1 = c * c / (1 + s)
    pts = {mpmath.mpf(0), w1, 2 - w1, mpmath.mpf(2)}
    pts |= {mpmath.mpf(b) / k for b in (0.5, 1, 2, 4, 8, 16, 32, 64) if b / kappa < 2}
    pts |= {w1 * 8 ** j for j in range(1, 10) if w1 * 8 ** j < 2}
    return mpmath.quad(lambda w: norm * mpmath.exp(-k * w) * ring(w), sorted(pts), maxdegree=10)


def test_projected_area_matches_mpmath():
    """Measured worst relative error 7e-10 (kappa 1e-3 .. 1e6, cos 1e-4 .. 1; these six points < 5e-10)."""
    cases = [(1e-3, 0.05), (1.0, 0.01), (30.0, 1e-3), (100.0, 0.5), (1e4, 1e-4), (1e6, 0.02)]
    for kappa, c in cases:
        exact = float(_mp_projected_area(c, kappa))
        assert abs(float(projected_area_exact(c, kappa)) / exact - 1.0) < 2e-9, (kappa, c)


@pytest.mark.parametrize("kappa", [1e-3, 1.0, 10.0, 1e3, 1e6])
def test_projected_area_matches_brute_force(kappa):
    """int max(0, v . m) M(m) dm by Monte Carlo over m ~ M (vmf.sample): all within 5 sigma (measured |z| < 3)."""
    rng = np.random.default_rng(int(kappa * 7) % 1000)
    m = vmf.sample(kappa, rng.random(400_000), rng.random(400_000))
    cosines = np.array([0.05, 0.2, 0.5, 0.8, 1.0])
    exact = projected_area_exact(cosines, kappa)
    for c, value in zip(cosines, exact):
        x = np.maximum(0.0, c * m[:, 2] + math.sqrt(1.0 - c * c) * m[:, 0])
        se = x.std() / math.sqrt(len(x))
        assert abs(value - x.mean()) < 5.0 * se + 1e-12, (kappa, c, value, x.mean(), se)


def test_projected_area_limits():
    c = np.array([0.0, 1e-3, 0.05, 0.3, 0.7, 1.0])
    assert np.all(np.abs(projected_area_exact(c, 1e-3) - 0.25) < 1e-3)  # uniform normals: 1/4 at every angle
    assert np.all(np.abs(projected_area_exact(c, 0.0) - 0.25) < 2e-9)  # exactly uniform: quadrature error only
    sharp = c[2:]
    assert np.all(np.abs(projected_area_exact(sharp, 1e6) / sharp - 1.0) < 2e-6)  # a flat surface: cos
    # array kappa broadcasts like scalars
    grid = projected_area_exact(c[:, None], np.array([1e-3, 1.0, 1e3])[None, :])
    for j, kappa in enumerate((1e-3, 1.0, 1e3)):
        assert np.allclose(grid[:, j], projected_area_exact(c, kappa), rtol=1e-12, atol=0.0)


def test_smith_g1_range_and_limits():
    c = np.linspace(0.0, 1.0, 201)
    for kappa in (1e-3, 0.1, 1.0, 10.0, 100.0, 1e4, 1e6):
        g = smith_g1(c, kappa)
        assert np.all((g >= 0.0) & (g <= 1.0)), kappa
        assert g[0] == 0.0
        assert np.all(np.diff(g) >= -1e-12), kappa  # less masking towards the normal
    for kappa in (100.0, 1e3, 1e6):
        assert smith_g1(1.0, kappa) > 1.0 - 1e-12
    assert smith_g1(0.5, 1e-3) < 1e-3  # almost all normals point sideways or down: A3 -> 0


@pytest.mark.parametrize("kappa,cos_v,n_theta", [(1.0, 0.6, 24), (5.0, 0.15, 48), (40.0, 0.05, 600)])
def test_visible_normals_chi_square(kappa, cos_v, n_theta):
    v = _direction(cos_v, 0.4)
    rng = np.random.default_rng(11)
    m = sample_visible_normals(np.tile(v, (200_000, 1)), kappa, rng)
    area = float(projected_area_exact(cos_v, kappa))

    def pdf(x):
        return np.maximum(0.0, x @ v) * vmf.density(x[:, 2], kappa) / area

    result = chi2_test(m, pdf, n_theta=n_theta, n_phi=48, res=6)
    assert abs(result.integral - 1.0) < 1e-3, result  # D_v normalised by the exact projected area
    assert result.p_value > 1e-3, result
    assert np.all(dot(m, v) > 0.0)


# ------------------------------------------------------------------------------------------ closed-form limits

@pytest.mark.parametrize("cos_o", [0.9, 0.5])
@pytest.mark.parametrize("sigma_a", [(0.0, 0.0, 0.0), (0.2, 0.6, 1.5)])
def test_mirror_interfaces_dielectric_base(cos_o, sigma_a):
    """kappa 1e6 on both interfaces: order k = (1 - F(c_o))^2 F_b(c_t)^k F_int(c_t)^(k - 1) A^(2k).

    The residual roughness (facet angles ~ 1e-3 rad) shifts each Fresnel factor by ~ F'' / kappa, most for the
    internal top reflection (convex towards TIR): measured relative biases (200000 paths, stderr < 1.2e-4) at
    cos_o 0.9 / 0.5: order 1 0 / -3e-5, order 2 +1.6e-5 / +2.9e-4, order 3 +5.6e-5 / +1.6e-3 (conductor alike),
    scaling as 1 / kappa (order 3 at cos 0.5: 0.16 at kappa 1e4, 1.3e-2 at 1e5). Tolerance per order below."""
    p = _params(sigma_a=list(sigma_a), bounces=3, base={"type": "dielectric_rough", "ior": 2.25})
    out = ground_truth_albedo(p, _direction(cos_o), n_paths=20_000, seed=2)
    c_t = math.sqrt(1.0 - (1.0 - cos_o ** 2) / p.eta ** 2)
    f_o = fresnel_dielectric(np.array([cos_o]), p.eta)[0]
    f_b = fresnel_dielectric(np.array([c_t]), p.base.ior / p.eta)[0]
    a = np.exp(-np.asarray(sigma_a) * p.depth / c_t)
    _assert_close(out["reflection"][0], out["stderr"]["reflection"][0], f_o)
    for k in range(1, 4):
        expected = (1.0 - f_o) ** 2 * f_b ** k * f_o ** (k - 1) * a ** (2 * k)
        _assert_close(out["reflection"][k], out["stderr"]["reflection"][k], expected, MIRROR_RTOL[k])
    assert np.all(out["transmission"] == 0.0)


MIRROR_RTOL = (3e-4, 3e-4, 1e-3, 4e-3)  # per order: the kappa = 1e6 roughness bias (docstring above) with margin


def _assert_close(got, stderr, expected, rtol=3e-4):
    assert np.all(np.abs(got - expected) <= 5.0 * stderr + rtol * expected), (got, stderr, expected)


def test_mirror_interfaces_conductor_base():
    cos_o = 0.7
    p = _params(eta=1.4, sigma_a=[0.1, 0.0, 0.3], bounces=3,
                base={"type": "conductor", "eta": [0.2, 0.9, 1.4], "k": [3.9, 2.4, 1.6]})
    out = ground_truth_albedo(p, _direction(cos_o), n_paths=20_000, seed=3)
    c_t = math.sqrt(1.0 - (1.0 - cos_o ** 2) / p.eta ** 2)
    f_o = fresnel_dielectric(np.array([cos_o]), p.eta)[0]
    f_b = fresnel_conductor(np.array([c_t]), np.array(p.base.eta) / p.eta, np.array(p.base.k) / p.eta)[0]
    a = np.exp(-np.asarray(p.sigma_a) * p.depth / c_t)
    for k in range(1, 4):
        expected = (1.0 - f_o) ** 2 * f_b ** k * f_o ** (k - 1) * a ** (2 * k)
        _assert_close(out["reflection"][k], out["stderr"]["reflection"][k], expected, MIRROR_RTOL[k])


def test_mirror_slab_transmission():
    """A free-standing mirror slab: T_j = (1 - F)^2 F^(2j) A^(2j + 1) (F_int = F at the matching angles)."""
    cos_o = 0.8
    p = _params(sigma_a=[0.0, 0.3, 1.0], bounces=2, base={"type": "slab"})
    out = ground_truth_albedo(p, _direction(cos_o), n_paths=20_000, seed=4)
    c_t = math.sqrt(1.0 - (1.0 - cos_o ** 2) / p.eta ** 2)
    f = fresnel_dielectric(np.array([cos_o]), p.eta)[0]
    a = np.exp(-np.asarray(p.sigma_a) * p.depth / c_t)
    for j in range(3):
        _assert_close(out["transmission"][j], out["stderr"]["transmission"][j],
                      (1 - f) ** 2 * f ** (2 * j) * a ** (2 * j + 1), MIRROR_RTOL[j + 1])
        d, w = out["exits"]["transmission"][j]
        assert np.allclose(d.mean(axis=0), -_direction(cos_o), atol=1e-3)  # straight through


def test_diffuse_base_under_mirror_top():
    """Mirror top over a Lambertian base (albedo a): order k = (1 - F(c_o)) e^{-tau / c_t} a^k R^(k-1) T with
    T = 2 int (1 - F_int(mu)) e^{-tau / mu} mu dmu, R = 2 int F_int(mu) e^{-2 tau / mu} mu dmu (mu: internal
    cosine, F_int = 1 beyond the critical angle). Measured |z| < 2.5."""
    cos_o, eta, albedo = 0.6, 1.5, np.array([0.9, 0.6, 0.3])
    p = _params(eta=eta, sigma_a=[0.0, 0.2, 0.8], bounces=3, base={"type": "diffuse", "albedo": list(albedo)})
    out = ground_truth_albedo(p, _direction(cos_o), n_paths=40_000, seed=5, n_batches=16)
    tau = np.asarray(p.sigma_a) * p.depth
    c_t = math.sqrt(1.0 - (1.0 - cos_o ** 2) / eta ** 2)
    mu_c = math.sqrt(1.0 - 1.0 / eta ** 2)
    f_int = lambda mu: fresnel_dielectric(mu, 1.0 / eta)[:, None]  # noqa: E731
    t = _cosine_integral(lambda mu: (1.0 - f_int(mu)) * np.exp(-tau / mu[:, None]), mu_c)
    r = _cosine_integral(lambda mu: f_int(mu) * np.exp(-2.0 * tau / mu[:, None]), mu_c)
    f_o = fresnel_dielectric(np.array([cos_o]), eta)[0]
    for k in range(1, 4):
        expected = (1.0 - f_o) * np.exp(-tau / c_t) * albedo ** k * r ** (k - 1) * t
        got, se = out["reflection"][k], out["stderr"]["reflection"][k]
        assert np.all(np.abs(got - expected) < 5.0 * se + 1e-4 * expected), (k, got, expected, se)


# ------------------------------------------------------------------------------------------ NEE vs sampled exits

def _nee_vs_sampled(p, wo, n_nee, n_alb, transmission, repeats=8):
    """int f_k |wi_z| dwi (hemisphere rules) from ``repeats`` independent NEE runs (their spread gives the stderr of
    the integral) against the sampled-exit energies; returns the worst |difference| / combined stderr."""
    dirs, weights = _hemisphere(48, 48)
    if transmission:
        below, w_below = _hemisphere(48, 48, -1.0)
        dirs, weights = np.concatenate([dirs, below]), np.concatenate([weights, w_below])
    proj = (np.abs(dirs[:, 2]) * weights)[None, :, None]
    up = dirs[:, 2] > 0.0
    runs = []
    for r in range(repeats):
        f, _ = ground_truth(p, dirs, wo, n_paths=n_nee // repeats, seed=100 + r, n_batches=2)
        runs.append([np.sum((f * proj)[:, up], axis=1), np.sum((f * proj)[:, ~up], axis=1)])
    runs = np.array(runs)  # (repeats, 2, orders, 3)
    integral, integral_se = runs.mean(axis=0), runs.std(axis=0, ddof=1) / math.sqrt(repeats)
    albedo = ground_truth_albedo(p, wo, n_paths=n_alb, seed=22, n_batches=16)
    worst = 0.0
    for i, name in enumerate(("reflection", "transmission")):
        if name == "transmission" and not transmission:
            continue
        ref, ref_se = albedo[name], albedo["stderr"][name]
        for k in range(p.bounces + 1):
            se = np.sqrt(integral_se[i, k] ** 2 + ref_se[k] ** 2) + 1e-3 * ref[k]  # + quadrature allowance
            z = np.abs(integral[i, k] - ref[k]) / se
            assert np.all(z < 4.0), (name, k, integral[i, k], ref[k], integral_se[i, k], ref_se[k])
            worst = max(worst, float(z.max()))
    return worst


def test_nee_matches_sampled_exits_rough_dielectric_base():
    """kappa 30 / 100: int f_k |wi_z| dwi over a 48 x 48 hemisphere rule = the sampled order-k energy
    (measured relative differences: order 0 1e-3, order 1 2e-3, order 2 2e-2 at these path counts)."""
    p = _params(kappa_top=30.0, kappa_bottom=100.0, sigma_a=[0.0, 0.5, 1.0], bounces=2)
    _nee_vs_sampled(p, _direction(math.cos(0.6)), 6000, 60_000, transmission=False)


def test_nee_matches_sampled_exits_slab():
    """A rougher slab (kappa 4 / 3: G1 down to ~0.3 at the exits), reflection and transmission orders."""
    p = _params(kappa_top=4.0, kappa_bottom=3.0, sigma_a=[0.0, 0.3, 1.0], bounces=1, base={"type": "slab"})
    _nee_vs_sampled(p, _direction(math.cos(0.5)), 6000, 60_000, transmission=True)


def test_nee_deterministic_and_shapes():
    p = _params(kappa_top=200.0, kappa_bottom=50.0, bounces=2, base={"type": "slab"})
    wi = np.array([_direction(0.7, 3.0), _direction(0.9, 2.0), -_direction(0.8, 0.1)])
    a = ground_truth(p, wi, _direction(0.8), n_paths=800, seed=9)
    b = ground_truth(p, wi, _direction(0.8), n_paths=800, seed=9)
    assert a[0].shape == (3, 3, 3) and a[1].shape == (3, 3, 3)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert np.all(a[1][0, :2] == 0.0)  # order 0 above is exact
    assert np.all(np.isfinite(a[0])) and np.all(a[0] >= 0.0)


# ------------------------------------------------------------------------------------------ order 0

def test_surface_reflection_reciprocity_and_albedo():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(500, 3))
    b = rng.normal(size=(500, 3))
    a[:, 2], b[:, 2] = np.abs(a[:, 2]), np.abs(b[:, 2])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    dirs, weights = _hemisphere(96, 96)
    for kappa in (1e-3, 1.0, 30.0, 300.0):
        for eta in (1.0001, 1.5, 3.0):
            fab, fba = surface_reflection(a, b, kappa, eta), surface_reflection(b, a, kappa, eta)
            # 1e-12 at eta 1.0001: Fresnel's own rounding (F ~ 1e-9 from c - eta cos_t)
            assert np.allclose(fab, fba, rtol=1e-14 if eta > 1.01 else 1e-11, atol=0.0)
            for cos_o in (1.0, 0.5, 0.02):
                albedo = np.sum(surface_reflection(dirs, _direction(cos_o), kappa, eta) * dirs[:, 2] * weights)
                assert 0.0 <= albedo <= 1.0, (kappa, eta, cos_o, albedo)


def test_surface_reflection_matches_sampled_order0():
    """The closed form (exact G1) integrated over the hemisphere against the sampled top reflection."""
    dirs, weights = _hemisphere(96, 96)
    for kappa, cos_o in ((3.0, 0.4), (30.0, 0.8)):
        p = _params(kappa_top=kappa, bounces=0)
        wo = _direction(cos_o)
        quad = np.sum(surface_reflection(dirs, wo, kappa, p.eta) * dirs[:, 2] * weights)
        out = ground_truth_albedo(p, wo, n_paths=40_000, seed=6, n_batches=16)
        assert abs(out["reflection"][0][0] - quad) < 5.0 * out["stderr"]["reflection"][0][0], (kappa, quad, out)


# ------------------------------------------------------------------------------------------ energy

EXTREMES = [  # (settings, cos wo, lower bound on the total); measured totals in the test's docstring
    (dict(kappa_top=1e-3, kappa_bottom=1e-3, eta=1.5, base={"type": "diffuse", "albedo": [1.0, 1.0, 1.0]}), 0.5, 0.0),
    (dict(kappa_top=1e6, kappa_bottom=1e6, eta=3.0, base={"type": "slab"}), 0.02, 0.9),
    (dict(kappa_top=1e-3, kappa_bottom=1e6, eta=1.0001, base={"type": "slab"}), 0.02, 0.0),
    (dict(kappa_top=1e6, kappa_bottom=1e-3, eta=1.0001, base={"type": "diffuse", "albedo": [1.0, 1.0, 1.0]}), 1.0,
     0.999),
    (dict(kappa_top=30.0, kappa_bottom=1e-3, eta=3.0, base={"type": "dielectric_rough", "ior": 1.0001}), 0.02, 0.0),
    (dict(kappa_top=1e3, kappa_bottom=5.0, eta=1.0001,
          base={"type": "conductor", "eta": [1.0, 1.0, 1.0], "k": [20.0, 20.0, 20.0]}), 0.3, 0.5),
    (dict(kappa_top=10.0, kappa_bottom=1e6, eta=1.5, base={"type": "diffuse", "albedo": [1.0, 1.0, 1.0]}), 0.02, 0.0),
]


@pytest.mark.parametrize("case,cos_o,lower", EXTREMES)
def test_energy_bounded_at_extremes(case, cos_o, lower):
    """White, non-absorbing: every order finite and >= 0, the sum over orders (reflection + transmission) <= 1 + 3
    stderr. Measured totals (8000 paths, bounces 4), in the order of EXTREMES: 2e-5 (kappa 1e-3 interfaces are
    almost black: G1 ~ 4 c A3 ~ 7e-4, see reference.thin_coat_truth), 0.955, 0, 1.0000, 0.389, 0.813, 0.723. The mirror
    top over a white Lambertian base at eta 1.0001 must return everything (> 0.999) within 4 bounces."""
    p = _params(bounces=4, **case)
    out = ground_truth_albedo(p, _direction(cos_o), n_paths=8000, seed=8)
    orders = np.concatenate([out["reflection"], out["transmission"]])
    assert np.all(np.isfinite(orders)) and np.all(orders >= 0.0)
    total = orders.sum(axis=0)
    se = np.sqrt(np.sum(np.concatenate([out["stderr"]["reflection"], out["stderr"]["transmission"]]) ** 2, axis=0))
    assert np.all(total <= 1.0 + 3.0 * se + 1e-12), (case, total, se)
    assert np.all(total >= lower), (case, total)
    for name in ("reflection", "transmission"):
        for d, w in out["exits"][name]:
            assert np.all(np.isfinite(d)) and np.all(w >= 0.0)
            assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-9) if len(d) else True
            side = 1.0 if name == "reflection" else -1.0
            assert np.all(side * d[:, 2] >= 0.0)


def test_lobe_moments_of_mirror_exit():
    """Order 1 under mirror interfaces leaves in the specular direction with a very sharp lobe."""
    p = _params(bounces=1)
    wo = _direction(0.6, 0.3)
    out = ground_truth_albedo(p, wo, n_paths=2000, seed=1)
    mu, kappa = warping.sample_moments(*out["exits"]["reflection"][1])
    assert np.allclose(mu, wo * [-1.0, -1.0, 1.0], atol=1e-4)
    assert kappa > 1e4
