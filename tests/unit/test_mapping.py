"""The Cycles mapping evaluated in numpy (what the node group and OSL forms render), bpy-free."""
import numpy as np
import pytest

from addon import presets
from addon.models import spongecake as model
from addon import nodes
from addon.nodes import closures_np, expr
from addon.nodes import spongecake as mapping
from addon.reference.frames import spherical


def _dirs(n, seed, lower=False):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = -np.abs(v[:, 2]) if lower else np.abs(v[:, 2])
    return v


def _predict(p, wi, wo, form="osl"):
    b = expr.NumpyBackend(wo, nodes.input_values(model.ID, p, form), form=form)
    mapping.shade(b, p)
    return b.evaluate(wi), b


@pytest.mark.parametrize("form", ["osl", "nodes"])
def test_thick_surface_layer_maps_to_exactly_half_ggx(form):
    p = model.params_from_dict(presets.load(model.ID, "thick_flakes"))
    wi, wo = _dirs(500, 1), _dirs(500, 2)
    f, _ = _predict(p, wi, wo, form)
    expected = 0.5 * closures_np.ggx_reflection(wi, wo, 0.3)
    np.testing.assert_allclose(f, expected, rtol=1e-9, atol=1e-300)


def test_node_form_schlick_is_exact_at_the_mirror_configuration():
    p = model.params_from_dict(presets.load(model.ID, "copper_flakes"))
    wo = _dirs(200, 3)
    wi = wo * np.array([-1.0, -1.0, 1.0])
    exact, _ = _predict(p, wi, wo, "osl")
    approx, _ = _predict(p, wi, wo, "nodes")
    np.testing.assert_allclose(approx, exact, rtol=1e-9)
    off = _dirs(200, 4)
    assert not np.allclose(_predict(p, off, wo, "nodes")[0], _predict(p, off, wo, "osl")[0], rtol=1e-3)


def test_only_the_layers_and_lobes_in_use_are_generated():
    leaf = model.params_from_dict(presets.load(model.ID, "leaf"))
    _, b = _predict(leaf, _dirs(4, 5), _dirs(4, 6))
    kinds = [c[0] for c in b.closures]
    assert kinds.count("ggx") == 2 and kinds.count("diffuse") == 1 and kinds.count("translucent") == 3
    assert "transparent" not in kinds
    shade = model.params_from_dict(presets.load(model.ID, "window_shade"))
    assert "transparent" in [c[0] for c in _predict(shade, _dirs(4, 5), _dirs(4, 6))[1].closures]


@pytest.mark.parametrize("name", presets.names(model.ID))
def test_mapped_weights_are_finite_and_non_negative_at_grazing(name):
    p = model.params_from_dict(presets.load(model.ID, name))
    wo = _dirs(300, 7)
    wo[:10] = [[np.sqrt(1 - c * c), 0.0, c] for c in np.geomspace(1e-9, 1e-2, 10)]
    for wi in (_dirs(300, 8), _dirs(300, 9, lower=True)):
        for form in ("osl", "nodes"):
            f, b = _predict(p, wi, wo, form)
            assert np.all(np.isfinite(f)) and np.all(f >= 0)
            for _, color, _ in b.closures:
                assert np.all(np.isfinite(color)) and np.all(color >= 0) and np.all(color <= 1.0 + 1e-12)


def test_socket_names_come_from_the_declaration():
    p = model.params_from_dict(presets.load(model.ID, "plastic"))
    names = [s.name for s in mapping.sockets(p)]
    assert names == ["L1 Roughness", "L1 Albedo", "L1 Thickness", "L1 F0", "L1 Orientation", "Substrate Albedo"]
    hg = model.params_from_dict({"layers": [{"type": "hg"}]})
    assert [s.name for s in mapping.sockets(hg)] == ["L1 Mean Cosine g", "L1 Albedo", "L1 Thickness"]


