"""Cycles renders what the mapping predicts (both forms, every preset), matches the reference where the mapping
is exact, stays finite at the extremes, and a saved .blend renders the same without Lamina."""
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import spongecake as model  # noqa: E402
from addon.nodes import material, predicted_image  # noqa: E402
from addon.operators import blend_io  # noqa: E402
from addon.operators.cycles_render import render_cycles  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from addon.reference import spongecake as reference  # noqa: E402

from renders import renders_with_and_without_lamina  # noqa: E402

pytestmark = pytest.mark.blender
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENES = [S.sphere_scene(resolution=40), S.plane_scene(resolution=(40, 20)), S.backlit_scene(resolution=(40, 20))]
FURNACE = S.furnace_scene(resolution=(24, 12))


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def _render(p, form, spec, samples, tmp_path):
    mat = material.new_material(model.ID, p, form)
    img, _ = render_cycles(mat, spec, samples, 0, str(tmp_path / f"{spec.name}.exr"))
    return img


@pytest.mark.under_4_2_for("copper_flakes", "leaf", "fabric")
@pytest.mark.parametrize("name", presets.names(model.ID))
@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_cycles_renders_the_predicted_mapping(name, form, tmp_path):
    """The generated node group / OSL computes exactly the mapping's closures and weights (up to noise)."""
    p = model.params_from_dict(presets.load(model.ID, name))
    for spec in SCENES + [FURNACE]:
        # the furnace samples the world through the lobes, noisier than a sun: 4x the samples
        img = _render(p, form, spec, 128 if spec is FURNACE else 32, tmp_path)
        predicted = predicted_image(model.ID, p, form, spec)
        mask = S.scene_mask(spec)
        err = metrics.rmse(img, predicted, mask) / max(predicted[mask].mean(), 1e-3)
        assert err < 0.02, f"{name} {form} {spec.name}: {err:.4f}"


@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_thick_surface_layer_renders_like_the_reference(form, tmp_path):
    """The calibration case: the mapping is exact, so Cycles must match the reference to noise (≤ 3%)."""
    p = model.params_from_dict(presets.load(model.ID, "thick_flakes"))
    for spec in SCENES[:2] + [S.furnace_scene(resolution=(32, 16))]:
        img = _render(p, form, spec, 64, tmp_path)
        ref = S.reference_image(spec, lambda wi, wo: reference.eval(p, wi, wo),
                                bsdf_albedo=lambda wo: reference.furnace_albedo(p, wo))
        assert metrics.rel_rmse(img, ref, S.scene_mask(spec)) < 0.03, spec.name


# Orientations off the normal (every preset has flakes along n or fibers in the tangent plane): a tilted
# closure normal is foreshortened and bent by Cycles (closures_np), tilted fibers keep the shading normal.
TILTED = {
    "thick-flakes": {"layers": [{"type": "surface", "roughness": 0.3, "thickness": 1e4, "albedo": [1, 1, 1],
                                 "orientation": [0.5, 0.0, 0.866]}]},
    "flakes-f0": {"layers": [{"type": "surface", "roughness": 0.3, "thickness": 1.0, "albedo": [0.8, 0.6, 0.4],
                              "f0": [0.2, 0.2, 0.2], "orientation": [-0.4, 0.3, 0.5]}]},
    "thick-fiber": {"layers": [{"type": "fiber", "roughness": 0.3, "thickness": 1e4, "albedo": [1, 1, 1],
                                "orientation": [0.707, 0.0, 0.707]}]},
    "flakes-below": {"layers": [{"type": "surface", "roughness": 0.3, "thickness": 1e4, "albedo": [1, 1, 1],
                                 "orientation": [0.5, 0.0, -0.866]}]},  # two-sided: mapped as -n
    "fiber-over-flakes": {"layers": [{"type": "fiber", "roughness": 0.5, "thickness": 1.0,
                                      "orientation": [-0.3, 0.6, 0.5]},
                                     {"type": "surface", "roughness": 0.2, "thickness": 1e3,
                                      "orientation": [0.0, -0.6, 0.8]}]},
}


