"""Switching form or multiple scattering replaces only Lamina's own nodes: the user's textures, mapping nodes and
shader mixes stay, with their links re-created on the new Lamina node (and keys and drivers on its inputs moved to
it); Lamina's baked texture nodes stay while
they feed it and go when they no longer do; a failed generation changes nothing in the tree."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon.bake import exr  # noqa: E402
from addon.models import spongecake as model  # noqa: E402
from addon.nodes import material, osl, texture_wiring, view_wiring  # noqa: E402
from addon.nodes import spongecake as spongecake_nodes  # noqa: E402
from addon.operators import bake_ops  # noqa: E402
from renders import view_lookup_kinds  # noqa: E402

pytestmark = pytest.mark.blender
LAYER = {"type": "surface", "roughness": 0.3, "thickness": 1.0, "albedo": [0.8, 0.8, 0.8]}


@pytest.fixture(autouse=True)
def empty_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def _params(ms=False):
    return model.params_from_dict({"layers": [LAYER], "multiple_scattering": ms})


def _input(mat, name):
    node = material.shader_node(mat)
    return node.inputs[material.socket_key(node, name)]


def _feeds(socket):
    return [(link.from_node.name, link.from_socket.name) for link in socket.links]


def _user_setup(mat, image_path=None, value=True):
    """An Image Texture (through UV Map → Mapping) into L1 Albedo, a Mix Shader between Lamina and the output,
    a Value node into L1 Thickness (unless ``value`` is False: a bake accepts only Image Textures), and an
    unlinked Geometry node of the user's; the Lamina node moved and widened."""
    tree = mat.node_tree
    lamina = material.shader_node(mat)
    lamina.location, lamina.width = (-120.0, 75.0), 310.0
    uv = tree.nodes.new("ShaderNodeUVMap")
    mapping = tree.nodes.new("ShaderNodeMapping")
    tex = tree.nodes.new("ShaderNodeTexImage")
    if image_path is not None:
        tex.image = bpy.data.images.load(image_path)
    tree.links.new(uv.outputs["UV"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], _input(mat, "L1 Albedo"))
    if value:
        value = tree.nodes.new("ShaderNodeValue")
        tree.links.new(value.outputs[0], _input(mat, "L1 Thickness"))
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    mix = tree.nodes.new("ShaderNodeMixShader")
    out = tree.nodes["Material Output"]
    tree.links.new(lamina.outputs["BSDF"], mix.inputs[1])
    tree.links.new(diffuse.outputs["BSDF"], mix.inputs[2])
    tree.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    mine = tree.nodes.new("ShaderNodeNewGeometry")
    mine.name = "my geometry"
    names = {"uv": uv.name, "mapping": mapping.name, "tex": tex.name, "diffuse": diffuse.name, "mix": mix.name,
             "out": out.name, "geometry": mine.name}
    return {**names, "value": value.name} if value else names


def _assert_user_setup_kept(mat, names, form):
    tree = mat.node_tree
    assert all(name in tree.nodes for name in names.values())
    lamina = material.shader_node(mat)
    assert material.form_of(mat) == form
    assert tuple(lamina.location) == (-120.0, 75.0) and lamina.width == 310.0
    assert _feeds(_input(mat, "L1 Albedo")) == [(names["tex"], "Color")]
    if "value" in names:
        assert _feeds(_input(mat, "L1 Thickness")) == [(names["value"], "Value")]
    assert [(link.to_node.name, link.to_socket.identifier) for link in lamina.outputs["BSDF"].links] == \
        [(names["mix"], tree.nodes[names["mix"]].inputs[1].identifier)]
    assert _feeds(tree.nodes[names["out"]].inputs["Surface"]) == [(names["mix"], "Shader")]
    assert _feeds(tree.nodes[names["tex"]].inputs["Vector"]) == [(names["mapping"], "Vector")]
    assert _feeds(tree.nodes[names["mapping"]].inputs["Vector"]) == [(names["uv"], "UV")]
    assert not any(o.is_linked for o in tree.nodes[names["geometry"]].outputs)
    helpers = [n for n in tree.nodes if n.get(material.HELPER_TAG)]
    if form == "osl":  # one tagged Geometry node feeds the tangent
        assert len(helpers) == 1 and helpers[0].name != names["geometry"]
        assert _feeds(lamina.inputs["LaminaTangent"]) == [(helpers[0].name, "Tangent")]
    else:
        assert helpers == []
    lookups = {n.name for n in view_wiring.lookups(tree)}  # the MS Energy table's, with MS on
    user = {n.name for n in tree.nodes} - {"Lamina"} - {n.name for n in helpers} - lookups
    assert user == set(names.values())  # nothing added, nothing lost


