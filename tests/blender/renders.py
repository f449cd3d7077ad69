"""Helpers of the Blender tests that render (imported like tests/unit/stats.py): a Cycles render of a material on a
comparison scene, its relative error against a prediction, a material made of one OSL closure, a saved .blend
rendered with and without Lamina, and the kinds of a material's view-table nodes."""
import os
import subprocess
import sys

import bpy  # noqa: F401  (Blender first: the add-on's Cycles layer imports it)

from addon.nodes import osl, view_wiring
from addon.nodes.material import empty_material
from addon.operators.cycles_render import render_cycles
from addon.reference import metrics
from addon.reference import scenes as S

# One closure expression in a shader; Tn is the tangent the mappings' closures use.
CLOSURE_SHADER = ('#include "stdcycles.h"\nshader t(vector LaminaTangent = vector(0), output closure color BSDF = 0) '
                  '{{ vector Tn = normalize(LaminaTangent); BSDF = {}; }}')


def render(mat, spec, samples, tmp_path):
    """Cycles' image of ``mat`` on the comparison scene ``spec`` (no noise seed offset)."""
    img, _ = render_cycles(mat, spec, samples, 0, str(tmp_path / f"{spec.name}.exr"))
    return img


def relative_error(img, predicted, spec):
    """RMSE over the object over the prediction's mean (floored at 1e-3 for nearly black scenes)."""
    mask = S.scene_mask(spec)
    return metrics.rmse(img, predicted, mask) / max(predicted[mask].mean(), 1e-3)


def texture_halves(spec):
    """{"left", "right"}: the pixels of the plane scene ``spec`` that see the left or the right half of a texture on
    the plane's UVs. The panorama sees the plane point x = -tan(theta) cos(phi): the texture's right half (x > 0) where
    cos(phi) < 0; columns next to the boundary and the top row (where jittered rays cross over) are left out."""
    import numpy as np

    phi = S.pixel_geometry(spec)["phi_o"]
    keep = np.abs(np.cos(phi)) > 0.2
    keep[0] = False
    return {"left": (np.cos(phi) > 0) & keep, "right": (np.cos(phi) < 0) & keep}


# Renders a scene of a .blend at 32 px, 16 samples, into an EXR; run here and as a fresh process's script.
SAVED_RENDER = """
def render(blend, scene_name, out):
    import bpy
    bpy.ops.wm.open_mainfile(filepath=blend)
    scene = bpy.data.scenes[scene_name]
    scene.render.resolution_x = scene.render.resolution_y = 32
    scene.cycles.samples = 16
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = out
    bpy.ops.render.render(write_still=True, scene=scene.name)
"""
FRESH_MAIN = """
import sys
render(sys.argv[1], sys.argv[2], sys.argv[3])
print("LAMINA_MODULES", [m for m in sys.modules if m == "addon" or m.startswith("addon.") or "lamina" in m])
"""


def renders_with_and_without_lamina(blend, scene_name: str, tmp_path):
    """(here, fresh) RGB images of the .blend's scene: rendered in this process (Lamina loaded) and in a fresh one
    where Lamina cannot even be imported (asserted)."""
    from addon.bake.exr import read_exr

    namespace = {}
    exec(SAVED_RENDER, namespace)
    here, fresh = tmp_path / "here.exr", tmp_path / "fresh.exr"
    namespace["render"](str(blend), scene_name, str(here))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run([sys.executable, "-c", SAVED_RENDER + FRESH_MAIN, str(blend), scene_name, str(fresh)],
                       capture_output=True, text=True, cwd=str(tmp_path), timeout=300, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "LAMINA_MODULES []" in r.stdout
    return read_exr(here, "RGB"), read_exr(fresh, "RGB")


def closure_material(closure: str):
    """A material whose Surface is an OSL script node returning ``closure`` (fed the Geometry node's tangent)."""
    mat, tree, out = empty_material("fact")
    node = tree.nodes.new("ShaderNodeScript")
    osl.load_into_script_node(node, osl.compile_source(CLOSURE_SHADER.format(closure)))
    tree.links.new(node.outputs["BSDF"], out.inputs["Surface"])
    tree.links.new(tree.nodes.new("ShaderNodeNewGeometry").outputs["Tangent"], node.inputs["LaminaTangent"])
    return mat


def view_lookup_kinds(mat) -> list[str]:
    """The sorted node types of Lamina's view-table lookups in ``mat`` (an Image Texture and its coordinates)."""
    return sorted(n.bl_idname for n in view_wiring.lookups(mat.node_tree))
