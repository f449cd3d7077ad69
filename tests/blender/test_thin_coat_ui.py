"""Thin coats as an artist meets them: the Add Thin Coat Material dialog (properties from the declaration, presets,
Custom with κ beside each roughness, every base), the material it adds and its undo, and the N-panel summary."""
import math

import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import thin_coat as model  # noqa: E402
from addon.nodes import MAPPINGS  # noqa: E402
from addon.nodes import material  # noqa: E402
from addon.models.metals import METALS  # noqa: E402
from addon.operators import material_ops  # noqa: E402
from addon.operators import thin_coat as dialog_module  # noqa: E402
from ui_helpers import dialog, draw_dialog, panel_text, text  # noqa: E402

pytestmark = pytest.mark.blender
OP = dialog_module.LAMINA_OT_add_thin_coat


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _dialog(registered, **values):
    return dialog("add_thin_coat", **values)


def _draw(ns) -> str:
    return text(draw_dialog(OP, ns, ("_draw_preset", "_draw_custom", "coat_dict")))


def test_the_dialog_properties_come_from_the_declaration(registered):
    rna = bpy.ops.lamina.add_thin_coat.get_rna_type().properties
    bounces = rna["bounces"]
    assert bounces.type == "INT" and (bounces.hard_min, bounces.hard_max, bounces.default) == (0, 4, 2)
    assert rna["merge_orders"].type == "BOOLEAN" and rna["merge_orders"].default is False
    eta = rna["eta"]
    assert (eta.hard_min, eta.hard_max, eta.default) == pytest.approx((1.0001, 3.0, 1.5))
    top = rna["roughness_top"]
    assert top.default == pytest.approx(math.sqrt(2.0 / 1e4)) and top.soft_max == 1.0
    assert [i.identifier for i in rna["preset"].enum_items] == [material_ops.CUSTOM] + presets.names(model.ID)
    for item in rna["preset"].enum_items[1:]:
        assert item.description == presets.description(model.ID, item.identifier)
    assert {i.identifier for i in rna["base_type"].enum_items} == set(model.BASE_TYPES)
    assert "UNDO" in OP.bl_options and "REGISTER" in OP.bl_options


@pytest.mark.parametrize("base", model.BASE_TYPES)
def test_custom_settings_make_a_clean_dict_for_every_base(registered, base):
    ns = _dialog(registered, base_type=base, roughness_top=0.1, roughness_bottom=0.2,
                 coat_color=(0.5, 0.8, 1.0), depth=0.25, bounces=3)
    v = model.validate(OP.coat_dict(ns))
    assert v.warnings == []
    p = v.params
    assert p.base.type == base and p.bounces == 3 and p.kappa_top == pytest.approx(200.0, rel=1e-6)
    assert p.kappa_bottom == pytest.approx(50.0, rel=1e-6)
    assert [math.exp(-s) for s in p.sigma_a] == pytest.approx([0.5, 0.8, 1.0], rel=1e-6)  # colour per unit depth
    text = _draw(ns)
    assert "κ 200" in text and "κ 50" in text and "bounces" in text
    assert "the first carries most of the energy" in text
    if base == "diffuse":
        assert "no effect over a diffuse base" in text
    if base == "conductor":
        assert p.base.eta == pytest.approx(METALS["aluminium"][0])


def test_custom_metal_takes_its_complex_ior(registered):
    ns = _dialog(registered, base_type="conductor", metal=material_ops.CUSTOM, metal_ior=(1.0, 0.5, 0.25),
                 metal_k=(4.0, 3.0, 2.0))
    p = model.params_from_dict(OP.coat_dict(ns))
    assert p.base.eta == pytest.approx((1.0, 0.5, 0.25)) and p.base.k == pytest.approx((4.0, 3.0, 2.0))


@pytest.mark.parametrize("name", presets.names(model.ID))
def test_presets_load_with_their_description_and_the_dialogs_bounces(registered, name):
    ns = _dialog(registered, preset=name, bounces=1)
    data = OP.coat_dict(ns)
    expected = {k: v for k, v in presets.load(model.ID, name).items() if k != "description"}
    assert data == {**expected, "bounces": 1, "merge_orders": False}
    assert model.params_from_dict(OP.coat_dict(_dialog(registered, preset=name, merge_orders=True))).merge_orders
    text = _draw(ns)
    p = model.params_from_dict(data)
    assert presets.description(model.ID, name) in text
    assert dialog_module.kappa_text(p.kappa_top) in text and f"η {p.eta:.2f}" in text


