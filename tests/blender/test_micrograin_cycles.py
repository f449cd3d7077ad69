"""Cycles renders what the micrograin mapping predicts (both forms, every preset), a texture can drive the filling
factor, and the extremes give no NaN, Inf or negative pixel."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import micrograin as model  # noqa: E402
from addon.nodes import material, predicted_image  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from renders import relative_error, render  # noqa: E402

pytestmark = pytest.mark.blender
SPHERE = S.sphere_scene(resolution=32)
BACKLIT = S.backlit_scene(resolution=(32, 16))
PLANE = S.plane_scene(resolution=(32, 16))
FURNACE = S.furnace_scene(resolution=(24, 12))


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


# Beyond the presets: dense metal grains, whose specular weight (G ratio ≥ 1) exceeds 1 at oblique views.
DENSE_METAL = {"filling_factor": 0.98, "anfractuosity": 1.0, "bulk": {"type": "diffuse", "albedo": [0.2, 0.2, 0.2]},
               "grain": {"type": "conductor", "ior": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.1]}}


@pytest.mark.under_4_2_for("rust_on_metal", "dirt_on_glass")
@pytest.mark.parametrize("name", presets.names(model.ID) + ["dense_metal"])
@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_cycles_renders_the_predicted_mapping(name, form, tmp_path):
    """The generated node group / OSL (and the bulk node under it) compute exactly the mapping's closures."""
    p = model.params_from_dict(DENSE_METAL if name == "dense_metal" else presets.load(model.ID, name))
    mat = material.new_material(model.ID, p, form)
    scenes = [SPHERE, FURNACE, PLANE] if name == "dense_metal" else [SPHERE, FURNACE]
    scenes += [BACKLIT] if p.bulk.type == "dielectric" else []
    for spec in scenes:
        img = render(mat, spec, 128 if spec is FURNACE else 32, tmp_path)
        err = relative_error(img, predicted_image(model.ID, p, form, spec), spec)
        assert err < _tolerance(p, spec, form), f"{name} {form} {spec.name}: {err:.4f}"


def _tolerance(p, spec, form) -> float:
    """2% everywhere, with two measured exceptions (the prediction models Blender 5.0's closures):
    * backlit glass: Cycles' rough refraction of light from inside the glass differs a little from Walter's (the
      numpy model): 2.3%, from views where numpy gives 0 and Cycles a faint 0.003;
    * Blender 4.2's conductor Fresnel is the approximate formula (exact in 5.0), off for conductors of small
      extinction k (soot, copper oxide; dielectric grains use k = 0): 2.3-4.1% in the furnace, where grazing
      angles count; and 4.2's node group draws metals as Principled with the normal-incidence F0
      (conductor-f0-blender-4.2, not predicted): 3.2% for dense gold-like grains.
    """
    if spec is BACKLIT:
        return 0.03
    old_metal = p.grain.type != "diffuse" and (min(p.grain.k) < 1.0 or form == "nodes")
    if bpy.app.version < (5, 0, 0) and old_metal:
        return 0.05
    return 0.02


EXTREMES = {
    "tau0=0": {"filling_factor": 0.0},
    "tau0=1e-6": {"filling_factor": 1e-6, "anfractuosity": 1e-3},
    "tau0=0.98,beta=1": {"filling_factor": 0.98, "anfractuosity": 1.0,
                         "grain": {"type": "dielectric", "albedo": [1, 1, 1], "ior": 1.0}},
    "tau0=0.98,beta=1e-3": {"filling_factor": 0.98, "anfractuosity": 1e-3,
                            "grain": {"type": "conductor", "ior": [1.0] * 3, "k": [0.0] * 3}},
    "tau0=0.5,beta=1e-3,glass": {"filling_factor": 0.5, "anfractuosity": 1e-3,
                                 "grain": {"type": "dielectric", "ior": 3.0},
                                 "bulk": {"type": "dielectric", "roughness": 1e-4, "ior": 1.0001}},
}


@pytest.mark.parametrize("form", ["nodes", "osl"])
@pytest.mark.parametrize("case", sorted(EXTREMES))
def test_extremes_render_finite_non_negative_pixels(case, form, tmp_path):
    p = model.params_from_dict(EXTREMES[case])
    mat = material.new_material(model.ID, p, form)
    scenes = (S.sphere_scene(resolution=24), S.plane_scene(resolution=(24, 12)), S.furnace_scene(resolution=(16, 8)))
    for spec in scenes:
        img = render(mat, spec, 16, tmp_path)
        assert np.isfinite(img).all() and (img >= 0).all(), f"{case} {form} {spec.name}"


@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_a_texture_drives_the_filling_factor(form, tmp_path):
    """A mask plugged into Filling Factor (here: object x > 0) renders each half as the constant it holds."""
    low, high = 0.1, 0.9
    base = {"grain": {"type": "diffuse", "albedo": [0.9, 0.8, 0.6]},
            "bulk": {"type": "diffuse", "albedo": [0.1, 0.1, 0.3]}}
    p = model.params_from_dict({**base, "filling_factor": low})
    mat = material.new_material(model.ID, p, form)
    tree = mat.node_tree
    coords = tree.nodes.new("ShaderNodeTexCoord")
    split = tree.nodes.new("ShaderNodeSeparateXYZ")
    mask = tree.nodes.new("ShaderNodeMapRange")
    mask.inputs["From Min"].default_value, mask.inputs["From Max"].default_value = -1e-4, 1e-4
    mask.inputs["To Min"].default_value, mask.inputs["To Max"].default_value = low, high
    tree.links.new(coords.outputs["Object"], split.inputs[0])
    tree.links.new(split.outputs["X"], mask.inputs["Value"])
    node = material.shader_node(mat)
    tree.links.new(mask.outputs["Result"], node.inputs["Filling Factor" if form == "nodes" else "Filling_Factor"])
    img = render(mat, SPHERE, 32, tmp_path)
    w = SPHERE.width
    for value, columns in ((low, slice(0, w // 2 - 2)), (high, slice(w // 2 + 2, w))):
        predicted = predicted_image(model.ID, model.params_from_dict({**base, "filling_factor": value}), form, SPHERE)
        inside = S.scene_mask(SPHERE)[:, columns]
        err = metrics.rmse(img[:, columns], predicted[:, columns], inside) / predicted[:, columns][inside].mean()
        assert err < 0.02, f"filling factor {value}: {err:.4f}"
