"""Anisotropic stacks as an artist meets them: the Add Anisotropic Stack Material dialog (presets, 1-4 interfaces,
Glossy-style or alpha roughness, metals, media), its undo, and the sidebar panel's summary (bpy 5.0 and 4.2)."""
import math

import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import aniso_stack as model  # noqa: E402
from addon.models.metals import METALS  # noqa: E402
from addon.nodes import material  # noqa: E402
from addon.operators import aniso_stack as dialog_module  # noqa: E402
from addon.operators.material_ops import CUSTOM  # noqa: E402
from ui_helpers import bind, dialog, draw_dialog, panel_text, props, text  # noqa: E402

pytestmark = pytest.mark.blender
OP = dialog_module.LAMINA_OT_add_aniso_stack
METHODS = ("_draw_custom", "_draw_medium", "alpha", "stack_dict")


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def test_the_panel_summarises_the_stack_and_names_texture_driven_inputs(registered):
    p = model.params_from_dict(presets.load(model.ID, "forward_scattering"))
    mat = material.new_material(model.ID, p, "osl")
    text = panel_text(mat)
    assert "anisotropic stack of 2 interface(s)" in text
    assert "1. Dielectric 1.49: α 0.3 × 0.05, rotation 0°" in text
    assert "2. Conductor 1+1i, 1+0i, 1+0i: α 0.3 × 0.05, rotation 90°" in text
    assert "medium: σa·d 0.01, 1, 0.01, scattering g 0.90" in text and "lamina.set_form" in text
    node = material.shader_node(mat)
    mat.node_tree.links.new(mat.node_tree.nodes.new("ShaderNodeTexImage").outputs["Color"], node.inputs["Rotation_2"])
    assert "Texture-driven: Rotation 2" in panel_text(mat) and "no UV map needed" in text


# ------------------------------------------------------------------------------------------ the Add dialog

def _dialog(**values):
    return bind(OP, dialog("add_aniso_stack", **values), METHODS)


def _draw(ns) -> tuple[str, list[str]]:
    """The labels and the properties the dialog draws for ``ns``."""
    log = draw_dialog(OP, ns, METHODS)
    return text([entry for entry in log if entry[0] == "label"]), props(log)


def test_the_dialog_offers_every_preset_and_metal(registered):
    rna = bpy.ops.lamina.add_aniso_stack.get_rna_type().properties
    assert [i.identifier for i in rna["preset"].enum_items] == [CUSTOM] + presets.names(model.ID)
    for item in rna["preset"].enum_items[1:]:
        assert item.description == presets.description(model.ID, item.identifier)
    assert [i.identifier for i in rna["metal"].enum_items] == [*METALS, CUSTOM]
    assert (rna["interfaces"].hard_min, rna["interfaces"].hard_max) == (1, model.MAX_INTERFACES)
    assert {f"rotation_{j}" for j in range(1, 5)} <= set(rna.keys()) and "g_3" in rna.keys() and "g_4" not in rna
    assert "UNDO" in OP.bl_options and "REGISTER" in OP.bl_options


@pytest.mark.parametrize("n", range(1, model.MAX_INTERFACES + 1))
@pytest.mark.parametrize("base", ["conductor", "dielectric"])
def test_custom_settings_make_a_clean_stack(registered, n, base):
    ns = _dialog(interfaces=n, base=base, metal="gold", roughness_2=0.5, anisotropy_2=-0.5,
                color_1=(0.5, 1.0, 1.0), depth_1=2.0, scattering_1=0.3)
    v = model.validate(ns.stack_dict())
    assert v.warnings == []
    p = v.params
    assert len(p.interfaces) == n and len(p.media) == n - 1
    assert [i.type for i in p.interfaces] == ["dielectric"] * (n - 1) + [base]
    if base == "conductor":
        assert p.interfaces[-1].ior + p.interfaces[-1].k == pytest.approx(sum(METALS["gold"], ()))
    assert p.interfaces[0].alpha == pytest.approx((0.15 ** 2, 0.15 ** 2))  # the coat's default: isotropic
    if n >= 2:
        assert p.interfaces[1].alpha == pytest.approx((0.25 / 0.5, 0.25 * 0.5))  # Glossy's a < 0: along the tangent
        m = p.media[0]
        assert [math.exp(-s) for s in m.sigma_a] == pytest.approx([0.5, 1.0, 1.0])  # colour per unit depth
        assert (m.depth, *m.sigma_s, m.g) == pytest.approx((2.0, 0.3, 0.3, 0.3, 0.9))
    labels, drawn = _draw(ns)
    assert f"Interface {n}" in labels and ("metal" in drawn) == (base == "conductor")
    assert labels.count("Medium between interfaces") == n - 1 and ("g_1" in drawn) == (n > 1)


