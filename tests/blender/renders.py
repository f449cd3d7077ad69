"""Helpers of the Blender tests that render (imported like tests/unit/stats.py): a Cycles render of a material on a
comparison scene, its relative error against a prediction, and a material made of one OSL closure."""
import bpy  # noqa: F401  (Blender first: the add-on's Cycles layer imports it)

from addon.nodes import osl
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


def closure_material(closure: str):
    """A material whose Surface is an OSL script node returning ``closure`` (fed the Geometry node's tangent)."""
    mat, tree, out = empty_material("fact")
    node = tree.nodes.new("ShaderNodeScript")
    osl.load_into_script_node(node, osl.compile_source(CLOSURE_SHADER.format(closure)))
    tree.links.new(node.outputs["BSDF"], out.inputs["Surface"])
    tree.links.new(tree.nodes.new("ShaderNodeNewGeometry").outputs["Tangent"], node.inputs["LaminaTangent"])
    return mat
