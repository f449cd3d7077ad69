"""The fitted mapping (issue 14): the fitter recovers a mixture it generated, keeps the analytic mapping where that
is already close, is deterministic and cached, and stays finite and non-negative on bad materials."""
import numpy as np
import pytest

from addon import presets
from addon.models import spongecake, thin_coat
from addon import nodes
from addon.nodes import budget, choice, fitted, predicted_eval, predicted_furnace, pruning
from addon.nodes.expr import NumpyBackend, OslBackend


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    """Each test fits into its own cache folder, with an empty memory cache (unless it asks for ``shared_fits``)."""
    monkeypatch.setenv("LAMINA_CACHE", str(tmp_path))
    monkeypatch.setattr(choice, "_fits", {})


@pytest.fixture(scope="module")
def _module_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("fits"), {}


@pytest.fixture
def shared_fits(private_cache, _module_cache, monkeypatch):
    """For tests that only read fits (they neither count fits nor patch the fitter): this module's fits, made once."""
    folder, memory = _module_cache
    monkeypatch.setenv("LAMINA_CACHE", str(folder))
    monkeypatch.setattr(choice, "_fits", memory)


def _preset(model, name):
    return model.params_from_dict(presets.load(model.ID, name))


def _backend_of(model_id, p, form):
    from addon.nodes import _backend

    return lambda wo: _backend(model_id, p, form, wo)


def test_nnls_matches_a_brute_force_solution():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(40, 5))
    b = rng.normal(size=40)
    x = fitted.nnls_gram(a.T @ a, a.T @ b)
    assert (x >= 0).all()
    best = min((np.linalg.norm(a[:, list(s)] @ np.clip(np.linalg.lstsq(a[:, list(s)], b, rcond=None)[0], 0, None)
                               - b), s) for s in _subsets(5))
    assert np.linalg.norm(a @ x - b) <= best[0] + 1e-9


def test_nnls_takes_the_unconstrained_minimum_only_where_it_is_positive():
    """The one-solve answer where every weight of the unconstrained minimum is positive, the active set otherwise:
    both the minimum over x ≥ 0 (the brute force over the supports)."""
    rng = np.random.default_rng(5)
    for shift in (3.0, 0.0):  # a target inside the positive cone, then one outside
        a = rng.random(size=(30, 4))
        b = a @ (rng.random(4) + shift - 1.5) + 0.01 * rng.normal(size=30)
        x = fitted.nnls_gram(a.T @ a, a.T @ b)
        assert (x >= 0).all() and ((x > 0).all() if shift else (x == 0).any())
        best = min(np.linalg.norm(a[:, list(s)] @ np.clip(np.linalg.lstsq(a[:, list(s)], b, rcond=None)[0], 0, None)
                                  - b) for s in _subsets(4))
        assert np.linalg.norm(a @ x - b) <= best + 1e-9


def _subsets(n):
    return [tuple(i for i in range(n) if m >> i & 1) for m in range(1, 1 << n)]


@pytest.mark.parametrize("form", ["osl", "nodes"])
def test_the_fitter_recovers_a_mixture_it_generated(form):
    """A reference made of the plastic's own closures times known view tables, one of them left out for a dictionary
    closure with known weights (within the analytic closure count), is fitted back: the same extra closure in place
    of the same closure, every table within 1%."""
    p = _preset(spongecake, "plastic")
    mu = np.linspace(0.0, 1.0, fitted.KNOTS)
    groups = fitted.atom_groups(_backend_of(spongecake.ID, p, form))
    scales = np.stack([np.stack([0.6 + 0.3 * mu + 0.1 * c + 0.05 * j for c in range(3)], axis=1)
                       for j in range(max(groups) + 1)])
    left_out = max(groups)
    scales[left_out] = 0.0
    extra = ("ggx_refraction", {"alpha": 0.3, "ior": 10.0, "normal": "view"})
    weights = (0.02 + 0.05 * mu)[None, :, None] * np.array([1.0, 0.5, 0.2])
    truth = fitted.Fit(scales, (extra,), weights, 0.0, 0.0, groups)
    got = fitted.fit(_backend_of(spongecake.ID, p, form), predicted_eval(spongecake.ID, p, form, truth),
                     predicted_furnace(spongecake.ID, p, form, truth), form)
    assert got.extras == (extra,)
    assert got.error_fitted < 0.01
    assert (got.scales[left_out] == 0.0).all()
    # an atom that carries no light at a view is free there: compare where it does
    carried = np.zeros((len(scales), fitted.KNOTS))
    for k, m in enumerate(fitted.view_cosines()):
        recorded = _backend_of(spongecake.ID, p, form)(np.array([[np.sqrt(1 - m * m), 0.0, m]])).closures
        for g, (_, color, _) in zip(groups, fitted._fitted_closures(recorded)):
            carried[g, k] += np.abs(color).max()
    live = (carried[:, :, None] > 1e-3 * carried.max()) & (scales > 0.0)
    assert np.abs(np.where(live, got.scales / np.where(live, scales, 1.0) - 1.0, 0.0)).max() < 0.01
    assert np.abs(got.extra_weights / weights - 1.0).max() < 0.01


