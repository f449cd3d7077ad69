"""Fit to budget in Blender: the operator and ``lamina optimize`` rebuild the Lamina node in the configuration the
budget chooses (``nodes.budget``), keep the user's nodes, record the decision (the panel shows it), choose the same
configuration when run again, and never choose OSL in a scene that does not render it."""
import os
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon import presets  # noqa: E402
from addon.models import micrograin  # noqa: E402
from addon.models import spongecake as sponge  # noqa: E402
from addon.nodes import budget, material, predicted_image, pruning  # noqa: E402
from addon.operators import blend_io  # noqa: E402
from addon.reference import scenes as S  # noqa: E402
from renders import relative_error, render, renders_with_and_without_lamina  # noqa: E402
from ui_helpers import panel_text  # noqa: E402

pytestmark = pytest.mark.blender
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(autouse=True)
def empty_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def rust_material(name="rust"):
    """rust_on_metal (the series geometric term over a reference metal) in the node group, with a Mix Shader of the
    user's between the Lamina node and the output."""
    mat = material.new_material(micrograin.ID, micrograin.params_from_dict(presets.load(micrograin.ID,
                                                                                      "rust_on_metal")), "nodes",
                                name=name)
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.name = "user mix"
    tree.links.new(material.shader_node(mat).outputs[0], mix.inputs[1])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def _fit(mat, percent: float):
    with bpy.context.temp_override(material=mat):
        assert bpy.ops.lamina.fit_to_budget(budget=percent) == {"FINISHED"}
    return material.budget_record(mat)


def _user_mix_is_fed_by_lamina(mat) -> bool:
    mix = mat.node_tree.nodes.get("user mix")
    return mix is not None and mix.inputs[1].links[0].from_node == material.shader_node(mat)


def test_the_operator_applies_the_cheapest_configuration_and_fitting_again_changes_nothing(registered):
    mat = rust_material()
    bpy.context.scene.cycles.shading_system = False
    record = _fit(mat, 50.0)  # a wide budget: the cheaper geometric term qualifies
    chosen = record["chosen"]
    assert {c["form"] for c in record["candidates"]} == {"nodes"}  # OSL is off in the scene: never a candidate
    assert chosen["variant"] == "GGX geometric term" and material.current_params(mat)[1].gaf == "ggx"
    assert record["target"]["gaf"] == "series" and _user_mix_is_fed_by_lamina(mat)
    assert " ".join(record["summary"].split()) in " ".join(panel_text(mat).split())
    assert bpy.context.scene.cycles.shading_system is False  # the user's scene settings are theirs

    assert "Changed since" not in panel_text(mat)
    node = material.shader_node(mat)
    socket = node.inputs[material.socket_key(node, "Filling Factor")]
    socket.default_value = 0.3
    assert "Changed since" in panel_text(mat)
    socket.default_value = record["chosen"]["params"]["filling_factor"]

    again = _fit(mat, 50.0)
    assert again["chosen"] == chosen and again["target"] == record["target"]
    assert again["current"]["variant"] == chosen["variant"]  # measured as what it renders now

    narrow = _fit(mat, 0.01)  # the most accurate configuration, measured against the material as set
    best = min(record["candidates"], key=lambda c: c["error"])
    assert narrow["chosen"]["error"] == pytest.approx(best["error"])
    assert material.current_params(mat)[1].gaf == best["params"]["gaf"] and _user_mix_is_fed_by_lamina(mat)


def test_osl_is_a_candidate_where_the_scene_renders_it(registered):
    mat = rust_material()
    bpy.context.scene.cycles.shading_system = True
    record = _fit(mat, 2.0)
    assert {c["form"] for c in record["candidates"]} == {"nodes", "osl"}
    assert material.form_of(mat) == record["chosen"]["form"]


