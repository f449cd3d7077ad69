"""The neural medium's gather (reference/neural_medium.py): Monte Carlo tables of an infinite medium, gathered along
camera rays from the sun's beams into a sphere, against the independent path tracer (neural_medium_truth).

Double scattering happens near the beam, where the object's boundary matters little: the gather reproduces the
truth's order 2. Multiple scattering travels further: the infinite-medium table also counts light that would
have left the object, so the gather can only overestimate it (the method's approximation, Sec. 3.2; measured by
training/medium_gather_check.py)."""
import math

import numpy as np
import pytest

from addon import presets
from addon.models import neural_medium as model
from addon.reference import neural_medium as nm
from addon.reference import neural_medium_truth as truth
from addon.reference import scenes as S
from training import medium_tracer as mt

SCENE = S.sphere_scene(resolution=12)
CLOUD = model.params_from_dict({**presets.load(model.ID, "cloud"), "scale": 0.5})  # 4.4 mfp across


@pytest.fixture(scope="module")
def cloud():
    """The cloud's Monte Carlo tables (albedo 0.909, g 0), the gather on the 12 px sphere, and the truth there."""
    r = mt.simulate(CLOUD.albedo[0], CLOUD.g, mt.default_grid(), mt.Settings(photons=60_000, double_photons=600_000,
                                                                             batches=4), seed=[5])
    grid = mt.default_grid()
    edges = (np.asarray(grid.rho_edges), np.asarray(grid.z_edges), grid.theta_centres(), grid.phi_centres())
    tables = {kind: nm.Table(r[kind], *edges) for kind in nm.KINDS}
    origins, directions = truth.camera_rays(SCENE, truth.Sphere())
    gathered = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), _beams(SCENE.suns, 32), origins,
                         directions, steps=16)
    t = truth.render(CLOUD, truth.Sphere(), SCENE, 1024, seed=11)
    mask = (S.scene_mask(SCENE) & t["mask"]).ravel()
    return tables, gathered, t, mask


def _beams(suns, cells):
    return nm.Beams.join(nm.sun_beams(truth.Sphere(), sun, cells) for sun in suns)


def _mean(image, mask):
    return image[..., 0].ravel()[mask].mean()


def test_double_scattering_is_the_truths_order_2(cloud):
    _, gathered, t, mask = cloud
    assert gathered["double"][mask].mean() == pytest.approx(_mean(t["order2"], mask), rel=0.05)


def test_the_infinite_medium_can_only_add_multiple_scattering(cloud):
    _, gathered, t, mask = cloud
    noise = np.sqrt(np.mean(t["noise"]["multiple"][..., 0].ravel()[mask] ** 2))
    assert gathered["multiple"][mask].mean() > _mean(t["multiple"], mask) + 3.0 * noise / np.sqrt(mask.sum())


def test_the_boundary_images_take_away_most_of_the_excess(cloud):
    """With the image sources, multiple scattering on the 4.4 mfp cloud sphere is within 10% of the truth (+74%
    without, +23% with the entry planes' images alone: training/medium_gather_check.py), and never negative."""
    tables, _, t, mask = cloud
    origins, directions = truth.camera_rays(SCENE, truth.Sphere())
    imaged = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), _beams(SCENE.suns, 32), origins, directions,
                       kinds=("multiple",), steps=16, images=nm.boundary(CLOUD.albedo[0], CLOUD.g))
    assert np.all(imaged["multiple"] >= 0.0)
    assert imaged["multiple"][mask].mean() == pytest.approx(_mean(t["multiple"], mask), rel=0.10)


def test_the_exit_planes_images_mend_a_thin_box(cloud):
    """A tile 1.6 x 1.6 x 0.5 of the cloud (1.1 mfp thick): light leaves through the bottom, which the entry planes'
    images alone miss (+79%); with the exit planes' images multiple scattering is within 15% of the truth."""
    tables = cloud[0]
    box = truth.Box((-0.8, -0.8, -0.25), (0.8, 0.8, 0.25))
    t = truth.render(CLOUD, box, SCENE, 1024, seed=12)
    mask = t["mask"].ravel()
    beams = nm.Beams.join(nm.sun_beams(box, sun, 32) for sun in SCENE.suns)
    imaged = nm.gather(tables, CLOUD.mean_free_path[0], box, beams, *truth.camera_rays(SCENE, box),
                       kinds=("multiple",), steps=16, images=nm.boundary(CLOUD.albedo[0], CLOUD.g))
    assert np.all(imaged["multiple"] >= 0.0)
    assert imaged["multiple"][mask].mean() == pytest.approx(_mean(t["multiple"], mask), rel=0.15)