@pytest.mark.parametrize("form", ["osl", "nodes"])
def test_the_fitted_mapping_renders_no_more_closures_than_the_analytic_one(form, shared_fits):
    """The fit may put a dictionary closure in place of one of the material's own, never beside them all (issue 14's
    cost: the same closure count or fewer). The leaf's OSL fit gained two closures before this rule, for about a
    point of error on the comparison scenes (docs/accuracy.md, sphere 42.3% then, 43.4% now)."""
    from addon.nodes import budget

    p = _preset(spongecake, "leaf")
    fit = choice.fit_for(spongecake.ID, p, form)
    assert fit.extras
    assert budget.shader_size(spongecake.ID, p, form, fit)[1] <= budget.shader_size(spongecake.ID, p, form)[1]


def test_auto_keeps_the_analytic_mapping_where_it_is_exact():
    """Thick flakes render within 0.1% analytically: Auto keeps that mapping (and says both errors)."""
    p = _preset(spongecake, "thick_flakes")
    chosen = choice.choose(spongecake.ID, p, "osl", "auto")
    assert chosen.used == "analytic" and chosen.fit is None
    assert chosen.error["analytic"] < 0.02
    assert "analytic" in chosen.summary() and "fitted" in chosen.summary()


def test_auto_takes_the_fitted_mapping_where_it_is_closer(shared_fits):
    p = _preset(thin_coat, "amber_lacquer")
    chosen = choice.choose(thin_coat.ID, p, "osl", "auto")
    assert chosen.used == "fitted"
    assert chosen.error["fitted"] < chosen.error["analytic"] - choice.AUTO_MARGIN


def test_fits_are_deterministic_and_cached(monkeypatch):
    p = _preset(thin_coat, "rough_over_smooth")
    first = choice.fit_for(thin_coat.ID, p, "nodes")
    files = list(choice.cache_folder().glob("*.npz"))  # the default weighting's
    assert len(files) == 1
    with monkeypatch.context() as m:
        m.setattr(choice, "_fits", {})
        m.setattr(fitted, "fit", lambda *a, **k: pytest.fail("refitted although cached"))
        again = choice.fit_for(thin_coat.ID, p, "nodes")
    assert again.digest() == first.digest() and again.extras == first.extras and again.groups == first.groups
    np.testing.assert_array_equal(again.scales, first.scales)
    files[0].write_bytes(b"not a fit")  # a broken cache file is refitted, to the same tables
    monkeypatch.setattr(choice, "_fits", {})
    refitted = choice.fit_for(thin_coat.ID, p, "nodes")
    np.testing.assert_array_equal(refitted.scales, first.scales)
    with np.load(files[0]) as data:
        assert fitted.Fit.from_arrays(data).digest() == first.digest()


