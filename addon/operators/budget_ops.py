"""Fit to budget (``nodes.budget``): the panel's operator and the headless ``lamina optimize``.

Both measure the candidate configurations of a Lamina material against its reference (numpy, no render), on the
comparison scenes or on the active camera's view of the objects that use it (``camera_view``), then rebuild its
Lamina node in the cheapest one within the error budget (``material.apply_decision``: undoable, the user's own nodes
untouched). OSL forms are candidates only where every scene already renders OSL: Lamina never turns the shading
system on.
"""
from __future__ import annotations

import threading

import bpy
from mathutils import Vector

from ..models import MODELS
from ..nodes import budget
from ..nodes import material as lamina_material
from ..reference import scenes as ref_scenes
from . import blend_io, compare_run
from .progress import begin_modal, end_modal


class BudgetRefusal(ValueError):
    """A material Fit to budget cannot choose for (nothing was changed)."""


def allowed_forms(scenes) -> tuple[str, ...]:
    """The node group, and OSL where every one of ``scenes`` renders with Cycles' OSL shading system."""
    scenes = list(scenes)
    osl = bool(scenes) and all(s.cycles.shading_system for s in scenes)
    return ("nodes", "osl") if osl else ("nodes",)


def refusal(mat) -> str | None:
    """Why Fit to budget cannot choose for ``mat`` (None: it can)."""
    if not lamina_material.is_lamina(mat):
        return "not a Lamina material"
    if lamina_material.info(mat)["model"] not in MODELS:
        return "a medium baked per object: it has no configurations to choose from"
    if lamina_material.shader_node(mat) is None:
        return "its Lamina node was removed"
    return compare_run.refusal(*lamina_material.current_params(mat))


def is_stale(mat, record: dict) -> bool:
    """Whether ``mat`` no longer renders the configuration its last Fit to budget (``record``) chose: a value edited,
    or the form, mapping or closures changed since."""
    chosen = record["chosen"]
    _, p = lamina_material.current_params(mat)
    pruned = lamina_material.pruned_of(mat)
    return (p.to_dict() != chosen["params"] or lamina_material.form_of(mat) != chosen["form"]
            or lamina_material.used_mapping(mat) != chosen["mapping"]
            or (pruned and pruned.to_json()) != chosen["pruned"])


def problem(mat) -> tuple:
    """(model id, the material as set, the configuration it renders with now) of a material without ``refusal``;
    read on the main thread."""
    model_id, p = lamina_material.current_params(mat)
    target = budget.target(model_id, p, lamina_material.budget_record(mat))
    return model_id, target, (p, lamina_material.form_of(mat), lamina_material.used_mapping(mat),
                              lamina_material.pruned_of(mat))


VIEW_RAYS = 24  # rays per side of the camera's frame that look for the material's objects
MAX_VIEW_POINTS = 128  # the points kept of those that hit (evenly spaced): the measure's cost grows with them
VIEWS = (("SCENES", "Comparison scenes", "Measure on Lamina's comparison scenes (sphere, plane, backlit, furnace)"),
         ("CAMERA", "Camera view", "Measure on the points of the objects with this material that the active camera "
                                   "sees, under a key light and in a white furnace"))


