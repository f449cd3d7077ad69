"""The sidebar panel on an anisotropic-stack material: a summary per interface and medium, the form switch, no
failure (bpy 5.0 and 4.2)."""
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import aniso_stack as model  # noqa: E402
from addon.nodes import material  # noqa: E402
from test_thin_coat_ui import _panel_text  # noqa: E402

pytestmark = pytest.mark.blender


def test_the_panel_summarises_the_stack_and_names_texture_driven_inputs(registered, sphere):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    p = model.params_from_dict(presets.load(model.ID, "forward_scattering"))
    mat = material.new_material(model.ID, p, "osl")
    text = _panel_text(mat)
    assert "anisotropic stack of 2 interface(s)" in text
    assert "1. Dielectric 1.49: α 0.3 × 0.05, rotation 0°" in text
    assert "2. Conductor 1+1i, 1+0i, 1+0i: α 0.3 × 0.05, rotation 90°" in text
    assert "medium: σa·d 0.01, 1, 0.01, scattering g 0.90" in text and "lamina.set_form" in text
    node = material.shader_node(mat)
    mat.node_tree.links.new(mat.node_tree.nodes.new("ShaderNodeTexImage").outputs["Color"], node.inputs["Rotation_2"])
    assert "Texture-driven: Rotation 2" in _panel_text(mat)
