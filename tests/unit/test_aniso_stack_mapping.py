"""The anisotropic-stack Cycles mapping (nodes/aniso_stack.py) in numpy: its sockets from the declaration, the table
fits, what it renders against the reference per preset and scene, its approximations, and the extremes.

Bounds are the errors measured by ``measured_errors`` (``python -m tests.unit.test_aniso_stack_mapping`` prints them)
with 25% + 0.005 headroom; Cycles renders these predictions (tests/blender/test_aniso_stack_cycles.py)."""
import numpy as np
import pytest

from addon import presets
from addon.models import aniso_stack as model
from addon.nodes import (MAPPINGS, closures_np, expr, predicted_furnace, predicted_image, principled_counterpart,
                         principled_models)
from addon.nodes import aniso_stack as mapping
from addon.reference import aniso_stack as reference
from addon.reference import metrics, scenes

PRESETS = presets.names(model.ID)
SCENES = {"sphere": scenes.sphere_scene(resolution=48), "plane": scenes.plane_scene(resolution=(48, 24))}
# Relative RMSE of the prediction (OSL; node groups on Blender 4.3+ the same but for metal-anisotropy-range, which no
# preset uses) against the reference, measured (sphere 48 px, plane 48 × 24).
MEASURED = {
    "brushed_steel_scratched_coat": (0.0101, 0.0052), "carbon_fibre": (0.0035, 0.0032),
    "forward_scattering": (0.0056, 0.0048), "frosted_metal": (0.0063, 0.0256), "gold_base": (0.0017, 0.0029),
    "metallic_paint": (0.0073, 0.0086), "rough_same_tangent": (0.0090, 0.0057), "rough_tangents_30": (0.0073, 0.0054),
    "rough_tangents_60": (0.0063, 0.0049), "rough_tangents_90": (0.0060, 0.0045),
    "smooth_coat_over_rough": (0.0156, 0.0101),
}
# Each approximation alone on its isolating configuration (sphere, plane), in the form that makes it.
MEASURED_APPROXIMATIONS = {"table-polynomials": (0.0037, 0.0066), "metal-anisotropy-range": (0.0891, 0.1014),
                           "top-fresnel-mean-blender-4.2": (0.0268, 0.0623)}
# The table fits against the reference's lookups (max, RMS absolute error at 4000 random points).
MEASURED_FITS = {("albedo",): (0.044, 0.0043), ("rule",): (0.31, 0.0104), ("fgd", 1.49): (0.037, 0.0029),
                 ("fgd", 1.2 / 1.49): (0.018, 0.0031), ("escape", 1.0 / 1.49): (0.109, 0.0085),
                 ("escape", 1.0 / 1.2): (0.098, 0.0079)}


def _bound(value: float) -> float:
    return 1.25 * value + 0.005


def _params(name_or_dict):
    data = presets.load(model.ID, name_or_dict) if isinstance(name_or_dict, str) else name_or_dict
    return model.params_from_dict(data)


def prediction_error(p, form: str, scene) -> float:
    reference_image = scenes.reference_image(scene, lambda wi, wo: reference.eval(p, wi, wo))
    return metrics.rel_rmse(predicted_image(model.ID, p, form, scene), reference_image, scenes.scene_mask(scene))


def approximation_error(name: str, scene) -> float:
    """The approximation alone: its configuration in the form that makes it (Blender 4.2's node group for the 4.2
    one) against the reference."""
    p = model.params_from_dict(mapping.APPROXIMATIONS[name][1])
    form = "osl" if name == "table-polynomials" else "nodes"
    metal = name != "top-fresnel-mean-blender-4.2"
    old, expr.NumpyBackend.metallic_node = expr.NumpyBackend.metallic_node, metal
    try:
        return prediction_error(p, form, scene)
    finally:
        expr.NumpyBackend.metallic_node = old


def measured_errors() -> dict:
    return {"presets": {name: tuple(round(prediction_error(_params(name), "osl", s), 4) for s in SCENES.values())
                        for name in PRESETS},
            "approximations": {name: tuple(round(approximation_error(name, s), 4) for s in SCENES.values())
                               for name in mapping.APPROXIMATIONS},
            "fits": {key: tuple(round(v, 4) for v in mapping.fit_error(*key).values()) for key in MEASURED_FITS}}


# ------------------------------------------------------------------------------------------ declaration