def test_kappa_is_shown_the_way_artists_read_it():
    assert dialog_module.kappa_text(200.0) == "κ 200" and dialog_module.kappa_text(2e4) == "κ 20000"
    assert dialog_module.kappa_text(1e6) == "κ 1e+06"
    assert material_ops.sigma_a_from_color((1.0, 0.0, math.exp(-2.0)), model.LAYER) == pytest.approx([0.0, 1000.0, 2.0])


# ------------------------------------------------------------------------------------ with the mapping


def test_the_dialog_adds_a_material_and_undo_removes_it(registered, sphere):
    mine = bpy.data.materials.new("My paint")
    sphere.data.materials.append(mine)
    bpy.ops.ed.undo_push(message="before")
    assert bpy.ops.lamina.add_thin_coat(preset="varnished_metal", form="nodes") == {"FINISHED"}
    bpy.ops.ed.undo_push(message=OP.bl_label)  # what Blender does after an UNDO operator from the UI
    new = bpy.data.objects["ball"].material_slots[0].material
    assert material.is_lamina(new) and new.name == "Thin Coat Varnished metal"
    model_id, p = material.current_params(new)
    assert model_id == model.ID and _same(p, model.params_from_dict(presets.load(model.ID, "varnished_metal")))
    assert bpy.data.materials.get("My paint") is not None  # kept in the file, untouched
    bpy.ops.ed.undo()
    assert [m.name for m in bpy.data.materials] == ["My paint"]
    assert bpy.data.objects["ball"].material_slots[0].material.name == "My paint"
    bpy.ops.ed.redo()
    assert "Thin Coat Varnished metal" in bpy.data.materials


def test_custom_coat_in_the_osl_form(registered, sphere):
    assert bpy.ops.lamina.add_thin_coat(base_type="slab", roughness_top=0.2, bounces=0, form="osl") == {"FINISHED"}
    mat = sphere.active_material
    _, p = material.current_params(mat)
    assert material.form_of(mat) == "osl" and p.base.type == "slab" and p.bounces == 0
    assert p.kappa_top == pytest.approx(50.0, rel=1e-5)


def _flat(d, prefix=""):
    if isinstance(d, dict):
        return {k: v for key, value in d.items() for k, v in _flat(value, f"{prefix}{key}.").items()}
    if isinstance(d, (list, tuple)):
        return {f"{prefix}{i}": v for i, v in enumerate(d)}
    return {prefix: d}


def _same(p, q) -> bool:
    """The same parameters up to the float32 of the node's sockets."""
    a, b = _flat(p.to_dict()), _flat(q.to_dict())
    return a.keys() == b.keys() and all(a[k] == pytest.approx(b[k], rel=1e-6) for k in a)


def test_the_panel_summarises_the_coat_and_names_texture_driven_inputs(registered, sphere):
    assert bpy.ops.lamina.add_thin_coat(preset="glazed_ceramic") == {"FINISHED"}
    mat = sphere.active_material
    p = model.params_from_dict(presets.load(model.ID, "glazed_ceramic"))
    text = panel_text(mat)
    assert "lamina.add_thin_coat" in text and "thin coat over diffuse" in text
    assert f"Top: roughness α {p.roughness_top:.3g} (κ 20000)" in text
    assert "Bottom: no effect over a diffuse base" in text
    assert "Coat IOR η 1.500" in text and "Absorption σa·d: (0.15, 0.075, 0.025)" in text
    assert "Bounces: 2" in text and "No texture-driven inputs" in text
    assert "principled" in text and "lamina.compare" in text  # the compare sub-panel's Principled checkbox
    node = material.shader_node(mat)
    texturable = next(s for s in MAPPINGS[model.ID].sockets(p) if s.kind != "shader" and s.param.texturable)
    image = mat.node_tree.nodes.new("ShaderNodeTexImage")
    mat.node_tree.links.new(image.outputs["Color"], node.inputs[texturable.name])
    text = panel_text(mat)
    assert f"Texture-driven: {texturable.name}" in text and "texture-driven" in text.split("Texture-driven")[0]