def test_the_variants_fitted_together_are_the_fits_made_one_by_one(monkeypatch):
    """``fitted.fit_variants`` evaluates the quadrature once for every weighting and dictionary: each of its fits is
    the one ``fitted.fit`` makes alone (a coarse grid of views keeps this quick)."""
    monkeypatch.setattr(fitted, "KNOTS", 5)
    monkeypatch.setattr(fitted, "AZIMUTHS", 2)
    p = _preset(thin_coat, "smooth_over_rough")
    problem = choice.fit_problem(thin_coat.ID, p, "osl")
    variants = [(v.damping, v.toons) for v in choice.VARIANTS]
    together = fitted.fit_variants(*problem, "osl", variants)
    alone = [fitted.fit(*problem, "osl", damping, toons) for damping, toons in variants]
    assert len({f.digest() for f in alone}) > 1  # the variants differ here
    for a, b in zip(together, alone):
        assert a.extras == b.extras and a.groups == b.groups
        np.testing.assert_allclose(a.scales, b.scales, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(a.extra_weights, b.extra_weights, rtol=1e-9, atol=1e-12)
        assert a.error_fitted == pytest.approx(b.error_fitted, rel=1e-9)


def test_spare_closures_may_render_beyond_the_analytic_count_and_never_fit_worse(monkeypatch):
    """``bench.fit_ceiling`` measures what a larger closure budget would buy: with spare closures the greedy fit may
    keep the material's closures beside the extras (the leaf's four and more), and its error can only fall (the
    shipped budget's fit is among those it keeps)."""
    monkeypatch.setattr(fitted, "KNOTS", 5)
    monkeypatch.setattr(fitted, "AZIMUTHS", 2)
    p = _preset(spongecake, "leaf")
    problem = choice.fit_problem(spongecake.ID, p, "osl")
    analytic_closures = budget.shader_size(spongecake.ID, p, "osl")[1]
    shipped, spared = (fitted.fit_variants(*problem, "osl", [(1.0, True)], spare=n)[0] for n in (0, 2))
    assert budget.shader_size(spongecake.ID, p, "osl", shipped)[1] <= analytic_closures
    assert budget.shader_size(spongecake.ID, p, "osl", spared)[1] <= analytic_closures + 2
    assert budget.shader_size(spongecake.ID, p, "osl", spared)[1] > budget.shader_size(spongecake.ID, p, "osl",
                                                                                         shipped)[1]
    assert spared.error_fitted < shipped.error_fitted


def test_every_closure_at_once_fits_no_worse_than_any_choice_of_them(monkeypatch):
    """``bench.fit_ceiling``'s every-closure row is a bound: each view's fit is a convex non-negative least squares,
    so the whole dictionary at once fits at least as well as the greedy choice of a few of its closures (the
    tiny ridge towards the analytic mapping aside), with spare closures or without."""
    monkeypatch.setattr(fitted, "KNOTS", 5)
    monkeypatch.setattr(fitted, "AZIMUTHS", 2)
    p = _preset(spongecake, "sheen")
    problem = choice.fit_problem(spongecake.ID, p, "osl")
    for damping in (0.5, 1.0):
        every = fitted.fit_variants(*problem, "osl", [(damping, True)], extras=fitted.extra_dictionary(toons=True))[0]
        assert len(every.extras) == len(fitted.extra_dictionary(toons=True))
        chosen = [fitted.fit_variants(*problem, "osl", [(damping, toons)], spare=spare)[0]
                  for toons in (False, True) for spare in (0, 2)]
        assert every.error_fitted <= min(f.error_fitted for f in chosen) + 1e-4
        assert every.error_fitted < every.error_analytic


def test_every_variant_is_fitted_at_once_and_cached_each_on_its_own(monkeypatch):
    p = _preset(thin_coat, "rough_over_smooth")
    calls = []
    together = fitted.fit_variants
    monkeypatch.setattr(fitted, "fit_variants", lambda *a, **k: calls.append(a[-1]) or together(*a, **k))
    fits = choice.fits_for(thin_coat.ID, p, "nodes")
    assert calls == [[(v.damping, v.toons) for v in choice.VARIANTS]]  # one quadrature for the four
    assert len(list(choice.cache_folder().glob("*.npz"))) == len(choice.VARIANTS)
    monkeypatch.setattr(choice, "_fits", {})
    monkeypatch.setattr(fitted, "fit", lambda *a, **k: pytest.fail("refitted although cached"))
    for v, f in fits.items():
        assert choice.fit_for(thin_coat.ID, p, "nodes", v).digest() == f.digest()


def test_a_changed_value_is_a_different_fit():
    p = _preset(thin_coat, "rough_over_smooth")
    q = thin_coat.params_from_dict({**p.to_dict(), "kappa_top": 11})
    assert choice.fit_key(thin_coat.ID, p, "osl") != choice.fit_key(thin_coat.ID, q, "osl")
    assert choice.fit_key(thin_coat.ID, p, "osl") != choice.fit_key(thin_coat.ID, p, "nodes")


def test_only_node_group_fits_depend_on_the_metallic_bsdf_node(monkeypatch):
    """Blender 4.2's node groups have no Metallic BSDF, so their prediction (and fit) differs; OSL always has
    ``metal``: its fit made under 4.2 is the one 5.0 would make."""
    from addon.nodes import expr

    p = _preset(thin_coat, "varnished_metal")
    keys = {form: choice.fit_key(thin_coat.ID, p, form) for form in ("osl", "nodes")}
    monkeypatch.setattr(expr.NumpyBackend, "metallic_node", not expr.NumpyBackend.metallic_node)
    assert choice.fit_key(thin_coat.ID, p, "osl") == keys["osl"]
    assert choice.fit_key(thin_coat.ID, p, "nodes") != keys["nodes"]
    closures = {}  # what the OSL key leaves out does not change what OSL renders (it does the node group's)
    for metal in (True, False):
        monkeypatch.setattr(expr.NumpyBackend, "metallic_node", metal)
        for form in ("osl", "nodes"):
            closures[form, metal] = repr(_backend_of(thin_coat.ID, p, form)(np.array([[0.0, 0.6, 0.8]])).closures)
    assert closures["osl", True] == closures["osl", False]
    assert closures["nodes", True] != closures["nodes", False]


def test_a_fit_with_multiple_scattering_follows_what_that_comes_from(monkeypatch):
    """The reference a fit matches includes the network's multiple scattering and its energy scale: a new version of
    either is a different fit; a material without multiple scattering keeps its fit."""
    from addon.bake import spongecake as bake

    with_ms = _preset(spongecake, "fabric")
    with_ms = spongecake.params_from_dict({**with_ms.to_dict(), "multiple_scattering": True})
    without = spongecake.params_from_dict({**with_ms.to_dict(), "multiple_scattering": False})
    keys = [choice.fit_key(spongecake.ID, q, "osl") for q in (with_ms, without)]
    monkeypatch.setattr(bake, "MS_VERSION", bake.MS_VERSION + 1)
    assert choice.fit_key(spongecake.ID, with_ms, "osl") != keys[0]
    assert choice.fit_key(spongecake.ID, without, "osl") == keys[1]


BAD = {
    "black": {"layers": [{"type": "surface", "roughness": 0.3, "thickness": 1.0, "albedo": [0, 0, 0]}],
              "substrate": {"type": "diffuse", "albedo": [0, 0, 0]}},
    "thickness-0": {"layers": [{"type": "hg", "roughness": 0.5, "thickness": 0.0, "albedo": [0.8, 0.8, 0.8]}]},
    "thickness-huge": {"layers": [{"type": "fiber", "roughness": 0.05, "thickness": 1e4, "albedo": [0.9, 0.9, 0.9],
                                   "orientation": [1, 0, 0]}]},
    "grazing-only": {"layers": [{"type": "fiber", "roughness": 0.02, "thickness": 0.01, "albedo": [1, 1, 1],
                                 "orientation": [0, 0, 1]}]},
}


@pytest.mark.parametrize("name", BAD)
def test_bad_materials_give_finite_non_negative_closures_and_a_message(name):
    p = spongecake.params_from_dict(BAD[name])
    chosen = choice.choose(spongecake.ID, p, "osl", "fitted")
    fit = chosen.fit
    for table in (fit.scales, fit.extra_weights):
        assert np.isfinite(table).all() and (table >= 0).all()
    assert np.isfinite(list(chosen.error.values())).all()
    wo = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.999, 0.0, 0.0447]])
    wi = np.array([[0.3, 0.1, 0.95], [-0.6, 0.0, 0.8], [0.0, 0.2, -0.98]])
    f = predicted_eval(spongecake.ID, p, "osl", fit)(wi, wo)
    assert np.isfinite(f).all() and (f >= 0).all()
    assert chosen.summary()
    if name == "black":
        assert "black" in chosen.summary()