def test_registered_with_sockets_from_the_declaration():
    assert MAPPINGS[model.ID] is mapping
    p = _params("forward_scattering")
    assert [s.name for s in mapping.sockets(p)] == ["Alpha X 1", "Alpha Y 1", "Rotation 1", "Absorption 1", "Depth 1",
                                                   "Alpha X 2", "Alpha Y 2", "Rotation 2"]
    assert [s.name for s in mapping.sockets(_params("metallic_paint"))] == [
        "Alpha X 1", "Alpha Y 1", "Rotation 1", "Alpha X 2", "Alpha Y 2", "Rotation 2"]
    assert {s.panel for s in mapping.sockets(p)} == {"Interface 1", "Medium 1", "Interface 2"}


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_validates_and_round_trips_its_socket_values(name):
    data = presets.load(model.ID, name)
    assert data["description"] and model.validate(data).warnings == []
    p = _params(name)
    assert mapping.with_values(p, mapping.input_values(p)) == p


def test_structure_is_the_interface_types_and_iors_and_the_media_scattering():
    a, b = _params("rough_same_tangent"), _params("rough_tangents_90")
    assert mapping.structure_key(a) == mapping.structure_key(b)  # rotations and roughnesses are socket values
    assert mapping.structure_key(a) != mapping.structure_key(_params("gold_base"))
    assert mapping.structure_key(b) != mapping.structure_key(_params("forward_scattering"))


def test_demo_presets_are_marked():
    assert presets.demo_names(model.ID) == ["metallic_paint"]  # one stack keeps make demo near 8 minutes


def test_approximations_have_isolating_configs_and_are_named_where_used():
    for name, (what, config) in mapping.APPROXIMATIONS.items():
        assert what and name in mapping.approximations_used(model.params_from_dict(config))
    assert "table-polynomials" not in mapping.approximations_used(_params({"interfaces": [{"type": "conductor"}],
                                                                          "media": []}))


def test_principled_settings_use_the_stack_interfaces():
    s = mapping.principled_settings(_params("gold_base"))
    assert s["Metallic"] == 1.0 and s["Coat Weight"] == 1.0 and s["Coat IOR"] == pytest.approx(1.49)
    assert 0.0 < s["Anisotropic"] <= 1.0 and s["Anisotropic Rotation"] == pytest.approx(0.25)
    assert s["Base Color"][0] > s["Base Color"][2]  # gold
    alone = mapping.principled_settings(_params({"interfaces": [{"type": "dielectric", "ior": 1.5}], "media": []}))
    assert "Coat Weight" not in alone and alone["IOR"] == pytest.approx(1.5)


def test_the_principled_bsdf_is_declared_a_counterpart_from_the_registry():
    """Comparisons render the Principled BSDF beside thin coats and stacks (their ``PRINCIPLED``), not beside the
    models whose Principled only has about the same lobe count (bpy-free half of ``compare_run.has_principled``)."""
    assert principled_counterpart(model.ID) is mapping.PRINCIPLED and mapping.PRINCIPLED.label == "Principled BSDF"
    assert "Anisotropic" in mapping.PRINCIPLED.mapping and "\n" not in mapping.PRINCIPLED.mapping
    assert principled_counterpart("thin_coat").label == "Principled coat"
    assert principled_counterpart("spongecake") is None and principled_counterpart("micrograin") is None
    assert principled_models() == ["thin_coat", "aniso_stack"]


# ------------------------------------------------------------------------------------------ the tables

@pytest.mark.parametrize("key", sorted(MEASURED_FITS, key=repr))
def test_table_fits_are_close_to_the_reference_lookups(key):
    error = mapping.fit_error(*key)
    worst, rms = MEASURED_FITS[key]
    assert error["max"] < 1.25 * worst and error["rms"] < 1.25 * rms


def test_a_single_interface_is_the_exact_top_lobe():
    """No tables reach a single interface's closure: the prediction equals the reference."""
    p = _params({"interfaces": [{"type": "conductor", "alpha": [0.3, 0.05], "rotation": 30}], "media": []})
    assert prediction_error(p, "osl", SCENES["plane"]) < 1e-9


# ------------------------------------------------------------------------------------------ accuracy

@pytest.mark.parametrize("name", PRESETS)
def test_prediction_matches_the_reference(name):
    for (scene_name, scene), measured in zip(SCENES.items(), MEASURED[name]):
        err = prediction_error(_params(name), "osl", scene)
        assert err < _bound(measured), f"{name} {scene_name}: {err:.4f}"