@pytest.mark.parametrize("name", TILTED)
@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_cycles_renders_the_prediction_for_tilted_flakes_and_fibers(name, form, tmp_path):
    p = model.params_from_dict(TILTED[name])
    for spec in SCENES[:2]:
        img = _render(p, form, spec, 32, tmp_path)
        predicted = predicted_image(model.ID, p, form, spec)
        mask = S.scene_mask(spec)
        err = metrics.rmse(img, predicted, mask) / max(predicted[mask].mean(), 1e-3)
        assert err < 0.02, f"{name} {form} {spec.name}: {err:.4f}"


def _furnace_leak(p, form, spec):
    """Blender 4.2's extra furnace light from GGX samples below a tilted closure normal (H x W x 3)."""
    from addon import nodes
    from addon.nodes import expr
    from addon.nodes import spongecake as mapping

    g = S.pixel_geometry(spec)
    b = expr.NumpyBackend(g["wo"].reshape(-1, 3), nodes.input_values("spongecake", p, form), form)
    mapping.shade(b, p)
    return spec.environment * b.sampling_leak_blender42().reshape(g["wo"].shape)


@pytest.mark.parametrize("name", ["thick-flakes", "flakes-f0", "flakes-below", "thick-fiber"])
@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_tilted_flakes_in_the_furnace_render_the_prediction_and_4_2s_sampling_leak(name, form, tmp_path):
    """Under environment light Blender 4.2 also gathers light below a tilted GGX normal through BSDF sampling
    (its sampling does not test the closure normal; 5.0's does): the prediction plus that modelled leak."""
    p = model.params_from_dict(TILTED[name])
    spec = S.furnace_scene(resolution=(16, 8))
    img = _render(p, form, spec, 512, tmp_path)
    predicted = predicted_image(model.ID, p, form, spec)
    leak = _furnace_leak(p, form, spec)
    if name == "thick-fiber":
        assert np.abs(leak).max() < 1e-12  # fibers keep the shading normal: nothing below it
    else:
        assert leak.mean() > 0.01 * predicted.mean()  # large enough that the test can tell
    if bpy.app.version < (5, 0):  # 4.2 checked (4.3-4.5 not)
        predicted = predicted + leak
    mask = S.scene_mask(spec)
    err = metrics.rmse(img, predicted, mask) / predicted[mask].mean()
    assert err < 0.01, f"{name} {form}: {err:.4f}"


EXTREMES = [
    {"layers": [{"type": "surface", "roughness": 1e-4, "thickness": 1e3, "f0": [0, 0, 0]}]},
    {"layers": [{"type": "surface", "roughness": 1.0, "thickness": 1e-6}], "delta_transmission": True},
    {"layers": [{"type": "fiber", "roughness": 1e-4, "thickness": 1e3, "orientation": [1, 0, 0]},
                {"type": "fiber", "roughness": 1e-4, "thickness": 1e-6, "orientation": [0, 0, 1]}]},
    {"layers": [{"type": "hg", "roughness": 0.99, "thickness": 1e3}, {"type": "hg", "roughness": -0.99,
                                                                        "thickness": 1e-6}],
     "substrate": {"type": "conductor", "roughness": 1e-4}},
    {"layers": [{"type": "surface", "roughness": 1e-4, "thickness": 1e-6, "f0": [1, 0, 0]},
                {"type": "hg", "roughness": 0.0, "thickness": 1e4}], "substrate": {"type": "dielectric"}},
]


@pytest.mark.parametrize("config", EXTREMES, ids=range(len(EXTREMES)))
@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_extreme_parameters_render_finite_non_negative_pixels(config, form, tmp_path):
    p = model.params_from_dict(config)
    for spec in SCENES + [FURNACE]:
        img = _render(p, form, spec.with_resolution(24, 24 if spec.kind == "sphere" else 12), 8, tmp_path)
        assert np.all(np.isfinite(img)) and np.all(img >= 0), spec.name


@pytest.mark.parametrize("model_id, name", [("spongecake", "leaf"), ("micrograin", "mud_on_plastic"),
                                           ("thin_coat", "varnished_metal")])
@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_saved_blend_renders_the_same_without_lamina(form, model_id, name, tmp_path):
    """Rendered here (Lamina loaded) and in a fresh process where Lamina cannot even be imported (the porous
    layer's bulk is a second Lamina node: SpongeCake plastic)."""
    from addon.models import MODELS

    blend = tmp_path / "m.blend"
    p = MODELS[model_id].params_from_dict(presets.load(model_id, name))
    blend_io.write_material_blend(model_id, p, form, name, str(blend))
    a, b = renders_with_and_without_lamina(blend, f"Lamina {name}", tmp_path)
    assert a.mean() > 1e-3
    np.testing.assert_array_equal(a, b)


