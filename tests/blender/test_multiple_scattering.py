"""Multiple scattering as an artist uses it: toggled on and off, baked into the Lamina node, re-baked by hand and
automatically (debounced), grouped for 3-layer stacks, drawn in the panel and rendered by Cycles as predicted.
Predicted values always come from the bake module (the shipped weights change with training)."""
from dataclasses import replace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402
from addon import presets  # noqa: E402
from addon.models import spongecake as model  # noqa: E402
from addon.nodes import MAPPINGS, material, predicted_image  # noqa: E402
from addon.nodes.spongecake import ms_values  # noqa: E402
from addon.operators import blend_io, ms_ops  # noqa: E402
from addon.operators.cycles_render import render_cycles  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from renders import relative_error, render, renders_with_and_without_lamina, view_lookup_kinds  # noqa: E402
from ui_helpers import panel_text  # noqa: E402

pytestmark = pytest.mark.blender
# two bright surface layers: much of the light scatters more than once
BRIGHT = {"layers": [{"type": "surface", "roughness": 0.5, "albedo": [0.95, 0.95, 0.95], "thickness": 1.0},
                     {"type": "surface", "roughness": 0.5, "albedo": [0.95, 0.95, 0.95], "thickness": 3.0}]}


@pytest.fixture(autouse=True)
def registered():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon.register()
    yield
    addon.unregister()


def _preset(name, **changes):
    return model.params_from_dict({**presets.load(model.ID, name), **changes})


def _inputs(mat, baked):
    """Socket name -> value of the Lamina node's model inputs (``baked=False``) or its MS inputs."""
    _, p = material.current_params(mat)
    node = material.shader_node(mat)
    return {s.name: material._read_socket(node, s) for s in MAPPINGS[model.ID].sockets(p) if s.baked == baked}


def _assert_ms_inputs_are_the_prediction(mat):
    _, p = material.current_params(mat)
    expected = ms_values(p, material.form_of(mat))
    got = _inputs(mat, baked=True)
    assert set(got) == set(expected)
    for name, value in expected.items():
        assert got[name] == pytest.approx(value, rel=1e-6, abs=1e-7), name


def _set_thickness(mat, value):
    node = material.shader_node(mat)
    node.inputs[material.socket_key(node, "L1 Thickness")].default_value = value


@pytest.mark.parametrize("form", material.FORMS)
def test_toggling_keeps_parameter_values_and_form(form):
    mat = material.new_material(model.ID, _preset("fabric"), form)
    _set_thickness(mat, 0.75)
    _, before = material.current_params(mat)
    material.set_multiple_scattering(mat, True)
    assert material.form_of(mat) == form and material.ms_enabled(mat)
    assert material.current_params(mat)[1] == replace(before, multiple_scattering=True)
    _assert_ms_inputs_are_the_prediction(mat)
    assert not material.ms_is_stale(mat)
    material.set_multiple_scattering(mat, False)
    assert material.form_of(mat) == form and not material.ms_enabled(mat)
    assert material.current_params(mat)[1] == before
    assert _inputs(mat, baked=True) == {} and "lamina_ms_key" not in mat.keys()


def test_new_material_records_its_bake_and_switching_form_keeps_it():
    mat = material.new_material(model.ID, _preset("plastic", multiple_scattering=True), "nodes")
    assert not material.ms_is_stale(mat)
    _assert_ms_inputs_are_the_prediction(mat)
    material.set_form(mat, "osl")
    assert not material.ms_is_stale(mat)
    _assert_ms_inputs_are_the_prediction(mat)


def test_a_parameter_edit_makes_the_bake_stale_and_rebake_writes_the_new_prediction():
    mat = material.new_material(model.ID, _preset("fabric", multiple_scattering=True), "nodes")
    old = _inputs(mat, baked=True)
    _set_thickness(mat, 3.0)
    assert material.ms_is_stale(mat)
    assert material.bake_constants(mat)
    assert not material.ms_is_stale(mat)
    _assert_ms_inputs_are_the_prediction(mat)
    assert _inputs(mat, baked=True) != old
    assert not material.bake_constants(mat)  # nothing left to change


