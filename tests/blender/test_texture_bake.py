"""Texture-driven layers: per-texel multiple-scattering bake into EXRs, wired into the Lamina node; Cycles renders
each half of a two-valued texture as the per-texel prediction for that half's parameters; bad inputs are refused
with nothing written or wired; the operator and ``lamina bake``.

Expected values come from the network itself (``nodes.spongecake.lobe_values`` of one texel's stack), never from
numbers written here: the shipped weights are placeholders until the real training run. Because the placeholder
network predicts almost no multiple scattering, the renders also run with a stand-in network whose lobes are
strong (W1 = 1/2, Lambert weights 0.3 albedo (1 - e^-T)), so a wrong or flipped baked texel shows."""
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon import cli  # noqa: E402
from addon.bake import exr, textures  # noqa: E402
from addon.bake import layer_rows as rows_  # noqa: E402
from addon.bake import spongecake as ms  # noqa: E402
from addon.models import spongecake as model  # noqa: E402
from addon.nodes import material, predicted_image, texture_wiring, view_wiring  # noqa: E402
from addon.nodes import spongecake as mapping  # noqa: E402
from addon.operators import bake_ops  # noqa: E402
from addon.operators.cycles_render import render_cycles  # noqa: E402
from addon.reference import metrics  # noqa: E402
from addon.reference import scenes as S  # noqa: E402

from renders import texture_halves  # noqa: E402
from ui_helpers import panel_text  # noqa: E402

pytestmark = pytest.mark.blender
LAYER = {"type": "surface", "roughness": 0.3, "thickness": 1.0, "albedo": [0.8, 0.8, 0.8]}
W, H = 8, 4
# parameter → (file kind, left half, right half, marker at the top-left texel): 8-bit values for PNGs
CASES = {
    "albedo": ("srgb-png", (200, 60, 30), (40, 120, 220), (255, 255, 255)),
    "thickness": ("exr", 0.3, 3.0, 8.0),
    "roughness": ("data-png", (80, 40, 20), (200, 230, 150), (255, 255, 255)),  # colour → float: luminance
    "orientation": ("exr", (0.5, 0.0, 0.866), (-0.4, 0.3, 0.5), (0.0, 0.0, 1.0)),  # raw vectors, not unit
}


@pytest.fixture(autouse=True)
def empty_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


@pytest.fixture
def saved(tmp_path):
    """A saved (empty) file, so that the cache folder is tmp_path/lamina_cache."""
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    return tmp_path


@pytest.fixture
def strong_network(monkeypatch):
    """A stand-in for the network with strong, parameter-dependent lobes (shapes from the real decode)."""
    real = ms.predict_rows

    def strong(rows):
        lobes, weights = real(rows)
        lobes = np.array(rows, dtype=np.float64)
        lobes[..., rows_.ALBEDO] *= 0.5
        top = rows[:, 0]
        weights[:] = (0.3 * top[:, rows_.ALBEDO].mean(axis=1) * (1 - np.exp(-top[:, rows_.THICKNESS])))[:, None]
        return lobes, weights

    _clear_caches()
    monkeypatch.setattr(ms, "predict_rows", strong)
    monkeypatch.setattr(textures, "predict_rows", strong)
    yield
    _clear_caches()


def _clear_caches():
    """The network's predictions and what is cached from them (per stack and weights folder, not per stand-in)."""
    ms.forget_networks()
    mapping._ms_values.cache_clear()
    mapping._budget_table.cache_clear()


# ------------------------------------------------------------------------------------------- helpers

