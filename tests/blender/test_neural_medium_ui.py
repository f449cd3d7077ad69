"""Neural media as an artist meets them: the Add Neural Medium Material dialog (presets, coefficients or colour +
density, the scale), the material it adds and its undo, and the panel (the medium, its bake's state, where the bake
is stored, the volume-bounce warning, the Bake button)."""
import json

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import neural_medium as model  # noqa: E402
from addon.nodes import neural_medium as medium_nodes  # noqa: E402
from addon.operators import neural_medium as dialog_module  # noqa: E402
from ui_helpers import bind, dialog, draw_dialog, operators, panel_log, panel_text, text  # noqa: E402

pytestmark = pytest.mark.blender
OP = dialog_module.LAMINA_OT_add_neural_medium


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _dict(**values) -> dict:
    ns = dialog("add_neural_medium", **values)
    return bind(OP, ns, ("medium_dict",)).medium_dict()


def test_a_preset_keeps_its_medium_and_takes_the_dialogs_scale(registered):
    assert _dict(preset="milk", scale=0.2) == {**presets.load(model.ID, "milk"), "scale": 0.2}


def test_custom_coefficients_and_colour_with_density(registered):
    d = _dict(preset="CUSTOM", sigma_s=(1.0, 2.0, 3.0), sigma_a=(0.1, 0.2, 0.3), g=0.4, scale=2.0)
    assert d == {"sigma_s": [1.0, 2.0, 3.0], "sigma_a": [0.1, 0.2, 0.3], "g": pytest.approx(0.4), "scale": 2.0}
    d = _dict(preset="CUSTOM", input_mode="color_density", color=(0.9, 0.5, 0.0), density=10.0)
    p = model.params_from_dict(d)
    np.testing.assert_allclose(p.albedo, [0.9, 0.5, 0.0], atol=1e-6)
    np.testing.assert_allclose(p.sigma_t, [10.0] * 3, rtol=1e-6)


def test_the_dialog_shows_albedo_and_mean_free_path(registered):
    ns = dialog("add_neural_medium", preset="cloud", scale=0.5)
    shown = text(draw_dialog(OP, ns, ("medium_dict", "params_or_none", "source_volume", "use_volume", "draw_medium")))
    assert "Albedo" in shown and "mean free path" in shown and "scale" in shown


def _closed_ball():
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8)
    return bpy.context.active_object


def test_the_dialog_adds_a_material_and_undo_removes_it(registered):
    ball = _closed_ball()
    bpy.ops.ed.undo_push(message="before")
    assert bpy.ops.lamina.add_neural_medium(preset="candle", scale=0.1) == {"FINISHED"}
    bpy.ops.ed.undo_push(message=OP.bl_label)
    mat = ball.material_slots[0].material
    assert medium_nodes.is_medium(mat) and json.loads(mat[medium_nodes.PROPERTY])["scale"] == pytest.approx(0.1)
    bpy.ops.ed.undo()
    assert not any(medium_nodes.is_medium(m) for m in bpy.data.materials)


def test_the_panel_shows_the_medium_and_its_bake(registered):
    ball = _closed_ball()
    bpy.ops.lamina.add_neural_medium(preset="milk", scale=0.05)
    mat = ball.material_slots[0].material
    shown = panel_text(mat)
    assert "neural medium" in shown and "Albedo 0.999" in shown and "Not baked" in shown
    assert "Stored in the mesh" in shown and "0 lamp(s)" in shown
    assert "Volume bounces" not in shown
    assert operators(panel_log(mat))["lamina.bake_medium"]
    bpy.context.scene.cycles.volume_bounces = 2
    assert "Volume bounces = 2" in panel_text(mat)  # a warning; the setting stays the user's
    assert bpy.context.scene.cycles.volume_bounces == 2


def _volume_material(kind: str):
    mat = bpy.data.materials.new(f"my {kind}")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    if kind == "principled":
        v = tree.nodes.new("ShaderNodeVolumePrincipled")
        v.inputs["Color"].default_value = (0.9, 0.5, 0.2, 1.0)
        v.inputs["Density"].default_value = 4.0
        v.inputs["Anisotropy"].default_value = 0.3
        v.inputs["Absorption Color"].default_value = (0.25, 0.0, 1.0, 1.0)
        tree.links.new(v.outputs[0], out.inputs["Volume"])
    else:
        scatter, absorb = tree.nodes.new("ShaderNodeVolumeScatter"), tree.nodes.new("ShaderNodeVolumeAbsorption")
        scatter.inputs["Color"].default_value = (0.8, 0.6, 0.4, 1.0)
        scatter.inputs["Density"].default_value = 2.0
        absorb.inputs["Color"].default_value = (0.5, 0.5, 1.0, 1.0)
        absorb.inputs["Density"].default_value = 0.2
        add = tree.nodes.new("ShaderNodeAddShader")
        tree.links.new(scatter.outputs[0], add.inputs[0])
        tree.links.new(absorb.outputs[0], add.inputs[1])
        tree.links.new(add.outputs[0], out.inputs["Volume"])
    return mat


def test_a_homogeneous_volume_converts_to_the_same_medium(registered):
    """Principled Volume as Cycles computes it: sigma_s = Color x Density, sigma_a = (1 - Color)(1 - sqrt(Absorption
    Color)) x Density; Scatter + Absorption: Color x Density and (1 - Color) x Density."""
    ball = _closed_ball()
    ball.data.materials.append(_volume_material("principled"))
    assert bpy.ops.lamina.add_neural_medium(scale=1.0) == {"FINISHED"}
    p = medium_nodes.current_params(ball.material_slots[0].material)
    np.testing.assert_allclose(p.sigma_s, [3.6, 2.0, 0.8], rtol=1e-5)
    np.testing.assert_allclose(p.sigma_a, [0.1 * 0.5 * 4.0, 0.5 * 1.0 * 4.0, 0.0], atol=1e-5)
    assert p.g == pytest.approx(0.3) and "my principled" in bpy.data.materials  # the original stays
    ball.material_slots[0].material = _volume_material("pair")
    pair = medium_nodes.volume_of(ball.material_slots[0].material)
    np.testing.assert_allclose(pair["sigma_s"], [1.6, 1.2, 0.8], rtol=1e-6)
    np.testing.assert_allclose(pair["sigma_a"], [0.1, 0.1, 0.0], atol=1e-6)
    plain = bpy.data.materials.new("plain")
    assert medium_nodes.volume_of(plain) is None