def test_structure_key_ignores_values_but_not_structure():
    a = model.params_from_dict({"layers": [{"roughness": 0.2}]})
    b = model.params_from_dict({"layers": [{"roughness": 0.7, "thickness": 3.0}]})
    c = model.params_from_dict({"layers": [{"roughness": 0.2, "f0": [0.5, 0.5, 0.5]}]})
    assert mapping.structure_key(a) == mapping.structure_key(b) != mapping.structure_key(c)


@pytest.mark.parametrize("layer", [
    {"type": "surface", "roughness": 0.3, "orientation": [0, 0, 1]},
    {"type": "fiber", "roughness": 0.3, "orientation": [1, 0, 0]},
    {"type": "fiber", "roughness": 0.05, "orientation": [0, 1, 0]},
])
def test_thick_flake_layers_map_exactly_onto_ggx_lobes(layer):
    """Research notes §1 generalised: an SGGX matrix with the normal as eigenvector is an (anisotropic) GGX."""
    from addon.reference import spongecake as reference

    p = model.params_from_dict({"layers": [{**layer, "thickness": 1e4, "albedo": [1, 1, 1]}]})
    wi, wo = _dirs(2000, 11), _dirs(2000, 12)
    f, _ = _predict(p, wi, wo)
    np.testing.assert_allclose(f, reference.eval(p, wi, wo), rtol=1e-9, atol=1e-300)


def test_every_named_approximation_is_declared_and_every_declared_one_is_used():
    import pathlib
    import re

    from addon.models import MODELS
    from addon.nodes import MAPPINGS

    source = "".join(p.read_text() for p in pathlib.Path(mapping.__file__).parent.glob("*.py"))
    tags = set(re.findall(r"\[approx: ([\w.-]+)\]", source))
    declared = [(m, name) for m in MODELS for name in MAPPINGS[m].APPROXIMATIONS]
    assert tags == {name for _, name in declared} and len(declared) == len(tags)
    for m, name in declared:
        assert MODELS[m].validate(MAPPINGS[m].APPROXIMATIONS[name][1]).warnings == []


@pytest.mark.parametrize("alpha", [0.01, 0.1, 0.3, 0.5, 0.8, 1.0])
def test_downward_shares_match_the_sggx_phase_function(alpha):
    """The shares of light along the normal scattered downwards, as the mapping states them, against
    sampling the reference's SGGX phase function: surface flakes and fibers along n exactly, in-plane fibers
    within 0.01 (the fitted form in _fiber_lobe)."""
    from addon.reference import sggx

    rng = np.random.default_rng(3)
    n = 200_000
    up = np.tile([0.0, 0.0, 1.0], (n, 1))

    def sampled(s):
        wo, _ = sggx.sample_phase(s, up, rng.random(n), rng.random(n))
        return (wo[:, 2] < 0).mean()

    normal = np.array([[0.0, 0.0, 1.0]])
    shares = {}
    for name, orientation in (("surface", [0, 0, 1]), ("fiber", [0, 0, 1]), ("fiber", [1, 0, 0])):
        p = model.params_from_dict({"layers": [{"type": name, "roughness": alpha, "orientation": orientation}]})
        b = expr.NumpyBackend(normal, mapping.input_values(p))
        shares[(name, orientation[2])] = float(np.squeeze(mapping._layer_terms(b, "L1 ", p.layers[0], 1.0)["p_down"]))
    noise = 4 * np.sqrt(0.25 / n)
    assert abs(shares[("surface", 1)] - sampled(sggx.surface(np.array([0.0, 0, 1]), alpha))) < noise
    assert abs(shares[("fiber", 1)] - sampled(sggx.fiber(np.array([0.0, 0, 1]), alpha))) < noise
    assert abs(shares[("fiber", 0)] - sampled(sggx.fiber(np.array([1.0, 0, 0]), alpha))) < 0.01 + noise