@pytest.mark.parametrize("name", sorted(MEASURED_APPROXIMATIONS))
def test_each_approximation_alone(name):
    for (scene_name, scene), measured in zip(SCENES.items(), MEASURED_APPROXIMATIONS[name]):
        err = approximation_error(name, scene)
        assert err < _bound(measured), f"{name} {scene_name}: {err:.4f}"


EXTREMES = {
    "alpha 1e-4": {"interfaces": [{"type": "dielectric", "alpha": 1e-4}, {"type": "conductor", "alpha": 1e-4}]},
    "alpha 1": {"interfaces": [{"type": "dielectric", "alpha": 1.0}, {"type": "conductor", "alpha": 1.0}]},
    "ratio 1e-3": {"interfaces": [{"type": "dielectric", "alpha": [0.5, 5e-4], "rotation": 30},
                                  {"type": "conductor", "alpha": [5e-4, 0.5], "rotation": -45}]},
    "ior 1.0001": {"interfaces": [{"type": "dielectric", "ior": 1.0001}, {"type": "dielectric", "ior": 1.0002}]},
    "ior 3": {"interfaces": [{"type": "dielectric", "ior": 3.0}, {"type": "dielectric", "ior": 1.0001}]},
    "k 10": {"interfaces": [{"type": "conductor", "ior": [1.0, 1.0, 1.0], "k": [10.0, 10.0, 10.0]}], "media": []},
    "absorbing 100": {"interfaces": [{"type": "dielectric"}, {"type": "conductor"}],
                      "media": [{"sigma_a": [100.0, 1.0, 0.0], "depth": 1.0}]},
    "four interfaces": {"interfaces": [{"type": "dielectric", "ior": 1.3, "alpha": [0.2, 0.01], "rotation": 10},
                                       {"type": "dielectric", "ior": 2.0, "alpha": 0.5},
                                       {"type": "dielectric", "ior": 1.2, "alpha": [1e-4, 1.0], "rotation": 80},
                                       {"type": "conductor", "alpha": [0.05, 0.6]}],
                        "media": [{"sigma_a": [1, 2, 3], "depth": 0.5}, {"sigma_s": [5, 5, 5], "g": 0.9,
                                                                          "depth": 1.0}, {}]},
}


@pytest.mark.parametrize("name", sorted(EXTREMES))
@pytest.mark.parametrize("form", ["osl", "nodes"])
def test_extremes_are_finite_and_non_negative(name, form):
    p = _params(EXTREMES[name])
    rng = np.random.default_rng(3)
    wo, wi = (v / np.linalg.norm(v, axis=1, keepdims=True) * np.array([1, 1, 1]) for v in rng.normal(size=(2, 400, 3)))
    wo[:, 2], wi[:, 2] = np.abs(wo[:, 2]), np.abs(wi[:, 2])
    wo = np.vstack([wo, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])
    wi = np.vstack([wi, [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]])
    for metal in (True, False):
        b = expr.NumpyBackend(wo, mapping.input_values(p), form)
        b.metallic_node = metal
        mapping.shade(b, p)
        f = b.evaluate(wi)
        assert np.all(np.isfinite(f)) and f.min() >= 0.0, name


if __name__ == "__main__":
    import pprint

    pprint.pprint(measured_errors())


def test_a_near_mirror_top_lobe_counts_in_the_predicted_furnace():
    """The furnace prediction integrates the conductor closure over its visible normals: a coat of α 0.001 (which a
    direction grid misses) is in it, as in the reference's albedo."""
    p = model.params_from_dict(presets.load(model.ID, "smooth_coat_over_rough"))
    wo = np.array([[0.0, 0.0, 1.0], [np.sin(1.3), 0.0, np.cos(1.3)]])
    np.testing.assert_allclose(predicted_furnace(model.ID, p, "osl")(wo), reference.furnace_albedo(p, wo, n=4096),
                               rtol=0.02)
    rough = {"alpha_x": np.full(2, 0.3), "alpha_y": np.full(2, 0.1), "tangent": (1.0, 0.0, 0.0),
             "eta": (0.2, 0.5, 1.0), "k": (3.0, 2.5, 2.0)}
    nq = 2 * 64 * 128
    grid = scenes.directional_albedo(lambda wi, w: closures_np.ggx_conductor(
        wi, w, **{**rough, "alpha_x": np.repeat(rough["alpha_x"], nq), "alpha_y": np.repeat(rough["alpha_y"], nq)}), wo)
    np.testing.assert_allclose(closures_np.ggx_conductor_albedo(wo, **rough), grid, rtol=1e-3)
