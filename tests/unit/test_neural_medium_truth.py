"""The medium's Monte Carlo ground truth (addon/reference/neural_medium_truth.py) against estimates that share
nothing with it: closed forms of single scattering in a slab (reflected and backlit), a 1-D quadrature of single
scattering along each pixel's ray through a sphere, a 3-D quadrature of second-order scattering in a slab, forward
photon tracing (slab_albedo) against the camera-side tracer per order, energy, reciprocity, the shapes' ray
intervals against point sampling, and valid extremes. Seeded, small: every test takes a few seconds at most.

Closed forms (one channel; slab of optical thickness tau, a sun of irradiance E at cosine mu0 to the normal,
viewed at cosine mu, optical depth u from the lit side, p the HG phase function of the propagation directions):

* reflected (sun above, entering through the top):
      L1 = Int_0^tau alpha p E exp(-u / mu0) exp(-u / mu) du / mu
         = alpha p E mu0 / (mu0 + mu) (1 - exp(-tau (1/mu0 + 1/mu)))
* backlit (sun below, entering through the bottom, camera above):
      L1 = Int_0^tau alpha p E exp(-u / mu0) exp(-(tau - u) / mu) du / mu
         = alpha p E mu0 (exp(-tau / mu) - exp(-tau / mu0)) / (mu - mu0)
      (-> alpha p E tau exp(-tau / mu) / mu at mu = mu0)
* single-scattered radiance inside (sun above), at depth u below the top, propagating along w' (z component mu',
  m = -mu'):
      upward:   I1 = alpha E p(w_sun . w') mu0 / (mu0 + mu') (exp(-u / mu0) - exp(-tau / mu0 - (tau - u) / mu'))
      downward: I1 = alpha E p(w_sun . w') mu0 (exp(-u / m) - exp(-u / mu0)) / (m - mu0)
  so the second order seen from straight above is L2 = Int_0^tau exp(-u) alpha Int_4pi p(w' . z) I1(u, w') dw' du.
"""
import math

import numpy as np
import pytest

from addon.models import neural_medium as nm
from addon.reference import hg
from addon.reference import neural_medium_truth as nt
from addon.reference import scenes as sc

BATCHES = 32  # the standard errors' own spread is small: z-scores close to normal
UP = [[0.0, 0.0, 1.0]]
DOWN = [[0.0, 0.0, -1.0]]


def medium(albedo, g, sigma_t=1.0, scale=1.0):
    a = np.broadcast_to(np.asarray(albedo, float), (3,))
    t = np.broadcast_to(np.asarray(sigma_t, float), (3,))
    return nm.params_from_dict({"sigma_s": list(a * t), "sigma_a": list((1.0 - a) * t), "g": g, "scale": scale})


def z_score(value, expected, sigma):
    return (value - expected) / sigma


def _d_term(u, m, mu0):
    """(exp(-u / m) - exp(-u / mu0)) / (m - mu0) without cancellation (its limit u exp(-u / mu0) / mu0^2 at m = mu0)."""
    x = u * (m - mu0) / (m * mu0)
    ratio = np.where(np.abs(x) > 1e-12, np.expm1(x) / np.where(x == 0.0, 1.0, x), 1.0)
    return np.exp(-u / mu0) * u / (m * mu0) * ratio


def slab_single_reflected(alpha, g, tau, mu0, mu, cos, E):
    return alpha * hg.eval(g, cos) * E * mu0 / (mu0 + mu) * -math.expm1(-tau * (1.0 / mu0 + 1.0 / mu))


def slab_single_backlit(alpha, g, tau, mu0, mu, cos, E):
    return alpha * hg.eval(g, cos) * E * mu0 * float(_d_term(tau, mu, mu0))


