"""Per-texel multiple-scattering bake (addon.bake.textures): values, validation, cache, cancellation, writes.

The network weights are placeholders until the real training run: expected values always come from the
network itself (``nodes.spongecake.lobe_values``: the constant bake of one texel's stack, less the energy budget,
which is the material's own), never from numbers written here."""
import os

import numpy as np
import pytest

from addon.bake import exr, textures
from addon.models import spongecake as model
from addon.nodes import spongecake as mapping

pytest.importorskip("OpenEXR")

STACK = {"layers": [{"type": "surface", "roughness": 0.3, "thickness": 1.0, "f0": [0.4, 0.4, 0.4]},
                    {"type": "hg", "roughness": 0.2, "albedo": [0.5, 0.6, 0.7], "thickness": 2.0}],
         "multiple_scattering": True}


def _params(data=STACK):
    return model.params_from_dict(data)


def _inputs(h=3, w=5):
    """Distinct per-texel values with row 0 = top; texel (y, x) differs from (h-1-y, x) and (y, w-1-x)."""
    y, x = np.mgrid[0:h, 0:w]
    albedo = np.stack([0.1 + 0.15 * x, 0.2 + 0.2 * y, 0.9 - 0.1 * x], axis=-1)
    orientation = np.stack([0.2 * x - 0.4, 0.3 * y, np.ones((h, w))], axis=-1)  # raw vectors, not unit
    return {(0, "albedo"): albedo, (0, "orientation"): orientation, (1, "thickness"): 0.5 + x + 3.0 * y}


def _texel_params(inputs, y, x):
    """The stack whose parameters are texel (y, x)'s, built from the model dict."""
    data = {**STACK, "layers": [dict(layer) for layer in STACK["layers"]]}
    for (k, name), a in inputs.items():
        data["layers"][k][name] = np.asarray(a[y, x], dtype=float).tolist()
    return model.params_from_dict(data)


def _expected(inputs, y, x):
    """Socket name → the constant MS value of texel (y, x)'s stack (``predict`` → ``predict_rows``)."""
    values = mapping.lobe_values(_texel_params(inputs, y, x))  # the same for both forms
    return {name: np.atleast_1d(np.asarray(v, dtype=float)) for name, v in values.items()}


def _assert_texel(maps, layout, inputs, y, x):
    """Within float32 inference's reach: the network runs in float32 (``bake.mlp``), and BLAS sums a chunk of texels
    in another order than one stack: up to 2.1e-5 relative on a machine of 2026-12-06 (AVX-512), where a tolerance of
    1e-6 had held on the machines before."""
    expected = _expected(inputs, y, x)
    for name, channels in layout.items():
        want = [expected[e[0]][e[1]] if e else (1.0 if c == 3 else 0.0) for c, e in enumerate(channels)]
        np.testing.assert_allclose(maps[name][y, x], want, rtol=1e-4, atol=1e-6, err_msg=f"{name} at {(y, x)}")


def test_every_texel_is_the_prediction_for_that_texels_parameters():
    p, inputs = _params(), _inputs()
    maps = textures.bake_maps(p, inputs)
    layout = textures.map_layout(p)
    assert set(maps) == set(layout)
    assert all(m.shape == (3, 5, 4) and m.dtype == np.float32 for m in maps.values())
    for y in range(3):
        for x in range(5):
            _assert_texel(maps, layout, inputs, y, x)
    # the maps really vary across both axes: a flipped or mirrored bake fails above
    reflection = next(maps[name] for name, channels in layout.items() if channels[0][0] == "MS Reflection")
    assert not np.allclose(reflection[0], reflection[-1]) and not np.allclose(reflection[:, 0], reflection[:, -1])


def test_the_layout_feeds_every_per_texel_ms_input_of_the_shader_once():
    """Every baked input but the energy scale (the material's own, not per texel) is fed by a map, once."""
    for data in (STACK, {**STACK, "substrate": {"type": "diffuse"}},
                 {"layers": [{"type": "fiber"}], "multiple_scattering": True}):
        p = _params(data)
        layout = textures.map_layout(p)
        fed = [(e[0], e[1]) for channels in layout.values() for e in channels if e]
        assert len(fed) == len(set(fed))
        widths = {s.name: 1 if s.kind == "float" else 3 for s in mapping.sockets(p) if s.per_texel}
        assert sorted(fed) == sorted((name, c) for name, n in widths.items() for c in range(n))
        assert all(ch[0] is not None for ch in layout.values())
    over_substrate = textures.map_layout(_params({**STACK, "substrate": {"type": "diffuse"}}))
    assert "MS Transmission" not in {e[0] for channels in over_substrate.values() for e in channels if e}
    assert not any("Energy" in name for name in textures.map_layout(_params(STACK)))