def _tilted_normals(n, seed):
    v = _dirs(n, seed)
    v[:, 2] = np.maximum(v[:, 2], 0.3)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_cycles_bends_a_tilted_closure_normal_only_where_the_mirror_direction_leaves_the_surface():
    """closures_np.ensure_valid_specular_reflection, as Cycles' kernel states it: unchanged where the mirror
    direction of wo is above min(0.9 cos θo, 0.01); elsewhere turned towards z in the plane of n and z until
    the mirror direction is exactly at that threshold."""
    n, wo = _tilted_normals(4000, 21), _dirs(4000, 22)
    bent = closures_np.ensure_valid_specular_reflection(n, wo)
    threshold = np.minimum(0.9 * wo[:, 2], 0.01)
    r_z = lambda m: 2.0 * np.einsum("ij,ij->i", m, wo) * m[:, 2] - wo[:, 2]  # noqa: E731
    valid = r_z(n) >= threshold
    assert 0.05 < (~valid).mean() < 0.95
    np.testing.assert_array_equal(bent[valid], n[valid])
    b, m = bent[~valid], n[~valid]
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(r_z(bent)[~valid], threshold[~valid], atol=1e-9)
    assert np.all(b[:, 2] > m[:, 2])  # towards z
    np.testing.assert_allclose(np.cross(m, b)[:, 2], 0.0, atol=1e-12)  # same azimuth: in the plane of n and z
    assert np.all(np.einsum("ij,ij->i", m[:, :2], b[:, :2]) >= 0.0)


def test_a_tilted_ggx_closure_is_foreshortened_by_its_own_normal():
    """What Cycles renders for a GGX closure around a tilted n (where n needs no bending): GGX in n's frame
    times cos(n, ωi), i.e. as a BSDF w.r.t. z, f_n · cos(n, ωi) / cos θi; light below the surface gives 0."""
    normal = np.array([0.5, 0.0, np.sqrt(0.75)])
    wi, wo = np.concatenate([_dirs(1500, 23), _dirs(1500, 27, lower=True)]), _dirs(3000, 24)
    wo = wo[closures_np.ensure_valid_specular_reflection(np.tile(normal, (len(wo), 1)), wo)[:, 2] == normal[2]]
    wi = np.random.default_rng(28).permutation(wi)[: len(wo)]
    # rotation taking normal to z (about y)
    c, s = normal[2], normal[0]
    rot = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    np.testing.assert_allclose(rot @ normal, [0, 0, 1], atol=1e-15)
    f = closures_np.ggx_reflection(wi, wo, 0.3, normal=normal)
    in_frame = closures_np.ggx_reflection(wi @ rot.T, wo @ rot.T, 0.3)
    expected = in_frame * ((wi @ normal) / wi[:, 2] * (wi[:, 2] > 0))[:, None]
    np.testing.assert_allclose(f, expected, rtol=1e-9, atol=1e-300)
    assert np.any((wi[:, 2] < 0) & (wi @ normal > 0) & (in_frame[:, 0] > 0))  # the case that must give 0


@pytest.mark.parametrize("block", [7, closures_np.PAIRS_PER_BLOCK])
def test_the_ggx_albedo_quadrature_gives_each_view_its_own_parameters(block, monkeypatch):
    """The visible-normal quadrature evaluates its nodes in blocks for every view at once: each view's albedo is the
    one it gets alone, with per-view roughness, normal, tangent and colours (three views: as long as a colour),
    whether a block ends within the views or not."""
    monkeypatch.setattr(closures_np, "PAIRS_PER_BLOCK", block)
    wo = spherical(np.array([0.9, 0.4, 0.05]), np.array([0.3, 2.0, 4.0]))
    normal = np.array([[0.3, 0.0, 0.95], [0.0, 0.0, 1.0], [-0.2, 0.4, 0.9]])
    tangent = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.8, 0.0]])
    ax, ay, f0 = np.array([0.05, 0.3, 0.8]), np.array([0.2, 0.3, 0.1]), np.array([[0.1, 0.5, 0.9], [1.0, 1.0, 1.0],
                                                                                     [0.3, 0.2, 0.1]])
    eta, k = np.array([[0.2, 0.9, 1.1], [1.5, 1.5, 1.5], [0.3, 0.4, 0.5]]), (3.0, 2.5, 2.0)
    together = closures_np.ggx_albedo(wo, ax, ay, normal, tangent, f0, nodes=16)
    metal = closures_np.ggx_conductor_albedo(wo, ax, ay, tangent, eta, k, nodes=16)
    for i in range(3):
        alone = closures_np.ggx_albedo(wo[i:i + 1], ax[i], ay[i], normal[i], tangent[i], f0[i], nodes=16)
        np.testing.assert_allclose(together[i], alone[0], rtol=1e-12)
        alone = closures_np.ggx_conductor_albedo(wo[i:i + 1], ax[i], ay[i], tangent[i], eta[i], k, nodes=16)
        np.testing.assert_allclose(metal[i], alone[0], rtol=1e-12)
    assert np.ptp(together, axis=1).max() > 0.01 and np.all(together > 0)  # the colours and views matter


