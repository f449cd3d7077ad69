"""The Monte Carlo ground truth of multiple scattering on the comparison scenes (addon.reference.spongecake_truth): sampled pixels,
the pixel -> (wi, wo) mapping of the walk, the picture fill, the noise estimate and energy conservation."""
import numpy as np
import pytest

from addon.reference import montecarlo
from addon.reference import spongecake_truth as ms_truth
from addon.reference import scenes as S
from addon.reference import spongecake as ref

TWO_LAYERS = ref.params_from_dict({"layers": [  # anisotropic and lopsided, so a mirrored pixel would differ
    {"type": "fiber", "roughness": 0.3, "albedo": [0.95, 0.9, 0.8], "thickness": 1.0, "orientation": [0.6, 0.8, 0]},
    {"type": "surface", "roughness": 0.4, "albedo": [0.9, 0.9, 0.9], "thickness": 2.0}],

    "multiple_scattering": False})


def test_sampled_pixels_are_a_grid_inside_the_mask():
    spec = S.sphere_scene(resolution=24)
    mask = S.scene_mask(spec)
    s = montecarlo.sampled_pixels(spec, 3)
    assert s.any() and not (s & ~mask).any()
    rows, cols = np.nonzero(s)
    assert set(rows % 3) == {1} and set(cols % 3) == {1}
    assert montecarlo.sampled_pixels(spec, 1).sum() == mask.sum()
    tiny = S.plane_scene(resolution=(2, 1))
    assert montecarlo.sampled_pixels(tiny, 8).sum() == 2  # grid misses the image: every pixel


def test_settings_refuse_nonsense():
    with pytest.raises(ValueError):
        ms_truth.TruthSettings(paths=1)
    with pytest.raises(ValueError):
        ms_truth.TruthSettings(stride=0)


def _expected_plane(p, spec, r, c, paths, seed):
    """The walk's orders >= 2 at one pixel, called directly with the pixel's directions (another seed)."""
    g = S.pixel_geometry(spec)
    wo = g["wo"][r, c][None]
    wi = np.asarray(spec.suns[0].direction)[None]
    ms = ref.ground_truth(p, wi, wo, n_paths=paths, seed=seed, max_depth=64)[1][0]
    return ms * abs(wi[0, 2]) * spec.suns[0].irradiance


@pytest.mark.parametrize("make", [S.plane_scene, S.backlit_scene])
def test_plane_pixels_are_the_walk_at_their_view_direction(make):
    spec = make(resolution=(6, 3))
    truth = ms_truth.multiple_scattering_truth(TWO_LAYERS, spec, ms_truth.TruthSettings(paths=8000, stride=1))
    assert truth["samples"].all()
    for r, c in [(0, 0), (1, 1), (2, 4)]:
        expected = _expected_plane(TWO_LAYERS, spec, r, c, 16000, seed=99)
        se = truth["noise"][r, c].max()
        assert se > 0
        # the direct call has half the variance: 5 sigma of the difference
        np.testing.assert_array_less(np.abs(truth["image"][r, c] - expected), 5.0 * se * np.sqrt(1.5))
        mirrored = _expected_plane(TWO_LAYERS, spec, r, spec.width - 1 - c, 16000, seed=98)
        if r > 0:  # the test can fail: the mirrored view direction gives another value
            assert np.abs(truth["image"][r, c] - mirrored).max() > 5.0 * se * np.sqrt(1.5)