def slab_second_order(alpha, g, tau, l, E, n=32):
    """L2 straight above a slab of optical thickness tau lit by the sun l from above (module docstring):
    Gauss-Legendre in u and in mu' on each hemisphere, midpoint rule in phi' (periodic)."""
    mu0 = l[2]
    w_sun = -np.asarray(l, float)
    x, wx = np.polynomial.legendre.leggauss(n)
    u, wu = 0.5 * tau * (x + 1.0), 0.5 * tau * wx
    xm, wm = np.polynomial.legendre.leggauss(2 * n)
    m, wmm = 0.5 * (xm + 1.0), 0.5 * wm
    phi = (np.arange(4 * n) + 0.5) * 2.0 * np.pi / (4 * n)
    U, M, PHI = np.meshgrid(u, m, phi, indexing="ij")
    s = np.sqrt(1.0 - M * M)
    total = 0.0
    for sign in (1.0, -1.0):
        w = np.stack([s * np.cos(PHI), s * np.sin(PHI), sign * M], axis=-1)
        ps = hg.eval(g, w @ w_sun)
        if sign > 0:
            i1 = alpha * E * ps * mu0 / (mu0 + M) * (np.exp(-U / mu0) - np.exp(-tau / mu0 - (tau - U) / M))
        else:
            i1 = alpha * E * ps * mu0 * _d_term(U, M, mu0)
        j2 = alpha * hg.eval(g, sign * M) * i1
        total += np.einsum("i,ijk,j->", wu * np.exp(-u), j2, wmm) * (2.0 * np.pi / (4 * n))
    return total


# ------------------------------------------------------------------------------------------ shapes

@pytest.mark.parametrize("shape", [nt.Sphere(0.8, (0.1, -0.2, 0.3)), nt.Slab(-0.3, 0.4),
                                   nt.Box((-0.5, -0.2, -0.7), (0.6, 0.3, 0.2))])
def test_intervals_match_point_sampling(shape):
    rng = np.random.default_rng(3)
    o = rng.uniform(-1.5, 1.5, (400, 3))
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:5] = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1], [1, 1, 0] / np.sqrt(2)]  # axis-parallel rays
    t0, t1 = shape.interval(o, d)
    ts = np.linspace(-4.0, 4.0, 8001)
    pts = o[:, None, :] + ts[None, :, None] * d[:, None, :]
    if isinstance(shape, nt.Sphere):
        inside = np.linalg.norm(pts - np.asarray(shape.centre), axis=-1) <= shape.radius
    elif isinstance(shape, nt.Slab):
        inside = (pts[..., 2] >= shape.z0) & (pts[..., 2] <= shape.z1)
    else:
        inside = np.all((pts >= np.asarray(shape.lo)) & (pts <= np.asarray(shape.hi)), axis=-1)
    step = ts[1] - ts[0]
    lo_t, hi_t = np.maximum(t0, -4.0), np.minimum(t1, 4.0)  # the sampled range (the slab is infinite)
    assert np.count_nonzero(lo_t < hi_t) > 40
    for i in range(len(o)):
        hit = inside[i]
        if not hit.any():
            assert lo_t[i] > hi_t[i] - 2.0 * step, i
            continue
        assert lo_t[i] == pytest.approx(ts[hit][0], abs=1.01 * step), i
        assert hi_t[i] == pytest.approx(ts[hit][-1], abs=1.01 * step), i


# ------------------------------------------------------------------------------------------ (a) closed forms

@pytest.mark.parametrize("elevation", [40.0, -55.0])  # sun above (reflected) and below (backlit)
def test_slab_single_scattering_closed_form(elevation):
    alpha, g, tau, E = 0.8, 0.7, 0.6, 2.0
    p = medium(alpha, g, sigma_t=2.0, scale=1.0)
    slab = nt.Slab(-0.1, 0.2)  # 0.3 scene units * sigma_t 2 = tau 0.6
    sun = sc.Sun(sc.sun_direction(elevation, 30.0), E)
    l = np.asarray(sun.direction)
    r = nt.radiance(p, slab, UP, DOWN, [sun], 40000, seed=1, max_order=1, batches=BATCHES)
    mu0, cos = abs(l[2]), -l[2]  # the camera ray travels along -z: cos = l . d
    form = slab_single_reflected if elevation > 0 else slab_single_backlit
    expected = form(alpha, g, tau, mu0, 1.0, cos, E)
    got, se = r["order1"][0], r["noise"]["order1"][0]
    assert np.all(np.abs(z_score(got, expected, se)) < 3.0), (got, expected, se)
    assert np.all(se < 0.01 * expected)  # precise enough to see a wrong transmittance or a flipped phase
    assert np.all(r["order2"] == 0.0) and np.all(r["multiple"] == 0.0)  # max_order = 1


