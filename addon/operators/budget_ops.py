"""Fit to budget (``nodes.budget``): the panel's operator and the headless ``lamina optimize``.

Both measure the candidate configurations of a Lamina material against its reference (numpy, no render), then
rebuild its Lamina node in the cheapest one within the error budget (``material.apply_decision``: undoable, the
user's own nodes untouched). OSL forms are candidates only where every scene already renders OSL: Lamina never
turns the shading system on.
"""
from __future__ import annotations

import threading

import bpy

from ..models import MODELS
from ..nodes import budget
from ..nodes import material as lamina_material
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


def decide(mat, value: float, forms, progress=None) -> budget.Decision:
    """The decision for ``mat`` within the budget ``value``; BudgetRefusal for a material it cannot choose for."""
    reason = refusal(mat)
    if reason:
        raise BudgetRefusal(f"{mat.name}: {reason}")
    model_id, target, current = problem(mat)
    return budget.fit_to_budget(model_id, target, value, forms, current, progress=progress)


def optimize_file(blend: str, names: list[str], value: float, out: str) -> list[str]:
    """Open ``blend``, fit the materials ``names`` (every Lamina BSDF material when empty) to the budget ``value``
    and save the file as ``out`` atomically; one summary line per material. A material that cannot be fitted, or a
    file without any, raises ``blend_io.BlendArgumentError`` before anything is changed."""
    blend_io.open_blend(blend)
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
        decision = decide(mat, value, forms)
        lamina_material.apply_decision(mat, decision)
        lines.append(f"{mat.name}: {decision.summary()}")
    blend_io.save_copy(out)
    return lines


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

    def execute(self, context):
        mat = context.material
        try:
            decision = decide(mat, self.budget / 100.0, allowed_forms([context.scene]))
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
        self._material = mat.name
        model_id, target, current = problem(mat)
        forms, value = allowed_forms([context.scene]), self.budget / 100.0
        # plain state the thread writes: the operator is freed when Esc ends it
        self._state = state = {"fraction": 0.0, "decision": None, "error": None}

        def work():
            try:
                state["decision"] = budget.fit_to_budget(model_id, target, value, forms, current,
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
