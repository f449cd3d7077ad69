"""The anisotropic stack's reference (Belcour's adding loop with 2×2 covariances): identities, sampling, tables,
energy and extremes."""
import zlib

import numpy as np
import pytest

from addon.reference import aniso_stack as ref
from addon.reference import aniso_stack_tables as tables
from addon.reference import microfacet
from addon.reference.frames import spherical
from stats import chi2_test, sphere_directions

GOLD = {"type": "conductor", "ior": [0.143, 0.374, 1.442], "k": [3.983, 2.385, 1.603]}
MIRROR = {"type": "conductor", "ior": 0.01, "k": 20.0}  # F > 0.9999 at every angle
COSINES = np.array([1.0, 0.8, 0.5, 0.2, 0.05, 1e-3, 0.0])
N = 200_000


def _stack(interfaces, media=None):
    return ref.params_from_dict({"interfaces": interfaces, **({"media": media} if media else {})})


def _views(cosines, phi=0.4):
    return spherical(np.asarray(cosines, dtype=float), np.full(len(cosines), phi))


def _lobes(p, cosines=COSINES):
    return ref.lobes(ref.F64, p, np.asarray(cosines, dtype=float), len(cosines))


def _per_view(x, n):
    """A lobe field as one value (or colour) per view: constants are broadcast."""
    x = np.asarray(x, dtype=float)
    return np.broadcast_to(x, (n,) + x.shape[1:])


ISOTROPIC = [
    [{"type": "dielectric", "ior": 1.5, "alpha": 0.1, "rotation": 30.0}, {**GOLD, "alpha": 0.3, "rotation": -70.0}],
    [{"type": "dielectric", "ior": [1.3, 1.45, 1.6], "alpha": 0.05, "rotation": 10.0},
     {"type": "dielectric", "ior": 2.2, "alpha": 0.4, "rotation": 80.0},
     {"type": "dielectric", "ior": 1.2, "alpha": 0.02, "rotation": -15.0}, {**GOLD, "alpha": 0.6}],
    [{"type": "dielectric", "ior": 2.0, "alpha": 0.2}, {"type": "dielectric", "ior": 1.4, "alpha": 0.7,
                                                         "rotation": 45.0}],
]
ISOTROPIC_MEDIA = [None, [{"sigma_a": [0.2, 0.5, 1.0], "depth": 0.5, "sigma_s": [0.5, 0.2, 0.1], "g": 0.8},
                          {"sigma_a": [0.0, 0.0, 0.0], "depth": 1.0, "sigma_s": [1.0, 1.0, 1.0], "g": 0.3},
                          {}], [{"sigma_a": [1.0, 0.1, 0.0], "depth": 2.0}]]


@pytest.mark.parametrize("case", range(len(ISOTROPIC)))
def test_isotropic_input_equals_the_scalar_loop(case):
    """αx = αy everywhere (any rotations): the covariance loop gives Belcour's scalar loop, lobe by lobe."""
    p = _stack(ISOTROPIC[case], ISOTROPIC_MEDIA[case])
    got, expected = _lobes(p), ref.isotropic_lobes(ref.F64, p, COSINES, len(COSINES))
    assert len(got) == len(expected) == len(p.interfaces)
    for a, b in zip(got, expected):
        assert (a.kind, a.interface) == (b.kind, b.interface)
        for field in ("weight", "energy"):
            assert np.allclose(getattr(a, field), getattr(b, field), rtol=1e-9, atol=1e-12), (a.interface, field)
        for field in ("alpha_u", "alpha_v"):
            assert np.allclose(_per_view(getattr(a, field), 7), _per_view(getattr(b, field), 7), rtol=1e-9, atol=0)


