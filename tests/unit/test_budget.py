"""Fit to budget (``addon.nodes.budget``): the choice stays within the budget of the most accurate configuration,
grows no more expensive as the budget grows, measures every variant against the material as set, and fitting
again after applying a decision chooses the same configuration."""
import math
from dataclasses import replace

import numpy as np
import pytest

from addon import presets
from addon.models import MODELS
from addon.nodes import budget


def preset(model_id: str, name: str):
    return MODELS[model_id].params_from_dict(presets.load(model_id, name))


@pytest.fixture(scope="module")
def varnished():
    """varnished_metal (2 bounces): its analytic configurations in both forms."""
    p = preset("thin_coat", "varnished_metal")
    return p, budget.candidates("thin_coat", p, ("nodes", "osl"), mappings=("analytic",))


@pytest.mark.parametrize("value", [0, -0.01, math.nan, math.inf, "2%", None])
def test_a_budget_that_is_not_a_positive_number_is_refused(value):
    with pytest.raises(budget.BudgetError, match="expected a number > 0"):
        budget.checked_budget(value)


def test_each_model_offers_its_cheaper_variants_only():
    coat = preset("thin_coat", "varnished_metal")
    assert [q.bounces for _, q in budget.variants("thin_coat", coat)] == [2, 0, 1]
    sponge = replace(preset("spongecake", "fabric"), multiple_scattering=True)
    assert [q.multiple_scattering for _, q in budget.variants("spongecake", sponge)] == [True, False]
    assert len(budget.variants("spongecake", replace(sponge, multiple_scattering=False))) == 1
    grains = preset("micrograin", "rust_on_metal")
    assert [q.gaf for _, q in budget.variants("micrograin", grains)] == ["series", "ggx"]
    assert len(budget.variants("aniso_stack", preset("aniso_stack", "carbon_fibre"))) == 1


def test_the_cost_model_counts_what_each_bounce_adds():
    coat = preset("thin_coat", "varnished_metal")
    sizes = [budget.shader_size("thin_coat", replace(coat, bounces=k), "osl") for k in range(5)]
    operations, closures = zip(*sizes)
    assert list(closures) == [1, 2, 3, 4, 5]  # the top, then one lobe per bounce (a conductor base)
    assert all(b > a for a, b in zip(operations, operations[1:]))
    seconds = [budget.COST["osl"].seconds(*s) for s in sizes]
    assert all(b > a for a, b in zip(seconds, seconds[1:]))


def test_every_variant_is_measured_against_the_material_as_set(varnished):
    p, cands = varnished
    by = {(c.variant, c.form): c for c in cands if c.pruned is None}
    assert len(by) == 6  # 3 variants x 2 forms, then their prunable closures left out
    assert {c.pruned.describe() for c in cands if c.pruned and c.variant == budget.AS_SET} == {"beckmann #3"}
    # the top interface alone misses the coat's subsurface light: far from the 2-bounce reference
    assert by[("0 bounces", "osl")].error > 10 * by[(budget.AS_SET, "osl")].error
    assert all(c.error >= 0 and math.isfinite(c.error) and c.seconds > 0 for c in cands)


@pytest.mark.parametrize("value", [0.001, 0.01, 0.02, 0.05, 0.1, 10.0])
def test_the_choice_is_the_cheapest_within_the_budget_of_the_most_accurate(varnished, value):
    _, cands = varnished
    chosen = budget.pick(cands, value)
    best = min(c.error for c in cands)
    assert chosen.error <= best + value and chosen.change <= value
    assert all(c.seconds >= chosen.seconds for c in cands if c.error <= best + value and c.change <= value)


def test_a_larger_budget_never_costs_more_and_the_smallest_keeps_the_most_accurate(varnished):
    _, cands = varnished
    costs = [budget.pick(cands, b).seconds for b in (1e-9, 0.01, 0.02, 0.05, 0.1, 1.0, 100.0)]
    assert all(b <= a for a, b in zip(costs, costs[1:]))
    assert budget.pick(cands, 1e-9).error == min(c.error for c in cands)
    assert budget.pick(cands, 100.0).seconds == min(c.seconds for c in cands)
    assert budget.pick(cands, 1e-9).pruned is None  # leaving the third bounce out changes the material