def test_both_forms_get_the_tables(shared_fits):
    """The OSL source carries a constant array per table (16 colours), declared among the shader's parameters (OSL
    keeps a parameter nothing sets as a constant; a local array is filled at every shading point); the numpy backend
    interpolates them, in √cos θo from the first knot's view to normal view."""
    p = _preset(thin_coat, "amber_lacquer")
    fit = choice.choose(thin_coat.ID, p, "osl", "fitted").fit
    b = OslBackend([(s.name, s.kind, s.param.default) for s in thin_coat_sockets(p)])
    nodes.shade(b, thin_coat.ID, p, fit)
    source = b.source("t", "//")
    rendered = sum(scales.max() > 0.0 for scales in fit.scales)  # an atom set to zero everywhere is left out
    assert source.count(f"[{fitted.KNOTS}] = {{") == rendered + len(fit.extras)
    parameters, body = source.split("output closure color BSDF = 0)")
    assert body.count(f"[{fitted.KNOTS}] = {{") == 0
    mu = fitted.view_cosines()
    wo = np.stack([np.sqrt(1.0 - mu * mu), np.zeros_like(mu), mu], axis=1)
    n = NumpyBackend(np.concatenate([wo, [[1.0, 0.0, 0.0]]]), {}, "osl")
    table = np.arange(fitted.KNOTS)[:, None] * np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(n.ramp(table, fitted.table_coordinate(n)), np.concatenate([table, table[:1]]),
                               atol=1e-9)