def test_the_exit_images_weigh_less_for_forward_scattering():
    assert nm.boundary(0.9, -0.5).exits == 1.0 and nm.boundary(0.9, 0.0).exits == 1.0
    assert nm.boundary(0.999, 0.7).exits == pytest.approx(0.3)
    assert nm.boundary(0.999, 0.7).zb == nm.extrapolation_distance(0.999, 0.7)


def test_the_extrapolated_boundary_is_the_diffusions():
    assert nm.extrapolation_distance(0.0, 0.9) == pytest.approx(2.0 / 3.0)
    assert nm.extrapolation_distance(0.999, 0.7) == pytest.approx(2.0 / (3.0 * (1.0 - 0.999 * 0.7)))
    assert np.isfinite(nm.extrapolation_distance(1.0, 1.0))


def test_the_truth_shapes_normals_point_out():
    x = np.array([[0.0, 0.0, 0.9], [0.95, 0.0, 0.0], [0.0, -0.2, -0.99]])
    np.testing.assert_allclose(truth.Sphere().normal(x), x / np.linalg.norm(x, axis=1, keepdims=True))
    np.testing.assert_allclose(truth.Box().normal(x), [[0, 0, 1], [1, 0, 0], [0, 0, -1]])
    np.testing.assert_allclose(truth.Slab().normal(x)[:, 2], [1, 1, -1])


def test_the_gather_is_linear_in_the_sun_and_zero_off_the_object(cloud):
    tables, _, _, _ = cloud
    origins, directions = truth.camera_rays(SCENE, truth.Sphere())
    brighter = [S.Sun(SCENE.suns[0].direction, 3.0)]
    a = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), _beams(SCENE.suns, 16), origins, directions,
                  steps=8)
    b = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), _beams(brighter, 16), origins, directions, steps=8)
    for kind in nm.KINDS:
        np.testing.assert_allclose(b[kind], 3.0 * a[kind], rtol=1e-12)
        assert np.all(a[kind] >= 0.0) and np.all(np.isfinite(a[kind]))
    missed = ~np.isfinite(truth.Sphere().interval(origins, directions)[0])
    assert missed.any() and all(np.all(a[kind][missed] == 0.0) for kind in nm.KINDS)


def test_table_lookup_interpolates_and_is_zero_outside(cloud):
    tables, _, _, _ = cloud
    table = tables["double"]
    rho_c, z_c = nm.cell_centres(table.rho_edges, table.z_edges)
    i, j, k, m = 3, 45, 4, 7
    exact = table.lookup(np.array([rho_c[i]]), np.array([z_c[j]]), np.array([table.theta[k]]),
                         np.array([table.phi[m]]))
    assert exact[0] == pytest.approx(table.values[i, j, k, m], rel=1e-9)
    mid = table.lookup(np.array([rho_c[i]]), np.array([z_c[j]]), np.array([0.5 * (table.theta[k] + table.theta[k + 1])]),
                       np.array([table.phi[m]]))
    assert mid[0] == pytest.approx(0.5 * (table.values[i, j, k, m] + table.values[i, j, k + 1, m]), rel=1e-9)
    outside = table.lookup(np.array([1e4]), np.array([0.0]), np.array([1.0]), np.array([1.0]))
    assert outside[0] == 0.0


def test_an_unbounded_shape_is_refused():
    with pytest.raises(ValueError, match="bounded shape"):
        nm.sun_beams(truth.Slab(), SCENE.suns[0], 8)


def test_a_far_point_light_is_a_sun(cloud):
    """A point light of intensity E D^2 at distance D along the sun's direction lights the sphere as the sun does."""
    tables, _, _, _ = cloud
    origins, directions = truth.camera_rays(SCENE, truth.Sphere())
    sun = SCENE.suns[0]
    distance = 1e4
    point = nm.point_beams(truth.Sphere(), distance * np.asarray(sun.direction), sun.irradiance * distance ** 2, 16)
    a = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), _beams(SCENE.suns, 16), origins, directions, steps=8)
    b = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), point, origins, directions, steps=8)
    for kind in nm.KINDS:
        assert b[kind].sum() == pytest.approx(a[kind].sum(), rel=0.03)


