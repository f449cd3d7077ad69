"""``add-porous`` on real .blend files: the new material replaces the original in every object slot, the original
stays with a fake user, files are written atomically and never overwritten without --overwrite; refusals exit 1
(the file's content) or 2 (arguments) with one line and write nothing."""
import json
import os
import subprocess
import sys

import pytest

bpy = pytest.importorskip("bpy")

from addon.models import micrograin  # noqa: E402
from addon.nodes import material  # noqa: E402

pytestmark = pytest.mark.blender
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def lamina(*args):
    return subprocess.run([sys.executable, "-m", "addon.cli", *args], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=ROOT), timeout=300)


@pytest.fixture
def scene_blend(tmp_path):
    """A .blend with "Paint" (Principled) on two objects sharing a mesh (data slot) and in one object slot, and
    "Other" on no object."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    paint, other = bpy.data.materials.new("Paint"), bpy.data.materials.new("Other")
    if bpy.app.version < (5, 0, 0):
        paint.use_nodes = other.use_nodes = True
    other.use_fake_user = True  # in the file, on no object
    mesh = bpy.data.meshes.new("shared")
    mesh.materials.append(paint)
    for name in ("a", "b"):
        bpy.context.scene.collection.objects.link(bpy.data.objects.new(name, mesh))
    c = bpy.data.objects.new("c", bpy.data.meshes.new("own"))
    bpy.context.scene.collection.objects.link(c)
    c.data.materials.append(None)
    c.material_slots[0].link = "OBJECT"
    c.material_slots[0].material = paint
    path = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return path


def _open(path):
    bpy.ops.wm.open_mainfile(filepath=str(path))
    return {o.name: [s.material.name for s in o.material_slots] for o in bpy.data.objects}


def test_add_porous_assigns_everywhere_and_keeps_the_original(scene_blend, tmp_path):
    original = scene_blend.read_bytes()
    out = tmp_path / "dusty.blend"
    r = lamina("add-porous", "--blend", str(scene_blend), "--material", "Paint", "--preset", "dust_on_wood",
               "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "in 3 object slot(s)" in r.stdout and str(out) in r.stdout
    assert scene_blend.read_bytes() == original  # --out: the input is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dusty.blend", "scene.blend"]  # no temporary left
    slots = _open(out)
    assert slots == {"a": ["Paint + Dust on wood"], "b": ["Paint + Dust on wood"], "c": ["Paint + Dust on wood"]}
    paint, new = bpy.data.materials["Paint"], bpy.data.materials["Paint + Dust on wood"]
    assert paint.use_fake_user and paint.users == 1  # the fake user only
    assert material.info(new)["model"] == micrograin.ID and material.form_of(new) == "nodes"
    assert material.info(new)["params"]["bulk"] == {"type": micrograin.WRAPPED}
    bulk = material.shader_node(new).inputs["Bulk"].links[0].from_node
    assert bulk.bl_idname == "ShaderNodeBsdfPrincipled" and bulk.id_data == new.node_tree
    assert paint.node_tree.get_output_node("CYCLES").inputs["Surface"].links[0].from_node.name == "Principled BSDF"


def test_add_porous_from_json_in_osl_over_the_input_with_overwrite(scene_blend, tmp_path):
    layer = tmp_path / "layer.json"
    layer.write_text(json.dumps({"filling_factor": 0.2, "roughness": 0.3,
                                 "grain": {"type": "dielectric", "albedo": [0.5, 0.5, 0.5], "ior": 1.4},
                                 "bulk": {"type": "diffuse"}}))  # the bulk is ignored
    r = lamina("add-porous", "--blend", str(scene_blend), "--material", "Paint", "--json", str(layer),
               "--form", "osl", "--overwrite")
    assert r.returncode == 0, r.stderr
    assert "Open Shading Language" in r.stderr  # warned, the scene is not changed
    _open(scene_blend)
    new = bpy.data.materials["Paint + Porous layer"]
    assert material.form_of(new) == "osl"
    _, p = material.current_params(new)
    assert p.roughness == pytest.approx(0.3, abs=1e-5) and p.grain.ior == pytest.approx(1.4)
    assert not any(s.cycles.shading_system for s in bpy.data.scenes)


def test_add_porous_refusals_write_nothing(scene_blend, tmp_path):
    out = tmp_path / "out.blend"
    r = lamina("add-porous", "--blend", str(scene_blend), "--material", "Chalk", "--preset", "dust_on_wood",
               "--out", str(out))
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0
    assert "--material 'Chalk': no such material" in r.stderr and "it has: Other, Paint" in r.stderr
    r = lamina("add-porous", "--blend", str(scene_blend), "--material", "Other", "--preset", "soot_on_clay",
               "--out", str(out))
    assert r.returncode == 0, r.stderr  # a material no object uses: added, reported
    assert "no object uses Other" in r.stderr
    existing = out.read_bytes()
    r = lamina("add-porous", "--blend", str(out), "--material", "Other + Soot on clay", "--preset", "dust_on_wood",
               "--out", str(tmp_path / "again.blend"))
    assert r.returncode == 2 and "already has a porous layer" in r.stderr  # a refusal of the material given
    r = lamina("add-porous", "--blend", str(scene_blend), "--material", "Paint", "--preset", "dust_on_wood",
               "--out", str(out))
    assert r.returncode == 2 and "--overwrite" in r.stderr
    assert out.read_bytes() == existing
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.blend", "scene.blend"]