def test_a_grey_albedo_texture_and_hg_roughness_are_accepted():
    p = _params()
    maps = textures.bake_maps(p, {(0, "albedo"): np.full((2, 2), 0.5), (1, "roughness"): np.full((2, 2), -0.4)})
    _assert_texel(maps, textures.map_layout(p), {(0, "albedo"): np.full((2, 2, 3), 0.5),
                                                 (1, "roughness"): np.full((2, 2), -0.4)}, 1, 1)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_texels_are_refused_naming_the_texture_and_count(bad, tmp_path):
    inputs = _inputs()
    inputs[(1, "thickness")] = inputs[(1, "thickness")].copy()
    inputs[(1, "thickness")][0, :2] = bad
    with pytest.raises(textures.BakeError, match=r"'thick.png' \(L2 Thickness\): 2 texel\(s\) are NaN or infinite"):
        textures.bake_maps(_params(), inputs, labels={(1, "thickness"): "'thick.png' (L2 Thickness)"})
    assert list(tmp_path.iterdir()) == []


def test_out_of_range_texels_are_clamped_with_a_warning():
    p = _params()
    albedo = np.full((2, 3, 3), 0.5)
    albedo[0, 0] = (1.5, 0.5, 0.5)
    albedo[1, 2] = (-0.2, 0.5, 0.5)
    rough = np.full((2, 3), 0.3)
    rough[1, 1] = 0.0  # below the flake minimum
    warnings = []
    maps = textures.bake_maps(p, {(0, "albedo"): albedo, (0, "roughness"): rough}, warnings=warnings)
    assert any("2 of 6 texel(s) outside [0, 1]" in w for w in warnings), warnings
    assert any("1 of 6 texel(s) outside [0.0001, 1]" in w for w in warnings), warnings
    clamped = {(0, "albedo"): np.clip(albedo, 0, 1), (0, "roughness"): np.maximum(rough, model.MIN_FLAKE_ROUGHNESS)}
    for y, x in ((0, 0), (1, 2), (1, 1)):
        _assert_texel(maps, textures.map_layout(p), clamped, y, x)


def test_zero_orientation_becomes_the_normal_with_a_warning():
    p, warnings = _params(), []
    o = np.zeros((1, 2, 3))
    o[0, 1] = (0.0, 0.0, 5.0)
    maps = textures.bake_maps(p, {(0, "orientation"): o}, warnings=warnings)
    assert any("1 texel(s) have no direction" in w for w in warnings)
    reflection = next(maps[name] for name, channels in textures.map_layout(p).items()
                      if channels[0][0] == "MS Reflection")
    np.testing.assert_array_equal(reflection[0, 0], reflection[0, 1])


@pytest.mark.parametrize("inputs, match", [
    ({}, "nothing to bake"),
    ({(0, "f0"): np.ones((2, 2, 3))}, "not texturable"),
    ({(1, "orientation"): np.ones((2, 2, 3))}, "not texturable"),
    ({(0, "albedo"): np.ones((2, 2, 3)), (1, "thickness"): np.ones((2, 3))}, "share one size"),
    ({(0, "roughness"): np.ones((2, 2, 3))}, r"expected H x W values"),
])
def test_inputs_that_cannot_be_baked_are_refused(inputs, match):
    with pytest.raises(textures.BakeError, match=match):
        textures.bake_maps(_params(), inputs)


def test_multiple_scattering_off_is_refused():
    with pytest.raises(textures.BakeError, match="multiple scattering is off"):
        textures.bake_maps(_params({**STACK, "multiple_scattering": False}), _inputs())


def test_progress_is_reported_per_chunk_and_cancel_writes_nothing(tmp_path, monkeypatch):
    fractions = []
    maps = textures.bake_maps(_params(), _inputs(4, 4), progress=fractions.append, chunk=5)
    assert fractions == pytest.approx([5 / 16, 10 / 16, 15 / 16, 1.0])
    calls = []
    real = textures.predict_rows
    monkeypatch.setattr(textures, "predict_rows", lambda rows: calls.append(len(rows)) or real(rows))
    with pytest.raises(textures.Cancelled):
        textures.bake_maps(_params(), _inputs(4, 4), cancel=lambda: len(calls) >= 1, chunk=5)
    assert calls == [5]
    assert list(tmp_path.iterdir()) == []
    assert set(maps) == set(textures.map_layout(_params()))


def test_written_maps_read_back_row_0_at_the_top(tmp_path):
    p, inputs = _params(), _inputs()
    maps = textures.bake_maps(p, inputs)
    paths = textures.write_maps(maps, tmp_path, textures.cache_key(p, inputs))
    for name, path in paths.items():
        assert os.path.basename(path).startswith("lamina_ms_") and name.replace(" ", "_") in path
        np.testing.assert_array_equal(exr.read_exr(path, "RGBA"), maps[name])