def test_thin_slab_single_scattering():
    """tau = 1e-4: the forced flights keep the noise small; L1 -> alpha p E tau / mu at mu = 1."""
    alpha, g, tau, E = 0.6, -0.4, 1e-4, 1.0
    p = medium(alpha, g, sigma_t=1e-4, scale=1.0)
    sun = sc.Sun(sc.sun_direction(60.0, 0.0), E)
    l = np.asarray(sun.direction)
    r = nt.radiance(p, nt.Slab(0.0, 1.0), UP, DOWN, [sun], 4000, seed=2)
    expected = slab_single_reflected(alpha, g, tau, l[2], 1.0, -l[2], E)
    assert np.all(np.abs(r["order1"][0] / expected - 1.0) < 1e-3)
    assert np.all(r["order2"][0] < 1e-3 * expected) and np.all(r["order2"][0] > 0.0)


def test_wide_box_centre_is_the_slab():
    """The box's own intervals, walls far away: its centre pixel renders the slab's closed form."""
    alpha, g, E = 0.9, 0.3, 1.0
    p = medium(alpha, g, sigma_t=1.5)
    scene = sc.sphere_scene(elevation_deg=50.0, resolution=1)
    box = nt.Box((-30.0, -30.0, -0.2), (30.0, 30.0, 0.2))
    r = nt.render(p, box, scene, 20000, seed=4, max_order=1, batches=BATCHES)
    l = np.asarray(scene.suns[0].direction)
    expected = slab_single_reflected(alpha, g, 1.5 * 0.4, l[2], 1.0, -l[2], E)
    assert np.all(np.abs(z_score(r["order1"][0, 0], expected, r["noise"]["order1"][0, 0])) < 3.0)


# ------------------------------------------------------------------------------------------ (b) sphere quadrature

def test_sphere_single_scattering_against_quadrature():
    """Each pixel's order 1 against a Gauss-Legendre integral along its ray (analytic sun transmittance through the
    sphere); an RGB medium with different extinctions per channel (each channel traced on its own)."""
    p = nm.params_from_dict({"sigma_s": [1.0, 2.0, 3.0], "sigma_a": [0.5, 0.2, 0.0], "g": 0.4, "scale": 0.5})
    scene = sc.sphere_scene(elevation_deg=35.0, azimuth_deg=120.0, irradiance=1.5, resolution=10)
    r = nt.render(p, nt.Sphere(), scene, 3200, seed=5, max_order=1, batches=64)
    ss, sa = (np.asarray(v) for v in p.per_scene_unit())
    st = ss + sa
    l = np.asarray(scene.suns[0].direction)
    hx, hy = sc.ortho_extent(scene)
    n = scene.width
    xs = (2.0 * (np.arange(n) + 0.5) / n - 1.0) * hx
    ys = (1.0 - 2.0 * (np.arange(n) + 0.5) / n) * hy
    node, weight = np.polynomial.legendre.leggauss(96)
    zs = []
    for row, y in enumerate(ys):
        for col, x in enumerate(xs):
            if x * x + y * y >= 1.0:
                assert not r["mask"][row, col] and np.all(r["total"][row, col] == 0.0)
                continue
            h = math.sqrt(1.0 - x * x - y * y)
            s = h * (node + 1.0)  # distance travelled from the entry point (0 .. 2h)
            pts = np.stack([np.full_like(s, x), np.full_like(s, y), h - s], axis=1)
            b = pts @ l
            t_sun = -b + np.sqrt(b * b - (np.sum(pts * pts, axis=1) - 1.0))
            integrand = ss[None, :] * np.exp(-st[None, :] * (s[:, None] + t_sun[:, None]))
            expected = h * (weight @ integrand) * hg.eval(p.g, -l[2]) * 1.5
            zs.append(z_score(r["order1"][row, col], expected, r["noise"]["order1"][row, col]))
    zs = np.asarray(zs)
    assert zs.size > 200  # 70-odd pixels x 3 channels
    # 240-odd z-scores (Student t with 63 degrees of freedom): none far out, and their mean square near 1 (noise
    # estimates honest, no bias shared by many pixels)
    assert np.max(np.abs(zs)) < 5.0, np.max(np.abs(zs))
    assert 0.6 < np.mean(zs ** 2) < 1.5, np.mean(zs ** 2)


# ------------------------------------------------------------------------------------------ (c) energy

