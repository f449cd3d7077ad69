"""Add Porous Layer: a micrograin layer over any material, as a new material wrapping a copy of it. The original
is never touched; at filling factor 0 the wrapped material renders exactly like it; a SpongeCake material becomes
a reference bulk; refusals create nothing; the operator, the form switch and the panel work on the result."""
import json

import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import micrograin  # noqa: E402
from addon.models import spongecake  # noqa: E402
from addon.models.params import ParamError  # noqa: E402
from addon.nodes import material, wrap  # noqa: E402
from addon.operators.cycles_render import render_cycles  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from ui_helpers import Layout, operators, panel_log  # noqa: E402

pytestmark = pytest.mark.blender
RED_DUST = {"filling_factor": 0.5, "anfractuosity": 0.5, "grain": {"type": "diffuse", "albedo": [0.9, 0.1, 0.1]}}


@pytest.fixture(autouse=True)
def empty_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def _principled(name="Paint"):
    """A user's material: a Principled BSDF with non-default values, fed by a Noise Texture through a ramp."""
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.7, 0.3, 0.1, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.4
    bsdf.inputs["Metallic"].default_value = 0.3
    noise = tree.nodes.new("ShaderNodeTexNoise")
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    tree.links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    mat["user_tag"] = "mine"
    return mat


def _value(v):
    try:
        return tuple(round(float(x), 6) for x in v)
    except TypeError:
        return v if not isinstance(v, float) else round(v, 6)


def _snapshot(mat) -> dict:
    """Everything about a material an edit could change: name, properties, nodes, their inputs and links."""
    tree = mat.node_tree
    nodes = {n.name: (n.bl_idname, tuple(n.location), n.width,
                      tuple((s.identifier, _value(getattr(s, "default_value", None))) for s in n.inputs))
             for n in (tree.nodes if tree else ())}
    links = sorted((lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier,
                    lk.is_muted) for lk in (tree.links if tree else ()))
    return {"name": mat.name, "props": {k: str(v) for k, v in mat.items()}, "nodes": nodes, "links": links,
            "fake_user": mat.use_fake_user}


def _feeds(socket):
    return [(lk.from_node.name, lk.from_socket.name) for lk in socket.links]


@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_wrapping_leaves_the_original_untouched_and_feeds_its_copy_into_bulk(form):
    src = _principled()
    before = _snapshot(src)
    mat = wrap.add_porous_layer(src, RED_DUST, form)
    assert _snapshot(src) == before  # same name, properties, nodes, values, links
    assert bpy.data.materials.get("Paint") is src and mat is not src and mat.node_tree != src.node_tree
    assert mat.name == "Paint + Porous layer"
    lamina = material.shader_node(mat)
    assert lamina.bl_idname == ("ShaderNodeGroup" if form == "nodes" else "ShaderNodeScript")
    bulk_link = lamina.inputs["Bulk"].links[0]
    assert bulk_link.from_node.bl_idname == "ShaderNodeBsdfPrincipled"
    assert bulk_link.from_node.id_data == mat.node_tree  # the copy's Principled, not the original's
    assert _feeds(bulk_link.from_node.inputs["Base Color"]) == [("Color Ramp", "Color")]  # its inputs came along
    out = mat.node_tree.get_output_node("CYCLES")
    assert _feeds(out.inputs["Surface"]) == [("Lamina", "BSDF")]
    bsdf = bulk_link.from_node
    assert bsdf.location.x < lamina.location.x < out.location.x  # between the shader and the output
    info = material.info(mat)
    assert info["model"] == micrograin.ID and info["params"]["bulk"] == {"type": micrograin.WRAPPED}
    assert info["params"]["filling_factor"] == 0.5 and mat["user_tag"] == "mine"
    assert material.form_of(mat) == form


@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_filling_factor_zero_renders_like_the_original(form, tmp_path):
    """At τ0 = 0 the bulk gets weight exactly 1 and the grains 0: the same picture up to Monte Carlo noise (the
    sun-lit sphere is noise-free); with grains it differs, so the comparison can tell."""
    src = _principled()
    bare = wrap.add_porous_layer(src, {**RED_DUST, "filling_factor": 0.0}, form)
    dusty = wrap.add_porous_layer(src, RED_DUST, form)
    for spec, samples in ((S.sphere_scene(resolution=24), 16), (S.furnace_scene(resolution=(16, 8)), 2048)):
        mask = S.scene_mask(spec)
        original, _ = render_cycles(src, spec, samples, 0, str(tmp_path / "original.exr"))
        wrapped, _ = render_cycles(bare, spec, samples, 0, str(tmp_path / "wrapped.exr"))
        with_grains, _ = render_cycles(dusty, spec, samples, 0, str(tmp_path / "dusty.exr"))
        assert metrics.rel_rmse(wrapped, original, mask) < 0.005, spec.name
        assert metrics.rel_rmse(with_grains, original, mask) > 0.05, spec.name


