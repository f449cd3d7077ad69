"""The add-on as an artist uses it: operators registered, a material added to an object, form switched,
comparison run; the user's data and scene settings are never changed behind their back."""
import pytest

bpy = pytest.importorskip("bpy")

from addon.nodes import material  # noqa: E402
from ui_helpers import panel_text  # noqa: E402

pytestmark = pytest.mark.blender


@pytest.fixture(autouse=True)
def clean_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def test_add_material_from_a_preset_keeps_the_users_material(registered, sphere):
    mine = bpy.data.materials.new("My paint")
    sphere.data.materials.append(mine)
    assert bpy.ops.lamina.add_spongecake(preset="fabric", form="nodes") == {"FINISHED"}
    new = sphere.material_slots[0].material
    assert material.is_lamina(new) and new is not mine
    assert bpy.data.materials.get("My paint") is mine  # still in the file, untouched


def test_add_material_from_scratch_builds_the_requested_stack(registered, sphere):
    assert bpy.ops.lamina.add_spongecake(preset="CUSTOM", layers=3, layer_1="fiber", layer_2="hg",
                                         layer_3="surface", substrate="diffuse") == {"FINISHED"}
    _, p = material.current_params(sphere.active_material)
    assert [layer.type for layer in p.layers] == ["fiber", "hg", "surface"]
    assert p.substrate.type == "diffuse"


def test_osl_form_does_not_switch_the_scene_to_osl(registered, sphere):
    scene = bpy.context.scene
    before = (scene.render.engine, scene.cycles.shading_system, scene.cycles.device)
    assert bpy.ops.lamina.add_spongecake(preset="leaf", form="osl") == {"FINISHED"}
    assert (scene.render.engine, scene.cycles.shading_system, scene.cycles.device) == before


def test_set_form_and_compare_from_the_operators(registered, sphere):
    bpy.ops.lamina.add_spongecake(preset="thick_flakes", form="nodes")
    mat = sphere.active_material
    settings = bpy.context.window_manager.lamina_compare
    settings.samples, settings.resolution, settings.scene = 16, 24, "sphere"
    counts = {c: len(getattr(bpy.data, c)) for c in ("scenes", "objects", "materials", "node_groups")}
    with bpy.context.temp_override(material=mat):
        assert bpy.ops.lamina.set_form(form="osl") == {"FINISHED"}
        assert material.form_of(mat) == "osl"
        assert bpy.ops.lamina.compare() == {"FINISHED"}
    assert settings.last_report.startswith("sphere: RMSE ") and "rel. RMSE" in settings.last_report
    assert float(settings.last_report.split("rel. RMSE ")[1].split("%")[0]) < 3.0
    assert "Lamina Compare" in bpy.data.images
    after = {c: len(getattr(bpy.data, c)) for c in counts}
    assert after == counts


@pytest.mark.parametrize("lamina", [False, True])
def test_panels_draw_for_lamina_and_other_materials(registered, sphere, lamina):
    if lamina:
        bpy.ops.lamina.add_spongecake(preset="plastic", form="osl")
    else:
        sphere.data.materials.append(bpy.data.materials.new("plain"))
    labels = panel_text(sphere.active_material)
    if lamina:
        assert "lamina.set_form" in labels and "lamina.compare" in labels
        assert "OSL renders only in Cycles with Open Shading Language on" in labels  # factory settings: OSL off
    else:
        assert "not a Lamina material" in labels
