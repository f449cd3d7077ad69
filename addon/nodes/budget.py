"""Fit to budget (issue 16; bpy-free): the cheapest configuration of a material whose predicted error stays within
an error budget of the most accurate one.

A configuration is what Lamina can build for the material: a shader form (the node group; OSL only where the scene
already renders it: Lamina never turns OSL on), a mapping (analytic, or fitted where the model has one: ``choice``)
and the material itself or one of its cheaper variants (``cheaper_variants`` of the model's mapping module: fewer
thin-coat bounces, multiple scattering off, GGX's geometric term under a porous layer). Every configuration is
measured with the numpy prediction of what Cycles renders against the reference of the material *as it is set*
(``choice.comparison_errors``: the comparison scenes, or the points a camera sees, ``CameraView``; no render) and
priced by the cost model (``COST`` of ``shader_size``). The budget is added to the lowest error of all
configurations, so the most accurate one always qualifies; the cheapest qualifying one is chosen (on equal cost, the
closer one).

Texture-driven and keyframed inputs are measured at the values the sockets hold; applying a fitted configuration
fits it over the driven range as the mapping switch does (``material.plan``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..models import MODELS
from . import FORM_LABELS, MAPPINGS, choice, fittable, pruning

DEFAULT_BUDGET = 0.02  # relative RMSE (absolute) above the most accurate configuration
AS_SET = "as set"  # the label of the material itself among its variants
MAPPINGS_TRIED = ("analytic", "fitted")


class BudgetError(ValueError):
    """A budget that is not a positive number."""


def checked_budget(value) -> float:
    """``value`` as a budget: a finite number > 0; BudgetError otherwise."""
    try:
        budget = float(value)
    except (TypeError, ValueError):
        raise BudgetError(f"{value!r}: expected a number > 0 (e.g. 0.02 for 2%)") from None
    if not math.isfinite(budget) or budget <= 0.0:
        raise BudgetError(f"{value!r}: expected a number > 0 (e.g. 0.02 for 2%)")
    return budget


# ------------------------------------------------------------------------------------------------ cost model


@dataclass(frozen=True)
class CostModel:
    """Predicted Cycles render time of the bench's timing sphere (``bench.Sizes.timing_*``), in seconds: ``base``
    (the scene without the material) plus ``per_operation`` × the shader's arithmetic operations (the OSL form's
    temporaries; the node group makes about one math node of each) plus ``per_closure`` × its closures."""
    base: float
    per_operation: float
    per_closure: float

    def seconds(self, operations: int, closures: int) -> float:
        return self.base + self.per_operation * operations + self.per_closure * closures


# Least squares over every preset's configurations, measured by ``python -m addon.bench.budget`` (docs/benchmarks.md,
# "Cost model", which also reports how well these coefficients rank the measured times).
COST = {"nodes": CostModel(1.81, 0.0172, 0.582), "osl": CostModel(2.12, 0.00191, 0.466)}


def shader_size(model_id: str, p, form: str, fit=None) -> tuple[int, int]:
    """(arithmetic operations, closures) of the shader of ``p`` in ``form`` (``fit``: ``nodes.shade``'s), with those
    of the reference bulk under a porous layer. The operations are the temporaries of the OSL code that ``form``'s
    branches write (``expr.OslBackend``) that feed a closure (``pruning.live_operations``): Cycles leaves out nodes
    that reach no output, and OSL's optimiser dead code."""
    import numpy as np

    from . import _backend, shade
    from .expr import OslBackend

    mapping = MAPPINGS[model_id]
    osl = OslBackend([(s.name, s.kind, s.param.default) for s in mapping.sockets(p)], form)
    shade(osl, model_id, p, fit)
    outputs = osl.closures + [color for colors in osl.lamberts.values() for color in colors]
    inner = mapping.bulk_shader(p) if hasattr(mapping, "bulk_shader") else None
    operations = pruning.live_operations(osl.lines, outputs) + (shader_size(*inner, form)[0] if inner else 0)
    return operations, _backend(model_id, p, form, np.array([[0.0, 0.0, 1.0]]), fit).closure_count()


# ------------------------------------------------------------------------------------------------ candidates


@dataclass(frozen=True)
class Candidate:
    """One configuration: the ``variant`` (``AS_SET`` or a cheaper variant's label) with its ``params``, the form,
    the mapping ("analytic" or "fitted"), its predicted ``error`` (mean relative RMSE over the comparison scenes
    that count, against the material as set) and ``seconds`` (the cost model's)."""
    variant: str
    params: object
    form: str
    mapping: str
    error: float
    seconds: float
    operations: int
    closures: int
    pruned: pruning.Pruned | None = None  # closures left out (analytic mapping)
    change: float = 0.0  # pruned: the mean relative RMSE against the same configuration with every closure

    def describe(self) -> str:
        left_out = f", without {self.pruned.describe()}" if self.pruned else ""
        return f"{FORM_LABELS[self.form]}, {self.mapping} mapping, {self.variant}{left_out}"

    def to_json(self) -> dict:
        return {"variant": self.variant, "params": self.params.to_dict(), "form": self.form, "mapping": self.mapping,
                "error": self.error, "seconds": self.seconds, "operations": self.operations,
                "closures": self.closures, "pruned": self.pruned and self.pruned.to_json(), "change": self.change}

    @classmethod
    def from_json(cls, model_id: str, data: dict) -> "Candidate":
        """``to_json``'s candidate, priced by the cost model as it is now."""
        pruned = data.get("pruned") and pruning.Pruned.from_json(data["pruned"])
        seconds = COST[data["form"]].seconds(data["operations"], data["closures"])
        return cls(**{**data, "params": MODELS[model_id].params_from_dict(data["params"]), "seconds": seconds,
                      "pruned": pruned})


@dataclass(frozen=True)
class CameraView:
    """The points of an object that a camera sees (``frames``: per point the world normal, tangent, bitangent and
    the direction towards the camera, 12 floats) and the direction towards a key light (``key_light``)."""
    frames: tuple
    key_light: tuple

    def scenes(self) -> list:
        from ..reference import scenes as ref_scenes

        return ref_scenes.view_scenes(self.frames, self.key_light)

    def describe(self) -> str:
        return f"the camera's view ({len(self.frames)} points)"


COMPARISON_SCENES = "the comparison scenes"  # what a Decision was measured on, unless on a CameraView


@dataclass
class Decision:
    """The configuration chosen within ``budget`` among ``candidates`` of the material ``target`` (as set, the
    variants' reference); ``current``: the one the material renders with now (None when it is not among them, e.g. a
    form the scene cannot render)."""
    budget: float
    target: object
    chosen: Candidate
    candidates: list[Candidate] = field(default_factory=list)
    current: Candidate | None = None
    measured_on: str = COMPARISON_SCENES

    @property
    def best_error(self) -> float:
        return min(c.error for c in self.candidates)

    def summary(self) -> str:
        cost = (f", predicted cost {self.chosen.seconds / self.current.seconds:.2f}× the current configuration"
                if self.current is not None else "")
        left_out = (f"; the closures left out change it by {100 * self.chosen.change:.1f}%" if self.chosen.pruned
                    else "")
        return (f"{self.chosen.describe()}: predicted error {100 * self.chosen.error:.1f}% on {self.measured_on} "
                f"(the most accurate {100 * self.best_error:.1f}%, budget +{100 * self.budget:g}%){cost}{left_out}")

    def to_json(self) -> dict:
        return {"budget": self.budget, "target": self.target.to_dict(), "chosen": self.chosen.to_json(),
                "best_error": self.best_error, "measured_on": self.measured_on,
                "current": self.current and self.current.to_json(), "summary": self.summary(),
                "candidates": [c.to_json() for c in self.candidates]}


def target(model_id: str, p, record: dict | None):
    """The material Fit to budget measures against: ``p`` (the values as the material holds them) with the fields
    that the last decision (``record``, ``Decision.to_json``) changed set back to the material as set, so that
    fitting again is idempotent and never drifts further from the reference."""
    if not record:
        return p
    authored, chosen = record["target"], record["chosen"]["params"]
    changed = {k: v for k, v in authored.items() if chosen.get(k) != v}
    return MODELS[model_id].params_from_dict({**p.to_dict(), **changed}) if changed else p


def variants(model_id: str, p) -> list[tuple[str, object]]:
    """The material itself, then the cheaper variants its mapping offers (label, params)."""
    cheaper = getattr(MAPPINGS[model_id], "cheaper_variants", None)
    return [(AS_SET, p), *(cheaper(p) if cheaper else [])]


def candidates(model_id: str, p, forms, mappings=MAPPINGS_TRIED, prune: bool = True,
               progress=None, scenes=None) -> list[Candidate]:
    """Every configuration of ``p`` in ``forms`` with ``mappings`` (the fitted one where the model has it) and, with
    ``prune``, the analytic mapping's prunable closures left out (``pruning.prunable``), measured on the comparison
    scenes (or ``scenes``: ``reference.scenes.view_scenes`` of a camera's view) and priced; ``progress(fraction)``
    after each configuration is set up."""
    from ..reference import scenes as ref_scenes

    scenes = scenes or ref_scenes.comparison_scenes(choice.CHOICE_RESOLUTION, choice.CHOICE_FURNACE_WIDTH)
    kinds = [m for m in mappings if m == "analytic" or fittable(model_id)]
    configs = [(label, q, form, kind) for label, q in variants(model_id, p) for form in forms for kind in kinds]
    shaders = {}
    for i, (label, q, form, kind) in enumerate(configs):
        if kind == "fitted":
            shaders[(label, form, kind, None)] = (form, choice.choose(model_id, q, form, "fitted").fit, q)
        else:
            for pruned in [None, *(pruning.prunable(model_id, q, form) if prune else [])]:
                shaders[(label, form, kind, pruned)] = (form, pruned, q)
        if progress:
            progress(0.8 * (i + 1) / len(configs))
    images = {}
    errors, means = choice.comparison_errors(model_id, p, shaders, images=images, scenes=scenes)
    changes = pruning_changes(shaders, images, means, scenes)
    out = []
    for key, (form, fit, q) in shaders.items():
        label, _, kind, pruned = key
        operations, closures = shader_size(model_id, q, form, fit)
        out.append(Candidate(label, q, form, kind, choice.counted(errors[key], means),
                             COST[form].seconds(operations, closures), operations, closures, pruned,
                             changes.get(key, 0.0)))
    if progress:
        progress(1.0)
    return out


def pruning_changes(shaders: dict, images: dict, means: dict, scenes) -> dict:
    """{key: mean relative RMSE} of each pruned shader of ``shaders`` (``candidates``' keys and values) against the
    same configuration with every closure, from their predicted ``images`` (``choice.comparison_errors``'), on the
    ``scenes`` that count (``means``: the reference's)."""
    from ..reference import metrics
    from ..reference import scenes as ref_scenes

    masks = {spec.name: ref_scenes.scene_mask(spec) for spec in scenes}
    out = {}
    for key, (_, pruned, _) in shaders.items():
        if isinstance(pruned, pruning.Pruned):
            whole = key[:3] + (None,)
            errors = {scene: metrics.rel_rmse(images[(key, scene)], images[(whole, scene)], mask)
                      for scene, mask in masks.items()}
            out[key] = choice.counted(errors, means)
    return out


def pick(cands: list[Candidate], budget: float) -> Candidate:
    """The cheapest candidate within ``budget`` of the lowest error and, where closures are left out, within
    ``budget`` of the same configuration with all of them (on equal cost, the closer one)."""
    best = min(c.error for c in cands)
    return min((c for c in cands if c.error <= best + budget and c.change <= budget),
               key=lambda c: (c.seconds, c.error))


def fit_to_budget(model_id: str, p, budget: float = DEFAULT_BUDGET, forms=("nodes",), current=None,
                  mappings=MAPPINGS_TRIED, progress=None, view: CameraView | None = None) -> Decision:
    """The ``Decision`` for the material ``p`` (as set: ``target``) within ``budget`` (``checked_budget``), measured
    on the comparison scenes or on a camera's ``view``; ``current``: (params, form, mapping, pruned) the material
    renders with now."""
    budget = checked_budget(budget)
    cands = candidates(model_id, p, forms, mappings, progress=progress, scenes=view and view.scenes())
    return Decision(budget, p, pick(cands, budget), cands, _matching(cands, current),
                    view.describe() if view else COMPARISON_SCENES)


def _matching(cands: list[Candidate], current) -> Candidate | None:
    if current is None:
        return None
    q, form, mapping, pruned = current
    return next((c for c in cands if (c.form, c.mapping, c.pruned) == (form, mapping, pruned)
                 and c.params.to_dict() == q.to_dict()), None)