def thin_coat_sockets(p):
    from addon.nodes import thin_coat as mapping

    return mapping.sockets(p)


def test_a_closure_the_node_group_weighs_in_grey_gets_a_grey_table():
    """The node group takes a Beckmann reflection with a Fresnel (the coat's top) through grey Mix Shaders: its
    fitted scale is the same in every channel, so both forms render what the fit predicts."""
    p = _preset(thin_coat, "amber_lacquer")
    backend_of = _backend_of(thin_coat.ID, p, "nodes")
    fit = choice.fit_for(thin_coat.ID, p, "nodes")
    closures = fitted._fitted_closures(backend_of(np.array([[0.0, 0.0, 1.0]])).closures)
    grey = {g for g, (kind, _, kw) in zip(fit.groups, closures) if fitted._grey(kind, kw, "nodes")}
    assert grey
    for g in grey:
        np.testing.assert_array_equal(fit.scales[g][:, 0], fit.scales[g][:, 2])
    assert any(np.ptp(fit.scales[g], axis=1).max() > 1e-3 for g in set(fit.groups) - grey)


# ------------------------------------------------------------------------------------ a texture-driven input

def test_a_driven_input_is_tabulated_across_its_range_clamped_to_the_parameter():
    p = _preset(thin_coat, "amber_lacquer")
    assert choice.driven_over(thin_coat.ID, p, "Absorption", -1.0, 2.0).values == (0.0, 0.5, 1.0, 1.5, 2.0)
    assert choice.driven_over(thin_coat.ID, p, "Depth", 0.3, 0.3).values == (0.3,)  # a constant texture
    with pytest.raises(ValueError, match="vector"):
        choice.driven_over(spongecake.ID, _preset(spongecake, "leaf"), "L1 Orientation", 0.0, 1.0)


