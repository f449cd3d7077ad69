"""Add Neural Medium Material and Bake Scattering (modal, cancellable), and the CLI's ``bake-medium`` file flow."""
from __future__ import annotations

import math

import bpy

from .. import presets
from ..bake import neural_medium as nb
from ..models import neural_medium as model
from ..models.params import ParamError
from ..nodes import neural_medium as medium_nodes
from . import blend_io, medium_bake
from .progress import begin_modal
from .material_ops import CUSTOM, assign_to_active_slot, built_or_reported, declared, preset_items

PRESET_ITEMS = preset_items(model.ID, "Set the medium's coefficients below")
INPUT_ITEMS = [("coefficients", "Coefficients", "Scattering and absorption per unit length (RGB), as the paper"),
               ("color_density", "Colour + density",
                "Single-scattering albedo (the colour of a thick piece) and extinction per unit length, the way an "
                "artist sets a Principled Volume")]


class LAMINA_OT_add_neural_medium(bpy.types.Operator):
    """Fill the active mesh with a homogeneous scattering medium (milk, wax, jade, cloud): Cycles renders its single
    scattering, Bake Scattering adds the rest"""

    bl_idname = "lamina.add_neural_medium"
    bl_label = "Add Neural Medium Material"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS, default="milk",
                                   description="A medium after the paper's Table 1, or Custom")
    input_mode: bpy.props.EnumProperty(name="Set", items=INPUT_ITEMS, default="coefficients")
    sigma_s: declared(model.MEDIUM, "sigma_s")
    sigma_a: declared(model.MEDIUM, "sigma_a")
    color: bpy.props.FloatVectorProperty(name="Colour", size=3, subtype="COLOR", min=0.0, max=1.0,
                                         default=(0.9, 0.9, 0.9),
                                         description="Single-scattering albedo per channel")
    density: bpy.props.FloatProperty(name="Density", default=1.0, min=1e-6, max=1e4,
                                     description="Extinction per unit length (all channels)")
    g: declared(model.MEDIUM, "g")
    scale: declared(model.MEDIUM, "scale")
    from_volume: bpy.props.BoolProperty(
        name="From the material's volume", default=True,
        description="Take the medium from the active material's homogeneous Principled Volume (or Volume Scatter + "
                    "Absorption); that material stays in the file")

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if obj is None or obj.type != "MESH":
            cls.poll_message_set("Select a closed mesh: the medium fills it")
            return False
        return True

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self, width=340)

    def draw(self, context):
        layout = self.layout
        if self.source_volume(context) is not None:
            layout.prop(self, "from_volume")
        if self.use_volume(context):
            layout.label(text=f"Converting the volume of {context.active_object.active_material.name}", icon="INFO")
        else:
            self.draw_medium(layout)
        layout.prop(self, "scale")
        p = self.params_or_none(context)
        if p is not None:
            mfp = ", ".join(f"{m:.3g}" for m in p.mean_free_path)
            layout.label(text=f"Albedo {', '.join(f'{a:.3f}' for a in p.albedo)}; mean free path {mfp}")

    def draw_medium(self, layout):
        layout.prop(self, "preset")
        if self.preset != CUSTOM:
            layout.label(text=presets.description(model.ID, self.preset)[:70], icon="INFO")
        else:
            layout.prop(self, "input_mode", expand=True)
            col = layout.column(align=True)
            if self.input_mode == "coefficients":
                col.prop(self, "sigma_s")
                col.prop(self, "sigma_a")
            else:
                col.prop(self, "color")
                col.prop(self, "density")
            layout.prop(self, "g")

    def source_volume(self, context) -> dict | None:
        mat = getattr(context.active_object, "active_material", None)
        if mat is None or medium_nodes.is_medium(mat):
            return None
        return medium_nodes.volume_of(mat)

    def use_volume(self, context) -> bool:
        return self.from_volume and self.source_volume(context) is not None

    def medium_dict(self, context=None) -> dict:
        if context is not None and self.use_volume(context):
            volume = self.source_volume(context)
            return {**volume, "sigma_s": [s * self.scale for s in volume["sigma_s"]],
                    "sigma_a": [a * self.scale for a in volume["sigma_a"]], "scale": self.scale}
        if self.preset != CUSTOM:
            return {**presets.load(model.ID, self.preset), "scale": self.scale}
        if self.input_mode == "coefficients":
            return {"sigma_s": list(self.sigma_s), "sigma_a": list(self.sigma_a), "g": self.g, "scale": self.scale}
        return {"sigma_s": [c * self.density for c in self.color],
                "sigma_a": [(1.0 - c) * self.density for c in self.color], "g": self.g, "scale": self.scale}

    def params_or_none(self, context=None):
        try:
            return model.params_from_dict(self.medium_dict(context))
        except ParamError:
            return None

    def execute(self, context):
        try:
            validated = model.validate(self.medium_dict(context))
        except ParamError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for w in validated.warnings:
            self.report({"WARNING"}, w)
        if self.use_volume(context):
            name = f"{context.active_object.active_material.name} ({model.LABEL})"
        else:
            name = model.LABEL if self.preset == CUSTOM else f"{model.LABEL} {self.preset.replace('_', ' ')}"
        mat = built_or_reported(self, lambda: medium_nodes.new_material(validated.params, name),
                                f"Could not build the {model.LABEL} material")
        if mat is None:
            return {"CANCELLED"}
        assign_to_active_slot(context.active_object, mat)
        problem = medium_bake.mesh_problem(context.active_object)
        if problem:
            self.report({"WARNING"}, f"{problem}: Bake Scattering will refuse it")
        self.report({"INFO"}, f"Added material {mat.name}; Bake Scattering adds the light of orders >= 2")
        return {"FINISHED"}


