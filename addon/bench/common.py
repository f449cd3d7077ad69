"""Measurements every model's benchmark module shares (``addon.bench.<model>``): the mapping's noise-free error
against the reference on the comparison scenes, the tables of named approximations and presets, reference
throughput and Cycles render times."""
from __future__ import annotations

import contextlib
import importlib
import os
import time

import numpy as np

from .. import presets
from ..nodes import budget, choice, expr, fittable
from ..nodes.choice import comparison_errors
from ..reference import scenes as ref_scenes
from ..reference.scenes import ACCURACY_SCENES, comparison_scenes  # noqa: F401 (the models' bench modules use them)

# The furnace reference needs the directional albedo per pixel; this many samples per pixel (MIS) keep
# its noise near 1%, below the approximations measured here.
ALBEDO_SAMPLES = 2048


def mapping_errors(p, resolution: int, model_id: str) -> dict:
    """{form: {scene: rel RMSE of the prediction vs the reference}} plus the reference's mean per scene."""
    errors, means = comparison_errors(model_id, p, {form: (form, None) for form in ("osl", "nodes")}, resolution,
                                      ALBEDO_SAMPLES, furnace_width=None)
    return {**errors, "mean": means}


def approximation_rows(model, approximations: dict, resolution: int, short=None) -> list[str]:
    """Table rows of ``mapping_errors`` for each named approximation's configuration and scene: name, what it does,
    the configuration (``short(config)``, when given), scene, reference mean, OSL, node group, and for models with a
    fitted mapping the OSL form's fitted mapping (``approximation_header``)."""
    rows = []
    for name, (what, config) in approximations.items():
        p = model.params_from_dict(config)
        errs = mapping_errors(p, resolution, model.ID)
        fitted_errs = _fitted_errors(model.ID, p, resolution) if fittable(model.ID) else None
        shown = f" `{short(config)}` |" if short else ""
        for scene in ACCURACY_SCENES:
            extra = f" {pct(fitted_errs[scene])} |" if fitted_errs else ""
            rows.append(f"| {name} | {what} |{shown} {scene} | {errs['mean'][scene]:.4f} | {pct(errs['osl'][scene])} | "
                        f"{pct(errs['nodes'][scene])} |{extra}")
    return rows


def approximation_header(model_id: str, short: bool = False) -> list[str]:
    """The header of ``approximation_rows``' table."""
    columns = ["approximation", "what it does"] + (["configuration"] if short else []) + [
        "scene", "ref. mean", "OSL", "node group"] + (["fitted (OSL)"] if fittable(model_id) else [])
    return ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def _fitted_errors(model_id: str, p, resolution: int) -> dict:
    """{scene: rel RMSE} of the OSL form's fitted mapping of ``p`` (the closer of its fits, ``choice.choose``)."""
    fit = choice.choose(model_id, p, "osl", "fitted").fit
    return comparison_errors(model_id, p, {"fitted": ("osl", fit)}, resolution, ALBEDO_SAMPLES,
                             furnace_width=None)[0]["fitted"]


# The goals for the mapping Auto chooses (docs/accuracy.md): rel. RMSE on these scenes at most this much;
# backlit counted only where the reference's mean reaches ``choice.BACKLIT_MIN_MEAN``.
GOALS = {"sphere": 0.15, "plane": 0.15, "furnace": 0.15, "backlit": 0.25}