def test_blender_4_2_sampling_leak_only_for_a_normal_off_the_shading_normal():
    wo = _dirs(20, 25)
    assert np.all(closures_np.ggx_sampling_leak(wo, 0.3) == 0.0)
    leak = closures_np.ggx_sampling_leak(wo, 0.3, normal=[0.5, 0.0, np.sqrt(0.75)])
    assert np.all(leak >= 0) and leak.max() > 1e-3
    p = model.params_from_dict({"layers": [{"type": "fiber", "orientation": [0.7, 0.0, 0.7]}]})
    _, b = _predict(p, _dirs(20, 26), wo)
    assert np.all(b.sampling_leak_blender42() == 0.0)


@pytest.mark.parametrize("roughness", [0.0, 0.3, 1.0])
def test_microfiber_sheen_integrates_to_its_tabulated_albedo_and_stays_finite(roughness):
    """closures_np.sheen: the LTC integrates to 1 over the upper hemisphere, so the directional albedo is the
    table's R (exact for the fit's albedo rows); finite and non-negative at grazing and normal views."""
    from addon.reference.scenes import directional_albedo
    views = np.radians([0.0, 30.0, 60.0, 80.0, 89.0])
    wo = np.stack([np.sin(views), np.zeros_like(views), np.cos(views)], axis=1)
    integral = directional_albedo(lambda wi, w: closures_np.sheen(wi, w, roughness), wo, quadrature=(256, 512))
    albedo = closures_np.sheen_albedo(wo, roughness)
    assert np.allclose(integral, albedo, rtol=0.02, atol=1e-5)
    assert albedo.max() < 1.0 and (albedo.max() > 0.3 or roughness < 0.5)
    f = closures_np.sheen(_dirs(4000, 27), np.tile(wo, (800, 1)), roughness)
    assert np.isfinite(f).all() and f.min() >= 0.0


@pytest.mark.parametrize("form", ["osl", "nodes"])
def test_a_flake_normal_below_the_tangent_plane_maps_like_its_opposite(form):
    """S = α²I + (1 − α²)nnᵀ is the same for ±n (two-sided flakes; the reference agrees): the closure normal
    is flipped up instead of pointing into the surface, where Cycles would render almost nothing."""
    from addon.reference import spongecake as reference

    wi, wo = _dirs(500, 31), _dirs(500, 32)
    f = {}
    for sign in (1.0, -1.0):
        layer = {"type": "surface", "roughness": 0.3, "thickness": 0.5, "f0": [0.3, 0.3, 0.3],
                 "orientation": [sign * -0.5, 0.0, sign * 0.866]}
        p = model.params_from_dict({"layers": [layer]})
        f[sign], _ = _predict(p, wi, wo, form)
        f[sign, "reference"] = reference.eval(p, wi, wo)
    np.testing.assert_allclose(f[-1.0, "reference"], f[1.0, "reference"], rtol=1e-12)
    np.testing.assert_allclose(f[-1.0], f[1.0], rtol=1e-12, atol=1e-300)
    assert f[1.0].max() > 0.1