def test_rebaking_a_node_made_before_the_energy_inputs_rebuilds_it():
    """A file from an earlier Lamina: its Lamina node lacks the ``MS Energy`` inputs; Re-bake rebuilds the node (the
    form kept, the user's other nodes untouched) and writes every input."""
    mat = material.new_material(model.ID, _preset("fabric", multiple_scattering=True), "nodes")
    mine = mat.node_tree.nodes.new("ShaderNodeValue")
    old = material.shader_node(mat).node_tree.copy()  # an earlier generator's group, under its own name
    old.interface.remove(old.interface.items_tree["MS Energy"])
    material.shader_node(mat).node_tree = old
    assert "MS Energy" not in material.shader_node(mat).inputs
    _set_thickness(mat, 3.0)
    assert material.bake_constants(mat)
    assert "MS Energy" in material.shader_node(mat).inputs and material.form_of(mat) == "nodes"
    assert mine.name in mat.node_tree.nodes and not material.ms_is_stale(mat)
    _assert_ms_inputs_are_the_prediction(mat)


def test_a_material_from_another_generator_is_stale_and_rebake_rebuilds_its_node():
    """A file from an earlier Lamina whose node has every input but other closures (an older generator): the panel
    asks for a re-bake, and Re-bake rebuilds the node before writing values that fit the current closures."""
    mat = material.new_material(model.ID, _preset("fabric", multiple_scattering=True), "nodes")
    old = material.shader_node(mat).node_tree.copy()  # the earlier generator's group, under its own name
    material.shader_node(mat).node_tree = old
    mat[material.GENERATOR_KEY] = material.GENERATOR_VERSION - 1
    mat[material.MS_KEY] = "a key made by the earlier Lamina"
    assert material.ms_is_stale(mat) and "Needs a re-bake" in panel_text(mat)
    assert material.bake_constants(mat)
    assert material.shader_node(mat).node_tree is not old and mat[material.GENERATOR_KEY] == material.GENERATOR_VERSION
    assert not material.ms_is_stale(mat)
    _assert_ms_inputs_are_the_prediction(mat)


def test_rebake_leaves_linked_inputs_alone():
    mat = material.new_material(model.ID, _preset("fabric", multiple_scattering=True), "nodes")
    node = material.shader_node(mat)
    texture = mat.node_tree.nodes.new("ShaderNodeValue")
    mat.node_tree.links.new(texture.outputs[0], node.inputs["MS L1 Thickness"])
    node.inputs["MS L1 Thickness"].default_value = 123.0
    _set_thickness(mat, 3.0)
    assert material.bake_constants(mat)
    assert node.inputs["MS L1 Thickness"].default_value == 123.0
    expected = ms_values(material.current_params(mat)[1], "nodes")["MS L1 Albedo"]
    assert tuple(node.inputs["MS L1 Albedo"].default_value)[:3] == pytest.approx(expected, rel=1e-6, abs=1e-7)


def test_a_three_layer_stack_gets_multiple_scattering_through_the_grouped_network():
    mat = material.new_material(model.ID, _preset("leaf"), "nodes")
    with bpy.context.temp_override(material=mat):
        assert bpy.ops.lamina.set_multiple_scattering(enabled=True) == {"FINISHED"}
    assert material.ms_enabled(mat) and not material.ms_is_stale(mat)
    p = material.current_params(mat)[1]
    baked = {name: np.ravel(value) for name, value in ms_values(p, "nodes").items()}
    assert baked and all(np.isfinite(v).all() for v in baked.values())
    energies = [v for name, v in baked.items() if any(k in name for k in ("Albedo", "Thickness", "Reflection"))]
    assert all((v >= 0).all() for v in energies)
    assert baked["MS L3 Albedo"].max() > 0  # the third layer has a lobe


def test_operators_add_toggle_and_rebake(sphere):
    assert bpy.ops.lamina.add_spongecake(preset="fabric", multiple_scattering=True) == {"FINISHED"}
    mat = sphere.active_material
    assert material.ms_enabled(mat) and not material.ms_is_stale(mat)
    _set_thickness(mat, 3.0)
    with bpy.context.temp_override(material=mat):
        assert bpy.ops.lamina.rebake() == {"FINISHED"}
        assert not material.ms_is_stale(mat)
        assert bpy.ops.lamina.set_multiple_scattering(enabled=False) == {"FINISHED"}
    assert not material.ms_enabled(mat)
    # a 3-layer preset: the grouped prediction
    assert bpy.ops.lamina.add_spongecake(preset="leaf", multiple_scattering=True) == {"FINISHED"}
    assert material.ms_enabled(sphere.active_material)