def test_driven_tables_interpolate_each_channel_at_its_own_value_and_clamp():
    driven = fitted.Driven("Absorption", "color", (0.0, 0.5, 1.0, 1.5, 2.0))
    rng = np.random.default_rng(1)
    table = rng.uniform(0.1, 2.0, (5, fitted.KNOTS, 3))
    fit = fitted.Fit(table[None], (), np.zeros((0, 5, fitted.KNOTS, 3)), 0.0, 0.0, (0,), driven)
    value = np.array([0.2, 1.3, 2.7])  # the last channel beyond the range: the last value's table
    wo = np.array([[np.sqrt(1 - 0.3 ** 2), 0.0, 0.3]])
    b = NumpyBackend(wo, {"Absorption": value})
    got = fitted.tables(b, fit)(table)[0]
    u = float(fitted.table_coordinate(b)[0])
    knots = np.linspace(0.0, 1.0, fitted.KNOTS)
    at_view = np.array([[np.interp(u, knots, table[j, :, c]) for c in range(3)] for j in range(5)])
    want = [np.interp(min(value[c], 2.0), driven.values, at_view[:, c]) for c in range(3)]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    again = fitted.Fit.from_arrays(fit.to_json())
    assert again.driven == driven and again.digest() == fit.digest()
    assert fitted.Fit.from_arrays(fitted.Fit(table[0][None], (), np.zeros((0, fitted.KNOTS, 3)), 0, 0, (0,))
                                  .to_arrays()).driven is None


def test_closures_alike_at_one_driven_value_only_stay_apart():
    """The leaf's two flake layers have one roughness (0.05): one atom at that value, two at the others."""
    from addon.nodes import _backend

    p = _preset(spongecake, "leaf")
    driven = choice.driven_over(spongecake.ID, p, "L1 Roughness", 0.05, 0.3)
    backends = [(lambda q: lambda wo: _backend(spongecake.ID, q, "nodes", wo))(choice.at(spongecake.ID, p, driven, j))
                for j in range(len(driven.values))]
    at_first, at_second = fitted.atom_groups(backends[0]), fitted.atom_groups(backends[1])
    assert max(at_first) < max(at_second)
    assert fitted.common_groups(backends) == at_second


def test_a_driven_fit_between_its_values_is_as_close_as_a_fit_made_there(shared_fits):
    """Depth of the amber lacquer from a texture over [0.1, 1]: at 0.4375, between two tabulated values, the
    interpolated tables are within 1% (absolute relative RMSE) of a fit made at 0.4375, on every comparison scene."""
    p = _preset(thin_coat, "amber_lacquer")
    driven = choice.driven_over(thin_coat.ID, p, "Depth", 0.1, 1.0)
    made = choice.choose(thin_coat.ID, p, "osl", "fitted", driven)
    assert made.fit.driven == driven and made.fit.scales.shape[1] == len(driven.values)
    between = choice.at(thin_coat.ID, p, fitted.Driven("Depth", "float", (0.4375,)), 0)
    direct = choice.fit_for(thin_coat.ID, between, "osl", made.variant)
    errors, _ = choice.comparison_errors(thin_coat.ID, between, {"driven": ("osl", made.fit), "direct": ("osl", direct),
                                                                   "analytic": ("osl", None)}, resolution=24,
                                         albedo_samples=256, furnace_width=8)
    for scene, error in errors["driven"].items():
        assert error <= errors["direct"][scene] + 0.01, scene
    assert choice.counted(errors["driven"], {s: 1.0 for s in errors["driven"]}) < choice.counted(
        errors["analytic"], {s: 1.0 for s in errors["analytic"]})


def test_velvet_is_reciprocal_and_its_grid_albedo_matches_a_monte_carlo_estimate():
    """The velvet closure (Cycles' Ashikhmin velvet, ``closures_np.velvet``): f(ωi, ωo) = f(ωo, ωi), and the direction
    grid that the furnace prediction integrates it on agrees with uniform hemisphere sampling, grazing views
    included (where its narrow lobes lie)."""
    from addon.nodes import closures_np
    from addon.reference.scenes import directional_albedo

    rng = np.random.default_rng(4)
    z = rng.random(400000)
    phi = 2.0 * np.pi * rng.random(len(z))
    wi = np.stack([np.sqrt(1.0 - z * z) * np.cos(phi), np.sqrt(1.0 - z * z) * np.sin(phi), z], axis=1)
    wo = np.array([[np.sin(t), 0.0, np.cos(t)] for t in np.radians([0.0, 60.0, 80.0, 88.0])])
    for sigma in (0.2, 0.5):
        f = closures_np.velvet(wi[:1000], wi[1000:2000], sigma)
        np.testing.assert_allclose(f, closures_np.velvet(wi[1000:2000], wi[:1000], sigma), rtol=1e-12)
        grid = directional_albedo(lambda a, b: closures_np.velvet(a, b, sigma), wo)[:, 0]
        sampled = [2.0 * np.pi * np.mean(closures_np.velvet(wi, np.tile(v, (len(wi), 1)), sigma)[:, 0] * z) for v in wo]
        np.testing.assert_allclose(grid, sampled, rtol=0.02, atol=2e-3)
        assert grid[-1] > 0.5 and grid[0] < 0.01  # light between grazing directions only