def _ggx_brdf_with_fresnel(wi, wo, ax, ay, degrees, fresnel):
    """The anisotropic GGX microfacet BRDF F D G2 / (4 cos cos), written out in the interface's rotated frame."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    i, o = wi @ rot.T, wo @ rot.T
    h = (i + o) / np.linalg.norm(i + o, axis=1, keepdims=True)
    d = 1.0 / (np.pi * ax * ay * ((h[:, 0] / ax) ** 2 + (h[:, 1] / ay) ** 2 + h[:, 2] ** 2) ** 2)

    def lam(w):
        return 0.5 * (np.sqrt(1.0 + ((ax * w[:, 0]) ** 2 + (ay * w[:, 1]) ** 2) / w[:, 2] ** 2) - 1.0)

    f = fresnel(np.sum(i * h, axis=1)) * (d / ((1.0 + lam(i) + lam(o)) * 4.0 * i[:, 2] * o[:, 2]))[:, None]
    return np.where(((wi[:, 2] > 0) & (wo[:, 2] > 0))[:, None], f, 0.0)


@pytest.mark.parametrize("interface, fresnel", [
    ({"type": "dielectric", "ior": [1.3, 1.5, 2.4], "alpha": [0.3, 0.04], "rotation": 35.0},
     lambda c: np.stack([microfacet.fresnel_dielectric(c, e) for e in (1.3, 1.5, 2.4)], axis=1)),
    ({**GOLD, "alpha": [0.05, 0.5], "rotation": -120.0},
     lambda c: microfacet.fresnel_conductor(c, GOLD["ior"], GOLD["k"])),
])
def test_a_single_interface_is_the_microfacet_brdf(interface, fresnel):
    p = _stack([interface])
    wi, wo = sphere_directions(3000, seed=1), sphere_directions(3000, seed=2)
    expected = _ggx_brdf_with_fresnel(wi, wo, *interface["alpha"], interface["rotation"], fresnel)
    got = ref.eval(p, wi, wo)
    assert np.any(got > 1.0)
    assert np.allclose(got, expected, rtol=1e-12, atol=0)


ANISOTROPIC = [{"type": "dielectric", "ior": 1.5, "alpha": [0.2, 0.01], "rotation": 20.0},
               {"type": "dielectric", "ior": 1.8, "alpha": [0.05, 0.3], "rotation": -50.0},
               {**GOLD, "alpha": [0.4, 0.04], "rotation": 75.0}]
ANISOTROPIC_MEDIA = [{"sigma_a": [0.3, 0.1, 0.0], "depth": 0.4, "sigma_s": [0.5, 0.5, 0.5], "g": 0.7}, {}]


def _angle_difference(a, b, shift):
    """a − b − shift modulo π (the axis of a lobe has no direction), in (−π/2, π/2]."""
    return np.angle(np.exp(2j * (np.asarray(a) - np.asarray(b) - shift))) / 2.0


@pytest.mark.parametrize("psi", [17.0, 90.0, -133.0])
def test_rotating_every_tangent_rotates_every_lobe(psi):
    p = _stack(ANISOTROPIC, ANISOTROPIC_MEDIA)
    turned = _stack([{**i, "rotation": i["rotation"] + psi} for i in ANISOTROPIC], ANISOTROPIC_MEDIA)
    for a, b in zip(_lobes(p), _lobes(turned)):
        assert np.allclose(a.weight, b.weight, rtol=1e-9, atol=0)
        assert np.allclose(_per_view(a.alpha_u, 7), _per_view(b.alpha_u, 7), rtol=1e-9)
        assert np.allclose(_per_view(a.alpha_v, 7), _per_view(b.alpha_v, 7), rtol=1e-9)
        defined = _per_view(a.alpha_u, 7) > 1.01 * _per_view(a.alpha_v, 7)  # (grazing views blur the lobes round)
        assert defined[:3].all()
        assert np.allclose(_per_view(_angle_difference(b.angle, a.angle, np.radians(psi)), 7)[defined], 0.0, atol=1e-7)
    wi, wo = sphere_directions(2000, seed=3, side=1), sphere_directions(2000, seed=4, side=1)
    c, s = np.cos(np.radians(psi)), np.sin(np.radians(psi))
    spin = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    assert np.allclose(ref.eval(turned, wi @ spin.T, wo @ spin.T), ref.eval(p, wi, wo), rtol=1e-9, atol=0)


@pytest.mark.parametrize("j", [0, 1, 2])
def test_a_quarter_turn_swaps_the_roughnesses(j):
    turned = [dict(i) for i in ANISOTROPIC]
    swapped = [dict(i) for i in ANISOTROPIC]
    turned[j]["rotation"] += 90.0
    swapped[j]["alpha"] = swapped[j]["alpha"][::-1]
    a, b = _stack(turned, ANISOTROPIC_MEDIA), _stack(swapped, ANISOTROPIC_MEDIA)
    wi, wo = sphere_directions(2000, seed=5, side=1), sphere_directions(2000, seed=6, side=1)
    assert np.allclose(ref.eval(a, wi, wo), ref.eval(b, wi, wo), rtol=1e-9, atol=0)
    for la, lb in zip(_lobes(a)[1:], _lobes(b)[1:]):
        assert np.allclose(la.weight, lb.weight, rtol=1e-9, atol=0)
        defined = _per_view(la.alpha_u, 7) > 1.01 * _per_view(la.alpha_v, 7)
        assert np.allclose(_per_view(_angle_difference(la.angle, lb.angle, 0.0), 7)[defined], 0.0, atol=1e-7)


class AveragedDenominator(ref.Float64Ops):
    """The known port bug: 1 − Ri0 R12 averaged over RGB (the loop floors it with ``maximum``; its other colour
    ``maximum``, the top's R12, is grey in the stack below)."""

    @staticmethod
    def maximum(a, b):
        a = np.asarray(a)
        return np.maximum(np.repeat(a.mean(axis=-1, keepdims=True), 3, axis=-1) if a.shape[-1:] == (3,) else a, b)


def test_the_inter_reflection_denominator_is_per_channel():
    """Grey coats over a coloured conductor (R12 ≈ 1, 0.18 and 0.06 at normal incidence: R·R differs strongly
    between channels): each channel's energies equal the scalar loop of a grey stack made of that channel alone (the lobes' roughness,
    hence their weights, is shared by the channels); the RGB-averaged denominator is off by more than 10%."""
    coats = [{"type": "dielectric", "ior": 3.0, "alpha": 0.3}, {"type": "dielectric", "ior": 1.2, "alpha": 0.6}]
    metal = {"type": "conductor", "ior": [0.02, 1.0, 2.0], "k": [20.0, 1.0, 0.0], "alpha": 0.2}
    p = _stack(coats + [metal])
    got, averaged = _lobes(p), ref.lobes(AveragedDenominator(), p, COSINES, len(COSINES))
    for channel in range(3):
        grey = _stack(coats + [{**metal, "ior": metal["ior"][channel], "k": metal["k"][channel]}])
        expected = ref.isotropic_lobes(ref.F64, grey, COSINES, len(COSINES))
        for a, b in zip(got, expected):
            assert np.allclose(a.energy[:, channel], b.energy[:, 0], rtol=1e-12, atol=0)
    assert np.max(np.abs(averaged[2].energy / got[2].energy - 1.0)) > 0.1


@pytest.mark.parametrize("name, stack, cos_o", [
    ("coat over gold", [{"type": "dielectric", "ior": 1.5, "alpha": [0.15, 0.03], "rotation": 30.0},
                        {**GOLD, "alpha": [0.3, 0.05], "rotation": -40.0}], 0.8),
    ("coat over gold", [{"type": "dielectric", "ior": 1.5, "alpha": [0.15, 0.03], "rotation": 30.0},
                        {**GOLD, "alpha": [0.3, 0.05], "rotation": -40.0}], 0.3),
    ("three rough", [{"type": "dielectric", "ior": 1.3, "alpha": 0.5}, {"type": "dielectric", "ior": 2.0,
                     "alpha": [0.6, 0.1], "rotation": 60.0}, {**GOLD, "alpha": 0.8}], 0.6),
])
def test_sampled_directions_follow_the_pdf(name, stack, cos_o):
    p = _stack(stack)
    wo = np.repeat(_views([cos_o]), N, axis=0)
    s = ref.sample(p, wo, np.random.default_rng(zlib.crc32(f"{name} {cos_o}".encode())).random((N, 3)))
    assert np.all(np.isfinite(s.weight)) and np.all(s.weight >= 0)
    result = chi2_test(s.wi, lambda wi: ref.pdf(p, wi, np.repeat(_views([cos_o]), len(wi), axis=0)), res=10)
    assert result.p_value > 0.01, result
    assert result.integral == pytest.approx(1.0, abs=2e-3)
    albedo = ref.directional_albedo(p, _views([cos_o]))[0]
    spread = s.weight.std(axis=0) / np.sqrt(N)
    assert np.all(np.abs(s.weight.mean(axis=0) - albedo) < 4.0 * spread + 1e-3), (s.weight.mean(axis=0), albedo)


def test_chi2_catches_a_wrong_lobe_angle():
    """The sampler test can fail: the pdf with the second lobe's tangent turned by 20° is rejected."""
    p = _stack(ANISOTROPIC[::2])
    wo = np.repeat(_views([0.7]), N, axis=0)
    s = ref.sample(p, wo, np.random.default_rng(9).random((N, 3)))

    def wrong(wi):
        w = np.repeat(_views([0.7]), len(wi), axis=0)
        found = ref.lobes_at(p, w)
        found[1] = found[1]._replace(angle=found[1].angle + np.radians(20.0))
        prob = ref._lobe_probabilities(found)
        return sum(prob[:, k] * ref.lobe_pdf(lobe, wi, w) for k, lobe in enumerate(found))
    assert chi2_test(s.wi, wrong, res=10).p_value < 1e-6


def test_the_committed_tables_are_the_scripts_output():
    """Nodes recomputed by the script's integrators equal the committed float32 values."""
    t = tables.load().arrays
    mus, alphas, etas = tables.cos_nodes(), tables.alpha_nodes(), tables.eta_nodes(tables.ETA_NODES)
    for j in (0, 13, 31):
        albedo, *rule = tables.lobe_rule(mus, alphas[j])
        assert np.allclose(t["albedo"][:, j], albedo, atol=1e-6)
        assert np.allclose(t["fresnel_rule"][:, j], np.stack(rule, axis=-1), atol=1e-6)
        for e in (2, 16, 29):
            assert np.allclose(t["fgd"][:, j, e], tables.dielectric_fgd(mus, alphas[j], etas[e]), atol=1e-6)
        e = 5
        assert np.allclose(t["escape"][:, j, e], tables.escape_fraction(
            tables.denser_cos(mus, etas[e]), alphas[j], etas[e]), atol=1e-6)


def test_table_lookups_are_within_the_stated_interpolation_error():
    """Random points against fresh integration: within the maxima the tables' docstring states, over the axes and
    on the mean paths of stacks."""
    rng = np.random.default_rng(11)
    t = tables.load()
    mu, alpha, _ = tables.random_points(rng, 40)
    fresh = np.array([tables.lobe_rule(np.array([m]), a)[0][0] for m, a in zip(mu, alpha)])
    assert np.max(np.abs(t.albedo(mu, alpha) - fresh)) < 0.031
    mu_rare, alpha, eta = tables.random_points(rng, 40)
    assert np.max(np.abs(tables.fgd_errors(t, tables.denser_cos(mu_rare, eta), alpha, eta))) < 0.13
    mu_rare, alpha, eta = tables.random_points(rng, 40, escape=True)
    assert np.max(np.abs(tables.escape_errors(t, tables.denser_cos(mu_rare, eta), alpha, eta))) < 0.10
    cos_above, cos_below, alpha, eta = tables.stack_points(rng, 60)
    assert np.max(np.abs(tables.fgd_errors(t, cos_above, alpha, eta))) < 0.018
    leaving = eta > 1.0
    assert np.max(np.abs(tables.escape_errors(t, cos_below[leaving], alpha[leaving], 1.0 / eta[leaving]))) < 0.012


OVER_A_MIRROR = {
    "smooth coat": [{"type": "dielectric", "ior": 1.5, "alpha": 1e-4}, {**MIRROR, "alpha": 1e-4}],
    "rough coat": [{"type": "dielectric", "ior": 1.5, "alpha": 0.1}, {**MIRROR, "alpha": 0.1}],
    "rougher": [{"type": "dielectric", "ior": 1.5, "alpha": 0.3}, {**MIRROR, "alpha": 0.3}],
    "anisotropic": [{"type": "dielectric", "ior": 1.5, "alpha": [0.2, 0.01], "rotation": 30.0},
                    {**MIRROR, "alpha": [0.3, 0.02], "rotation": -60.0}],
    "three coats": [{"type": "dielectric", "ior": 1.3, "alpha": 0.05},
                    {"type": "dielectric", "ior": 2.0, "alpha": [0.1, 0.3]},
                    {"type": "dielectric", "ior": 1.4, "alpha": 0.02, "rotation": 45.0}, {**MIRROR, "alpha": 0.05}],
    "dense over light": [{"type": "dielectric", "ior": 3.0, "alpha": 0.5}, {"type": "dielectric", "ior": 1.0001,
                         "alpha": 0.5}, {**MIRROR, "alpha": 0.5}],
}


@pytest.mark.parametrize("name", sorted(OVER_A_MIRROR))
def test_non_absorbing_stacks_over_a_mirror_return_at_most_what_they_receive(name):
    """White furnace, views down to grazing; smooth stacks return everything (the G2 energy of rough interfaces
    is lost, as by the FGD tables: printed with -s)."""
    p = _stack(OVER_A_MIRROR[name])
    albedo = ref.furnace_albedo(p, _views([1.0, 0.7, 0.4, 0.1]))
    print(name, np.round(albedo[:, 0], 4))
    assert np.all(albedo <= 1.0 + 2e-3)
    if name == "smooth coat":
        assert np.all(albedo >= 0.999)


def test_no_stack_gains_energy():
    """Random non-absorbing stacks of 1-4 interfaces (any roughness, anisotropy, IOR order) never return more
    than they receive."""
    rng = np.random.default_rng(12)
    for _ in range(12):
        count = rng.integers(1, 5)
        interfaces = [{"type": "dielectric", "ior": float(rng.uniform(1.0001, 3.0)),
                       "alpha": [float(10 ** rng.uniform(-4, 0)), float(10 ** rng.uniform(-4, 0))],
                       "rotation": float(rng.uniform(-180, 180))} for _ in range(count - 1)]
        interfaces.append({**MIRROR, "alpha": [float(10 ** rng.uniform(-4, 0))] * 2})
        albedo = ref.furnace_albedo(_stack(interfaces), _views([1.0, 0.5, 0.1]), n=1024)
        assert np.all(albedo <= 1.0 + 1.5e-2), (interfaces, albedo)


EXTREMES = [
    [{"type": "dielectric", "ior": 1.0001, "alpha": [1e-4, 1.0]}, {**GOLD, "alpha": [1.0, 1e-3]}],
    [{"type": "dielectric", "ior": 3.0, "alpha": 1e-4}, {"type": "conductor", "ior": 10.0, "k": 10.0, "alpha": 1.0}],
    [{"type": "dielectric", "ior": 3.0, "alpha": [1.0, 1e-3], "rotation": 10.0},
     {"type": "dielectric", "ior": 2.0, "alpha": [1e-4, 1e-4]},
     {"type": "dielectric", "ior": 1.2, "alpha": [0.5, 5e-4], "rotation": 90.0},
     {"type": "dielectric", "ior": 1.0001, "alpha": 1.0}],  # TIR at every interface (dense over light)
    [{"type": "conductor", "ior": 0.01, "k": 10.0, "alpha": [1e-4, 1e-4]}],
    [{"type": "dielectric", "ior": 1.0001, "alpha": 1.0}],
]
EXTREME_MEDIA = [[{"sigma_a": [100.0] * 3, "depth": 1.0}], [{"sigma_a": [0.0] * 3, "depth": 0.0}],
                 [{"sigma_a": [100.0] * 3, "depth": 1.0, "sigma_s": [5.0] * 3, "g": 0.0}, {},
                  {"sigma_s": [1.0] * 3, "depth": 100.0, "g": 0.999}], None, None]


@pytest.mark.parametrize("case", range(len(EXTREMES)))
def test_extremes_are_finite_and_non_negative(case):
    """α ∈ {1e-4, 1}, αy / αx down to 1e-3, IOR 1.0001 and 3, k 10, σa·depth 0 and 100, TIR everywhere, 4
    interfaces, views down to exactly grazing and below."""
    p = _stack(EXTREMES[case], EXTREME_MEDIA[case])
    wo = np.repeat(_views([1.0, 0.5, 1e-3, 1e-6, 0.0, -0.5]), 50, axis=0)
    wi = np.concatenate([sphere_directions(len(wo) - 6, seed=7), _views([1.0, 0.5, 1e-3, 1e-6, 0.0, -0.5], 3.5)])
    for lobe in ref.lobes_at(p, wo):
        for field in ("weight", "alpha_u", "alpha_v", "angle", "energy"):
            value = np.asarray(getattr(lobe, field))
            assert np.all(np.isfinite(value)), (lobe.interface, field)
        assert np.all(np.asarray(lobe.weight) >= 0) and np.all(np.asarray(lobe.energy) >= 0)
        for alpha in (lobe.alpha_u, lobe.alpha_v):
            assert np.all((np.asarray(alpha) >= 1e-4) & (np.asarray(alpha) <= 1.0))
    f, density = ref.eval(p, wi, wo), ref.pdf(p, wi, wo)
    assert np.all(np.isfinite(f)) and np.all(f >= 0) and np.all(np.isfinite(density)) and np.all(density >= 0)
    s = ref.sample(p, wo, np.random.default_rng(case).random((len(wo), 3)))
    assert np.all(np.isfinite(s.weight)) and np.all(s.weight >= 0)
    assert np.all(np.isfinite(s.pdf)) and np.all(s.pdf >= 0)
    assert np.allclose(np.linalg.norm(s.wi, axis=1), 1.0)
    assert np.all(ref.eval(p, wo * [1, 1, -1], wo)[wo[:, 2] > 0] == 0)  # nothing from below


def test_lobes_are_one_per_interface():
    p = _stack(ANISOTROPIC, ANISOTROPIC_MEDIA)
    found = _lobes(p)
    assert [(lobe.kind, lobe.interface) for lobe in found] == [("surface", 0), ("reflection", 1), ("reflection", 2)]
    assert np.all(found[0].weight == 1.0)
    assert np.all(np.asarray(found[1].alpha_u) >= np.asarray(found[1].alpha_v))


def test_backend_inputs_replace_the_texturable_values():
    """``lobes``' inputs (what a Cycles mapping feeds from sockets) give the lobes of the stack with those values."""
    n = len(COSINES)
    media = [{"sigma_a": [0.5, 0.2, 0.1], "depth": 0.3, "sigma_s": [0.2, 0.2, 0.2], "g": 0.6}, {}]
    changed = [{**ANISOTROPIC[0], "alpha": [0.3, 0.05], "rotation": 55.0}, ANISOTROPIC[1],
               {**ANISOTROPIC[2], "alpha": [0.1, 0.2]}]
    inputs = {("alpha_x", 0): np.full(n, 0.3), ("alpha_y", 0): np.full(n, 0.05), ("rotation", 0): np.full(n, 55.0),
              ("alpha_x", 2): np.full(n, 0.1), ("alpha_y", 2): np.full(n, 0.2),
              ("sigma_a", 0): np.tile([0.5, 0.2, 0.1], (n, 1)), ("depth", 0): np.full(n, 0.3)}
    got = ref.lobes(ref.F64, _stack(ANISOTROPIC, [{**media[0], "sigma_a": [0, 0, 0], "depth": 0.0}, {}]), COSINES, n,
                    inputs)
    for a, b in zip(got, _lobes(_stack(changed, media))):
        for field in ("weight", "energy", "alpha_u", "alpha_v", "angle"):
            assert np.allclose(_per_view(getattr(a, field), n), _per_view(getattr(b, field), n), rtol=1e-12,
                               atol=1e-15), field