@pytest.mark.parametrize("round_", [False, True])
def test_a_far_area_light_facing_the_object_is_a_sun(cloud, round_):
    """A Lambertian area lamp of power P at distance D facing the sphere has intensity P / pi along its normal: with
    P = pi E D^2 it lights the sphere as a sun of irradiance E (square and disc)."""
    tables, _, _, _ = cloud
    origins, directions = truth.camera_rays(SCENE, truth.Sphere())
    sun = SCENE.suns[0]
    distance, towards = 1e3, np.asarray(sun.direction)
    u = nm._perpendicular(towards)
    v = np.cross(towards, u)  # (u, v) emits along -towards, to the sphere
    area = nm.area_beams(truth.Sphere(), distance * towards, 0.5 * v, 0.5 * u, math.pi * sun.irradiance * distance ** 2,
                         16, round_)
    assert area.powers.min() > 0.0
    a = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), _beams(SCENE.suns, 16), origins, directions, steps=8)
    b = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), area, origins, directions, steps=8)
    for kind in nm.KINDS:
        assert b[kind].sum() == pytest.approx(a[kind].sum(), rel=0.05)


def test_an_area_light_facing_away_gives_nothing():
    beams = nm.area_beams(truth.Sphere(), (0.0, 0.0, 3.0), (0.5, 0.0, 0.0), (0.0, 0.5, 0.0), 100.0, 16)  # emits +z
    assert len(beams) == 0


def test_a_point_light_inside_the_object_is_refused():
    with pytest.raises(ValueError, match="inside"):
        nm.point_beams(truth.Sphere(), (0.0, 0.0, 0.5), 1.0, 8)


# ---------------------------------------------------------------------------------- the bake (bake/neural_medium.py)

def test_the_linear_fit_is_exact_for_linear_radiance():
    from addon.bake import neural_medium as nb
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(5, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    directions = nb.hemisphere_directions(normals)
    assert np.allclose(np.linalg.norm(directions, axis=2), 1.0)
    assert np.all(np.einsum("nkj,nj->nk", directions, normals) >= 0.5 - 1e-12)  # the outward hemisphere
    c = rng.normal(size=(5, 4))
    values = c[:, :1] + np.einsum("nkj,nj->nk", directions, c[:, 1:])
    np.testing.assert_allclose(nb.fit_linear(directions, values), c, atol=1e-12)


def test_the_baked_surface_gives_the_gathered_light_towards_the_camera(cloud):
    """Baked at points of the sphere's camera side, the fit evaluated towards the camera (+z) is the gather along the
    camera ray through the point: within 3% in the mean, and within 10% where the view is within 30 degrees of the
    normal (towards the silhouette the radiance is not linear in the direction: the fit's named approximation)."""
    from addon.bake import neural_medium as nb
    tables, _, _, _ = cloud
    rng = np.random.default_rng(1)
    normals = rng.normal(size=(40, 3)) * [0.4, 0.4, 1.0] + [0.0, 0.0, 1.5]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    beams = [_beams(SCENE.suns, 16)] * 3
    grey = model.params_from_dict({**CLOUD.to_dict(), "sigma_s": [CLOUD.sigma_s[0]] * 3,
                                   "sigma_a": [CLOUD.sigma_a[0]] * 3})
    coefficients = nb.bake_points(grey, [tables] * 3, truth.Sphere(), beams, normals, normals, nb.Settings(steps=8))
    assert coefficients.shape == (40, 4, 3) and np.all(np.isfinite(coefficients))
    baked = nb.evaluate(coefficients, np.tile([0.0, 0.0, 1.0], (40, 1)))[:, 0]
    direct = nm.gather(tables, grey.mean_free_path[0], truth.Sphere(), beams[0], normals + [0.0, 0.0, 1e-3],
                       np.tile([0.0, 0.0, -1.0], (40, 1)), steps=8,
                       images=nm.boundary(grey.albedo[0], grey.g))
    expected = direct["double"] + direct["multiple"]
    assert np.all(expected > 0.0)
    assert baked.mean() == pytest.approx(expected.mean(), rel=0.03)
    facing = normals[:, 2] > np.cos(np.radians(30.0))
    assert facing.sum() > 20 and np.all(np.abs(baked[facing] / expected[facing] - 1.0) < 0.1)


def test_no_lamp_bakes_black(cloud):
    from addon.bake import neural_medium as nb
    tables, _, _, _ = cloud
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    none = [nm.Beams.join([])] * 3
    assert np.all(nb.bake_points(CLOUD, [tables] * 3, truth.Sphere(), none, normals, normals) == 0.0)


# ------------------------------------------------------------- gathering at fewer points (bake/neural_medium.py)

def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r, phi = np.sqrt(1.0 - z * z), math.pi * (1.0 + 5 ** 0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def test_gathering_points_keep_one_point_per_cell_and_side():
    from addon.bake import neural_medium as nb
    points = _fibonacci_sphere(2000)
    assert np.array_equal(nb.gathering_points(points, points, 0.0), np.arange(2000))
    chosen = nb.gathering_points(points, points, 0.25)
    assert 50 < len(chosen) < 1000 and len(np.unique(chosen)) == len(chosen)
    # every point lies within a cell's diagonal of its nearest chosen point
    d = np.linalg.norm(points[:, None, :] - points[chosen][None, :, :], axis=2).min(axis=1)
    assert d.max() <= 0.25 * math.sqrt(3.0)
    # the two faces of a sheet thinner than the spacing never share a point
    top = np.array([[x, y, 0.01] for x in (0.1, 0.2) for y in (0.1, 0.2)])
    sheet = np.concatenate([top, top * [1, 1, -1]])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (4, 1)), np.tile([0.0, 0.0, -1.0], (4, 1))])
    chosen = nb.gathering_points(sheet, normals, 1.0)
    assert len(chosen) == 2 and set(normals[chosen, 2]) == {1.0, -1.0}


