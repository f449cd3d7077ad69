"""Compare with reference: render the active Lamina material with Cycles and with the Python reference in a
temporary scene (the user's scene is untouched), step by step from a timer so the UI stays responsive."""
from __future__ import annotations

import tempfile

import bpy

from ..nodes import material as lamina_material
from . import compare_run
from .progress import end_modal

SCENE_ITEMS = [("ALL", "All scenes", "")] + [(s, s.capitalize(), "") for s in compare_run.SCENES]


class LaminaCompareSettings(bpy.types.PropertyGroup):
    samples: bpy.props.IntProperty(name="Samples", default=64, min=1, max=4096)
    resolution: bpy.props.IntProperty(name="Resolution", default=96, min=16, max=1024)
    scene: bpy.props.EnumProperty(name="Scene", items=SCENE_ITEMS, default="sphere")
    multiple_scattering: bpy.props.BoolProperty(
        name="Multiple scattering", default=False,
        description="Also compare single scattering alone and SS + MS (network) with a Monte Carlo ground truth "
                    "of SS + MS (slower: a random walk per pixel)")
    ms_paths: bpy.props.IntProperty(
        name="Monte Carlo paths", default=1000, min=2, max=1_000_000,
        description="Random-walk paths per light direction of the multiple-scattering ground truth")
    ms_stride: bpy.props.IntProperty(
        name="Monte Carlo stride", default=2, min=1, max=16,
        description="The ground truth runs at every n-th row and column; errors use those pixels")
    blends: bpy.props.BoolProperty(
        name="Other blending weights", default=False,
        description="Porous layers: also render the reference with a plain linear mix by the filling factor (the "
                    "paper's Fig. 14) and with d'Eon et al.'s weighting (Eq. 26), beside the view- and "
                    "light-dependent weight")
    principled: bpy.props.BoolProperty(
        name="Principled BSDF", default=True,
        description="Also render Blender's Principled BSDF set up from the same parameters (what you would "
                    "otherwise use) and measure it against the reference (models whose mapping has one: thin "
                    "coats, anisotropic stacks)")
    truth: bpy.props.BoolProperty(
        name="Monte Carlo ground truth", default=False,
        description="Also measure the reference, Cycles (and the Principled BSDF) against a Monte Carlo simulation "
                    "of the material's light paths at sampled pixels (slower; models with such a ground truth)")
    truth_paths: bpy.props.IntProperty(
        name="Monte Carlo paths", default=2000, min=16, max=1_000_000,
        description="Paths per sampled pixel of the Monte Carlo ground truth")
    truth_stride: bpy.props.IntProperty(
        name="Monte Carlo stride", default=4, min=1, max=16,
        description="The ground truth runs at every n-th row and column; errors use those pixels")
    last_report: bpy.props.StringProperty(name="Last report", default="")


class LAMINA_OT_compare(bpy.types.Operator):
    """Render the active Lamina material with Cycles and with the reference, and show both with an error map"""

    bl_idname = "lamina.compare"
    bl_label = "Compare with Reference"

    _timer = None

    @classmethod
    def poll(cls, context):
        return lamina_material.is_lamina(getattr(context, "material", None))

    def _start(self, context):
        settings = context.window_manager.lamina_compare
        self._mat = context.material
        _, p = lamina_material.current_params(self._mat)
        self._scenes = compare_run.default_scene_names(p) if settings.scene == "ALL" else [settings.scene]
        self._done = []
        self._cache = {}
        # Blender's session temp folder: removed when Blender exits; the picture shown is packed into the file
        self._out = tempfile.mkdtemp(prefix="lamina_compare_", dir=bpy.app.tempdir or None)
        context.window_manager.progress_begin(0, len(self._scenes))

    def _refusal(self, context) -> str | None:
        """Why the comparison cannot run with these settings (None: it can)."""
        from ..models.params import ParamError

        model_id, p = lamina_material.current_params(context.material)
        reason = compare_run.refusal(model_id, p)
        if reason or not self._multiple_scattering(context, model_id):
            return reason
        try:
            compare_run.with_multiple_scattering(model_id, p)
        except (ParamError, KeyError) as e:
            return f"Multiple scattering: {e}"
        return None

    @staticmethod
    def _multiple_scattering(context, model_id: str) -> bool:
        wanted = context.window_manager.lamina_compare.multiple_scattering
        return wanted and compare_run.has_multiple_scattering(model_id)

    def invoke(self, context, event):
        refusal = self._refusal(context)
        if refusal:
            self.report({"ERROR"}, refusal)
            return {"CANCELLED"}
        self._start(context)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):  # scripted and headless use: every step at once
        refusal = self._refusal(context)
        if refusal:
            self.report({"ERROR"}, refusal)
            return {"CANCELLED"}
        self._start(context)
        while self._step(context):
            pass
        return self._finish(context)

    def modal(self, context, event):
        if event.type == "ESC":
            self._cleanup(context)
            self.report({"WARNING"}, "Comparison cancelled")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._step(context):
            return {"RUNNING_MODAL"}
        return self._finish(context)

    def _step(self, context) -> bool:
        """Render the next scene; False when all are done."""
        if len(self._done) == len(self._scenes):
            return False
        scene = self._scenes[len(self._done)]
        if context.workspace is not None:
            context.workspace.status_text_set(f"Lamina: comparing {self._mat.name} ({scene})…")
        settings = context.window_manager.lamina_compare
        model_id = lamina_material.info(self._mat)["model"]
        ms = None
        if self._multiple_scattering(context, model_id):
            from ..reference.spongecake_truth import TruthSettings

            ms = TruthSettings(paths=settings.ms_paths, albedo_paths=2 * settings.ms_paths, stride=settings.ms_stride)
        blends = settings.blends and compare_run.has_blends(model_id)
        principled = settings.principled and compare_run.has_principled(model_id)
        truth = None
        if settings.truth and compare_run.has_truth(model_id):
            truth = compare_run.CoatTruth(paths=settings.truth_paths, stride=settings.truth_stride)
        self._done.append(compare_run.compare_material(self._mat, [scene], settings.samples, settings.resolution,
                                                       0, self._out, reference_cache=self._cache, ms=ms,
                                                       blends=blends, principled=principled, truth=truth))
        context.window_manager.progress_update(len(self._done))
        return True

    def _finish(self, context):
        self._cleanup(context)
        report = {scene: entry for part in self._done for scene, entry in part.items()}
        lines = compare_run.scene_lines(report)
        context.window_manager.lamina_compare.last_report = "\n".join(lines)
        image = compare_run.show_side_by_side(context, report, self._out)
        for line in lines:
            self.report({"INFO"}, line)
        self.report({"INFO"}, f"Images in {self._out}" + (f"; shown as image {image.name!r}" if image else ""))
        return {"FINISHED"}

    def _cleanup(self, context):
        end_modal(context, self._timer)
        self._timer = None