def test_alpha_control_takes_any_ratio_and_the_glossy_control_shows_its_alphas(registered):
    ns = _dialog(roughness_control="alpha", alpha_x_2=0.5, alpha_y_2=0.001, rotation_2=30.0)
    p = model.params_from_dict(ns.stack_dict())
    assert p.interfaces[1].alpha == pytest.approx((0.5, 0.001)) and p.interfaces[1].rotation == pytest.approx(30.0)
    drawn = _draw(ns)[1]
    assert "alpha_x_2" in drawn and "anisotropy_2" not in drawn
    ns = _dialog(roughness_2=0.8, anisotropy_2=0.5)
    assert "α 0.32 along the tangent × 1.28 across (capped at 1)" in _draw(ns)[0]  # 0.64·(1 − 0.5), 0.64 / (1 − 0.5)


def test_custom_metal_takes_its_complex_ior(registered):
    ns = _dialog(metal=CUSTOM, metal_ior=(1.0, 0.5, 0.25), metal_k=(4.0, 3.0, 2.0))
    bottom = model.params_from_dict(ns.stack_dict()).interfaces[-1]
    assert bottom.ior == pytest.approx((1.0, 0.5, 0.25)) and bottom.k == pytest.approx((4.0, 3.0, 2.0))
    assert "metal_k" in _draw(ns)[1]


@pytest.mark.parametrize("name", presets.names(model.ID))
def test_presets_show_their_stack(registered, name):
    ns = _dialog(preset=name)
    assert ns.stack_dict() == presets.load(model.ID, name)
    labels, drawn = _draw(ns)
    for line in dialog_module.stack_lines(model.params_from_dict(presets.load(model.ID, name))):
        assert line in labels
    assert drawn == ["preset", "form"]  # the custom settings are not drawn


def test_the_dialog_adds_a_material_and_undo_removes_it(registered, sphere):
    ball = bpy.data.objects["ball"]
    mine = bpy.data.materials.new("My paint")
    ball.data.materials.append(mine)
    bpy.ops.ed.undo_push(message="before")
    assert bpy.ops.lamina.add_aniso_stack(interfaces=3, base="dielectric", anisotropy_2=0.3, form="osl") == {"FINISHED"}
    bpy.ops.ed.undo_push(message=OP.bl_label)
    new = ball.material_slots[0].material
    assert material.is_lamina(new) and new.name == "Anisotropic Stack" and material.form_of(new) == "osl"
    model_id, p = material.current_params(new)
    assert model_id == model.ID and [i.type for i in p.interfaces] == ["dielectric"] * 3
    bpy.ops.ed.undo()
    assert [m.name for m in bpy.data.materials] == ["My paint"]
    assert bpy.ops.lamina.add_aniso_stack(preset="brushed_steel_scratched_coat") == {"FINISHED"}
    assert bpy.data.objects["ball"].material_slots[0].material.name == "Anisotropic Stack Brushed steel scratched coat"


def test_a_glossy_setting_beyond_alpha_1_is_clamped_with_a_warning(registered, sphere, capsys):
    """Roughness 0.8 with Anisotropy 0.5 asks for αy = 1.28: the material is made with αy = 1 and the report says so."""
    assert bpy.ops.lamina.add_aniso_stack(roughness_2=0.8, anisotropy_2=0.5) == {"FINISHED"}
    _, p = material.current_params(bpy.data.objects["ball"].material_slots[0].material)
    assert p.interfaces[1].alpha == pytest.approx((0.32, 1.0))
    assert "interface 2: alpha_y: 1.28 is outside [0.0001, 1], clamped to 1" in capsys.readouterr().out