def test_the_fit_of_fibers_along_the_normal_adds_velvet(shared_fits):
    """The sheen preset (fibers standing along the normal) scatters most between grazing directions, which only the
    velvet closure follows: its fit adds one and brings the furnace from 90% to within 5%."""
    p = _preset(spongecake, "sheen")
    chosen = choice.choose(spongecake.ID, p, "osl", "fitted")
    assert [kind for kind, _ in chosen.fit.extras] == ["velvet"]
    assert chosen.errors["analytic"]["furnace"] > 0.5 and chosen.errors["fitted"]["furnace"] < 0.05
    assert chosen.error["fitted"] < chosen.error["analytic"] - 0.2


def test_toon_lobes_keep_grazing_light_and_carry_their_stated_energy():
    """Cycles' Toon lobes (``closures_np.glossy_toon``, ``diffuse_toon``): f cos θi = I(γ) / (2π (1 − cos S)) without
    masking, so light at grazing incidence counts; the diffuse one of size 1 reflects all light at every view, the
    glossy tent (size 0, smooth 1: I = 1 − γ / 90°) reflects 1 − 2/π at normal view and nothing beyond 90° of the
    mirror direction."""
    from addon.nodes import closures_np
    from addon.reference.scenes import directional_albedo

    wo = np.array([[np.sin(t), 0.0, np.cos(t)] for t in np.radians([0.0, 45.0, 80.0])])
    flat = directional_albedo(lambda a, b: closures_np.diffuse_toon(a, b, 1.0, 0.0), wo, quadrature=(256, 512))
    np.testing.assert_allclose(flat, 1.0, atol=2e-3)
    tent = directional_albedo(lambda a, b: closures_np.glossy_toon(a, b, 0.0, 1.0), wo[:1], quadrature=(256, 512))
    np.testing.assert_allclose(tent, 1.0 - 2.0 / np.pi, atol=2e-3)
    view = np.tile(wo[1], (3, 1))  # 45° from the normal: its mirror direction is 45° up on the other side
    light = np.array([[-np.sin(t), 0.0, np.cos(t)] for t in np.radians([45.0, 89.0, 10.0])])
    f_cos = closures_np.glossy_toon(light, view, 0.0, 1.0)[:, 0] * light[:, 2]
    expected = np.array([1.0, 1.0 - 44.0 / 90.0, 1.0 - 35.0 / 90.0]) / (2.0 * np.pi)  # size 0 is 1e-5 in Cycles
    np.testing.assert_allclose(f_cos, expected, rtol=1e-4)  # at 89° (grazing) too: no masking
    assert closures_np.glossy_toon(-light, view, 0.0, 1.0).max() == 0.0  # light from below


def test_the_fit_of_a_rough_bottom_under_a_smooth_top_takes_the_toon_lobes(shared_fits):
    """smooth_over_rough's wide ENDF lobes keep light at grazing incidence, which the Beckmann closures' masking takes
    away: the fit with the Toon lobes in its dictionary replaces the reflection orders by them and brings the sphere
    and the plane within the issue's 15% (from 27.5% and 16.9% without them)."""
    p = _preset(thin_coat, "smooth_over_rough")
    chosen = choice.choose(thin_coat.ID, p, "osl", "auto")
    assert chosen.used == "fitted" and chosen.variant.toons
    assert {kind for kind, _ in chosen.fit.extras} & {"glossy_toon", "diffuse_toon"}
    assert chosen.errors["fitted"]["sphere"] < 0.15 and chosen.errors["fitted"]["plane"] < 0.15