def test_each_approximations_isolating_config_reports_itself_and_nothing_undeclared_is_reported():
    from addon.models import MODELS
    from addon.nodes import MAPPINGS

    for m, declaration in MODELS.items():
        table = MAPPINGS[m].APPROXIMATIONS
        for name, (_, config) in table.items():
            assert name in MAPPINGS[m].approximations_used(declaration.params_from_dict(config)), (m, name)
        for config in [c for _, c in table.values()] + [presets.load(m, n) for n in presets.names(m)]:
            used = MAPPINGS[m].approximations_used(declaration.params_from_dict(config))
            assert set(used) <= set(table) and used == [n for n in table if n in used], (m, config)


def test_what_the_mapping_renders_exactly_reports_no_approximation():
    """Thick surface flakes are exactly half a GGX lobe (test above); a porous layer without grains is its bulk."""
    from addon.models import micrograin
    from addon.nodes import micrograin as micrograin_mapping

    assert mapping.approximations_used(model.params_from_dict(presets.load(model.ID, "thick_flakes"))) == []
    assert micrograin_mapping.approximations_used(micrograin.params_from_dict({"filling_factor": 0.0})) == []
    # an opaque stack's transmission lobes carry nothing: their approximations are not in use
    plastic = mapping.approximations_used(model.params_from_dict(presets.load(model.ID, "plastic")))
    assert "translucent-lobe" not in plastic and "substrate-attenuation" in plastic


@pytest.mark.parametrize("name", ["fabric", "window_shade", "leaf"])
def test_multiple_scattering_closures_follow_the_view_only_through_the_energy_scale(name):
    """[ms-weights-at-normal]: the lobe's closure weights are those of the view along the normal at every view."""
    from dataclasses import replace

    p = replace(model.params_from_dict(presets.load(model.ID, name)), multiple_scattering=True)
    wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.98, 0.199], [0.4, -0.3, -0.866]])
    b = expr.NumpyBackend(wo, nodes.input_values(model.ID, p, "osl"), form="osl")
    mapping._multiple_scattering(b, p)
    assert len(b.closures) >= 2
    for kind, color, _ in b.closures:
        np.testing.assert_allclose(color, np.broadcast_to(color[0], color.shape), rtol=1e-12, err_msg=kind)