class LAMINA_OT_bake_medium(bpy.types.Operator):
    """Bake the double and multiple scattering of the active object's Lamina medium from the scene's lamps into its
    mesh (Esc cancels; nothing is written until the bake is complete)"""

    bl_idname = "lamina.bake_medium"
    bl_label = "Bake Scattering"
    bl_options = {"REGISTER", "UNDO"}

    cells: bpy.props.IntProperty(name="Beams per lamp side", default=nb.Settings.cells, min=1, max=256,
                                 description="Each lamp sends cells x cells virtual ray lights into the object")
    steps: bpy.props.IntProperty(name="Steps per ray", default=nb.Settings.steps, min=1, max=256,
                                 description="Quadrature points along each gathering ray")
    spacing: bpy.props.FloatProperty(name="Point spacing (mfp)", default=nb.Settings.spacing, min=0.0, max=16.0,
                                     description="Surface points closer than this many mean free paths share one "
                                                 "gather (0: every vertex gathers; 0.5: 2-3% from that, docs/accuracy.md)")
    grid_angle: bpy.props.FloatProperty(name="Beam grid angle", default=nb.Settings.grid_angle, min=0.0,
                                        max=math.pi, subtype="ANGLE",
                                        description="Beams in a cube seen under less than this angle are gathered "
                                                    "through one representative beam (the paper's grid of virtual "
                                                    "ray lights; 0: every beam, docs/accuracy.md)")
    grid_cube: bpy.props.FloatProperty(name="Beam grid cube (mfp)", default=nb.Settings.grid_cube, min=0.01,
                                       max=64.0, description="Side of the beam grid's cubes in mean free paths")
    segments: bpy.props.BoolProperty(name="Accumulated segments", default=nb.Settings.segments,
                                     description="Gather with the paper's camera segments integrated ahead of time: "
                                                 "one lookup per ray instead of one per step, a few seconds to "
                                                 "build (docs/accuracy.md)")

    _timer = None
    _steps = None
    _object = ""

    @classmethod
    def poll(cls, context):
        if medium_bake.medium_material(context.active_object) is None:
            cls.poll_message_set("The active object has no Lamina medium material")
            return False
        return True

    def _start(self, context):
        obj = context.active_object
        self._object = obj.name  # the bake is applied to this object, wherever the selection goes meanwhile
        p = medium_nodes.current_params(medium_bake.medium_material(obj))
        self._steps = medium_bake.bake_steps(obj, context.scene, context.evaluated_depsgraph_get(), p,
                                             nb.Settings(self.cells, self.steps, spacing=self.spacing,
                                                         grid_angle=self.grid_angle, grid_cube=self.grid_cube,
                                                         segments=self.segments))

    def execute(self, context):  # scripts and headless: the whole bake at once
        try:
            self._start(context)
            result = _drain(self._steps)
        except (medium_bake.BakeError, ValueError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        return self._finish(context, result)

    def invoke(self, context, event):
        try:
            self._start(context)
            next(self._steps)  # checks the input before any work, and finds the beams
        except (medium_bake.BakeError, ValueError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self._timer = begin_modal(self, context, 0.05, 1000)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self._end(context)
            self.report({"WARNING"}, "Bake cancelled: nothing was changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            fraction, message = next(self._steps)
        except StopIteration as done:
            self._end(context)
            return self._finish(context, done.value)
        except Exception as e:  # noqa: BLE001 - report and leave the object as it was
            self._end(context)
            self.report({"ERROR"}, f"Bake failed: {e}")
            return {"CANCELLED"}
        context.window_manager.progress_update(int(1000 * fraction))
        context.workspace.status_text_set(f"Lamina: {message} (Esc cancels)")
        return {"RUNNING_MODAL"}

    def _end(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)

    def _finish(self, context, result):
        obj = bpy.data.objects.get(self._object)
        if obj is None or obj.type != "MESH" or len(obj.data.vertices) != len(result["coefficients"]):
            self.report({"ERROR"}, f"{self._object} changed during the bake: nothing was written; bake again")
            return {"CANCELLED"}
        medium_bake.apply(obj, result)
        for note in result["notes"]:
            self.report({"WARNING"}, note)
        r = result["record"]
        self.report({"INFO"}, f"Baked {r['points']} points from {r['beams']} beams in {r['seconds']:.1f} s")
        return {"FINISHED"}


def _drain(steps):
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def bake_medium_file(blend: str, object_name: str, data: dict | None, out: str,
                     settings: nb.Settings = nb.Settings()) -> tuple[str, list[str]]:
    """``lamina bake-medium``: open ``blend``, give the object a new medium material from ``data`` (or use the one it
    has), bake, save as ``out``. BlendArgumentError / BakeError before anything is written."""
    blend_io.open_blend(blend)
    obj = bpy.data.objects.get(object_name)
    if obj is None:
        names = ", ".join(sorted(o.name for o in bpy.data.objects if o.type == "MESH")) or "none"
        raise blend_io.BlendArgumentError(f"--object {object_name!r}: no such object in {blend} (meshes: {names})")
    problem = medium_bake.mesh_problem(obj)
    if problem:
        raise medium_bake.BakeError(problem)
    warnings = []
    if data is not None:
        validated = model.validate(data)
        warnings += validated.warnings
        mat = medium_nodes.new_material(validated.params)
        assign_to_active_slot(obj, mat)
    mat = medium_bake.medium_material(obj)
    if mat is None:
        raise blend_io.BlendArgumentError(f"--object {object_name!r} has no Lamina medium material: pass --preset or "
                                          f"--json")
    scene = bpy.context.scene
    p = medium_nodes.current_params(mat)
    result = medium_bake.run(obj, scene, bpy.context.evaluated_depsgraph_get(), p, settings)
    blend_io.save_copy(out)
    r = result["record"]
    return (f"baked {obj.name} ({mat.name}): {r['points']} points ({r['gathered']} gathered), {r['beams']} beams, "
            f"{r['seconds']:.1f} s",
            warnings + result["notes"])


# The panel's button; the bake button is drawn by ui/neural_medium.py.
ADD = (LAMINA_OT_add_neural_medium.bl_idname, "MOD_FLUIDSIM")
classes = (LAMINA_OT_add_neural_medium, LAMINA_OT_bake_medium)
