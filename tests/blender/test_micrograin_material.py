"""A porous layer's bulk node: rebuilt with the layer, left alone once the user plugs their own shader into Bulk,
and never half-rebuilt when generation fails."""
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import micrograin as model  # noqa: E402
from addon.nodes import material  # noqa: E402
from addon.operators import compare_run  # noqa: E402

pytestmark = pytest.mark.blender


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def _layer(form="nodes"):
    return material.new_material(model.ID, model.params_from_dict(presets.load(model.ID, "mud_on_plastic")), form)


def test_the_bulk_node_follows_the_layer_form():
    mat = _layer()
    material.set_form(mat, "osl")
    bulk = mat.node_tree.nodes[material.BULK_NODE]
    assert bulk.bl_idname == "ShaderNodeScript"
    assert material.shader_node(mat).inputs["Bulk"].links[0].from_node == bulk
    assert material.current_params(mat)[1].bulk.type == "spongecake"


def test_a_shader_plugged_into_bulk_by_the_user_becomes_the_bulk():
    mat = _layer()
    tree = mat.node_tree
    own = tree.nodes.new("ShaderNodeBsdfPrincipled")
    tree.links.new(own.outputs[0], material.shader_node(mat).inputs["Bulk"])
    _, p = material.current_params(mat)
    assert p.bulk.type == model.WRAPPED and compare_run.refusal(model.ID, p)
    material.set_form(mat, "osl")
    assert material.shader_node(mat).inputs["Bulk"].links[0].from_node == own


def test_a_failing_bulk_leaves_the_material_untouched(monkeypatch):
    mat = _layer()
    before = sorted((n.name, n.bl_idname) for n in mat.node_tree.nodes)
    stored = mat["lamina"]
    build = material._new_node

    def refuse_the_bulk(m, mapping_id, p, form, fit=None):
        if mapping_id != model.ID:
            raise RuntimeError("bulk generation failed")
        return build(m, mapping_id, p, form, fit)

    monkeypatch.setattr(material, "_new_node", refuse_the_bulk)
    with pytest.raises(RuntimeError, match="bulk generation failed"):
        material.set_form(mat, "osl")
    assert sorted((n.name, n.bl_idname) for n in mat.node_tree.nodes) == before and mat["lamina"] == stored