def test_slab_energy_albedo_one():
    """Every photon leaves through one face with its whole weight: R + T = 1 to rounding, per order too."""
    res = nt.slab_albedo(medium(1.0, 0.5, sigma_t=2.0), 1.0, 0.6, 20000, seed=6)
    R, T = res["reflectance"]["total"], res["transmittance"]["total"]
    np.testing.assert_allclose(R + T, 1.0, atol=1e-12)
    np.testing.assert_allclose(res["balance"], 1.0, atol=1e-12)
    assert np.all(res["absorbed"] == 0.0) and np.all(res["left"] == 0.0)
    parts = sum(res["reflectance"][k] + res["transmittance"][k] for k in nt.SLAB_ORDERS)
    np.testing.assert_allclose(parts, 1.0, atol=1e-12)
    assert np.all(res["reflectance"]["direct"] == 0.0)
    # the direct beam: binomial with exp(-tau / mu0)
    t0 = math.exp(-2.0 / 0.6)
    se = math.sqrt(t0 * (1.0 - t0) / 20000)
    assert np.all(np.abs(res["transmittance"]["direct"] - t0) < 3.0 * se)
    assert np.all(res["reflectance"]["total"] > 0.3)  # tau 2: a good share comes back


def test_slab_albedo_single_scattering_against_quadrature():
    """Forward photon tracing's order 1 against the closed forms integrated over the exit hemispheres:
    R1 = Int alpha p mu / (mu0 + mu) (1 - exp(-tau (1/mu0 + 1/mu))) dw and
    T1 = Int alpha p m (exp(-tau / m) - exp(-tau / mu0)) / (m - mu0) dw (flux over the beam's E mu0)."""
    alpha, g, tau, mu0 = 0.7, 0.5, 0.8, 0.6
    res = nt.slab_albedo(medium(alpha, g, sigma_t=2.0), tau / 2.0, mu0, 100000, seed=22, batches=BATCHES)
    s0 = math.sqrt(1.0 - mu0 * mu0)
    x, w = np.polynomial.legendre.leggauss(64)
    mu, wmu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(128) + 0.5) * 2.0 * np.pi / 128
    MU, PHI = np.meshgrid(mu, phi, indexing="ij")
    sin = np.sqrt(1.0 - MU * MU) * np.cos(PHI) * s0
    refl = alpha * hg.eval(g, sin - mu0 * MU) * MU / (mu0 + MU) * -np.expm1(-tau * (1.0 / mu0 + 1.0 / MU))
    trans = alpha * hg.eval(g, sin + mu0 * MU) * MU * _d_term(tau, MU, mu0)
    for name, integrand in (("reflectance", refl), ("transmittance", trans)):
        expected = wmu @ integrand.sum(axis=1) * (2.0 * np.pi / 128)
        got, se = res[name]["order1"], res["noise"][name]["order1"]
        assert np.all(np.abs(z_score(got, expected, se)) < 3.0), (name, got, expected, se)
        assert np.all(se < 0.02 * expected)


def test_slab_energy_with_absorption_and_roulette():
    res = nt.slab_albedo(medium([0.95, 0.7, 0.3], -0.3, sigma_t=1.0), 1.5, 0.8, 20000, seed=7, batches=BATCHES)
    summed = res["reflectance"]["total"] + res["transmittance"]["total"] + res["absorbed"]
    np.testing.assert_allclose(res["balance"], summed, rtol=1e-12)
    se = res["noise"]["balance"]  # roulette makes the per-photon sum noisy (1 to rounding where it never plays)
    assert np.all(se[1:] > 1e-5) and np.all(np.abs(summed - 1.0) < 3.0 * se + 1e-12), (summed, se)
    assert res["absorbed"][2] > res["absorbed"][1] > res["absorbed"][0] > 0.0


def test_albedo_zero_scatters_nothing():
    p = medium(0.0, 0.5, sigma_t=1.0)
    res = nt.slab_albedo(p, 1.0, 0.7, 20000, seed=8)
    for k in ("order1", "order2", "multiple", "total"):
        assert np.all(res["reflectance"][k] == 0.0)
    for k in ("order1", "order2", "multiple"):
        assert np.all(res["transmittance"][k] == 0.0)
    t0 = math.exp(-1.0 / 0.7)
    assert np.all(np.abs(res["transmittance"]["direct"] - t0) < 3.0 * math.sqrt(t0 * (1 - t0) / 20000))
    np.testing.assert_allclose(res["absorbed"] + res["transmittance"]["direct"], 1.0, atol=1e-12)
    image = nt.render(p, nt.Sphere(), sc.sphere_scene(resolution=8), 16, seed=8)
    assert image["mask"].any()
    for k in ("order1", "order2", "multiple", "total"):
        assert np.all(image[k] == 0.0)


# ------------------------------------------------------------------------------------------ (d) reciprocity

