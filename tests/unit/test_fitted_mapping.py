"""The fitted mapping (issue 14): the fitter recovers a mixture it generated, keeps the analytic mapping where that
is already close, is deterministic and cached, and stays finite and non-negative on bad materials."""
import numpy as np
import pytest

from addon import presets
from addon.models import spongecake, thin_coat
from addon.nodes import choice, fitted, predicted_eval, predicted_furnace
from addon.nodes.expr import NumpyBackend, OslBackend


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    """Each test fits into its own cache folder, with an empty memory cache."""
    monkeypatch.setenv("LAMINA_CACHE", str(tmp_path))
    monkeypatch.setattr(choice, "_fits", {})


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


def _subsets(n):
    return [tuple(i for i in range(n) if m >> i & 1) for m in range(1, 1 << n)]


@pytest.mark.parametrize("form", ["osl", "nodes"])
def test_the_fitter_recovers_a_mixture_it_generated(form):
    """A reference made of the plastic's own closures times known view tables, plus one dictionary closure with known
    weights, is fitted back: the same extra closure, every table within 1%."""
    p = _preset(spongecake, "plastic")
    mu = np.linspace(0.0, 1.0, fitted.KNOTS)
    groups = fitted.atom_groups(_backend_of(spongecake.ID, p, form))
    scales = np.stack([np.stack([0.6 + 0.3 * mu + 0.1 * c + 0.05 * j for c in range(3)], axis=1)
                       for j in range(max(groups) + 1)])
    extra = ("beckmann_refraction", {"alpha": 0.3, "ior": 10.0, "normal": "view"})
    weights = (0.02 + 0.05 * mu)[None, :, None] * np.array([1.0, 0.5, 0.2])
    truth = fitted.Fit(scales, (extra,), weights, 0.0, 0.0, groups)
    got = fitted.fit(_backend_of(spongecake.ID, p, form), predicted_eval(spongecake.ID, p, form, truth),
                     predicted_furnace(spongecake.ID, p, form, truth), form)
    assert got.extras == (extra,)
    assert got.error_fitted < 0.01
    # an atom that carries no light at a view is free there: compare where it does
    carried = np.zeros((len(scales), fitted.KNOTS))
    for k, m in enumerate(fitted.view_cosines()):
        recorded = _backend_of(spongecake.ID, p, form)(np.array([[np.sqrt(1 - m * m), 0.0, m]])).closures
        for g, (_, color, _) in zip(groups, fitted._fitted_closures(recorded)):
            carried[g, k] += np.abs(color).max()
    live = carried[:, :, None] > 1e-3 * carried.max()
    assert np.abs(np.where(live, got.scales / scales - 1.0, 0.0)).max() < 0.01
    assert np.abs(got.extra_weights / weights - 1.0).max() < 0.01



def test_auto_keeps_the_analytic_mapping_where_it_is_exact():
    """Thick flakes render within 0.1% analytically: Auto keeps that mapping (and says both errors)."""
    p = _preset(spongecake, "thick_flakes")
    chosen = choice.choose(spongecake.ID, p, "osl", "auto")
    assert chosen.used == "analytic" and chosen.fit is None
    assert chosen.error["analytic"] < 0.02
    assert "analytic" in chosen.summary() and "fitted" in chosen.summary()


def test_auto_takes_the_fitted_mapping_where_it_is_closer():
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


def test_a_changed_value_is_a_different_fit():
    p = _preset(thin_coat, "rough_over_smooth")
    q = thin_coat.params_from_dict({**p.to_dict(), "kappa_top": 11})
    assert choice.fit_key(thin_coat.ID, p, "osl") != choice.fit_key(thin_coat.ID, q, "osl")
    assert choice.fit_key(thin_coat.ID, p, "osl") != choice.fit_key(thin_coat.ID, p, "nodes")


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


def test_both_forms_get_the_tables():
    """The OSL source carries a constant array per table (16 colours); the numpy backend interpolates them, in
    √cos θo from the first knot's view to normal view."""
    p = _preset(thin_coat, "amber_lacquer")
    fit = choice.choose(thin_coat.ID, p, "osl", "fitted").fit
    b = OslBackend([(s.name, s.kind, s.param.default) for s in thin_coat_sockets(p)])
    fitted.shade(b, __import__("addon.nodes", fromlist=["MAPPINGS"]).MAPPINGS[thin_coat.ID], p, fit)
    source = b.source("t", "//")
    assert source.count(f"[{fitted.KNOTS}] = {{") == len(fit.scales) + len(fit.extras)
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