def mapping_section(model, resolution: int) -> list[str]:
    """"## Analytic and fitted mappings": per preset and scene, both forms' analytic error and the error of the
    mapping Auto chooses (at the bench's settings), against ``GOALS``; per preset and form, what Auto picked, the
    closure counts, and the time to fit and to measure (fresh caches)."""
    lines = ["", "## Analytic and fitted mappings", "",
             "Auto renders, per material and form, whichever mapping has the lower mean error on these comparison "
             "scenes (measured when the material is built, at 48 px with a 12 px furnace; `nodes.choice`). Goals: "
             + ", ".join(f"{scene} ≤ {100 * g:.0f}%" for scene, g in GOALS.items())
             + f" (backlit only where the reference's mean reaches {choice.BACKLIT_MIN_MEAN:g}).", "",
             "| preset | scene | ref. mean | OSL analytic | OSL Auto | node group analytic | node group Auto | goal |",
             "|---|---|---|---|---|---|---|---|"]
    summary = ["", f"Fit s: the {len(choice.VARIANTS)} fits (weightings "
               f"{', '.join(sorted({f'{v.damping:g}' for v in choice.VARIANTS}))}, without and with the Toon lobes, "
               "`nodes.choice.fits_for`: one quadrature for all) from scratch; measure s: the analytic mapping and the "
               "distinct fits on the comparison scenes, the reference's images included (each form with empty caches, "
               "as a material's first build). Operations: the shader's arithmetic that feeds a closure "
               "(`nodes.budget.shader_size`, what Fit to budget's cost model prices).", "",
               "| preset | form | Auto renders | closures analytic → fitted | operations analytic → fitted | fit s | "
               "measure s |",
               "|---|---|---|---|---|---|---|"]
    with fresh_fit_cache():
        for name in presets.names(model.ID):
            p = model.params_from_dict(presets.load(model.ID, name))
            chosen = {}
            for form in ("osl", "nodes"):
                forget_measurements()  # each form's times cold, as a user's first build of the material
                fit_seconds = timed(lambda: choice.fits_for(model.ID, p, form))
                start = time.perf_counter()
                chosen[form] = choice.choose(model.ID, p, form, "auto")
                measure_seconds = time.perf_counter() - start
                fit = choice.choose(model.ID, p, form, "fitted").fit
                (ops, closures), (fitted_ops, fitted_closures) = (budget.shader_size(model.ID, p, form, f)
                                                                  for f in (None, fit))
                summary.append(f"| {name} | {form} | {chosen[form].used} | {closures} → {fitted_closures} | "
                               f"{ops} → {fitted_ops} | {fit_seconds:.1f} | {measure_seconds:.1f} |")
            shaders = {f"{form} {m}": (form, chosen[form].fit if m == "auto" else None)
                       for form in ("osl", "nodes") for m in ("analytic", "auto")}
            errors, means = comparison_errors(model.ID, p, shaders, resolution, ALBEDO_SAMPLES, furnace_width=None)
            for scene in ACCURACY_SCENES:
                cells = " | ".join(pct(errors[label][scene]) for label in shaders)
                lines.append(f"| {name} | {scene} | {means[scene]:.4f} | {cells} | "
                             f"{_goal(scene, means[scene], errors['osl auto'][scene], errors['nodes auto'][scene])} |")
    return lines + summary


def driven_section(model, cases, resolution: int) -> list[str]:
    """"## Texture-driven fits": for each case (preset, shader input, least and greatest texture value), the node
    group's error with the interpolated tables halfway between the first two and the last two tabulated values, where
    interpolation is furthest from them, beside a fit made at that value and the analytic mapping."""
    from ..nodes import fitted

    lines = ["", "## Texture-driven fits", "",
             f"A fitted material whose input follows a texture is fitted at {choice.DRIVEN_VALUES} values across the "
             "texture's range and its tables are interpolated between them per shading point (`nodes.fitted.tables`): "
             "an approximation, measured here halfway between two tabulated values (node group; mean relative RMSE "
             "over the comparison scenes that count, as in the mapping goals).", "",
             "| preset | input (texture range) | value | interpolated | fitted at the value | analytic |",
             "|---|---|---|---|---|---|"]
    with fresh_fit_cache():
        for name, socket, lo, hi in cases:
            p = model.params_from_dict(presets.load(model.ID, name))
            driven = choice.driven_over(model.ID, p, socket, lo, hi)
            made = choice.choose(model.ID, p, "nodes", "fitted", driven)
            values = driven.values
            for v in (0.5 * (values[0] + values[1]), 0.5 * (values[-2] + values[-1])):
                q = choice.at(model.ID, p, fitted.Driven(socket, driven.kind, (v,)), 0)
                shaders = {"interpolated": ("nodes", made.fit),
                           "direct": ("nodes", choice.fit_for(model.ID, q, "nodes", made.variant)),
                           "analytic": ("nodes", None)}
                errors, means = comparison_errors(model.ID, q, shaders, resolution, ALBEDO_SAMPLES, furnace_width=None)
                cells = " | ".join(pct(choice.counted(errors[label], means)) for label in shaders)
                lines.append(f"| {name} | {socket} ({lo:g} to {hi:g}) | {v:g} | {cells} |")
    return lines