def test_slab_reflection_reciprocity():
    """f(wi, wo) = L / (E cos_i) is symmetric: swapping the sun and the view gives L(wo; wi) / mu_i = L(wi; wo) / mu_o,
    order by order (the higher orders included) and in total; g != 0 and different cosines."""
    p = medium(0.95, 0.6, sigma_t=1.0)
    slab = nt.Slab(0.0, 1.0)
    wi = np.asarray(sc.sun_direction(math.degrees(math.asin(0.9)), 0.0))
    wo = np.asarray(sc.sun_direction(math.degrees(math.asin(0.45)), 140.0))
    origin = [[0.0, 0.0, 2.0]]
    a = nt.radiance(p, slab, origin, [-wo], [sc.Sun(tuple(wi), 1.0)], 60000, seed=9, batches=BATCHES)
    b = nt.radiance(p, slab, origin, [-wi], [sc.Sun(tuple(wo), 1.0)], 60000, seed=10, batches=BATCHES)
    for k in nt.GROUPS + ("total",):
        fa, fb = a[k][0, 0] / wi[2], b[k][0, 0] / wo[2]
        se = math.hypot(a["noise"][k][0, 0] / wi[2], b["noise"][k][0, 0] / wo[2])
        assert abs(fa - fb) < 3.0 * se, (k, fa, fb, se)
        assert se < 0.03 * fa, k  # precise enough: L itself differs by a factor mu_i / mu_o = 2
    assert a["multiple"][0, 0] > 0.3 * a["order1"][0, 0]


# ------------------------------------------------------------------------------------------ (e) orders

def test_second_order_against_quadrature_and_max_order():
    alpha, g, E = 0.9, -0.6, 2.0
    p = medium(alpha, g, sigma_t=1.0, scale=0.5)  # 1 scene unit = 2 mean free paths
    slab = nt.Slab(0.0, 1.0)
    sun = sc.Sun(sc.sun_direction(50.0, 30.0), E)
    l = np.asarray(sun.direction)
    expected = slab_second_order(alpha, g, 2.0, l, E)
    full = nt.radiance(p, slab, UP, DOWN, [sun], 200000, seed=11, batches=BATCHES)
    assert np.all(np.abs(z_score(full["order2"][0], expected, full["noise"]["order2"][0])) < 3.0)
    assert np.all(full["noise"]["order2"][0] < 0.01 * expected)
    expected1 = slab_single_reflected(alpha, g, 2.0, l[2], 1.0, -l[2], E)
    assert np.all(np.abs(z_score(full["order1"][0], expected1, full["noise"]["order1"][0])) < 3.0)
    two = nt.radiance(p, slab, UP, DOWN, [sun], 50000, seed=12, max_order=2, batches=BATCHES)
    assert np.all(two["multiple"] == 0.0)
    assert np.all(np.abs(z_score(two["order2"][0], expected, two["noise"]["order2"][0])) < 3.0)
    one = nt.radiance(p, slab, UP, DOWN, [sun], 20000, seed=13, max_order=1, batches=BATCHES)
    assert np.all(one["order2"] == 0.0) and np.all(one["multiple"] == 0.0)
    np.testing.assert_array_equal(one["total"], one["order1"])
    assert np.all(np.abs(z_score(one["order1"][0], expected1, one["noise"]["order1"][0])) < 3.0)


def test_camera_tracer_agrees_with_photon_tracer_per_order():
    """Hemispherical reflectance per order from the camera side (next-event estimation, forced flights; views drawn
    cosine-weighted: R = pi mean(L) / (E mu0)) against forward photon tracing with analog exits (slab_albedo)."""
    p = medium([0.99, 0.8, 0.5], 0.5, sigma_t=1.0)
    thickness, mu0 = 1.2, 0.7
    slab = nt.Slab(0.0, thickness)
    rng = np.random.default_rng(14)
    n = 6000
    u1, u2 = rng.random(n), rng.random(n)
    mu, phi = np.sqrt(u1), 2.0 * np.pi * u2  # cosine-weighted view directions
    s = np.sqrt(1.0 - mu * mu)
    views = np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=1)
    sun = sc.Sun((math.sqrt(1.0 - mu0 * mu0), 0.0, mu0), 1.0)
    cam = nt.radiance(p, slab, np.tile([0.0, 0.0, thickness + 1.0], (n, 1)), -views, [sun], 8, seed=15)
    photons = nt.slab_albedo(p, thickness, mu0, 100000, seed=16, batches=BATCHES)
    for k in nt.GROUPS + ("total",):
        values = math.pi * cam[k] / mu0  # (n, 3): each view an independent estimate
        R_cam, se_cam = values.mean(axis=0), values.std(axis=0, ddof=1) / math.sqrt(n)
        R_ph, se_ph = photons["reflectance"][k], photons["noise"]["reflectance"][k]
        z = (R_cam - R_ph) / np.hypot(se_cam, se_ph)
        assert np.all(np.abs(z) < 3.0), (k, R_cam, R_ph, se_cam, se_ph)
    assert np.all(photons["reflectance"]["multiple"][0] > photons["reflectance"]["order2"][0])