def test_wrapping_a_spongecake_material_makes_it_the_reference_bulk():
    p = spongecake.params_from_dict(presets.load(spongecake.ID, "plastic"))
    src = material.new_material(spongecake.ID, p, "osl", name="Plastic")
    src_lamina = material.shader_node(src)
    src_lamina.inputs["L1_Roughness"].default_value = 0.21  # an edit on the node: the current value counts
    before = _snapshot(src)
    mat = wrap.add_porous_layer(src, presets.load(micrograin.ID, "mud_on_plastic"), "nodes")
    assert _snapshot(src) == before and material.shader_node(src).bl_idname == "ShaderNodeScript"
    bulk = material.info(mat)["params"]["bulk"]
    _, current = material.current_params(src)
    assert bulk == json.loads(json.dumps({"type": spongecake.ID, **current.to_dict()}))  # lists, not tuples
    assert abs(bulk["layers"][0]["roughness"] - 0.21) < 1e-6
    nodes = mat.node_tree.nodes
    assert _feeds(nodes["Lamina"].inputs["Bulk"]) == [(material.BULK_NODE, "BSDF")]
    assert nodes[material.BULK_NODE].bl_idname == "ShaderNodeGroup"  # rebuilt in the layer's form
    assert "SpongeCake" in nodes[material.BULK_NODE].node_tree.name
    _, p_mat = material.current_params(mat)
    assert p_mat.bulk.type == spongecake.ID and abs(p_mat.bulk.params.layers[0].roughness - 0.21) < 1e-6
    assert material.MS_KEY not in mat.keys()


def test_refusals_create_nothing():
    unlinked = _principled("Unlinked")
    out = unlinked.node_tree.get_output_node("CYCLES")
    unlinked.node_tree.links.remove(out.inputs["Surface"].links[0])
    no_output = _principled("No output")
    no_output.node_tree.nodes.remove(no_output.node_tree.get_output_node("CYCLES"))
    porous = material.new_material(micrograin.ID, micrograin.params_from_dict(
        presets.load(micrograin.ID, "dust_on_wood")), "nodes")
    wrapped = wrap.add_porous_layer(_principled(), RED_DUST, "nodes")
    cases = [(unlinked, "nothing to wrap"), (no_output, "nothing to wrap"), (porous, "already has a porous layer"),
             (wrapped, "already has a porous layer")]
    if bpy.app.version < (5, 0, 0):  # 4.2: a material can render without nodes (its viewport colour)
        cases.append((bpy.data.materials.new("No nodes"), "does not use nodes"))
    counts = {c: len(getattr(bpy.data, c)) for c in ("materials", "node_groups", "texts")}
    for mat, reason in cases:
        before = _snapshot(mat)
        with pytest.raises(ParamError, match=reason):
            wrap.add_porous_layer(mat, RED_DUST, "osl")
        assert _snapshot(mat) == before
    with pytest.raises(ParamError, match="velvet"):
        wrap.add_porous_layer(_principled("Fine"), {"grain": {"type": "velvet"}}, "nodes")
    counts["materials"] += 1  # "Fine" itself
    assert {c: len(getattr(bpy.data, c)) for c in counts} == counts


def test_set_form_on_a_wrapped_material_keeps_the_bulk_link_and_the_values():
    mat = wrap.add_porous_layer(_principled(), RED_DUST, "nodes")
    material.shader_node(mat).inputs["Filling Factor"].default_value = 0.25
    for form in ("osl", "nodes", "osl"):
        material.set_form(mat, form)
        lamina = material.shader_node(mat)
        assert material.form_of(mat) == form
        assert _feeds(lamina.inputs["Bulk"]) == [("Principled BSDF", "BSDF")]
        assert _feeds(mat.node_tree.get_output_node("CYCLES").inputs["Surface"]) == [("Lamina", "BSDF")]
        _, p = material.current_params(mat)
        assert abs(p.filling_factor - 0.25) < 1e-6 and p.bulk.type == micrograin.WRAPPED
    assert [n.name for n in mat.node_tree.nodes if n.name.startswith("Lamina")] == ["Lamina"]


# ------------------------------------------------------------------------------------------------ operator


def test_operator_with_a_preset_replaces_the_slot_and_keeps_the_original(registered, sphere):
    src = _principled("My paint")
    sphere.data.materials.append(src)
    before = _snapshot(src)
    scene = bpy.context.scene
    settings = (scene.render.engine, scene.cycles.shading_system)
    assert bpy.ops.lamina.add_porous_layer(preset="rust_on_metal", form="osl") == {"FINISHED"}
    new = sphere.material_slots[0].material
    assert new.name == "My paint + Rust on metal" and material.info(new)["model"] == micrograin.ID
    _, p = material.current_params(new)
    assert p.filling_factor == pytest.approx(0.6) and p.grain.type == "conductor"
    assert p.bulk.type == micrograin.WRAPPED  # the preset's own bulk is ignored
    assert bpy.data.materials.get("My paint") is src and src.use_fake_user  # no user left: kept for saving
    assert _snapshot(src) == {**before, "fake_user": True}
    assert (scene.render.engine, scene.cycles.shading_system) == settings  # OSL form: no scene change
    with pytest.raises(RuntimeError):  # poll: already a porous layer
        bpy.ops.lamina.add_porous_layer()