def test_unchanged_inputs_are_a_cache_hit_and_nothing_is_rewritten(tmp_path, monkeypatch):
    p, inputs = _params(), _inputs()
    key = textures.cache_key(p, inputs)
    assert textures.cached_maps(p, tmp_path, key) is None
    paths = textures.write_maps(textures.bake_maps(p, inputs), tmp_path, key)
    stamps = {path: os.stat(path).st_mtime_ns for path in paths.values()}
    assert textures.cache_key(p, {k: v.copy() for k, v in inputs.items()}) == key
    assert textures.cached_maps(p, tmp_path, key) == paths

    def no_write(*args, **kwargs):
        raise AssertionError("a cache hit must not rewrite")

    monkeypatch.setattr(textures, "write_exr", no_write)
    assert textures.write_maps(textures.bake_maps(p, inputs), tmp_path, key) == paths
    assert {path: os.stat(path).st_mtime_ns for path in paths.values()} == stamps
    changed = dict(inputs)
    changed[(1, "thickness")] = inputs[(1, "thickness")] + 1e-3
    other = model.params_from_dict({**STACK, "layers": [STACK["layers"][0], {**STACK["layers"][1], "albedo": 0.4}]})
    assert len({key, textures.cache_key(p, changed), textures.cache_key(other, inputs)}) == 3
    substrate = model.params_from_dict({**STACK, "substrate": {"type": "diffuse"}})
    assert textures.cache_key(substrate, inputs) != key


def test_a_failed_write_leaves_nothing_behind(tmp_path, monkeypatch):
    p, inputs = _params(), _inputs()
    maps = textures.bake_maps(p, inputs)
    written = []

    def fail_on_third(path, image):
        if len(written) == 2:
            raise OSError("disk full")
        written.append(path)
        exr.write_exr(path, image)

    monkeypatch.setattr(textures, "write_exr", fail_on_third)
    with pytest.raises(OSError, match="disk full"):
        textures.write_maps(maps, tmp_path, textures.cache_key(p, inputs))
    assert list(tmp_path.iterdir()) == []


def test_colour_helpers_match_cycles_conventions():
    np.testing.assert_allclose(textures.srgb_to_linear([0.0, 0.04045, 0.5, 1.0]),
                               [0.0, 0.04045 / 12.92, 0.21404114, 1.0], rtol=1e-5)
    assert textures.luminance(np.ones((1, 1, 3)))[0, 0] == pytest.approx(1.0)
    a = np.arange(8.0).reshape(2, 4)
    np.testing.assert_array_equal(textures.resample(a, (2, 4)), a)
    np.testing.assert_array_equal(textures.resample(a, (4, 8), nearest=True), np.repeat(np.repeat(a, 2, 0), 2, 1))
    up = textures.resample(a, (4, 8))
    assert up.shape == (4, 8) and up[0, 0] == a[0, 0] and up[-1, -1] == a[-1, -1]
    assert up[0, 1] == pytest.approx(0.25)  # a quarter of the way from texel 0 to texel 1
    rgb = textures.resample(np.dstack([a, a, a]), (1, 2))
    assert rgb.shape == (1, 2, 3)


def test_synthetic_inputs_bake_without_warnings():
    """What the benchmark times: every texturable input driven, all values in range."""
    p, warnings = _params(), []
    inputs = textures.synthetic_inputs(p, 16)
    assert set(inputs) == set(textures.texturable_inputs(p))
    maps = textures.bake_maps(p, inputs, warnings=warnings)
    assert warnings == [] and all(m.shape == (16, 16, 4) and np.isfinite(m).all() for m in maps.values())


def test_a_four_layer_stack_bakes_through_the_grouped_two_layer_network(tmp_path):
    """Deeper stacks (grouped in two): every texel is still the prediction for its own stack, and the bake is
    cached by content like any other."""
    layers = [{"type": "surface", "roughness": 0.3, "thickness": 1.0}, {"type": "hg", "thickness": 2.0},
              {"type": "fiber", "roughness": 0.4, "thickness": 0.5}, {"type": "surface", "thickness": 3.0}]
    p = model.params_from_dict({"layers": layers, "multiple_scattering": True})
    inputs = {(2, "thickness"): np.array([[0.2, 4.0], [1.0, 8.0]])}
    maps = textures.bake_maps(p, inputs)
    name, channel = next((n, c) for n, entries in textures.map_layout(p).items() for c, e in enumerate(entries)
                         if e and e[0] == "MS L3 Thickness")
    for (y, x), t in np.ndenumerate(inputs[2, "thickness"]):
        texel = model.params_from_dict({"layers": [*layers[:2], {**layers[2], "thickness": t}, layers[3]],
                                        "multiple_scattering": True})
        np.testing.assert_allclose(maps[name][y, x, channel], mapping.lobe_values(texel)["MS L3 Thickness"], rtol=1e-6)
    key = textures.cache_key(p, inputs)
    assert textures.write_maps(maps, tmp_path, key) == textures.cached_maps(p, tmp_path, key)