@pytest.mark.version_independent("a CLI pipeline in a subprocess; the Fit to budget operator runs under 4.2 too")
def test_lamina_optimize_writes_the_fitted_file_and_leaves_the_original(tmp_path):
    for name in ("rust", "rust 2"):
        rust_material(name).use_fake_user = True  # saved though on no object
    blend, out = str(tmp_path / "in.blend"), str(tmp_path / "out.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    before = open(blend, "rb").read()
    r = subprocess.run([sys.executable, "-m", "addon.cli", "optimize", "--blend", blend, "--all", "--budget", "0.5",
                        "--out", out], capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=ROOT),
                       timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("GGX geometric term") == 2 and f"wrote {out}" in r.stdout
    assert open(blend, "rb").read() == before
    bpy.ops.wm.open_mainfile(filepath=out)
    for name in ("rust", "rust 2"):
        mat = bpy.data.materials[name]
        assert material.current_params(mat)[1].gaf == "ggx" and material.budget_record(mat) is not None
        assert _user_mix_is_fed_by_lamina(mat)


def _prune(mat, p, form, left_out) -> None:
    """Rebuild ``mat`` (window_shade) without the closures ``left_out``, as Fit to budget applies it."""
    chosen = budget.Candidate(budget.AS_SET, p, form, "analytic", 0.0, 1.0, 0, 0, left_out)
    material.apply_decision(mat, budget.Decision(0.02, p, chosen, [chosen]))
    assert material.pruned_of(mat) == left_out


@pytest.mark.parametrize("form", ["nodes", "osl"])
def test_a_pruned_material_renders_its_prediction_and_renders_without_lamina(form, tmp_path):
    p = sponge.params_from_dict(presets.load(sponge.ID, "window_shade"))
    left_out = pruning.prunable(sponge.ID, p, form)[-1]  # the largest set offered: the weakest three closures
    mat = material.new_material(sponge.ID, p, form, name="shade")
    _prune(mat, p, form, left_out)
    for spec, samples in ((S.sphere_scene(resolution=40), 32), (S.furnace_scene(resolution=(24, 12)), 128)):
        predicted = predicted_image(sponge.ID, p, form, spec, left_out)
        assert relative_error(render(mat, spec, samples, tmp_path), predicted, spec) < 0.02, spec.name
    material.set_form(mat, "osl" if form == "nodes" else "nodes")  # any other rebuild builds every closure again
    assert material.pruned_of(mat) is None
    blend = tmp_path / "pruned.blend"
    blend_io.write_material_blend(sponge.ID, p, form, "pruned", str(blend))
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    _prune(bpy.data.materials["Lamina pruned"], p, form, left_out)
    bpy.ops.wm.save_mainfile()
    here, fresh = renders_with_and_without_lamina(blend, "Lamina pruned", tmp_path)
    assert here.mean() > 1e-3
    np.testing.assert_array_equal(here, fresh)


def camera_scene(mat):
    """A UV sphere with ``mat`` at the origin and the scene's camera 6 units away on -y, looking at it along +y."""
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0)
    bpy.context.object.data.materials.append(mat)
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    bpy.context.scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0.0, -6.0, 0.0), (np.pi / 2, 0.0, 0.0)
    bpy.context.scene.camera = camera
    return camera


def test_the_camera_view_is_the_points_of_the_material_it_sees(registered):
    from addon.operators import budget_ops

    mat = rust_material()
    camera_scene(mat)
    scene = bpy.context.scene
    frames = np.array(budget_ops.camera_view(scene, mat).frames)
    n, t, b, wo = frames.reshape(-1, 4, 3).transpose(1, 0, 2)
    assert 20 < len(frames) <= budget_ops.MAX_VIEW_POINTS
    assert np.all(np.sum(n * wo, axis=1) > 0.0) and np.all(wo[:, 1] < -0.9)  # facing the camera, on -y
    for u, v in ((n, t), (n, b), (t, b)):
        np.testing.assert_allclose(np.sum(u * v, axis=1), 0.0, atol=1e-5)
    assert n[:, 0].min() < -0.8 and n[:, 0].max() > 0.8
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-0.5, -3.0, 0.0))  # hides the sphere's -x half
    bpy.context.object.data.materials.append(bpy.data.materials.new("wall"))
    hidden = np.array(budget_ops.camera_view(scene, mat).frames)
    assert len(hidden) > 20 and hidden[:, 0].min() > -0.2 and hidden[:, 0].max() > 0.8
    assert budget_ops.camera_view(scene, bpy.data.materials["wall"]) is not None
    assert budget_ops.camera_view(scene, bpy.data.materials.new("nowhere")) is None
    scene.camera = None
    assert budget_ops.camera_view(scene, mat) is None


def test_fit_to_budget_measures_on_the_camera_view_where_asked(registered):
    mat = rust_material()
    camera = camera_scene(mat)
    bpy.context.scene.cycles.shading_system = False
    with bpy.context.temp_override(material=mat):
        assert bpy.ops.lamina.fit_to_budget(budget=2.0, view="CAMERA") == {"FINISHED"}
    record = material.budget_record(mat)
    assert record["measured_on"].startswith("the camera's view (") and "on the camera's view" in record["summary"]
    assert " ".join(record["summary"].split()) in " ".join(panel_text(mat).split())
    bpy.context.scene.camera = None
    bpy.data.objects.remove(camera)
    with bpy.context.temp_override(material=mat), pytest.raises(RuntimeError, match="no active camera"):
        bpy.ops.lamina.fit_to_budget(budget=2.0, view="CAMERA")
    assert material.budget_record(mat) == record  # left as it was