def test_spread_returns_the_gathered_values_and_keeps_sides_apart():
    from addon.bake import neural_medium as nb
    points = _fibonacci_sphere(1500)
    chosen = nb.gathering_points(points, points, 0.3)
    field = np.stack([np.ones(len(points)), points[:, 0], points[:, 1], points[:, 2]], axis=1)[:, :, None] * [1, 2, 3]
    out = nb.spread(field[chosen], points[chosen], points[chosen], points, points, 0.3)
    np.testing.assert_allclose(out[chosen], field[chosen], rtol=1e-12)  # a gathered point keeps its value
    np.testing.assert_allclose(out[:, 0], field[:, 0], rtol=1e-12)  # a constant stays constant
    assert np.abs(out[:, 1:] - field[:, 1:]).max() < 0.3 * 3  # a linear field moves by less than the spacing
    # a sheet: the bottom face gets the bottom's value, never the top's
    sources = np.array([[0.0, 0.0, 0.01], [0.0, 0.0, -0.01]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    values = np.array([[[1.0]], [[2.0]]])
    got = nb.spread(values, sources, normals, np.array([[0.05, 0.0, -0.01]]), normals[1:], 1.0)
    assert got[0, 0, 0] == 2.0


def test_a_bake_at_fewer_points_stays_close_to_gathering_at_every_point(cloud):
    """Half a mean free path between gathering points (the default) against every point: within 3% relative RMSE
    on the cloud's sphere (the bench measures other spacings and media)."""
    from addon.bake import neural_medium as nb
    tables, _, _, _ = cloud
    p = model.params_from_dict({**CLOUD.to_dict(), "sigma_s": [CLOUD.sigma_s[0]] * 3,
                                "sigma_a": [CLOUD.sigma_a[0]] * 3})
    points = _fibonacci_sphere(600)
    beams = [_beams(SCENE.suns, 16)] * 3
    settings = nb.Settings(cells=16, steps=3)  # 2.2% (2.1% with 6 steps); 5.0% with the spacing in scene units
    full = nb.evaluate(nb.bake_points(p, [tables] * 3, truth.Sphere(), beams, points, points, settings), points)
    spacing = nb.gathering_spacing(p, settings)
    chosen = nb.gathering_points(points, points, spacing)
    assert len(chosen) < 0.5 * len(points)
    part = nb.bake_points(p, [tables] * 3, truth.Sphere(), beams, points[chosen], points[chosen], settings)
    got = nb.evaluate(nb.spread(part, points[chosen], points[chosen], points, points, spacing), points)
    assert np.sqrt(np.mean((got - full) ** 2)) < 0.03 * full.mean()


def test_the_bake_key_changes_with_the_spacing_and_refuses_nonsense():
    from addon.bake import neural_medium as nb
    key = [nb.bake_key({"g": 0.0}, "mesh", [], nb.Settings(spacing=s), "w") for s in (0.0, 0.5, 0.5)]
    assert key[0] != key[1] == key[2]
    with pytest.raises(ValueError, match="spacing"):
        nb.Settings(spacing=float("nan"))


def test_a_grid_whose_cubes_all_stay_near_is_the_plain_gather(cloud):
    """The VRL grid (Sec. 4.3) with angle 0 never takes a representative: the gather is unchanged (the rays' order
    and the beams' within a chunk change, so up to rounding)."""
    tables, _, _, _ = cloud
    origins, directions = truth.camera_rays(SCENE, truth.Sphere())
    beams, images = _beams(SCENE.suns, 16), nm.boundary(CLOUD.albedo[0], CLOUD.g)
    a = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), beams, origins, directions, steps=6, images=images)
    b = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), beams, origins, directions, steps=6, images=images,
                  grid=nm.beam_grid(beams, 0.2, 0.0))
    for kind in nm.KINDS:
        np.testing.assert_allclose(b[kind], a[kind], rtol=1e-9, atol=1e-15)