def test_a_new_material_is_lamina_into_the_output():
    for form in material.FORMS:
        mat = material.new_material(model.ID, _params(), form)
        tree = mat.node_tree
        expected = {"Lamina", "Material Output"} | ({"Geometry"} if form == "osl" else set())
        assert {n.name for n in tree.nodes} == expected
        assert _feeds(tree.nodes["Material Output"].inputs["Surface"]) == [("Lamina", "BSDF")]
        assert len(tree.links) == (2 if form == "osl" else 1)


def test_switching_form_keeps_the_users_nodes_and_links():
    mat = material.new_material(model.ID, _params(), "nodes")
    names = _user_setup(mat)
    material.set_form(mat, "osl")
    _assert_user_setup_kept(mat, names, "osl")
    material.set_form(mat, "osl")  # same form again: the helper is reused, not duplicated
    _assert_user_setup_kept(mat, names, "osl")
    material.set_form(mat, "nodes")
    _assert_user_setup_kept(mat, names, "nodes")


@pytest.mark.parametrize("form", material.FORMS)
def test_toggling_multiple_scattering_keeps_the_users_nodes_and_links(form):
    mat = material.new_material(model.ID, _params(ms=True), form)
    names = _user_setup(mat)
    ms_value = mat.node_tree.nodes.new("ShaderNodeValue")  # the user's own node into an MS input
    mat.node_tree.links.new(ms_value.outputs[0], _input(mat, "MS L1 Thickness"))
    material.set_multiple_scattering(mat, False)
    _assert_user_setup_kept(mat, {**names, "ms": ms_value.name}, form)
    assert not any(o.is_linked for o in ms_value.outputs)  # its input is gone: the link with it, not the node
    assert view_lookup_kinds(mat) == []  # and the MS Energy table's lookup with its image
    material.set_multiple_scattering(mat, True)
    _assert_user_setup_kept(mat, {**names, "ms": ms_value.name}, form)
    assert not material.ms_is_stale(mat) and view_lookup_kinds(mat) == ["ShaderNodeGroup", "ShaderNodeTexImage"]


def test_a_lamina_node_in_a_frame_stays_there():
    mat = material.new_material(model.ID, _params(), "nodes")
    frame = mat.node_tree.nodes.new("NodeFrame")
    frame.location = (400.0, -250.0)
    material.shader_node(mat).parent = frame
    where = tuple(material.shader_node(mat).location)
    for form in ("osl", "nodes"):
        material.set_form(mat, form)
        node = material.shader_node(mat)
        assert node.parent == frame and tuple(node.location) == pytest.approx(where)