def test_auto_rebake_is_debounced_and_does_not_loop(sphere):
    bpy.ops.lamina.add_spongecake(preset="fabric", multiple_scattering=True)
    mat = sphere.active_material
    bpy.context.view_layer.update()
    assert not bpy.app.timers.is_registered(ms_ops.rebake_stale)
    _set_thickness(mat, 3.0)
    bpy.context.view_layer.update()  # runs depsgraph_update_post
    assert bpy.app.timers.is_registered(ms_ops.rebake_stale)
    _set_thickness(mat, 4.0)
    bpy.context.view_layer.update()
    assert bpy.app.timers.is_registered(ms_ops.rebake_stale)  # still one pending call, pushed back
    bpy.app.timers.unregister(ms_ops.rebake_stale)
    ms_ops.rebake_stale()  # what the timer does 0.3 s after the last edit (no event loop in background mode)
    assert not material.ms_is_stale(mat)
    _assert_ms_inputs_are_the_prediction(mat)
    bpy.context.view_layer.update()  # the values the bake wrote: not stale, nothing scheduled
    assert not bpy.app.timers.is_registered(ms_ops.rebake_stale)
    bpy.context.window_manager.lamina_auto_rebake = False
    _set_thickness(mat, 5.0)
    bpy.context.view_layer.update()
    assert not bpy.app.timers.is_registered(ms_ops.rebake_stale) and material.ms_is_stale(mat)


def test_unregister_removes_the_handler_and_a_pending_rebake(sphere):
    bpy.ops.lamina.add_spongecake(preset="fabric", multiple_scattering=True)
    _set_thickness(sphere.active_material, 3.0)
    bpy.context.view_layer.update()
    assert bpy.app.timers.is_registered(ms_ops.rebake_stale)
    addon.unregister()
    try:
        assert not bpy.app.timers.is_registered(ms_ops.rebake_stale)
        assert ms_ops.on_depsgraph_update not in bpy.app.handlers.depsgraph_update_post
        assert not hasattr(bpy.types.WindowManager, "lamina_auto_rebake")
    finally:
        addon.register()


def test_energy_share_is_the_rendered_furnace_difference():
    """The share as Cycles renders it: the form's predicted white furnace (on its direction grid, an independent
    quadrature) with and without multiple scattering, along the normal."""
    from addon.nodes import predicted_furnace

    mat = material.new_material(model.ID, _preset("fabric", multiple_scattering=True), "nodes")
    _, p = material.current_params(mat)
    total = predicted_furnace(model.ID, p, "osl")(np.array([[0.0, 0.0, 1.0]])).mean()
    single = predicted_furnace(model.ID, replace(p, multiple_scattering=False), "osl")(np.array([[0.0, 0.0, 1.0]])).mean()
    assert material.ms_energy_share(mat) == pytest.approx((total - single) / total, rel=0.02)
    share = material.ms_energy_share(material.new_material(model.ID, _preset("leaf", multiple_scattering=True), "nodes"))
    assert 0.0 < share < 1.0  # three layers: the grouped prediction


def test_panel_shows_toggle_share_stale_warning_and_rebake():
    mat = material.new_material(model.ID, _preset("fabric", multiple_scattering=True), "nodes")
    text = panel_text(mat)
    assert "lamina.set_multiple_scattering" in text and "lamina_auto_rebake" in text and "lamina.rebake" in text
    assert f"Multiple scattering: {material.ms_energy_share(mat):.0%} of the leaving energy" in text
    assert ("lamina.bake_textures" in text) == hasattr(bpy.types, "LAMINA_OT_bake_textures")
    _set_thickness(mat, 3.0)
    assert "Needs a re-bake: parameters, network or Lamina changed" in panel_text(mat)
    text = panel_text(material.new_material(model.ID, _preset("leaf", multiple_scattering=True), "nodes"))
    assert "Lobes: 2-layer network, layers grouped in two (an approximation)" in text and "lamina.rebake" in text
    text = panel_text(material.new_material(model.ID, _preset("leaf"), "nodes"))
    assert "lamina.set_multiple_scattering" in text and "lamina.rebake" not in text  # off: the toggle only


@pytest.mark.parametrize("form", material.FORMS)
def test_cycles_renders_the_predicted_multiple_scattering(form, tmp_path):
    single = model.params_from_dict(BRIGHT)
    multiple = replace(single, multiple_scattering=True)
    for spec, samples in ((S.sphere_scene(resolution=40), 32), (S.furnace_scene(resolution=(24, 12)), 128)):
        mask = S.scene_mask(spec)
        images = {}
        for p in (single, multiple):
            mat = material.new_material(model.ID, p, form)
            images[p], _ = render_cycles(mat, spec, samples, 0, str(tmp_path / f"{spec.name}.exr"))
            predicted = predicted_image(model.ID, p, form, spec)
            err = metrics.rmse(images[p], predicted, mask) / max(predicted[mask].mean(), 1e-3)
            assert err < 0.02, f"{form} {spec.name} ms={p.multiple_scattering}: {err:.4f}"
        assert images[multiple][mask].mean() > images[single][mask].mean(), spec.name