def _goal(scene: str, mean: float, *errors) -> str:
    if mean < choice.BACKLIT_MIN_MEAN:
        return "n/a"
    return "met" if max(errors) <= GOALS[scene] else "not met"


@contextlib.contextmanager
def fresh_fit_cache():
    """Fits and measurements from scratch (a temporary cache folder, empty memory caches), so times are real."""
    import tempfile

    saved = os.environ.get("LAMINA_CACHE")
    with tempfile.TemporaryDirectory(prefix="lamina_fits_") as tmp:
        os.environ["LAMINA_CACHE"] = tmp
        choice._fits.clear()
        forget_measurements()
        try:
            yield
        finally:
            if saved is None:
                os.environ.pop("LAMINA_CACHE", None)
            else:
                os.environ["LAMINA_CACHE"] = saved
            choice._fits.clear()


def forget_measurements() -> None:
    """Empty the in-memory caches of what the choice measures: the reference's images and the closures' albedos."""
    choice._references.clear()
    expr._unit_albedos.clear()


def preset_rows(model, resolution: int) -> list[str]:
    """The "## Presets" table of ``mapping_errors`` for each of the model's presets and scene."""
    lines = ["", "## Presets", "", "| preset | scene | ref. mean | OSL | node group |", "|---|---|---|---|---|"]
    for name in presets.names(model.ID):
        errs = mapping_errors(model.params_from_dict(presets.load(model.ID, name)), resolution, model.ID)
        for scene in ACCURACY_SCENES:
            lines.append(f"| {name} | {scene} | {errs['mean'][scene]:.4f} | {pct(errs['osl'][scene])} | "
                         f"{pct(errs['nodes'][scene])} |")
    return lines