def test_operator_custom_settings_and_no_slot_assignment(registered, sphere):
    src = _principled("Wood")
    sphere.data.materials.append(src)
    assert bpy.ops.lamina.add_porous_layer(filling_factor=0.5, roughness_control="roughness", roughness=0.3,
                                           grain_type="conductor", conductor="soot",
                                           assign_to_slot=False) == {"FINISHED"}
    assert sphere.material_slots[0].material is src and not src.use_fake_user
    new = bpy.data.materials["Wood + Porous layer"]
    assert new.use_fake_user  # assigned nowhere: kept so that saving keeps it
    _, p = material.current_params(new)
    assert p.roughness == pytest.approx(0.3, abs=1e-5) and p.filling_factor == pytest.approx(0.5)
    assert list(p.grain.ior) == pytest.approx(micrograin.CONDUCTORS["soot"][0])


def test_operator_refuses_a_material_with_nothing_to_wrap(registered, sphere):
    src = _principled("Empty")
    src.node_tree.links.remove(src.node_tree.get_output_node("CYCLES").inputs["Surface"].links[0])
    sphere.data.materials.append(src)
    count = len(bpy.data.materials)
    with pytest.raises(RuntimeError, match="nothing to wrap"):
        bpy.ops.lamina.add_porous_layer(preset="dust_on_wood")
    assert len(bpy.data.materials) == count and sphere.material_slots[0].material is src


# --------------------------------------------------------------------------------------------------- panel


def _draw(mat):
    log = panel_log(mat)
    return " | ".join(str(k.get("text", "")) for _, a, k, _ in log), operators(log)


def test_panel_summarises_a_porous_layer_and_offers_add_on_other_materials(registered):
    src = _principled()
    texts, ops = _draw(src)
    assert ops["lamina.add_porous_layer"] is True and "not a Lamina material" in texts
    mat = wrap.add_porous_layer(src, presets.load(micrograin.ID, "rust_on_metal"), "nodes")
    material.shader_node(mat).inputs["Filling Factor"].default_value = 0.4  # read from the node
    texts, ops = _draw(mat)
    assert ops["lamina.add_porous_layer"] is False
    assert "Grains: conductor" in texts and "Filling factor: 0.40" in texts
    assert f"{micrograin.equivalent_roughness(0.4, 0.5):.3f}" in texts
    assert "Bulk: the material's own shader" in texts and "needs a reference bulk" in texts
    assert "lamina.set_form" in ops and ops["lamina.compare"] is False
    assert "lamina.set_multiple_scattering" not in ops
    sc = material.new_material(spongecake.ID, spongecake.params_from_dict(presets.load(spongecake.ID, "plastic")),
                               "nodes")
    texts, ops = _draw(wrap.add_porous_layer(sc, RED_DUST, "nodes"))
    assert "Bulk: SpongeCake" in texts and ops["lamina.compare"] is True and "needs a reference" not in texts
    texts, ops = _draw(sc)  # a SpongeCake material's panel is unchanged
    assert "lamina.set_multiple_scattering" in ops and ops["lamina.add_porous_layer"] is True


@pytest.mark.parametrize("preset, grain_type, control, conductor", [
    ("CUSTOM", "diffuse", "anfractuosity", "gold"), ("CUSTOM", "dielectric", "roughness", "soot"),
    ("CUSTOM", "conductor", "roughness", "CUSTOM"), ("mud_on_plastic", "diffuse", "anfractuosity", "gold")])
def test_dialog_draws_each_choice(preset, grain_type, control, conductor):
    """The dialog (drawn by Blender only in a UI session): the settings that apply, and the other roughness value."""
    from addon.operators.micrograin import LAMINA_OT_add_porous_layer as Op

    log = []
    fields = dict(layout=Layout(log), preset=preset, filling_factor=0.5, roughness_control=control,
                  anfractuosity=0.5, roughness=0.9, grain_type=grain_type, conductor=conductor)
    op = type("Op", (), {**fields, **{k: getattr(Op, k) for k in ("_other_control", "layer_dict", "_draw_custom")}})()
    Op.draw(op, bpy.context)
    props = [a[1] for name, a, k, _ in log if name == "prop"]
    texts = " | ".join(str(k.get("text", "")) for _, a, k, _ in log)
    assert props[0] == "preset" and props[-2:] == ["form", "assign_to_slot"]
    if preset != "CUSTOM":
        assert props == ["preset", "form", "assign_to_slot"] and "filling factor 0.50" in texts
        return
    assert ("grain_color" in props) == (grain_type != "conductor")
    assert ("grain_ior" in props) == (grain_type == "dielectric")
    assert ("conductor_ior" in props) == (grain_type == "conductor" and conductor == "CUSTOM")
    if control == "anfractuosity":
        assert f"Equivalent roughness α = {micrograin.equivalent_roughness(0.5, 0.5):.3f}" in texts
    else:  # 0.9 is above the largest α̃ at τ0 = 0.5: β capped at 1
        assert f"Anfractuosity β = 1 (largest α here: {micrograin.equivalent_roughness(0.5, 1.0):.3f})" in texts