def _halves(folder, param, size=(H, W), name=None):
    """Write the case's two-valued image (row 0 = top); returns (path, what the input receives per texel)."""
    kind, left, right, marker = CASES[param]
    h, w = size
    values = np.empty((h, w, 3))
    values[:, :w // 2] = left
    values[:, w // 2:] = right
    values[0, 0] = marker
    path = os.path.join(str(folder), (name or f"{param}") + (".exr" if kind == "exr" else ".png"))
    if kind == "exr":
        exr.write_exr(path, np.dstack([values, np.ones((h, w))]).astype(np.float32))
        received = values if np.ndim(left) else values[:, :, 0]
    else:
        exr.write_png(path, np.dstack([values, np.full((h, w), 255)]).astype(np.uint8))
        received = values / 255.0
        if kind == "srgb-png":
            received = textures.srgb_to_linear(received).astype(np.float64)
        else:
            received = textures.luminance(received).astype(np.float64)
    return path, received


def _material(param, path, form="nodes", name="textured", vector=None):
    """A Lamina material with multiple scattering whose layer-1 ``param`` is an Image Texture (Closest)."""
    p = model.params_from_dict({"layers": [LAYER], "multiple_scattering": True})
    mat = material.new_material(model.ID, p, form, name=name)
    tex = _texture(mat, param, path)
    if vector is not None:
        mat.node_tree.links.new(vector, tex.inputs["Vector"])
    return mat, tex


def _texture(mat, param, path):
    tree = mat.node_tree
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = bpy.data.images.load(path)
    if CASES[param][0] == "data-png":
        tex.image.colorspace_settings.name = "Non-Color"
    tex.interpolation = "Closest"
    node = material.shader_node(mat)
    socket = textures.texturable_inputs(material.current_params(mat)[1])[(0, param)]
    tree.links.new(tex.outputs["Color"], node.inputs[material.socket_key(node, socket)])
    return tex


def _params(values: dict):
    return model.params_from_dict({"layers": [{**LAYER, **values}], "multiple_scattering": True})


def _texel_value(received, y, x):
    v = received[y, x]
    return float(v) if np.ndim(v) == 0 else [float(c) for c in v]


def _cache_files(folder):
    cache = os.path.join(str(folder), "lamina_cache")
    return sorted(os.listdir(cache)) if os.path.isdir(cache) else []


def _ms_links(mat):
    """The Lamina node's MS inputs fed by baked textures (not the ``MS Energy`` view table's lookup)."""
    node = material.shader_node(mat)
    return {s.name: s.links[0].from_node for s in node.inputs
            if s.is_linked and s.name.startswith("MS") and not view_wiring.fed(s)}


# ------------------------------------------------------------------------------------------- baking

@pytest.mark.parametrize("param", sorted(CASES))
def test_baked_maps_load_as_non_color_and_match_the_prediction_per_source_texel(param, saved):
    path, received = _halves(saved, param)
    mat, _ = _material(param, path)
    summary, warnings = bake_ops.bake(mat)
    assert "Baked" in summary and warnings == []
    p = material.current_params(mat)[1]
    layout = textures.map_layout(p)
    nodes = {n.image.name: n for n in texture_wiring.baked_nodes(mat) if n.bl_idname == "ShaderNodeTexImage"}
    assert len(nodes) == len(layout)
    links = _ms_links(mat)
    assert set(links) == {material.socket_key(material.shader_node(mat), s.name)
                          for s in mapping.sockets(p) if s.per_texel}
    form = material.form_of(mat)
    own = mapping.ms_values(p, form)  # the energy scale is the material's own, not per texel
    node = material.shader_node(mat)
    energy = node.inputs[material.socket_key(node, mapping.MS_ENERGY_INPUT)]
    np.testing.assert_allclose(np.asarray(energy.default_value)[:3], own[mapping.MS_ENERGY_INPUT], rtol=1e-5)
    assert view_wiring.fed(energy)  # from the material's own view table
    for name, channels in layout.items():
        tex = next(n for n in nodes.values() if n.label == f"Lamina bake: {name}")
        image = tex.image
        assert image.colorspace_settings.name == "Non-Color" and image.alpha_mode == "CHANNEL_PACKED"
        assert image.filepath.startswith("//lamina_cache/")  # relative to the saved file
        px = np.empty(W * H * 4, dtype=np.float32)
        image.pixels.foreach_get(px)
        px = px.reshape(H, W, 4)[::-1]  # Blender's rows start at the bottom
        np.testing.assert_array_equal(px, exr.read_exr(bpy.path.abspath(image.filepath), "RGBA"))
        for y in range(H):
            for x in range(W):
                want = mapping.lobe_values(_params({param: _texel_value(received, y, x)}))
                expected = [np.atleast_1d(want[e[0]])[e[1]] if e else (1.0 if c == 3 else 0.0)
                            for c, e in enumerate(channels)]
                np.testing.assert_allclose(px[y, x], expected, rtol=1e-5, atol=1e-7, err_msg=f"{name} {(x, y)}")
    # the marker texel differs from its half: a flipped map fails above
    marker = mapping.lobe_values(_params({param: _texel_value(received, 0, 0)}))
    left = mapping.lobe_values(_params({param: _texel_value(received, H - 1, 0)}))
    assert marker != left


def test_srgb_textures_are_linearised_like_blender():
    """textures.srgb_to_linear against Blender's own colour management (which Cycles uses for 8-bit sRGB)."""
    from mathutils import Color

    v = np.arange(256) / 255.0
    blender = [Color((c, c, c)).from_srgb_to_scene_linear()[0] for c in v]
    np.testing.assert_allclose(textures.srgb_to_linear(v), blender, atol=2e-5)


# -------------------------------------------------------------------------------------------- renders

def _render_halves(param, form, folder, monkeypatch):
    """Cycles' render of a two-valued texture and the prediction of each half: that texel's baked lobes with the
    material's energy budget table (``MS Energy``), which follows the texture's value where one float input is
    driven (``nodes.spongecake.TexelEnergy``: looked up at each half's value) and is the material's own otherwise."""
    path, received = _halves(folder, param)
    mat, _ = _material(param, path, form)
    bake_ops.bake(mat)
    spec = S.plane_scene(resolution=(40, 20))
    img, _ = render_cycles(mat, spec, 32, 0, os.path.join(str(folder), f"{form}.exr"))
    halves = texture_halves(spec)
    texel = {"left": (H - 1, 0), "right": (H - 1, W - 1)}
    views = mapping.view_inputs(material.current_params(mat)[1], form, material.texel_energy(mat))
    monkeypatch.setattr(mapping, "view_inputs", lambda p, f, texels=None: views)
    predicted = {half: predicted_image(model.ID, _params({param: _texel_value(received, *texel[half])}), form, spec)
                 for half in halves}
    return img, halves, predicted, received


@pytest.mark.parametrize("form", ["nodes", "osl"])
@pytest.mark.parametrize("param", sorted(CASES))
def test_cycles_renders_each_half_as_predicted_for_its_parameters(param, form, saved, strong_network, monkeypatch):
    img, halves, predicted, received = _render_halves(param, form, saved, monkeypatch)
    for half, mask in halves.items():
        pred = predicted[half]
        err = metrics.rmse(img, pred, mask) / max(pred[mask].mean(), 1e-3)
        assert err < 0.02, f"{param} {form} {half}: {err:.4f}"
    # the test can tell: the halves differ, and the (stand-in) multiple scattering is a large part of each
    whole = np.ones(img.shape[:2], dtype=bool)
    assert metrics.rmse(predicted["left"], predicted["right"], whole) / predicted["left"].mean() > 0.1
    off = model.params_from_dict({"layers": [{**LAYER, param: _texel_value(received, H - 1, 0)}]})
    single = predicted_image(model.ID, off, form, S.plane_scene(resolution=(40, 20)))
    assert metrics.rmse(predicted["left"], single, whole) / predicted["left"].mean() > 0.1


@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_cycles_renders_the_shipped_networks_bake_per_half(form, saved, monkeypatch):
    img, halves, predicted, _ = _render_halves("albedo", form, saved, monkeypatch)
    for half, mask in halves.items():
        err = metrics.rmse(img, predicted[half], mask) / max(predicted[half][mask].mean(), 1e-3)
        assert err < 0.02, f"{form} {half}: {err:.4f}"


def test_a_thickness_texture_gives_the_energy_table_a_column_per_tabulated_thickness(saved, registered):
    """The ``MS Energy`` table follows the texels (``nodes.spongecake.TexelEnergy``): its columns are thicknesses over
    the texture's range and its coordinates take the texture's value; without the texture, a bake gives it back the
    material's own table."""
    path, _ = _halves(saved, "thickness")
    mat, tex = _material("thickness", path)
    bake_ops.bake(mat)
    node = material.shader_node(mat)
    lookup = node.inputs[mapping.MS_ENERGY_INPUT].links[0].from_node
    assert tuple(lookup.image.size) == (mapping.DRIVEN_ENERGY_VALUES, model.VIEW_ENERGY_GRID[0])
    assert lookup.inputs["Vector"].links[0].from_node.inputs[0].links[0].from_node == tex
    assert "Energy follows L1 Thickness's texture (9 values)" in panel_text(mat)
    axis = material.texel_energy(mat).axis
    assert axis.socket == "L1 Thickness" and (axis.values[0], axis.values[-1]) == pytest.approx((0.3, 8.0), rel=1e-6)
    del mat[material.TEXEL_ENERGY_KEY]  # as a texture bake of an earlier Lamina left it: one table, no fraction
    assert material.texel_energy(mat) == mapping.TexelEnergy()
    material.bake_constants(mat)
    assert node.inputs[mapping.MS_ENERGY_INPUT].links[0].from_node.image.size[0] == 2
    mat.node_tree.links.remove(node.inputs["L1 Thickness"].links[0])
    bake_ops.bake(mat)
    assert material.texel_energy(mat) is None
    assert node.inputs[mapping.MS_ENERGY_INPUT].links[0].from_node.image.size[0] == 2


def test_an_albedo_texture_is_looked_up_per_channel_and_rebaking_leaves_no_lookup_behind(saved, registered):
    path, _ = _halves(saved, "albedo")
    mat, tex = _material("albedo", path)
    bake_ops.bake(mat)
    node = material.shader_node(mat)
    join = node.inputs[mapping.MS_ENERGY_INPUT].links[0].from_node
    assert join.bl_idname == "ShaderNodeCombineColor" and material.texel_energy(mat).axis.channels
    textures_read = {link.from_node.inputs[0].links[0].from_node.name for s in join.inputs[:3] for link in s.links}
    assert len(textures_read) == 3
    assert len(view_wiring.lookups(mat.node_tree)) == 11  # split, 3 × (coordinates, texture, channel), join
    assert "Energy follows L1 Albedo's texture (9 values)" in panel_text(mat)
    mat.node_tree.links.remove(node.inputs["L1 Albedo"].links[0])
    bake_ops.bake(mat)
    assert {n.bl_idname for n in view_wiring.lookups(mat.node_tree)} == {"ShaderNodeTexImage", "ShaderNodeGroup"}
    assert len(view_wiring.lookups(mat.node_tree)) == 2


# ---------------------------------------------------------------------------------------- cache, re-bake

def test_rebaking_unchanged_inputs_is_a_cache_hit_that_replaces_only_lamina_nodes(saved, monkeypatch):
    path, _ = _halves(saved, "albedo")
    mat, tex = _material("albedo", path)
    note = mat.node_tree.nodes.new("ShaderNodeValue")
    note.name = "my value"
    bake_ops.bake(mat)
    files = _cache_files(saved)
    stamps = {f: os.stat(os.path.join(str(saved), "lamina_cache", f)).st_mtime_ns for f in files}
    before = sorted(n.name for n in mat.node_tree.nodes)

    def no_network(rows):
        raise AssertionError("a cache hit must not run the network")

    monkeypatch.setattr(textures, "predict_rows", no_network)
    summary, _ = bake_ops.bake(mat)
    assert "cache hit" in summary
    assert _cache_files(saved) == files
    assert {f: os.stat(os.path.join(str(saved), "lamina_cache", f)).st_mtime_ns for f in files} == stamps
    assert len(texture_wiring.baked_nodes(mat)) == len(files) and len(mat.node_tree.nodes) == len(before)
    assert mat.node_tree.nodes.get("my value") == note and tex.name in mat.node_tree.nodes
    assert len([i for i in bpy.data.images if i.name.startswith("lamina_ms_")]) == len(files)


def test_a_changed_texture_is_rebaked_and_the_old_bake_unwired(saved):
    path, _ = _halves(saved, "albedo")
    mat, tex = _material("albedo", path)
    bake_ops.bake(mat)
    old = {n.image.name for n in texture_wiring.baked_nodes(mat) if n.bl_idname == "ShaderNodeTexImage"}
    exr.write_png(path, np.full((H, W, 4), 90, dtype=np.uint8))
    tex.image.reload()
    summary, _ = bake_ops.bake(mat)
    assert "cache hit" not in summary
    new = {n.image.name for n in texture_wiring.baked_nodes(mat) if n.bl_idname == "ShaderNodeTexImage"}
    assert len(new) == len(old) and not new & old
    assert not any(name in bpy.data.images for name in old)  # no one else used them
    assert len(_cache_files(saved)) == 2 * len(new)  # the earlier bake stays in the cache


def test_without_textures_the_bake_writes_the_constants_and_removes_an_old_bake(saved):
    path, _ = _halves(saved, "albedo")
    mat, tex = _material("albedo", path)
    bake_ops.bake(mat)
    mat.node_tree.nodes.remove(tex)
    summary, _ = bake_ops.bake(mat)
    assert "nothing to bake" in summary
    assert texture_wiring.baked_nodes(mat) == [] and _ms_links(mat) == {}
    node = material.shader_node(mat)
    for name, value in mapping.ms_values(material.current_params(mat)[1], material.form_of(mat)).items():
        np.testing.assert_allclose(np.atleast_1d(node.inputs[name].default_value)[:np.size(value)],
                                   np.atleast_1d(value), rtol=1e-5)


def test_textures_of_different_sizes_are_resampled_to_the_largest(saved):
    albedo, _ = _halves(saved, "albedo")
    thickness, _ = _halves(saved, "thickness", size=(H // 2, W // 2))
    mat, _ = _material("albedo", albedo)
    _texture(mat, "thickness", thickness)
    summary, warnings = bake_ops.bake(mat)
    assert f"at {W} x {H}" in summary
    assert any("resampled from 4 x 2 to 8 x 4" in w for w in warnings), warnings
    assert all(n.image.size[:] == (W, H) for n in texture_wiring.baked_nodes(mat)
               if n.bl_idname == "ShaderNodeTexImage")


def test_baked_textures_share_the_sources_vector_input(saved):
    path, _ = _halves(saved, "albedo")
    p = model.params_from_dict({"layers": [LAYER], "multiple_scattering": True})
    mat = material.new_material(model.ID, p, "nodes")
    mapping_node = mat.node_tree.nodes.new("ShaderNodeMapping")
    tex = _texture(mat, "albedo", path)
    mat.node_tree.links.new(mapping_node.outputs["Vector"], tex.inputs["Vector"])
    bake_ops.bake(mat)
    for n in texture_wiring.baked_nodes(mat):
        if n.bl_idname == "ShaderNodeTexImage":
            assert n.inputs["Vector"].links[0].from_node == mapping_node
            assert n.interpolation == "Closest"


# ------------------------------------------------------------------------------------------ refusals

def _nan_texture(folder):
    values = np.full((H, W, 4), 1.0, dtype=np.float32)
    values[1, 2:5, 0] = np.nan
    path = os.path.join(str(folder), "holes.exr")
    exr.write_exr(path, values)
    return path


def _missing_file(folder):
    path, _ = _halves(folder, "albedo", name="gone")
    return path


@pytest.mark.parametrize("case, match", [
    ("nan", r"image 'holes.exr' \(L1 Thickness\): 3 texel\(s\) are NaN or infinite"),
    ("missing", r"image 'gone.png' \(L1 Albedo\): the image has no pixels: the file .*gone.png is missing"),
    ("no lamina node", "has no Lamina node"),
    ("ms off", "multiple scattering off"),
    ("math node", "driven by a Math node"),
    ("two mappings", "different Vector inputs"),
    ("f0 linked", "F0 is linked"),
])
def test_bad_inputs_are_refused_with_nothing_written_or_wired(case, match, saved):
    path, _ = _halves(saved, "albedo")
    mat, tex = _material("albedo", path)
    tree, node = mat.node_tree, material.shader_node(mat)
    if case == "nan":
        tex.image = bpy.data.images.load(_nan_texture(saved))
        tree.links.new(tex.outputs["Color"], node.inputs["L1 Thickness"])
        tree.links.remove(node.inputs["L1 Albedo"].links[0])
    elif case == "missing":
        tex.image = bpy.data.images.load(_missing_file(saved))
        os.remove(bpy.path.abspath(tex.image.filepath))
        tex.image.reload()
    elif case == "no lamina node":
        node.name = "renamed by hand"
    elif case == "ms off":
        data = material.info(mat)
        data["params"]["multiple_scattering"] = False
        mat["lamina"] = __import__("json").dumps(data)
    elif case == "math node":
        math = tree.nodes.new("ShaderNodeMath")
        tree.links.new(math.outputs[0], node.inputs["L1 Roughness"])
    elif case == "two mappings":
        other = _texture(mat, "thickness", _halves(saved, "thickness")[0])
        tree.links.new(tree.nodes.new("ShaderNodeTexCoord").outputs["Object"], other.inputs["Vector"])
    elif case == "f0 linked":
        p = model.params_from_dict({"layers": [{**LAYER, "f0": [0.5, 0.5, 0.5]}], "multiple_scattering": True})
        mat = material.new_material(model.ID, p, "nodes")
        tex = _texture(mat, "albedo", path)
        mat.node_tree.links.new(tex.outputs["Color"], material.shader_node(mat).inputs["L1 F0"])
    nodes_before = sorted(n.name for n in mat.node_tree.nodes)
    with pytest.raises(textures.BakeError, match=match):
        bake_ops.bake(mat)
    assert _cache_files(saved) == []
    assert sorted(n.name for n in mat.node_tree.nodes) == nodes_before and texture_wiring.baked_nodes(mat) == []


def test_a_cancelled_bake_writes_and_wires_nothing(saved):
    path, _ = _halves(saved, "albedo")
    mat, _ = _material("albedo", path)
    run = bake_ops.BakeRun(mat)
    assert run.step() and run.fraction == 1.0
    run.cancel()
    assert not run.step()
    assert _cache_files(saved) == [] and texture_wiring.baked_nodes(mat) == [] and _ms_links(mat) == {}


def test_unsaved_files_bake_into_a_user_or_temporary_folder():
    import tempfile

    assert bake_ops.cache_folder().startswith(tempfile.gettempdir())  # Lamina runs from a source tree here


# ------------------------------------------------------------------------------------- operator, CLI

def test_the_operator_bakes_and_reports(saved, registered):
    path, _ = _halves(saved, "albedo")
    mat, _ = _material("albedo", path)
    with bpy.context.temp_override(material=mat):
        assert bpy.ops.lamina.bake_textures() == {"FINISHED"}
        assert len(_ms_links(mat)) == len([s for s in mapping.sockets(material.current_params(mat)[1]) if s.per_texel])
        material.shader_node(mat).name = "gone"
        with pytest.raises(RuntimeError, match="has no Lamina node"):
            bpy.ops.lamina.bake_textures()


class _WindowManager:
    """Records what the modal operator asks of the window manager (no window exists in background mode)."""

    def __init__(self):
        self.calls = []

    def __getattr__(self, name):
        return lambda *args, **kwargs: self.calls.append(name) or name  # a timer handle for event_timer_add


def _modal_operator(mat):
    """The operator's own invoke/modal/... run on a stand-in instance (bpy only creates operators it runs)."""
    op = bake_ops.LAMINA_OT_bake_textures
    methods = {name: getattr(op, name) for name in ("invoke", "modal", "_start", "_finish", "_cleanup")}
    reports = []
    instance = type("Op", (), {**methods, "_timer": None, "_run": None,
                               "report": lambda self, kind, text: reports.append((kind.pop(), text))})()
    context = type("Ctx", (), {"material": mat, "window_manager": _WindowManager(), "window": None,
                               "workspace": None})()
    return instance, context, reports


def _event(kind):
    return type("Event", (), {"type": kind})()


@pytest.mark.parametrize("cancel", [False, True])
def test_the_modal_operator_steps_from_the_timer_and_esc_cancels_cleanly(cancel, saved):
    path, _ = _halves(saved, "albedo")
    mat, _ = _material("albedo", path)
    op, context, reports = _modal_operator(mat)
    assert op.invoke(context, _event("NONE")) == {"RUNNING_MODAL"}
    assert op.modal(context, _event("MOUSEMOVE")) == {"PASS_THROUGH"}
    assert op.modal(context, _event("TIMER")) == {"RUNNING_MODAL"}  # one chunk computed
    if cancel:
        assert op.modal(context, _event("ESC")) == {"CANCELLED"}
        assert reports == [("WARNING", "Bake cancelled: nothing was written or changed")]
        assert _cache_files(saved) == [] and texture_wiring.baked_nodes(mat) == []
    else:
        steps = [op.modal(context, _event("TIMER")) for _ in range(2)]  # the last chunk, then the energy table
        assert steps == [{"RUNNING_MODAL"}, {"FINISHED"}]
        assert reports[-1][0] == "INFO" and "Baked" in reports[-1][1] and texture_wiring.baked_nodes(mat)
    calls = context.window_manager.calls
    assert calls[:3] == ["progress_begin", "event_timer_add", "modal_handler_add"] and "progress_update" in calls
    assert calls[-2:] == ["event_timer_remove", "progress_end"]


def _blend_with_texture(folder, ms=True):
    path, _ = _halves(folder, "albedo")
    mat, _ = _material("albedo", path, name="Textured")
    if not ms:
        data = material.info(mat)
        data["params"]["multiple_scattering"] = False
        mat["lamina"] = __import__("json").dumps(data)
    mat.use_fake_user = True  # kept in the saved file without an object
    bpy.data.materials.new("Plain").use_fake_user = True
    blend = os.path.join(str(folder), "in.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    return blend


def test_cli_bake_writes_a_baked_copy(tmp_path, capsys):
    blend = _blend_with_texture(tmp_path)
    out = tmp_path / "out" / "baked.blend"
    out.parent.mkdir()
    assert cli.main(["bake", "--blend", blend, "--material", "Textured", "--out", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    bpy.ops.wm.open_mainfile(filepath=str(out))
    mat = bpy.data.materials["Textured"]
    baked = [n for n in texture_wiring.baked_nodes(mat) if n.bl_idname == "ShaderNodeTexImage"]
    assert baked and all(os.path.isfile(bpy.path.abspath(n.image.filepath)) for n in baked)
    assert all(n.image.size[:] == (W, H) for n in baked)  # the relative paths were remapped on save
    assert [p.name for p in out.parent.iterdir()] == ["baked.blend"]  # no temporary left


@pytest.mark.parametrize("args, code, reason", [
    (["--material", "Nope"], 2, "--material 'Nope': no such material"),
    (["--material", "Plain"], 2, "Plain is not a Lamina material"),
    (["--material", "Textured", "--exists"], 2, "exists; pass --overwrite"),
    (["--material", "Textured", "--no-out"], 2, "pass --out FILE, or --overwrite"),
    (["--material", "Textured", "--nan"], 1, "NaN or infinite"),
    (["--material", "Textured", "--ms-off"], 2, "multiple scattering off"),
])
def test_cli_bake_refusals_exit_non_zero_with_one_line_and_write_nothing(args, code, reason, tmp_path, capsys):
    blend = _blend_with_texture(tmp_path, ms="--ms-off" not in args)
    if "--nan" in args:
        mat = bpy.data.materials["Textured"]
        tex = next(n for n in mat.node_tree.nodes
                   if n.bl_idname == "ShaderNodeTexImage" and not n.get(view_wiring.VIEW_TAG))
        tex.image = bpy.data.images.load(_nan_texture(tmp_path))
        bpy.ops.wm.save_mainfile()
    out = tmp_path / "out.blend"
    if "--exists" in args:
        out.write_bytes(b"user data")
    argv = ["bake", "--blend", blend, "--material", args[1]] + ([] if "--no-out" in args else ["--out", str(out)])
    capsys.readouterr()
    assert cli.main(argv) == code
    err = capsys.readouterr().err
    assert reason in err and err.strip().count("\n") == 0
    assert not out.exists() or out.read_bytes() == b"user data"
    assert _cache_files(tmp_path) == []