def test_sphere_pixels_use_their_own_light_direction_and_the_closed_sphere():
    spec = S.sphere_scene(resolution=8, elevation_deg=10.0)
    truth = ms_truth.multiple_scattering_truth(TWO_LAYERS, spec, ms_truth.TruthSettings(paths=4000, stride=1))
    g = S.pixel_geometry(spec)
    sun = np.asarray(spec.suns[0].direction)
    cos_i = np.sum(g["n"] * sun, axis=-1)
    mask = S.scene_mask(spec)
    assert np.all(truth["image"][mask & (cos_i <= 0)] == 0)  # light below the local horizon is blocked
    lit = np.argwhere(mask & (cos_i > 0.3))
    r, c = lit[len(lit) // 2]
    wi = S.to_local(sun[None], g["t"][r, c][None], g["b"][r, c][None], g["n"][r, c][None])
    wo = S.to_local(g["wo"][r, c][None], g["t"][r, c][None], g["b"][r, c][None], g["n"][r, c][None])
    expected = ref.ground_truth(TWO_LAYERS, wi, wo, n_paths=8000, seed=5, max_depth=64)[1][0] * cos_i[r, c]
    np.testing.assert_array_less(np.abs(truth["image"][r, c] - expected), 5.0 * truth["noise"][r, c].max() * np.sqrt(2))


def test_unsampled_pixels_copy_the_nearest_sample_for_the_picture_only():
    spec = S.plane_scene(resolution=(8, 4))
    truth = ms_truth.multiple_scattering_truth(TWO_LAYERS, spec, ms_truth.TruthSettings(paths=400, stride=2))
    s = truth["samples"]
    assert 0 < s.sum() < s.size
    assert np.all(truth["noise"][~s] == 0) and np.all(truth["noise"][s] > 0)
    values = {tuple(v) for v in truth["image"][s]}
    assert all(tuple(v) in values for v in truth["image"][~s])  # one sun, constant cos: the nearest's value


def test_stated_noise_matches_the_spread_between_seeds():
    """The plane's pixels share their paths, so this checks that the batches, not the pixels, give the noise."""
    spec = S.plane_scene(resolution=(6, 3))
    runs = [ms_truth.multiple_scattering_truth(TWO_LAYERS, spec, ms_truth.TruthSettings(paths=2000, stride=1,
                                                                                       seed=seed))
            for seed in range(6)]
    spread = np.std([r["image"] for r in runs], axis=0, ddof=1)
    stated = np.sqrt(np.mean([r["noise"] ** 2 for r in runs], axis=0))
    ratio = np.sqrt(np.mean(spread**2)) / np.sqrt(np.mean(stated**2))
    assert 0.5 < ratio < 2.0


def test_noise_shrinks_with_the_number_of_paths():
    spec = S.plane_scene(resolution=(8, 4))
    ss = S.reference_image(spec, lambda wi, wo: ref.eval(TWO_LAYERS, wi, wo))
    noise = []
    for paths in (500, 8000):
        t = ms_truth.multiple_scattering_truth(TWO_LAYERS, spec, ms_truth.TruthSettings(paths=paths, stride=1))
        noise.append(montecarlo.relative_noise(ss + t["image"], t["noise"], t["samples"]))
    assert 0.1 < noise[1] / noise[0] < 0.45  # 1/4 expected


def test_furnace_truth_of_a_white_stack_conserves_energy():
    """Closed-form single scattering + unscattered light + the walk's orders >= 2 = 1 for albedo 1."""
    p = ref.params_from_dict({"layers": [{"type": "hg", "roughness": 0.5, "albedo": [1, 1, 1], "thickness": 0.7},
                                         {"type": "fiber", "roughness": 0.3, "albedo": [1, 1, 1], "thickness": 0.5,
                                          "orientation": [1, 0, 0]}], "delta_transmission": True})
    spec = S.furnace_scene(resolution=(4, 4))
    truth = ms_truth.multiple_scattering_truth(p, spec, ms_truth.TruthSettings(albedo_paths=20000, stride=1))
    single = S.reference_image(spec, lambda wi, wo: ref.eval(p, wi, wo),
                               bsdf_albedo=lambda wo: ref.furnace_albedo(p, wo, n=16384))
    total = single + truth["image"]
    np.testing.assert_allclose(total, 1.0, atol=0.03)
    assert truth["image"].min() > 0.02  # multiple scattering is really there


def test_the_network_flag_does_not_change_the_truth():
    spec = S.plane_scene(resolution=(4, 2))
    on = ref.params_from_dict({**TWO_LAYERS.to_dict(), "multiple_scattering": True})
    settings = ms_truth.TruthSettings(paths=200, stride=1)
    a = ms_truth.multiple_scattering_truth(TWO_LAYERS, spec, settings)["image"]
    b = ms_truth.multiple_scattering_truth(on, spec, settings)["image"]
    np.testing.assert_array_equal(a, b)