def test_with_view_independent_weights_a_white_stack_still_returns_what_it_receives_at_the_rows():
    """The energy scale restores each view's total [ms-weights-at-normal, ms-energy]: a white isotropic stack
    with multiple scattering is 1 less the scale's margin in the form's furnace at the rows of its energy table."""
    white = model.params_from_dict({"layers": [
        {"type": "surface", "roughness": 0.3, "albedo": [1, 1, 1], "thickness": 0.5},
        {"type": "hg", "roughness": 0.4, "albedo": [1, 1, 1], "thickness": 1.0}],
        "multiple_scattering": True, "delta_transmission": True})
    rows = model.VIEW_ENERGY_GRID[0]
    mu = np.asarray(model.view_table_cosines(rows))[[rows // 8, rows // 2, rows - 1]]
    views = np.stack([np.sqrt(1.0 - mu * mu), 0.0 * mu, mu], axis=1)
    furnace = expr.closure_furnace(lambda w: nodes._backend(model.ID, white, "osl", w),
                                   views, mapping.ENERGY_QUADRATURE, closures_np.SHARP_ALBEDO)
    np.testing.assert_allclose(furnace, 1.0 - model.ENERGY_MARGIN, atol=2e-3)


@pytest.mark.parametrize("views", [3, 7])
def test_the_furnace_reuses_each_views_closures_exactly(views):
    """``closure_furnace`` integrates the closures recorded once per view (``NumpyBackend.unit_albedo``): the same numbers as
    shading every direction of the grid again, also for 3 views (a constant direction has 3 entries too); a fiber
    layer and a tilted flake layer give closures with per-view normals and tangents."""
    from addon.reference.scenes import directional_albedo

    p = model.params_from_dict({"layers": [
        {"type": "fiber", "roughness": 0.3, "albedo": [0.9, 0.5, 0.2], "thickness": 0.7, "orientation": [1, 0, 0]},
        {"type": "surface", "roughness": 0.4, "albedo": [0.6, 0.6, 0.9], "thickness": 2.0,
         "orientation": [0.3, 0.2, 0.9]}]})
    wo = _dirs(views, 5)

    def backend_at(w):
        return _predict(p, w, w)[1]

    regridded = directional_albedo(lambda wi, w: backend_at(w).evaluate(wi), wo, (16, 32))
    reused = expr.closure_furnace(backend_at, wo, (16, 32), quadratures={})
    np.testing.assert_allclose(reused, regridded, rtol=1e-12, atol=1e-15)


def test_the_furnace_integrates_a_closure_seen_before_only_once(monkeypatch):
    """Each closure's albedo is kept (``NumpyBackend.unit_albedo``): a second shader with the same closures at other
    weights (as a fitted mapping rescales the analytic one's) is integrated without the direction grid, and gives its
    own weights times the same albedos."""
    from addon.reference import scenes

    p = model.params_from_dict(presets.load(model.ID, "fabric"))
    wo = _dirs(7, 3)
    first = expr.closure_furnace(lambda w: nodes._backend(model.ID, p, "osl", w), wo)

    def halved(w):
        b = nodes._backend(model.ID, p, "osl", w)
        b.closures = [(kind, 0.5 * np.asarray(color), kw) for kind, color, kw in b.closures]
        return b

    monkeypatch.setattr(scenes, "directional_albedo", lambda *a, **k: pytest.fail("integrated again"))
    np.testing.assert_allclose(expr.closure_furnace(halved, wo), 0.5 * first, rtol=1e-12)


@pytest.mark.parametrize("name, merged", [("fabric", 1), ("window_shade", 2)])
def test_the_node_group_makes_one_closure_of_each_fiber_layers_two_lobes(name, merged):
    """[ms-merged-fiber-lobe]: in the node group a fiber layer's GGX lobe and the network's lobe for it are one
    Glossy BSDF whose colour is the sum of OSL's two and whose α_x keeps their weighted peak, Σ c / α_x (energy
    inputs 2: both shares of the budget 1, so the colours are the unscaled ones the mix is computed from)."""
    from dataclasses import replace

    p = replace(model.params_from_dict(presets.load(model.ID, name)), multiple_scattering=True)
    values = {**nodes.input_values(model.ID, p, "osl"), mapping.MS_ENERGY_INPUT: (2.0, 2.0, 2.0)}
    wo = _dirs(6, 7)
    lobes = {}
    for form in ("osl", "nodes"):
        b = expr.NumpyBackend(wo, values, form=form)
        mapping.shade(b, p)
        lobes[form] = [(color, kw) for kind, color, kw in b.closures if kind == "ggx"]
    assert len(lobes["osl"]) - len(lobes["nodes"]) == merged
    flakes = [layer for layer in p.layers if layer.is_flake]
    osl_single, osl_multiple = lobes["osl"][:len(flakes)], lobes["osl"][len(flakes):]
    fibers = [k for k, layer in enumerate(flakes) if layer.type == "fiber"]
    one = [(color, kw) for color, kw in lobes["nodes"] if np.all(kw["alpha_y"] == 1.0)]
    assert len(one) == len(fibers)
    for k, (color, kw) in zip(fibers, one):
        (c1, kw1), (c2, kw2) = osl_single[k], osl_multiple[k]
        np.testing.assert_allclose(color, c1 + c2, rtol=1e-9)
        peak = c1.mean(axis=1) / kw1["alpha_x"] + c2.mean(axis=1) / kw2["alpha_x"]
        np.testing.assert_allclose(color.mean(axis=1) / kw["alpha_x"], peak, rtol=1e-9)
        np.testing.assert_allclose(kw["tangent"], kw1["tangent"], rtol=1e-12)