def test_a_node_group_computes_each_pure_operation_once():
    """The same Math / Vector Math operation on the same inputs is one node (Cycles' SVM evaluates every node), and
    a different operand is a node of its own."""
    import bpy
    from addon.nodes.node_backend import NodeBackend

    tree = bpy.data.node_groups.new("lamina cse test", "ShaderNodeTree")
    try:
        b = NodeBackend(tree, tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput"))
        mu = b.cos_view()
        once = b.sqrt(mu) * 2.0
        made = len(tree.nodes)
        again = b.sqrt(mu) * 2.0
        assert again.socket == once.socket and len(tree.nodes) == made
        assert (b.sqrt(mu) * 3.0).socket != once.socket and len(tree.nodes) == made + 1
    finally:
        bpy.data.node_groups.remove(tree)


def test_an_operation_with_its_identity_makes_no_node():
    """a · 1, 1 · a, a / 1, a + 0, 0 + a and a − 0 are a itself, for floats and colours (a node on a varying value is
    a node Cycles evaluates at every shading point); 1 / a and 0 − a are operations."""
    import bpy
    from addon.nodes.node_backend import NodeBackend

    tree = bpy.data.node_groups.new("lamina identity test", "ShaderNodeTree")
    try:
        b = NodeBackend(tree, tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput"))
        mu, view = b.cos_view(), b.view()
        made = len(tree.nodes)
        for a in (mu, view):
            assert all(x is a for x in (a * 1.0, 1.0 * a, a / 1.0, a + 0.0, 0.0 + a, a - 0.0))
        assert b.scale(view, 1.0) is view and len(tree.nodes) == made
        assert (1.0 / mu) is not mu and (0.0 - mu) is not mu and len(tree.nodes) == made + 2
    finally:
        bpy.data.node_groups.remove(tree)


def test_a_shared_computation_is_one_nested_group_that_every_tree_reuses():
    """``NodeBackend.shared`` builds its body once, as a nested group whose outputs are the body's values (a float and
    a colour here), and each tree that calls it gets one Group node of it, linked to the arguments, instead of the
    body's nodes. The group's name carries the generator's version, so a file made by a Lamina whose body differed
    keeps its own group and gets a new one."""
    import bpy
    from addon.nodes.node_backend import GENERATOR_VERSION, NodeBackend

    def body(b, x, c):
        return [b.sqrt(x) * 2.0, b.scale(c, x)]

    asked = "lamina shared test"
    name = f"{asked} (v{GENERATOR_VERSION})"
    earlier = bpy.data.node_groups.new(f"{asked} (v{GENERATOR_VERSION - 1})", "ShaderNodeTree")
    trees = [bpy.data.node_groups.new(f"lamina caller {i}", "ShaderNodeTree") for i in range(2)]
    try:
        for tree in trees:
            b = NodeBackend(tree, tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput"))
            mu = b.cos_view()
            made = len(tree.nodes)
            out = b.shared(asked, body, mu, (0.2, 0.4, 0.6))
            assert [v.kind for v in out] == ["float", "color"]
            assert len(tree.nodes) == made + 1
            call = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeGroup")
            assert call.node_tree.name == name and call.inputs[0].links[0].from_socket == mu.socket
            assert tuple(call.inputs[1].default_value) == pytest.approx((0.2, 0.4, 0.6))
            assert [v.socket for v in out] == list(call.outputs)
        shared = bpy.data.node_groups[name]
        assert sum(g.name.startswith(name) for g in bpy.data.node_groups) == 1 and earlier.users == 0
        kinds = {n.bl_idname for n in shared.nodes}
        assert {"ShaderNodeMath", "ShaderNodeVectorMath"} <= kinds
        assert all(s.is_linked for s in shared.nodes["Group Output"].inputs[:2])
    finally:
        for tree in trees + [earlier]:
            bpy.data.node_groups.remove(tree)
        if name in bpy.data.node_groups:
            bpy.data.node_groups.remove(bpy.data.node_groups[name])