def test_the_choice_keeps_the_fit_without_toon_lobes_where_they_mislead(shared_fits):
    """The Toon lobes lower leaf's fit in the fit's own measure (its quadrature) but raise its comparison scenes'
    error: each variant is measured on the scenes, and the Fitted mapping is the closest (not one with toons)."""
    p = _preset(spongecake, "leaf")
    chosen = choice.choose(spongecake.ID, p, "osl", "fitted")
    assert not chosen.variant.toons
    shaders = {v.label: ("osl", choice.fit_for(spongecake.ID, p, "osl", v)) for v in choice.VARIANTS if v.toons}
    errors, means = choice.comparison_errors(spongecake.ID, p, shaders)
    assert all(choice.counted(errors[label], means) > chosen.error["fitted"] for label in shaders)


def test_the_fit_solves_on_one_blas_thread_and_gives_the_count_back(monkeypatch):
    """The fit's thousands of small solves run on one OpenBLAS thread (a threaded solve waits for a busy core, as in
    Blender beside a render), and the caller's thread count is restored after the fit."""
    threads = fitted.openblas_threads()
    if threads is None:
        pytest.skip("numpy uses another BLAS than its own OpenBLAS")
    get, put = threads
    seen = []
    solve = fitted.nnls_gram
    monkeypatch.setattr(fitted, "nnls_gram", lambda *a, **k: seen.append(get()) or solve(*a, **k))
    before = get()
    put(2)
    try:
        choice.fit_for(thin_coat.ID, _preset(thin_coat, "glazed_ceramic"), "osl")
        assert seen and set(seen) == {1}
        assert get() == 2
    finally:
        put(before)


@pytest.mark.parametrize("model, name", [(thin_coat, "varnished_metal"), (spongecake, "leaf"), (spongecake, "fabric")])
def test_folded_colours_render_the_same_at_the_knots_with_fewer_operations(model, name, shared_fits):
    """Where an atom's colour follows the view's elevation alone, its table carries colour × scale
    (``fitted.folded_colours``): the closures are the same at the knots' views, and the colour's arithmetic is gone
    from the shader. fabric's oriented fibers see the view's azimuth: those atoms keep their colour math."""
    p = _preset(model, name)
    fit = choice.choose(model.ID, p, "osl", "fitted").fit
    knot_backend = lambda wo: nodes.numpy_backend(model.ID, p, "osl", wo)
    folded = fitted.folded_colours(nodes.MAPPINGS[model.ID], p, fit, knot_backend)
    rendered = {g for g, scales in enumerate(fit.scales) if scales.max() > 0.0}
    if name == "fabric":
        assert 0 < len(folded) < len(set(fit.groups))
    else:
        assert rendered <= set(folded)
    mu = fitted.view_cosines()
    wo = np.stack([np.sqrt(1.0 - mu * mu) * np.cos(0.4), np.sqrt(1.0 - mu * mu) * np.sin(0.4), mu], axis=1)

    def closures(fold):
        b = knot_backend(wo)
        scaled = fitted.ScaledBackend(b, fit, fitted.tables(b, fit))
        nodes.MAPPINGS[model.ID].shade(scaled, p)
        scaled.flush(folded if fold else None)
        return [np.broadcast_to(color, (len(wo), 3)) for _, color, _ in b.closures]

    for plain, with_fold in zip(closures(False), closures(True)):
        np.testing.assert_allclose(with_fold, plain, rtol=1e-9, atol=1e-12)
    def operations(fold):
        b = OslBackend([(s.name, s.kind, s.param.default) for s in nodes.MAPPINGS[model.ID].sockets(p)], "osl")
        scaled = fitted.ScaledBackend(b, fit, fitted.tables(b, fit))
        nodes.MAPPINGS[model.ID].shade(scaled, p)
        scaled.flush(folded if fold else None)
        return pruning.live_operations(b.lines, b.closures + [c for cs in b.lamberts.values() for c in cs])

    assert operations(True) < operations(False)
    if name != "fabric":
        assert budget.shader_size(model.ID, p, "osl", fit)[0] < budget.shader_size(model.ID, p, "osl", None)[0]
