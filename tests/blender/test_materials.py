"""Building Lamina materials in Blender: node groups reused per structure, OSL compiled, forms switchable."""
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import spongecake as model  # noqa: E402
from addon.nodes import material, osl  # noqa: E402

pytestmark = pytest.mark.blender


def _params(name):
    return model.params_from_dict(presets.load(model.ID, name))


@pytest.fixture(autouse=True)
def empty_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


@pytest.mark.parametrize("name", presets.names(model.ID))
def test_every_preset_builds_in_both_forms(name):
    p = _params(name)
    for form in material.FORMS:
        mat = material.new_material(model.ID, p, form, name=name)
        node = material.shader_node(mat)
        assert node.outputs["BSDF"].is_linked
        assert material.form_of(mat) == form
        assert material.current_params(mat)[1].layers[0].type == p.layers[0].type


def test_node_groups_are_reused_per_structure_not_duplicated():
    a = material.new_material(model.ID, _params("fabric"), "nodes")
    b = material.new_material(model.ID, _params("fabric"), "nodes")
    other = model.params_from_dict({**presets.load(model.ID, "fabric"), "delta_transmission": True})
    c = material.new_material(model.ID, other, "nodes")
    groups = [m.node_tree.nodes["Lamina"].node_tree for m in (a, b, c)]
    assert groups[0] is groups[1] is not groups[2]
    assert all(g.name.startswith("Lamina SpongeCake") for g in groups)
    assert len(bpy.data.node_groups) == 2


def test_group_interface_has_one_panel_per_layer_and_declared_ranges():
    group = material.node_group(model.ID, _params("plastic"))
    panels = [i.name for i in group.interface.items_tree if i.item_type == "PANEL"]
    assert panels == ["Layer 1", "Substrate"]
    thickness = next(i for i in group.interface.items_tree if i.name == "L1 Thickness")
    assert thickness.min_value == 0.0 and thickness.max_value == 1e4


def test_osl_form_keeps_readable_source_and_internal_bytecode():
    mat = material.new_material(model.ID, _params("leaf"), "osl")
    node = material.shader_node(mat)
    assert node.mode == "INTERNAL" and node.bytecode.startswith("OpenShadingLanguage")
    text = bpy.data.texts[node.label]
    assert "shader lamina_spongecake" in text.as_string()
    names = {p.name for p in osl.parse_params(node.bytecode) if not p.output}
    assert names == {s.name for s in node.inputs}
    assert node.inputs["LaminaTangent"].links[0].from_socket.name == "Tangent"


def test_switching_form_keeps_edited_values():
    mat = material.new_material(model.ID, _params("plastic"), "nodes")
    material.shader_node(mat).inputs["L1 Thickness"].default_value = 0.75
    material.set_form(mat, "osl")
    assert material.shader_node(mat).inputs["L1_Thickness"].default_value == pytest.approx(0.75)
    material.set_form(mat, "nodes")
    assert material.shader_node(mat).inputs["L1 Thickness"].default_value == pytest.approx(0.75)


def test_failed_generation_leaves_the_material_untouched(monkeypatch):
    mat = material.new_material(model.ID, _params("plastic"), "nodes")
    before = [n.bl_idname for n in mat.node_tree.nodes]

    def refuse(_):
        raise osl.OslCompileError("refused")

    monkeypatch.setattr(osl, "compile_source", refuse)
    with pytest.raises(osl.OslCompileError):
        material.set_form(mat, "osl")
    assert [n.bl_idname for n in mat.node_tree.nodes] == before