def test_forced_and_analog_flights_agree():
    p = nm.params_from_dict({"sigma_s": [2.0, 1.0, 0.5], "sigma_a": [0.05, 0.3, 0.5], "g": 0.7, "scale": 1.0})
    scene = sc.sphere_scene(resolution=3)
    forced = nt.render(p, nt.Sphere(), scene, 20000, seed=17, batches=BATCHES)
    analog = nt.render(p, nt.Sphere(), scene, 20000, seed=18, forced=False, batches=BATCHES)
    m = forced["mask"]
    assert m.all()  # a 3 x 3 image: every pixel centre is inside the unit sphere
    for k in nt.GROUPS:
        se = np.hypot(forced["noise"][k][m], analog["noise"][k][m])
        z = (forced[k][m] - analog[k][m]) / se  # 9 pixels x 3 channels
        assert np.max(np.abs(z)) < 4.5 and 0.4 < np.mean(z * z) < 1.8, (k, z)


# ------------------------------------------------------------------------------------------ (f) extremes

@pytest.mark.parametrize("albedo, g, tau, max_order", [
    (0.0, 0.0, 1.0, None), (1.0, 0.99, 1.0, None), (1.0, -0.99, 1.0, None), (0.7, 0.99, 1e-4, None),
    (1.0, -0.99, 1e-4, None), (0.9, 0.0, 1e3, None), (1.0, 0.99, 1e3, 40), (1.0, -0.99, 1e3, 40),
])
def test_extremes_finite_and_non_negative(albedo, g, tau, max_order):
    p = medium(albedo, g, sigma_t=tau)
    sun = sc.Sun(sc.sun_direction(45.0, 0.0), 1.0)
    r = nt.radiance(p, nt.Slab(0.0, 1.0), UP, DOWN, [sun], 400, seed=19, max_order=max_order)
    for k in nt.GROUPS + ("total",):
        assert np.all(np.isfinite(r[k])) and np.all(r[k] >= 0.0), k
        assert np.all(np.isfinite(r["noise"][k])), k
    if albedo > 0.0:
        assert np.all(r["order1"] > 0.0)
    image = nt.render(p, nt.Sphere(), sc.sphere_scene(resolution=4), 8, seed=20, max_order=max_order)
    assert np.all(np.isfinite(image["total"])) and np.all(image["total"] >= 0.0)
    if tau <= 1e3 and max_order is None:
        res = nt.slab_albedo(p, 1.0, 0.5, 400, seed=21)
        total = res["reflectance"]["total"] + res["transmittance"]["total"] + res["absorbed"]
        assert np.all(np.isfinite(total)) and np.all(total >= 0.0)


def test_refusals(monkeypatch):
    p = medium(0.5, 0.0)
    with pytest.raises(ValueError):
        nt.render(p, nt.Sphere(), sc.plane_scene(resolution=4), 4)
    with pytest.raises(ValueError):
        nt.render(p, nt.Sphere(), sc.sphere_scene(resolution=4, environment=1.0), 4)
    with pytest.raises(ValueError):
        nt.radiance(p, nt.Sphere(), UP, DOWN, [], 4, max_order=0)
    for bad in (lambda: nt.Sphere(0.0), lambda: nt.Slab(1.0, 1.0), lambda: nt.Box((0, 0, 0), (1, 0, 1))):
        with pytest.raises(ValueError):
            bad()
    monkeypatch.setattr(nt, "MAX_VERTICES", 50)
    with pytest.raises(RuntimeError):  # albedo 1, optically huge: the walk guard, not a hang
        nt.radiance(medium(1.0, 0.0, sigma_t=1e3), nt.Slab(0.0, 1.0), UP, DOWN, [sc.Sun((0.0, 0.0, 1.0))], 20)