def test_each_beam_lies_in_its_cube_and_the_representatives_carry_the_cubes_power():
    beams = _beams(SCENE.suns, 16)
    grid = nm.beam_grid(beams, 0.3, 0.5)
    assert sorted(np.concatenate(grid.members)) == list(range(len(beams)))
    rep = nm._representatives(grid, {"power": beams.powers, "entry": beams.entries, "direction": beams.directions})
    powers, entries, directions = rep["power"], rep["entry"], rep["direction"]
    assert powers.sum() == pytest.approx(beams.powers.sum(), rel=1e-12)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    for k, members in enumerate(grid.members):
        assert np.all(np.abs(beams.entries[members] - grid.centres[k]) <= 0.5 * grid.cube + 1e-12)
        assert np.all(np.abs(entries[k] - grid.centres[k]) <= 0.5 * grid.cube + 1e-12)


def test_far_cubes_gather_through_their_representatives_within_a_percent(cloud):
    """A dense patch of rays on the 4.4 mfp cloud sphere: cubes of a mean free path seen under less than a radian
    stand in for their beams; fewer sources, the same light within 1% (the bench measures other sizes and angles)."""
    tables, _, _, _ = cloud
    ell = CLOUD.mean_free_path[0]
    points = _fibonacci_sphere(2000)
    points = points[points[:, 2] > 0.6]
    beams, images = _beams(SCENE.suns, 32), nm.boundary(CLOUD.albedo[0], CLOUD.g)
    grid = nm.beam_grid(beams, ell, 1.0)
    chosen, cubes = nm._chosen_sources(grid, points[:16])
    assert len(chosen) + len(cubes) < 0.8 * len(beams)
    a = nm.gather(tables, ell, truth.Sphere(), beams, points * 1.0001, -points, steps=4, images=images)
    b = nm.gather(tables, ell, truth.Sphere(), beams, points * 1.0001, -points, steps=4, images=images, grid=grid)
    for kind in nm.KINDS:
        assert np.sqrt(np.mean((b[kind] - a[kind]) ** 2)) < 0.01 * a[kind].mean()


