"""Measurements every model's benchmark module shares (``addon.bench.<model>``): the mapping's noise-free error
against the reference on the comparison scenes, the tables of named approximations and presets, reference
throughput and Cycles render times."""
from __future__ import annotations

import importlib
import os
import time

import numpy as np

from .. import presets
from ..nodes import predicted_image
from ..reference import metrics
from ..reference import scenes as ref_scenes

ACCURACY_SCENES = ("sphere", "plane", "backlit", "furnace")
# The furnace reference needs the directional albedo per pixel; this many samples per pixel (MIS) keep
# its noise near 1%, below the approximations measured here.
ALBEDO_SAMPLES = 2048


def comparison_scenes(resolution: int):
    """The comparison scenes; the furnace at half resolution (its reference costs an albedo per pixel)."""
    scenes = [s for s in ref_scenes.default_scenes(resolution) if s.name in ACCURACY_SCENES]
    return [s.with_resolution(resolution // 2, resolution // 4) if s.kind == "furnace" else s for s in scenes]


def mapping_errors(p, resolution: int, model_id: str) -> dict:
    """{form: {scene: rel RMSE of the prediction vs the reference}} plus the reference's mean per scene."""
    ref_model = importlib.import_module(f"..reference.{model_id}", __package__)
    out = {"osl": {}, "nodes": {}, "mean": {}}
    for spec in comparison_scenes(resolution):
        ref = ref_scenes.reference_image(spec, lambda wi, wo: ref_model.eval(p, wi, wo),
                                         bsdf_albedo=lambda wo: ref_model.furnace_albedo(p, wo, n=ALBEDO_SAMPLES))
        mask = ref_scenes.scene_mask(spec)
        out["mean"][spec.name] = float(ref[mask].mean())
        for form in ("osl", "nodes"):
            out[form][spec.name] = metrics.rel_rmse(predicted_image(model_id, p, form, spec), ref, mask)
    return out


def approximation_rows(model, approximations: dict, resolution: int, short=None) -> list[str]:
    """Table rows of ``mapping_errors`` for each named approximation's configuration and scene: name, what it does,
    the configuration (``short(config)``, when given), scene, reference mean, OSL, node group."""
    rows = []
    for name, (what, config) in approximations.items():
        errs = mapping_errors(model.params_from_dict(config), resolution, model.ID)
        shown = f" `{short(config)}` |" if short else ""
        for scene in ACCURACY_SCENES:
            rows.append(f"| {name} | {what} |{shown} {scene} | {errs['mean'][scene]:.4f} | {pct(errs['osl'][scene])} | "
                        f"{pct(errs['nodes'][scene])} |")
    return rows


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
    which damps the machine's noise. Rows {"preset": name, label: seconds, ...}."""
    import bpy

    from ..operators import blend_io
    from ..operators.cycles_render import render_cycles

    spec = ref_scenes.sphere_scene(resolution=resolution)
    path = os.path.join(bpy.app.tempdir, "bench.exr")
    rows = []
    for name in names:
        before = blend_io.snapshot()
        try:
            times = {label: min(render_cycles(mat, spec, samples, 0, path)[1] for _ in range(repeats))
                     for label, mat in materials_of(name).items()}
        finally:
            blend_io.remove_new_data(before)
        rows.append({"preset": name, **times})
    return rows


def pct(x: float) -> str:
    return f"{100 * x:.1f}%" if np.isfinite(x) else "n/a"


def preset_render_times(model_id: str, samples: int, resolution: int, repeats: int = 3) -> list[dict]:
    """Cycles render time of each of the model's presets as node group, OSL and its Principled BSDF
    (``principled_settings``: about the same lobe count, or the same material where the model has a counterpart)."""
    from ..models import MODELS
    from ..nodes import material as lamina_material

    def materials(name):
        p = MODELS[model_id].params_from_dict(presets.load(model_id, name))
        return {**{form: lamina_material.new_material(model_id, p, form) for form in ("nodes", "osl")},
                "principled": lamina_material.principled_material(model_id, p)}

    return fastest_renders(presets.names(model_id), materials, samples, resolution, repeats)