def reference_throughput(p, model_id: str, n: int = 200_000, repeats: int = 3) -> float:
    """Reference ``eval`` calls per second on random direction pairs (fastest of ``repeats``; the first call also
    warms caches such as micrograin's specular albedo table)."""
    ref_model = importlib.import_module(f"..reference.{model_id}", __package__)
    rng = np.random.default_rng(0)

    def dirs():
        v = rng.normal(size=(n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        return v

    wi, wo = dirs(), dirs()
    ref_model.eval(p, wi[:10], wo[:10])
    best = min(timed(lambda: ref_model.eval(p, wi, wo)) for _ in range(repeats))
    return n / best


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def fastest_renders(names, materials_of, samples: int, resolution: int, repeats: int = 3) -> list[dict]:
    """For each name, the Cycles render time of the sphere scene for each material of ``materials_of(name)``
    ({label: material}, created for the purpose and removed again): the fastest of ``repeats`` renders each,
    which damps the machine's noise, rendered in rounds (each round renders every material once), so that a slow
    drift of the machine's speed touches the materials compared alike. Rows {"preset": name, label: seconds, ...}."""
    import bpy

    from ..operators import blend_io
    from ..operators.cycles_render import render_cycles

    spec = ref_scenes.sphere_scene(resolution=resolution)
    path = os.path.join(bpy.app.tempdir, "bench.exr")
    rows = []
    for name in names:
        before = blend_io.snapshot()
        try:
            mats = materials_of(name)
            times = {label: [] for label in mats}
            for _ in range(repeats):
                for label, mat in mats.items():
                    times[label].append(render_cycles(mat, spec, samples, 0, path)[1])
            times = {label: min(seconds) for label, seconds in times.items()}
        finally:
            blend_io.remove_new_data(before)
        rows.append({"preset": name, **times})
    return rows


# The sampling-only cost: the render at this many times the bench's samples less the render at the bench's samples.
SAMPLING_FACTOR = 4


def paired_render_times(names, materials_of, samples: int, resolution: int, repeats: int) -> list[dict]:
    """For each name, the Cycles render times of the sphere scene for each material of ``materials_of(name)``
    ({label: material}, created for the purpose and removed again), at ``samples`` and at ``SAMPLING_FACTOR`` times
    as many, in ``repeats`` rounds (each round renders every material at both counts, in turn). Rows {"preset":
    name, "whole": {label: [the render at ``samples`` per round]}, "sampling": {label: [the render at the larger
    count less the render at ``samples``, per round]}}: the time of the samples between them alone, what shading
    costs (the scene sync, shader compilation and kernel set-up are the same in both and cancel). ``compared``
    reads two labels' rows."""
    import bpy

    from ..operators import blend_io
    from ..operators.cycles_render import render_cycles

    spec = ref_scenes.sphere_scene(resolution=resolution)
    path = os.path.join(bpy.app.tempdir, "bench_pairs.exr")
    counts = (samples, SAMPLING_FACTOR * samples)
    rows = []
    for name in names:
        before = blend_io.snapshot()
        try:
            mats = materials_of(name)
            times = {(label, n): [] for label in mats for n in counts}
            for _ in range(repeats):
                for label, mat in mats.items():
                    for n in counts:
                        times[label, n].append(render_cycles(mat, spec, n, 0, path)[1])
        finally:
            blend_io.remove_new_data(before)
        rows.append({"preset": name, "whole": {label: times[label, counts[0]] for label in mats},
                     "sampling": {label: [b - a for a, b in zip(times[label, counts[0]], times[label, counts[1]])]
                                  for label in mats}})
    return rows


def compared(row: dict, label, base) -> dict:
    """``label``'s render time against ``base``'s in a row of ``paired_render_times``. Whole renders: the fastest of
    each (``base``, ``other``), ``ratio`` theirs and ``rounds`` each round's ratio. Sampling alone: the median over the
    rounds of each (``base_sampling``, ``sampling``); ``sampling_ratio`` is the median of each round's ratio (a
    round's renders share the machine's state, so slow drifts cancel too, and the median ignores a round that a
    hiccup disturbed) and ``sampling_rounds`` holds them (their spread is the measurement's)."""
    whole, sampling = row["whole"], row["sampling"]
    rounds = [b / a for a, b in zip(sampling[base], sampling[label]) if a > 0.0]
    return {"base": min(whole[base]), "other": min(whole[label]),
            "ratio": min(whole[label]) / min(whole[base]),
            "rounds": [b / a for a, b in zip(whole[base], whole[label])],
            "base_sampling": float(np.median(sampling[base])), "sampling": float(np.median(sampling[label])),
            "sampling_ratio": float(np.median(rounds)) if rounds else float("nan"), "sampling_rounds": rounds}


# Nodes whose outputs Cycles computes at compile time when every input is a constant (constant folding); any other
# node (geometry, texture, closure) is evaluated at each shading point.
FOLDABLE_NODES = frozenset(("ShaderNodeMath", "ShaderNodeVectorMath", "ShaderNodeMix", "ShaderNodeMixRGB",
                            "ShaderNodeSeparateXYZ", "ShaderNodeCombineXYZ", "ShaderNodeSeparateColor",
                            "ShaderNodeCombineColor", "ShaderNodeValToRGB", "ShaderNodeClamp", "ShaderNodeMapRange"))


def per_point_nodes(material) -> int:
    """How many arithmetic nodes (``FOLDABLE_NODES``) of ``material`` Cycles evaluates at each shading point: those
    that reach its output and take, through any chain of links and node groups, a value that varies over the
    surface (the view, the normal, a texture); Cycles folds the others into constants. A measure of a node group's
    shading cost that does not move between runs, as render times do."""
    varying: dict = {}

    def varies(path, node, socket) -> bool:
        """Whether output ``socket`` of ``node``, in the group nodes ``path`` from the material's tree, varies."""
        key = (tuple(n.name for n in path), node.name, socket.identifier)
        if key not in varying:
            varying[key] = _varies(path, node, socket)
        return varying[key]

    def linked_varies(path, socket) -> bool:
        found = _source(path, socket)
        return found is not None and varies(*found)

    def _varies(path, node, socket) -> bool:
        if node.bl_idname == "ShaderNodeGroup":
            return linked_varies(path + (node,), _peer(_group_output(node.node_tree).inputs, socket))
        if node.bl_idname in FOLDABLE_NODES:
            return any(linked_varies(path, s) for s in node.inputs)
        return node.bl_idname not in ("ShaderNodeValue", "ShaderNodeRGB")

    seen, count = set(), 0
    todo = [((), next(n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"
                      and n.is_active_output))]
    while todo:
        path, node = todo.pop()
        key = (tuple(n.name for n in path), node.name)
        if key in seen:
            continue
        seen.add(key)
        count += node.bl_idname in FOLDABLE_NODES and any(varies(path, node, o) for o in node.outputs)
        if node.bl_idname == "ShaderNodeGroup":
            todo.append((path + (node,), _group_output(node.node_tree)))
            continue
        todo += [found[:2] for found in (_source(path, s) for s in node.inputs) if found is not None]
    return count


def _source(path, socket):
    """(path, node, output socket) that feeds input ``socket``, through Group Input nodes; None if unlinked."""
    while socket.is_linked:
        link = socket.links[0]
        if link.from_node.bl_idname != "NodeGroupInput":
            return path, link.from_node, link.from_socket
        path, socket = path[:-1], _peer(path[-1].inputs, link.from_socket)
    return None


def _peer(sockets, socket):
    """The socket of ``sockets`` with ``socket``'s identifier (a group node's socket and its group's, inside)."""
    return next(s for s in sockets if s.identifier == socket.identifier)


def _group_output(tree):
    return next(n for n in tree.nodes if n.bl_idname == "NodeGroupOutput" and n.is_active_output)


def ratio_cells(c: dict, kind: str = "") -> list[str]:
    """A ``compared`` result's table cells: base s, other s, ratio, the rounds' range; ``kind`` "" (whole renders)
    or "sampling"."""
    if kind:
        base, other, ratio, rounds = c["base_sampling"], c["sampling"], c["sampling_ratio"], c["sampling_rounds"]
    else:
        base, other, ratio, rounds = c["base"], c["other"], c["ratio"], c["rounds"]
    spread = f"{min(rounds):.2f}–{max(rounds):.2f}" if rounds else "–"
    return [f"{base:.2f}", f"{other:.2f}", f"{ratio:.2f}" if np.isfinite(ratio) else "–", spread]


FITTED_REPEATS = 3


def fitted_speed_section(model_id: str, samples: int, resolution: int, repeats: int = FITTED_REPEATS) -> list[str]:
    """"### Fitted against analytic mapping": each preset's render time with the fitted mapping against the
    analytic one, both forms, sampling alone (``paired_render_times``; issue 14's goal: ≤ 1.0×)."""
    from ..models import MODELS
    from ..nodes import material as lamina_material

    def materials(name):
        p = MODELS[model_id].params_from_dict(presets.load(model_id, name))
        return {(form, mapping): lamina_material.new_material(model_id, p, form, mapping=mapping)
                for form in ("nodes", "osl") for mapping in ("analytic", "fitted")}

    rows = paired_render_times(presets.names(model_id), materials, samples, resolution, repeats)
    more = SAMPLING_FACTOR * samples
    lines = ["", "### Fitted against analytic mapping", "",
             f"The same material with the analytic and the fitted mapping, sphere scene, {resolution}×{resolution} "
             f"px, {repeats} rounds, renders alternating. Sampling alone: the time of {more - samples} samples, each "
             f"round's render at {more} samples less its render at {samples} (scene sync, shader compilation and "
             "kernel set-up are the same in both and cancel: what shading the material costs), the median over the "
             "rounds; the ratio is the median of the rounds' ratios, and their range beside it. Goal: fitted ≤ 1.0× "
             "analytic.", "",
             "| preset | node group analytic s | fitted s | fitted : analytic | per round | OSL analytic s | fitted s "
             "| fitted : analytic | per round |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [r["preset"]]
        for form in ("nodes", "osl"):
            cells += ratio_cells(compared(r, (form, "fitted"), (form, "analytic")), "sampling")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def pct(x: float) -> str:
    return f"{100 * x:.1f}%" if np.isfinite(x) else "n/a"


def preset_render_times(model_id: str, samples: int, resolution: int, repeats: int = 3) -> list[dict]:
    """Cycles render time of each of the model's presets as node group, OSL and its Principled BSDF
    (``principled_settings``: about the same lobe count, or the same material where the model has a counterpart).
    ``fitted_speed_section`` measures the fitted mapping against the analytic one."""
    from ..models import MODELS
    from ..nodes import material as lamina_material

    def materials(name):
        p = MODELS[model_id].params_from_dict(presets.load(model_id, name))
        return {**{form: lamina_material.new_material(model_id, p, form) for form in ("nodes", "osl")},
                "principled": lamina_material.principled_material(model_id, p)}

    return fastest_renders(presets.names(model_id), materials, samples, resolution, repeats)