def camera_view(scene, mat, rays: int = VIEW_RAYS) -> budget.CameraView | None:
    """The points of objects whose faces use ``mat`` that ``scene``'s active camera sees (``rays`` x ``rays`` rays
    through its frame), each with its normal turned towards the camera, the tangent Cycles gives anisotropic
    closures by default (radial around the object's Z axis), and the key light of the comparison sphere (45° up,
    30° round from the camera's right); None without a camera, or where it sees none of them."""
    camera = scene.camera
    if camera is None:
        return None
    depsgraph = bpy.context.evaluated_depsgraph_get()
    to_world = camera.matrix_world
    corners = [to_world @ v for v in camera.data.view_frame(scene=scene)]  # top right, bottom right, bottom left, ..
    forward = (to_world.to_3x3() @ Vector((0.0, 0.0, -1.0))).normalized()
    frames = []
    for i in range(rays):
        for j in range(rays):
            u, v = (i + 0.5) / rays, (j + 0.5) / rays
            top = corners[3].lerp(corners[0], u)
            point = top.lerp(corners[2].lerp(corners[1], u), v)
            if camera.data.type == "ORTHO":
                origin, direction = point - forward * camera.data.clip_end, forward
            else:
                origin, direction = to_world.translation, (point - to_world.translation).normalized()
            frame = _seen_point(scene, depsgraph, mat, origin, direction)
            if frame is not None:
                frames.append(frame)
    if not frames:
        return None
    step = max(1, -(-len(frames) // MAX_VIEW_POINTS))
    key = to_world.to_3x3() @ Vector(ref_scenes.sphere_scene().suns[0].direction)  # as the sphere's camera sees it
    return budget.CameraView(tuple(frames[::step]), tuple(key.normalized()))


def _seen_point(scene, depsgraph, mat, origin, direction):
    """(n, t, b, wo) of the first surface along the ray if its face uses ``mat``, else None; n is the face's
    (flat) normal."""
    hit, location, normal, index, obj, matrix = scene.ray_cast(depsgraph, origin, direction)
    if not hit or obj.type != "MESH":
        return None
    evaluated = obj.evaluated_get(depsgraph)
    slot = evaluated.data.polygons[index].material_index if index < len(evaluated.data.polygons) else 0
    if slot >= len(obj.material_slots) or obj.material_slots[slot].material != mat:
        return None
    wo = -direction
    n = normal.normalized()
    if n.dot(wo) < 0.0:  # Cycles turns a back face's normal towards the ray
        n = -n
    low, high = Vector(evaluated.bound_box[0]), Vector(evaluated.bound_box[6])
    generated = Vector(g / s if s > 0.0 else 0.5 for g, s in zip(matrix.inverted() @ location - low, high - low))
    # Cycles' radial Z tangent of the Generated coordinates (svm_node_tangent), transformed as a normal
    t = matrix.to_3x3().inverted_safe().transposed() @ Vector((0.5 - generated.y, generated.x - 0.5, 0.0))
    t = t - n * n.dot(t)
    if t.length < 1e-6:
        t = n.orthogonal()
    t.normalize()
    return (*n, *t, *n.cross(t), *wo)


def decide(mat, value: float, forms, progress=None, view: budget.CameraView | None = None) -> budget.Decision:
    """The decision for ``mat`` within the budget ``value`` (on ``view`` when given, ``camera_view``); BudgetRefusal
    for a material it cannot choose for."""
    reason = refusal(mat)
    if reason:
        raise BudgetRefusal(f"{mat.name}: {reason}")
    model_id, target, current = problem(mat)
    return budget.fit_to_budget(model_id, target, value, forms, current, progress=progress, view=view)


def optimize_file(blend: str, names: list[str], value: float, out: str, camera: bool = False) -> list[str]:
    """Open ``blend``, fit the materials ``names`` (every Lamina BSDF material when empty) to the budget ``value``
    (with ``camera``, on the active camera's view of each, where it sees it) and save the file as ``out``
    atomically; one summary line per material. A material that cannot be fitted, a file without any, or ``camera``
    in a file without an active camera raises ``blend_io.BlendArgumentError`` before anything is changed."""
    blend_io.open_blend(blend)
    scene = bpy.context.scene
    if camera and scene.camera is None:
        raise blend_io.BlendArgumentError(f"--view camera: the scene {scene.name!r} of {blend} has no active camera")
    if names:
        materials = [blend_io.find_material(name, blend) for name in names]
    else:
        materials = [m for m in bpy.data.materials if lamina_material.is_lamina(m)
                     and lamina_material.info(m)["model"] in MODELS]
        if not materials:
            raise blend_io.BlendArgumentError(f"--all: {blend} has no Lamina material to fit")
    for mat in materials:
        reason = refusal(mat)
        if reason:
            raise blend_io.BlendArgumentError(f"--material {mat.name!r}: {reason}")
    forms = allowed_forms(bpy.data.scenes)
    lines = []
    for mat in materials:
        view = camera_view(scene, mat) if camera else None
        decision = decide(mat, value, forms, view=view)
        lamina_material.apply_decision(mat, decision)
        unseen = " (the camera does not see it)" if camera and view is None else ""
        lines.append(f"{mat.name}: {decision.summary()}{unseen}")
    blend_io.save_copy(out)
    return lines


def view_setting(**kw):
    """Where Fit to budget measures (``VIEWS``): the operator's, and the panel's (on the window manager)."""
    return bpy.props.EnumProperty(name="Measure on", items=VIEWS, default="SCENES", **kw)


def budget_setting(**kw):
    """The error budget as a property (percent): the operator's, and the panel's (on the window manager)."""
    return bpy.props.FloatProperty(name="Error budget", default=100 * budget.DEFAULT_BUDGET, min=0.01, max=100.0,
                                   subtype="PERCENTAGE", precision=1,
                                   description="Relative RMSE allowed above the most accurate configuration Lamina "
                                               "can build (predicted on the comparison scenes)", **kw)


class LAMINA_OT_fit_to_budget(bpy.types.Operator):
    """Rebuild the active Lamina material in the cheapest configuration (form, mapping, bounces, multiple
    scattering, geometric term) whose predicted error stays within the error budget of the most accurate one"""

    bl_idname = "lamina.fit_to_budget"
    bl_label = "Fit to Budget"
    bl_options = {"REGISTER", "UNDO"}

    budget: budget_setting()
    view: view_setting()

    @classmethod
    def poll(cls, context):
        return lamina_material.is_lamina(getattr(context, "material", None))

    def _apply(self, mat, decision) -> set:
        try:
            lamina_material.apply_decision(mat, decision)
        except Exception as e:  # noqa: BLE001 - report, leave the material as it was
            self.report({"ERROR"}, f"Could not rebuild {mat.name}: {e}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"{mat.name}: {decision.summary()}")
        return {"FINISHED"}

    def _view(self, context, mat) -> tuple[bool, budget.CameraView | None]:
        """(whether to go on, the camera's view when the operator measures on it); reports why not."""
        if self.view != "CAMERA":
            return True, None
        view = camera_view(context.scene, mat)
        if view is None:
            why = ("the scene has no active camera" if context.scene.camera is None
                   else "the active camera sees no object with it")
            self.report({"ERROR"}, f"{mat.name}: {why}; measure on the comparison scenes instead")
        return view is not None, view

    def execute(self, context):
        mat = context.material
        go, view = self._view(context, mat)
        if not go:
            return {"CANCELLED"}
        try:
            decision = decide(mat, self.budget / 100.0, allowed_forms([context.scene]), view=view)
        except (BudgetRefusal, budget.BudgetError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        return self._apply(mat, decision)

    def invoke(self, context, event):
        """Measure in a thread (numpy only) with a progress bar, then rebuild on the main thread (in background
        mode, at once: no event loop runs a modal operator there)."""
        mat = context.material
        if bpy.app.background:
            return self.execute(context)
        reason = refusal(mat)
        if reason:
            self.report({"ERROR"}, f"{mat.name}: {reason}")
            return {"CANCELLED"}
        go, view = self._view(context, mat)
        if not go:
            return {"CANCELLED"}
        self._material = mat.name
        model_id, target, current = problem(mat)
        forms, value = allowed_forms([context.scene]), self.budget / 100.0
        # plain state the thread writes: the operator is freed when Esc ends it
        self._state = state = {"fraction": 0.0, "decision": None, "error": None}

        def work():
            try:
                state["decision"] = budget.fit_to_budget(model_id, target, value, forms, current, view=view,
                                                         progress=lambda f: state.__setitem__("fraction", f))
            except Exception as e:  # noqa: BLE001 - reported on the main thread
                state["error"] = e

        self._thread = threading.Thread(target=work, daemon=True)
        self._thread.start()
        self._timer = begin_modal(self, context, 0.25, 100)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            end_modal(context, self._timer)
            self.report({"WARNING"}, f"{self._material}: left as it was (the fits go on in the background and are "
                                     "cached)")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._thread.is_alive():
            context.window_manager.progress_update(int(95 * self._state["fraction"]))
            if context.workspace is not None:
                context.workspace.status_text_set(f"Lamina: measuring the configurations of {self._material} "
                                                  "(Esc: leave it)")
            return {"RUNNING_MODAL"}
        end_modal(context, self._timer)
        mat = bpy.data.materials.get(self._material)
        if self._state["error"] is not None or mat is None:
            self.report({"ERROR"}, f"Could not fit {self._material}: {self._state['error'] or 'it was removed'}")
            return {"CANCELLED"}
        return self._apply(mat, self._state["decision"])


classes = (LAMINA_OT_fit_to_budget,)