def test_the_accumulated_segment_of_a_uniform_table_is_its_attenuation_integral():
    """Sec. 3.7's segment table of a table constant within 40 mfp: A = Phi (1 - exp(-5)) wherever the segment stays
    inside; the weight W of Eq. 5 (continuous form) is 0 for an empty segment and the share of exp(-s) covered."""
    edges = (np.linspace(0.0, 40.0, 9), np.linspace(-40.0, 40.0, 17), (np.arange(6) + 0.5) * math.pi / 6,
             (np.arange(4) + 0.5) * math.pi / 4)
    table = nm.Table(np.full((8, 16, 6, 4), 2.0), *edges)
    a = nm.segment_table(table, steps=8)
    assert a.segment == nm.SEGMENT
    inner = a.values[:3, 4:12]
    np.testing.assert_allclose(inner, 2.0 * -math.expm1(-nm.SEGMENT), rtol=1e-12)
    assert nm.segment_weight(0.0) == 0.0
    assert nm.segment_weight(nm.SEGMENT) == pytest.approx(1.0)
    assert nm.segment_weight(1.0) == pytest.approx((1.0 - math.exp(-1.0)) / (1.0 - math.exp(-5.0)))


def test_the_papers_accumulated_segments_gather_what_the_quadrature_gathers(cloud):
    """The segment tables with the paper's weight against the quadrature along each camera segment, on the cloud's
    sphere: the same light within 5% in the mean (the bench measures the error per pixel on other media)."""
    tables, _, _, mask = cloud
    origins, directions = truth.camera_rays(SCENE, truth.Sphere())
    beams = _beams(SCENE.suns, 16)
    segments = {kind: nm.segment_table(table) for kind, table in tables.items()}
    a = nm.gather(tables, CLOUD.mean_free_path[0], truth.Sphere(), beams, origins, directions, steps=16)
    b = nm.gather(segments, CLOUD.mean_free_path[0], truth.Sphere(), beams, origins, directions)
    for kind in nm.KINDS:
        assert b[kind][mask].mean() == pytest.approx(a[kind][mask].mean(), rel=0.05)


def _plain_and_changed_bake(tables, points: int, settings, **changes):
    """The radiance along the normal of a bake of the grey cloud on ``points`` points of the unit sphere with
    ``settings`` and with ``changes`` to them (the sun's beams at ``settings.cells``)."""
    import dataclasses

    from addon.bake import neural_medium as nb
    p = model.params_from_dict({**CLOUD.to_dict(), "sigma_s": [CLOUD.sigma_s[0]] * 3,
                                "sigma_a": [CLOUD.sigma_a[0]] * 3})
    x = _fibonacci_sphere(points)
    beams = [_beams(SCENE.suns, settings.cells)] * 3
    return [nb.evaluate(nb.bake_points(p, [tables] * 3, truth.Sphere(), beams, x, x, s), x)
            for s in (settings, dataclasses.replace(settings, **changes))]


def test_the_bake_gathers_through_the_beam_grid_when_asked(cloud):
    """``Settings.grid_angle`` reaches the gather: a bake with the grid differs from one without (representatives
    stood in) by under 2%, and the grid enters the bake key only when it is on."""
    from addon.bake import neural_medium as nb
    # 0.55% (0.58% on 400 points); 18% with a cube's mean power for its sum, 4.3% with every cube far
    a, b = _plain_and_changed_bake(cloud[0], 200, nb.Settings(cells=24, steps=4), grid_angle=1.0, grid_cube=0.5)
    assert not np.array_equal(a, b)
    assert np.sqrt(np.mean((b - a) ** 2)) < 0.02 * a.mean()
    keys = [nb.bake_key({}, "m", [], s, "w") for s in (nb.Settings(), nb.Settings(grid_cube=2.0),
                                                        nb.Settings(grid_angle=0.5), nb.Settings(grid_angle=0.5,
                                                                                                 grid_cube=2.0))]
    assert keys[0] == keys[1] and len(set(keys[1:])) == 3


def test_the_bake_gathers_through_accumulated_segments_when_asked(cloud):
    """``Settings.segments`` reaches the gather: within 5% of the quadrature along each segment on the cloud's
    sphere (the bench measures the error per point), and in the bake key only when on."""
    from addon.bake import neural_medium as nb
    # 1.0% (1.1% on 200 points); 53% with half the segment weight
    a, b = _plain_and_changed_bake(cloud[0], 100, nb.Settings(cells=12, steps=8), segments=True)
    assert not np.array_equal(a, b)
    assert np.sqrt(np.mean((b - a) ** 2)) < 0.05 * a.mean()
    assert nb.bake_key({}, "m", [], nb.Settings(), "w") != nb.bake_key({}, "m", [], nb.Settings(segments=True), "w")