# one flake layer tilted 53° off the normal: its multiple scattering changes with the view's azimuth
TILTED = {"layers": [{"type": "surface", "roughness": 0.2, "albedo": [0.95, 0.95, 0.95], "thickness": 3.0,
                      "orientation": [0.8, 0.0, 0.6]}], "multiple_scattering": True}


@pytest.mark.parametrize("form", material.FORMS)
def test_an_oriented_stack_renders_its_energy_table_over_the_view(form, tmp_path):
    """An oriented stack's ``MS Energy`` is fed a packed float image over the view's angle and azimuth, looked up at
    the view; Cycles renders the prediction that uses it (the least over the azimuths is 24% off on this sphere: the
    test fails without the azimuth). Turning multiple scattering off removes the lookup and its image."""
    p = model.params_from_dict(TILTED)
    mat = material.new_material(model.ID, p, form)
    node = material.shader_node(mat)
    (tex,) = [n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage"]
    assert tex.image.packed_file is not None and tex.interpolation == "Linear" and tex.extension == "EXTEND"
    assert node.inputs[material.socket_key(node, "MS Energy")].links[0].from_node == tex
    assert tex.image.size[:] == (model.VIEW_ENERGY_GRID[1] + 1, model.VIEW_ENERGY_GRID[0])
    spec = S.sphere_scene(resolution=40)
    assert relative_error(render(mat, spec, 32, tmp_path), predicted_image(model.ID, p, form, spec), spec) < 0.02
    image = tex.image.name
    material.set_multiple_scattering(mat, False)
    assert not [n for n in mat.node_tree.nodes if n.bl_idname in ("ShaderNodeTexImage", "ShaderNodeGroup")
                and n != material.shader_node(mat)]
    assert image not in bpy.data.images


def _table_images(mat):
    return {n.image.name for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage"}


def test_the_view_table_follows_rebakes_and_forms_and_leaves_the_users_links_alone():
    mat = material.new_material(model.ID, model.params_from_dict(TILTED), "nodes")
    assert view_lookup_kinds(mat) == ["ShaderNodeGroup", "ShaderNodeTexImage"]
    (first,) = _table_images(mat)
    material.set_form(mat, "osl")  # the lookup moves to the new node: still one
    node = material.shader_node(mat)
    assert view_lookup_kinds(mat) == ["ShaderNodeGroup", "ShaderNodeTexImage"]
    assert node.inputs["MS_Energy"].links[0].from_node.image.name == first
    _set_thickness(mat, 1.5)  # a new table: a new image, the old one removed
    assert material.bake_constants(mat)
    (second,) = _table_images(mat)
    assert second != first and first not in bpy.data.images
    assert not material.bake_constants(mat)  # nothing changes the second time: no depsgraph loop
    _set_orientation(mat, (0.0, 0.0, 1.0))  # along the normal: a table over the view's angle alone
    assert material.bake_constants(mat)
    (third,) = _table_images(mat)
    assert second not in bpy.data.images and bpy.data.images[third].size[:] == (2, model.VIEW_ENERGY_GRID[0])
    mine = mat.node_tree.nodes.new("ShaderNodeRGB")
    mat.node_tree.links.new(mine.outputs[0], node.inputs["MS_Energy"])  # the user's own link replaces the lookup
    _set_thickness(mat, 2.5)
    assert material.bake_constants(mat)
    assert view_lookup_kinds(mat) == [] and third not in bpy.data.images  # the idle lookup went, with its image
    assert node.inputs["MS_Energy"].links[0].from_node == mine


def _set_orientation(mat, value):
    node = material.shader_node(mat)
    node.inputs[material.socket_key(node, "L1 Orientation")].default_value = value


@pytest.mark.parametrize("orientation, form", [([0.8, 0.0, 0.6], "nodes"), ([0.0, 0.0, 1.0], "osl")])
def test_a_saved_stack_with_multiple_scattering_renders_the_same_without_lamina(orientation, form, tmp_path):
    """Its ``MS Energy`` table (over the azimuth too where the layer is oriented) is packed into the file."""
    p = model.params_from_dict({**TILTED, "layers": [{**TILTED["layers"][0], "orientation": orientation}]})
    blend = tmp_path / "ms.blend"
    blend_io.write_material_blend(model.ID, p, form, "ms", str(blend))
    here, fresh = renders_with_and_without_lamina(blend, "Lamina ms", tmp_path)
    assert here.mean() > 1e-3
    np.testing.assert_array_equal(here, fresh)