def test_an_old_untagged_tangent_helper_is_recognised():
    mat = material.new_material(model.ID, _params(), "osl")
    geometry = mat.node_tree.nodes["Geometry"]
    del geometry[material.HELPER_TAG]  # as made before helpers were tagged
    material.set_multiple_scattering(mat, True)
    assert [n.name for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeNewGeometry"] == ["Geometry"]
    assert mat.node_tree.nodes["Geometry"].get(material.HELPER_TAG)
    del mat.node_tree.nodes["Geometry"][material.HELPER_TAG]
    material.set_form(mat, "nodes")
    assert "Geometry" not in mat.node_tree.nodes


def test_a_deleted_lamina_node_is_rebuilt_without_taking_the_output():
    mat = material.new_material(model.ID, _params(), "nodes")
    tree = mat.node_tree
    tree.nodes.remove(material.shader_node(mat))
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    tree.links.new(diffuse.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
    material.set_form(mat, "osl")
    assert material.form_of(mat) == "osl"
    assert _feeds(tree.nodes["Material Output"].inputs["Surface"]) == [(diffuse.name, "BSDF")]


# ------------------------------------------------------------------------------------------- baked textures

@pytest.fixture
def baked(tmp_path):
    """A saved file with a material whose L1 Albedo is an Image Texture (two-valued), baked."""
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    values = np.full((4, 8, 4), 255, dtype=np.uint8)
    values[:, :4, :3], values[:, 4:, :3] = (200, 60, 30), (40, 120, 220)
    path = str(tmp_path / "albedo.png")
    exr.write_png(path, values)
    mat = material.new_material(model.ID, _params(ms=True), "nodes")
    names = _user_setup(mat, path, value=False)
    summary, _ = bake_ops.bake(mat)
    assert "Baked" in summary
    return mat, names


def _bake_state(mat):
    """The baked nodes and what each MS input is fed by (node name, output name)."""
    node = material.shader_node(mat)
    ms = {material._norm(s.name): _feeds(s) for s in node.inputs if s.name.startswith("MS")}
    return sorted(n.name for n in texture_wiring.baked_nodes(mat)), ms


def test_baked_textures_survive_a_form_switch(baked):
    mat, names = baked
    nodes, ms = _bake_state(mat)
    energy = material._norm(spongecake_nodes.MS_ENERGY_INPUT)
    assert nodes and all(feeds for name, feeds in ms.items() if name != energy)  # every per-texel MS input is
    assert view_wiring.fed(_input(mat, "MS Energy"))  # driven by a baked node; the energy scale is the material's
    assert not {name for name, _ in ms[energy]} & set(nodes)  # own: its view table
    images = {n.image.name for n in texture_wiring.baked_nodes(mat) if n.bl_idname == "ShaderNodeTexImage"}
    key = mat[material.MS_KEY]
    for form in ("osl", "nodes"):
        material.set_form(mat, form)
        _assert_user_setup_kept(mat, {**names, **{n: n for n in nodes}}, form)
        assert _bake_state(mat) == (nodes, ms)
        assert all(name in bpy.data.images for name in images)
        assert mat[material.MS_KEY] == key and not material.ms_is_stale(mat)


@pytest.mark.parametrize("form", material.FORMS)
def test_turning_multiple_scattering_off_removes_the_bake_and_nothing_else(baked, form):
    mat, names = baked
    material.set_form(mat, form)
    images = {n.image.name for n in texture_wiring.baked_nodes(mat) if n.bl_idname == "ShaderNodeTexImage"}
    material.set_multiple_scattering(mat, False)
    assert texture_wiring.baked_nodes(mat) == []
    assert not any(name in bpy.data.images for name in images)  # no one else used them
    _assert_user_setup_kept(mat, names, form)
    material.set_multiple_scattering(mat, True)  # constants again, until the next bake
    assert texture_wiring.baked_nodes(mat) == [] and not material.ms_is_stale(mat)
    _assert_user_setup_kept(mat, names, form)


# ------------------------------------------------------------------------------------------- failures

def _snapshot(mat):
    """Everything about the tree a rebuild could change: nodes, their settings and inputs, links."""
    def value(socket):
        v = getattr(socket, "default_value", None)
        return tuple(v) if hasattr(v, "__len__") else v

    nodes = [(n.name, n.bl_idname, n.label, tuple(n.location), n.width, n.parent.name if n.parent else None,
              dict(n.items()) if n.keys() else {}, getattr(getattr(n, "node_tree", None), "name", None),
              getattr(n, "bytecode_hash", None),
              [(s.identifier, s.name, s.hide, value(s)) for s in n.inputs],
              [(s.identifier, s.name) for s in n.outputs]) for n in mat.node_tree.nodes]
    links = [(link.from_node.name, link.from_socket.identifier, link.to_node.name, link.to_socket.identifier,
              link.is_muted) for link in mat.node_tree.links]
    return nodes, links, mat["lamina"], mat.get(material.MS_KEY)


def _refuse(*_):
    raise osl.OslCompileError("refused")


@pytest.mark.parametrize("form", material.FORMS)
@pytest.mark.parametrize("change", ["form", "ms"])
def test_a_failed_generation_leaves_the_tree_exactly_as_it_was(form, change, monkeypatch):
    mat = material.new_material(model.ID, _params(ms=True), form)
    _user_setup(mat)
    before = _snapshot(mat)
    monkeypatch.setattr(osl, "compile_source", _refuse)  # both generators fail
    monkeypatch.setattr(material, "node_group", _refuse)
    with pytest.raises(osl.OslCompileError):
        if change == "form":
            material.set_form(mat, "osl" if form == "nodes" else "nodes")
        else:
            material.set_multiple_scattering(mat, False)
    assert _snapshot(mat) == before


@pytest.mark.parametrize("first, second", [("nodes", "osl"), ("osl", "nodes")])
def test_keys_and_drivers_on_the_inputs_move_to_the_new_node(first, second):
    """Blender deletes a removed node's F-curves: the rebuild points them at the new node's input of the same name
    first, so an animated roughness and a driven thickness keep animating after a form switch."""
    mat = material.new_material(model.ID, _params(), first)
    roughness = _input(mat, "L1 Roughness")
    for frame, value in ((1, 0.2), (10, 0.7)):
        roughness.default_value = value
        roughness.keyframe_insert("default_value", frame=frame)
    driver = _input(mat, "L1 Thickness").driver_add("default_value").driver
    driver.expression = "2.5"
    material.set_form(mat, second)
    animation = mat.node_tree.animation_data
    curves = {c.data_path: c for c in list(animation.drivers) + material._fcurves(animation.action)}
    assert len(curves) == 2
    for name, kind in (("L1 Roughness", "keys"), ("L1 Thickness", "driver")):
        target = _input(mat, name)
        curve = next(c for path, c in curves.items() if mat.node_tree.path_resolve(path.rsplit(".", 1)[0]) == target)
        assert (curve.driver is not None) == (kind == "driver")
    keyed = next(c for c in curves.values() if c.driver is None)
    assert [keyed.evaluate(f) for f in (1, 10)] == pytest.approx([0.2, 0.7])
    assert material.driven_inputs(mat) == sorted(material.socket_key(material.shader_node(mat), n)
                                                 for n in ("L1 Roughness", "L1 Thickness"))
