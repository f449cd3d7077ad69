"""Lobe pruning (``addon.nodes.pruning``): a pruned material renders its closures but the listed ones (what Cycles
renders is linear in its closures), the sets offered leave out the weakest closures first and never more than
``MAX_SHARE`` of the material's albedo, the cost counts only what feeds a closure of the form's own shader, and Fit
to budget keeps a pruned configuration only within the budget of the same configuration with every closure."""
import numpy as np
import pytest

from addon import presets
from addon.models import MODELS
from addon.nodes import _backend, budget, predicted_eval, predicted_furnace, pruning


def preset(model_id: str, name: str):
    return MODELS[model_id].params_from_dict(presets.load(model_id, name))


def directions(n: int, seed: int, upper: bool = False):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if upper:
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v


@pytest.mark.parametrize("model_id, name", [("spongecake", "window_shade"), ("thin_coat", "varnished_metal"),
                                            ("micrograin", "dust_on_wood")])
@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_a_pruned_material_is_the_whole_less_the_closures_left_out(model_id, name, form):
    p = preset(model_id, name)
    n = len(pruning.call_kinds(model_id, p, form))
    wi, wo = directions(200, 1), directions(200, 2, upper=True)
    whole = predicted_eval(model_id, p, form)(wi, wo)
    parts = sum(predicted_eval(model_id, p, form, pruning.Pruned(tuple(j for j in range(n) if j != i)))(wi, wo)
                for i in range(n))
    np.testing.assert_allclose(parts, whole, rtol=1e-9, atol=1e-12)
    dropped = pruning.Pruned((n - 1,), ("last",))
    assert _backend(model_id, p, form, wo[:1], dropped).closure_count() <= _backend(model_id, p, form,
                                                                                    wo[:1]).closure_count()


def test_the_sets_offered_are_nested_weakest_first_and_within_the_share():
    p = preset("spongecake", "window_shade")
    energy = pruning.lobe_energies("spongecake", p, "osl")
    albedo = np.max(predicted_furnace("spongecake", p, "osl")(pruning.views()))
    sets = pruning.prunable("spongecake", p, "osl")
    assert len(sets) >= 2
    for smaller, larger in zip(sets, sets[1:]):
        assert set(smaller.calls) < set(larger.calls)
    for s in sets:
        assert energy[list(s.calls)].sum() <= pruning.MAX_SHARE * albedo
        kept = [i for i in range(len(energy)) if i not in s.calls]
        assert energy[list(s.calls)].max() <= energy[kept].min()
    # a closure that carries nothing (a layer's zero diffuse share here) is the first to go, and costs no error
    assert energy[list(sets[0].calls)].max() == 0.0


def test_the_cost_counts_only_what_feeds_a_closure():
    lines = ["float t1 = 1.0;", "float t2 = t1 * 2.0;", "float t3 = t1 + 5.0;", "color t4 = color(t2);"]
    assert pruning.live_operations(lines, ["t4 * diffuse(N)"]) == 3
    assert pruning.live_operations(lines, ["t3 * diffuse(N)", "t3 * translucent(N)"]) == 2
    assert pruning.live_operations(lines, []) == 0
    p = preset("thin_coat", "varnished_metal")
    third = pruning.Pruned((2,), ("beckmann",))
    (whole_ops, whole_closures), (ops, closures) = (budget.shader_size("thin_coat", p, "osl", fit)
                                                    for fit in (None, third))
    assert closures == whole_closures - 1 and ops < whole_ops


def test_each_form_is_counted_in_its_own_closure_calls():
    """An anisotropic stack's node group adds a lobe where the Metallic BSDF is not anisotropic enough (the top's
    mean Fresnel), so its calls are metal, glossy, glossy where OSL's are metal, glossy: leaving out the node group's
    bottom lobe (its third call) takes the stack's arithmetic with it, leaving out the top's second lobe does not."""
    p = preset("aniso_stack", "carbon_fibre")
    assert pruning.call_kinds("aniso_stack", p, "nodes") == ["metal", "glossy", "glossy"]
    assert pruning.call_kinds("aniso_stack", p, "osl") == ["metal", "glossy"]
    whole, top, bottom = (budget.shader_size("aniso_stack", p, "nodes", fit) for fit in (
        None, pruning.Pruned((1,), ("glossy",)), pruning.Pruned((2,), ("glossy",))))
    osl_whole = budget.shader_size("aniso_stack", p, "osl")
    assert whole[0] > osl_whole[0] and whole[1] == 3
    assert bottom[0] < 0.5 * whole[0] < top[0] < whole[0]


def test_a_pruned_configuration_is_chosen_only_within_the_budget_of_its_whole():
    p = preset("spongecake", "window_shade")
    cands = budget.candidates("spongecake", p, ("osl",), mappings=("analytic",))
    pruned = [c for c in cands if c.pruned]
    assert pruned and all(c.change >= 0.0 for c in pruned)
    free = [c for c in pruned if c.change < 1e-12]  # the zero-energy closures: nothing changes
    assert free and all(c.seconds < next(w for w in cands if w.pruned is None).seconds for c in free)
    for value in (1e-6, 0.01, 0.05, 0.2):
        chosen = budget.pick(cands, value)
        assert chosen.change <= value and chosen.error <= min(c.error for c in cands) + value


def jittered(model_id: str, name: str, seed: int):
    """The preset ``name`` with every number scaled by a random factor in [0.5, 1.5] (colours and directions per
    channel), then clamped into the model's ranges by its own validation: a random material of the same structure."""
    rng = np.random.default_rng(seed)

    def jitter(value):
        if isinstance(value, dict):
            return {k: v if k in ("name", "description", "demo") else jitter(v) for k, v in value.items()}
        if isinstance(value, list):
            return [jitter(v) for v in value]
        if isinstance(value, float):
            return value * rng.uniform(0.5, 1.5)
        return value

    return MODELS[model_id].params_from_dict(jitter(presets.load(model_id, name)))


MATERIALS = [(m, presets.names(m)[0], None) for m in MODELS] + [
    ("spongecake", "leaf", 1), ("thin_coat", "varnished_metal", 2), ("micrograin", "rust_on_metal", 3)]


@pytest.mark.parametrize("model_id, name, seed", MATERIALS)
def test_pruning_stays_within_the_budget_across_presets_and_random_materials(model_id, name, seed):
    """What Fit to budget chooses is never further than the budget from the most accurate configuration, nor a
    pruned one more than the budget from its whole, and the closures it leaves out carry what ``lobe_energies``
    measured: at most ``MAX_SHARE`` of the material's albedo."""
    p = preset(model_id, name) if seed is None else jittered(model_id, name, seed)
    cands = budget.candidates(model_id, p, ("osl",), mappings=("analytic",))
    best = min(c.error for c in cands)
    albedo = float(np.max(predicted_furnace(model_id, p, "osl")(pruning.views())))
    energy = pruning.lobe_energies(model_id, p, "osl")
    for c in cands:
        if c.pruned and c.variant == budget.AS_SET:
            assert energy[list(c.pruned.calls)].sum() <= pruning.MAX_SHARE * albedo + 1e-12
    for value in (0.01, 0.02, 0.05, 0.1):
        chosen = budget.pick(cands, value)
        assert chosen.error <= best + value and chosen.change <= value