def test_fitting_again_after_applying_measures_against_the_material_as_set(varnished):
    p, _ = varnished
    first = budget.fit_to_budget("thin_coat", p, 0.1, ("nodes",), mappings=("analytic",))
    assert first.chosen.params.bounces < p.bounces  # a cheaper variant, else this test shows nothing
    record = first.to_json()
    applied = first.chosen.params
    # the values as the material holds them after the rebuild, the bounce count the decision's
    assert budget.target("thin_coat", applied, record) == p
    again = budget.fit_to_budget("thin_coat", budget.target("thin_coat", applied, record), 0.1, ("nodes",),
                                 current=(applied, "nodes", "analytic", first.chosen.pruned), mappings=("analytic",))
    assert again.chosen.to_json() == first.chosen.to_json()
    assert again.current is not None and again.current.to_json() == first.chosen.to_json()
    # an edit since (a value, not the structure) is kept; the bounce count goes back to the authored one
    edited = replace(applied, eta=1.7)
    assert budget.target("thin_coat", edited, record) == replace(p, eta=1.7)
    assert budget.target("thin_coat", p, None) == p


def test_the_decision_says_what_it_chose_and_what_it_costs(varnished):
    p, _ = varnished
    decision = budget.fit_to_budget("thin_coat", p, 0.02, ("nodes", "osl"), current=(p, "nodes", "analytic", None),
                                    mappings=("analytic",))
    text = decision.summary()
    assert decision.chosen.describe() in text and "budget +2%" in text and "× the current configuration" in text
    assert decision.chosen.error <= decision.best_error + 0.02
    with pytest.raises(budget.BudgetError):
        budget.fit_to_budget("thin_coat", p, 0.0, ("nodes",), mappings=("analytic",))


def test_the_measurement_reports_its_progress(varnished):
    p, _ = varnished
    seen = []
    budget.fit_to_budget("thin_coat", p, 0.02, ("nodes",), mappings=("analytic",), progress=seen.append)
    assert len(seen) > 2 and seen == sorted(seen) and seen[-1] == 1.0


def test_a_decision_on_a_camera_view_is_measured_there(varnished):
    """A camera that sees the comparison sphere's points (under its sun) measures the sphere's light: the sphere's
    own errors for a coat that lets nothing through (its view scenes differ from the sphere only below the
    surface), and the decision says where it was measured."""
    from addon.nodes import choice
    from addon.reference import scenes as S

    p, _ = varnished
    # 16 px (about 200 points) rather than the choice's 48: each point is measured on its own, so the view's errors
    # equal the sphere's at any size; a ninth of the points keeps the test in the unit suite's time
    sphere = S.sphere_scene(resolution=16)
    g = S.pixel_geometry(sphere)
    m = g["mask"]
    frames = np.concatenate([g["n"][m], g["t"][m], g["b"][m], g["wo"][m]], axis=1)
    view = budget.CameraView(tuple(map(tuple, frames)), sphere.suns[0].direction)
    decision = budget.fit_to_budget("thin_coat", p, 0.02, ("nodes",), mappings=("analytic",), view=view)
    assert decision.measured_on == f"the camera's view ({len(frames)} points)" and decision.measured_on in \
        decision.summary() and decision.to_json()["measured_on"] == decision.measured_on
    shaders = {"whole": ("nodes", None)}
    on_view = choice.comparison_errors("thin_coat", p, shaders, scenes=view.scenes())[0]["whole"]
    on_sphere = choice.comparison_errors("thin_coat", p, shaders, scenes=[sphere])[0]["whole"]
    assert on_view["camera, key light"] == pytest.approx(on_sphere["sphere"], rel=1e-9)
