"""Comparison runs shared by the operator, the CLI, the demo and the benchmarks (bpy).

A run renders a Lamina material with Cycles and with the bundled reference on the standard scenes
(``reference.scenes``) and also measures the mapping alone: the numpy prediction of what the form renders
against the reference, which separates the approximation's error from Cycles' sampling noise.

With multiple scattering (``ms``: an ``addon.ms_truth.TruthSettings``) a run compares three things per scene:
single scattering alone (the closed-form reference), SS + MS from the network (the material with the flag on,
rendered by Cycles and by the reference) and SS + MS from Monte Carlo (the closed-form single scattering plus
the random walk's orders >= 2 at sampled pixels, ``addon.ms_truth``). The entries gain an ``ms`` dict.
"""
from __future__ import annotations

import html
import importlib
import json
import os

import numpy as np

from .. import ms_truth, presets
from ..bake.exr import atomic_path, read_exr, read_png, write_exr, write_png
from ..models import MODELS
from ..nodes import material as lamina_material
from ..nodes import predicted_image
from ..reference import metrics
from ..reference import scenes as ref_scenes
from . import blend_io, compare_core

SCENES = ref_scenes.KINDS


def write_text_atomic(path: str, text: str) -> None:
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write(text)


def scene_specs(names, resolution: int):
    """Standard scenes by name at ``resolution``; ``Scene`` objects pass through unchanged."""
    by_name = {s.name: s for s in ref_scenes.default_scenes(resolution)}
    return [n if isinstance(n, ref_scenes.Scene) else by_name[n] for n in names]


def reference_module(model_id: str):
    return importlib.import_module(f"..reference.{model_id}", __package__)


def refusal(model_id: str, p) -> str | None:
    """Why ``p`` cannot be compared with its reference (None: it can), as the model says (``reference_refusal``)."""
    hook = getattr(MODELS[model_id], "reference_refusal", None)
    return None if hook is None else hook(p)


def has_multiple_scattering(model_id: str) -> bool:
    return hasattr(MODELS[model_id], "MS_MAX_LAYERS")


def has_blends(model_id: str) -> bool:
    return hasattr(reference_module(model_id), "BLENDS")


# Samples per pixel of the reference's directional albedo (furnace scene): ~0.7% relative noise.
ALBEDO_SAMPLES = 4096


def reference_functions(model_id: str, p):
    """(eval, albedo) of the exact reference for ``p``: what every comparison measures against."""
    ref = reference_module(model_id)
    return (lambda wi, wo: ref.eval(p, wi, wo)), (lambda wo: ref.furnace_albedo(p, wo, n=ALBEDO_SAMPLES))


def compare_material(mat, scenes, samples: int, resolution: int, seed: int, out_dir: str, progress=None,
                     reference_cache: dict | None = None, ms: ms_truth.TruthSettings | None = None,
                     blends: bool = False) -> dict:
    """Cycles vs reference for an existing Lamina material (it is assigned to temporary objects, never edited).
    ``scenes``: names of standard scenes (at ``resolution``) or ``Scene`` objects.
    ``reference_cache`` lets several forms of the same parameters share the reference renders (and, with ``ms``,
    the single-scattering images and the Monte Carlo ground truth).
    ``blends``: also render the reference with the model's other blending weights (micrograin: the linear mix by
    τ0 of the paper's Fig. 14 and d'Eon et al.'s weighting, Eq. 26) beside ours (``blend_comparison``).
    ``ms``: compare with multiple scattering (module docstring). A material whose flag is off is compared
    through a temporary copy with the flag on, removed again afterwards."""
    model_id, p = lamina_material.current_params(mat)
    if ms is not None and not p.multiple_scattering:
        p_on = with_multiple_scattering(model_id, p)
        before = blend_io.snapshot()
        try:
            tmp = lamina_material.new_material(model_id, p_on, lamina_material.form_of(mat),
                                               name=f"{mat.name} (multiple scattering)")
            return compare_material(tmp, scenes, samples, resolution, seed, out_dir, progress, reference_cache, ms,
                                    blends)
        finally:
            blend_io.remove_new_data(before)
    bsdf_eval, bsdf_albedo = reference_functions(model_id, p)
    specs = scene_specs(scenes, resolution)
    cache = {} if reference_cache is None else reference_cache
    report = compare_core.compare(mat, bsdf_eval, specs, samples, seed, out_dir, progress, bsdf_albedo=bsdf_albedo,
                                  reference_cache=cache)
    form = lamina_material.form_of(mat)
    for spec in specs:
        reference = read_exr(report[spec.name]["files"]["reference"], "RGB")
        approx = predicted_image(model_id, p, form, spec)
        report[spec.name]["mapping_rel_rmse"] = metrics.rel_rmse(approx, reference, ref_scenes.scene_mask(spec))
        if ms is not None:
            cycles = read_exr(report[spec.name]["files"]["cycles"], "RGB")
            report[spec.name]["ms"] = ms_comparison(model_id, p, spec, cycles, reference, ms, out_dir, cache)
        if blends:
            cycles = read_exr(report[spec.name]["files"]["cycles"], "RGB")
            report[spec.name]["blends"] = blend_comparison(model_id, p, spec, cycles, reference, out_dir, cache)
    return report


def blend_comparison(model_id: str, p, spec, cycles, reference, out_dir: str, cache: dict) -> dict:
    """The reference with each of the model's other blending weights (``reference.<model>.BLENDS[1:]``) against
    ours: their relative RMSE from ours, and ``<scene>_blends.png`` = Cycles | ours | each other blend, one
    exposure."""
    ref = reference_module(model_id)
    if not has_blends(model_id):
        raise ValueError(f"{model_id} has a single blending weight")
    mask = ref_scenes.scene_mask(spec)
    images, out = [cycles, reference], {}
    for blend in ref.BLENDS[1:]:
        key = f"{spec.name}/blend {blend}"
        if key not in cache:
            cache[key] = ref_scenes.reference_image(
                spec, lambda wi, wo, _b=blend: ref.eval(p, wi, wo, blend=_b),
                bsdf_albedo=lambda wo, _b=blend: ref.furnace_albedo(p, wo, n=ALBEDO_SAMPLES, blend=_b))
        images.append(cache[key])
        out[blend] = metrics.rel_rmse(cache[key], reference, mask)
    exposure = metrics.auto_exposure(reference, mask)
    panels = [metrics.tonemap(x, exposure) for x in images]
    sep = np.full((panels[0].shape[0], 2, 3), 255, dtype=np.uint8)
    path = os.path.join(out_dir, f"{compare_core.safe_file_stem(spec.name)}_blends.png")
    write_png(path, np.concatenate([x for panel in panels for x in (panel, sep)][:-1], axis=1))
    return {"vs_ours": out, "panels": ["Cycles", *ref.BLENDS], "files": {"blends_picture": path}}


def with_multiple_scattering(model_id: str, p):
    """``p`` with the multiple-scattering flag on, validated by the model (ParamError: e.g. too many layers)."""
    return MODELS[model_id].validate({**p.to_dict(), "multiple_scattering": True}).params


def ms_comparison(model_id: str, p, spec, cycles, network, settings: ms_truth.TruthSettings, out_dir: str,
                  cache: dict) -> dict:
    """Cycles (SS + MS) | reference SS only | reference SS + MS (network) | SS + MS Monte Carlo for one scene:
    relative RMSEs, the ground truth's noise, ``<scene>_single.exr``, ``<scene>_ground_truth.exr`` and
    ``<scene>_ms.png`` (those four pictures, then the error maps network vs Monte Carlo and SS only vs Monte
    Carlo, one exposure and one heat scale = 10% of the ground truth's mean). Errors against the Monte Carlo
    are taken over its sampled pixels only."""
    import time

    if model_id != "spongecake":
        raise ValueError(f"multiple-scattering ground truth exists for spongecake only, not {model_id}")
    p_ss = ms_truth.single_scattering(p)
    key = f"{spec.name}/single scattering"
    if key not in cache:
        t0 = time.perf_counter()
        ss_eval, ss_albedo = reference_functions(model_id, p_ss)
        cache[key] = (ref_scenes.reference_image(spec, ss_eval, bsdf_albedo=ss_albedo), time.perf_counter() - t0)
    single = cache[key][0]
    key = f"{spec.name}/ground truth"
    if key not in cache or cache[key][1] != settings:
        cache[key] = (ms_truth.multiple_scattering_truth(p, spec, settings), settings)
    truth_ms = cache[key][0]
    truth = single + truth_ms["image"]
    samples, mask = truth_ms["samples"], ref_scenes.scene_mask(spec)
    stem = compare_core.safe_file_stem(spec.name)
    files = {"single": os.path.join(out_dir, f"{stem}_single.exr"),
             "ground_truth": os.path.join(out_dir, f"{stem}_ground_truth.exr"),
             "ms_picture": os.path.join(out_dir, f"{stem}_ms.png")}
    write_exr(files["single"], single)
    write_exr(files["ground_truth"], truth)
    write_png(files["ms_picture"], ms_picture(cycles, single, network, truth, mask))
    return {
        "cycles_vs_network": metrics.rel_rmse(cycles, network, mask),
        "network_vs_truth": metrics.rel_rmse(network, truth, samples),
        "single_vs_truth": metrics.rel_rmse(single, truth, samples),
        "cycles_vs_truth": metrics.rel_rmse(cycles, truth, samples),
        "truth_noise": ms_truth.relative_noise(truth, truth_ms["noise"], samples),
        "truth_mean": float(truth[samples].mean()),
        "ms_share": float(truth_ms["image"][samples].mean() / max(truth[samples].mean(), 1e-300)),
        "truth_pixels": int(samples.sum()),
        "truth_paths": settings.albedo_paths if spec.kind == "furnace" else settings.paths,
        "truth_stride": settings.stride,
        "truth_seconds": truth_ms["seconds"],
        "files": files,
    }


MS_PANELS = ("Cycles SS+MS", "SS only", "SS+MS network", "SS+MS Monte Carlo", "error network", "error SS only")


def ms_picture(cycles, single, network, truth, mask, gap: int = 2) -> np.ndarray:
    """``MS_PANELS`` side by side (uint8), one exposure (the ground truth's) and one heat scale for both maps."""
    exposure = metrics.auto_exposure(truth, mask)
    heat_net, vmax = metrics.heat_map(network, truth, mask)
    heat_ss, _ = metrics.heat_map(single, truth, mask, vmax=vmax)
    panels = [metrics.tonemap(x, exposure) for x in (cycles, single, network, truth)]
    panels += [np.round(x * 255).astype(np.uint8) for x in (heat_net, heat_ss)]
    sep = np.full((panels[0].shape[0], gap, 3), 255, dtype=np.uint8)
    return np.concatenate([x for p in panels for x in (p, sep)][:-1], axis=1)


def compare_params(model_id: str, p, forms, scenes, samples: int, resolution: int, seed: int, out_dir: str,
                   label: str = "custom", ms: ms_truth.TruthSettings | None = None, blends: bool = False) -> dict:
    """Build a temporary material per form, compare it, remove it again; write ``report.json``.
    With ``ms`` the materials have multiple scattering on and every scene is also compared with the Monte
    Carlo ground truth (``compare_material``); ``report["ms"]`` records the ground truth's settings."""
    if ms is not None:
        p = with_multiple_scattering(model_id, p)
    report = {"model": model_id, "label": label, "params": p.to_dict(), "samples": samples,
              "resolution": resolution, "seed": seed, "forms": {}}
    if ms is not None:
        report["ms"] = {"paths": ms.paths, "albedo_paths": ms.albedo_paths, "stride": ms.stride,
                        "max_depth": ms.max_depth, "seed": ms.seed}
    references = {}
    for form in forms:
        before = blend_io.snapshot()
        try:
            mat = lamina_material.new_material(model_id, p, form, name=f"Lamina compare {label}")
            entries = compare_material(mat, scenes, samples, resolution, seed, os.path.join(out_dir, form),
                                       reference_cache=references, ms=ms, blends=blends)
        finally:
            blend_io.remove_new_data(before)
        report["forms"][form] = {scene: _json_entry(e, out_dir) for scene, e in entries.items()}
    write_text_atomic(os.path.join(out_dir, "report.json"), json.dumps(report, indent=2))
    return report


REPORT_KEYS = ("rmse", "rel_rmse", "max_abs_error", "mapping_rel_rmse", "cycles_seconds", "reference_seconds",
               "samples", "worst_pixels", "files", "ms", "blends")


def _json_entry(entry: dict, out_dir: str) -> dict:
    out = {k: entry[k] for k in REPORT_KEYS if k in entry}
    out["files"] = {k: os.path.relpath(v, out_dir) for k, v in entry["files"].items()}
    out["worst_pixels"] = [[int(r), int(c), [float(x) for x in a], [float(x) for x in b]]
                           for r, c, a, b in entry["worst_pixels"]]
    for key in ("ms", "blends"):
        if key in entry:
            out[key] = {**entry[key], "files": {k: os.path.relpath(v, out_dir) for k, v in entry[key]["files"].items()}}
    return out


def scene_lines(entries: dict) -> list[str]:
    lines = []
    for scene, e in entries.items():
        lines.append(f"{scene}: RMSE {e['rmse']:.3g}, rel. RMSE {e['rel_rmse']:.2%} (mapping alone "
                     f"{e['mapping_rel_rmse']:.2%}), Cycles {e['cycles_seconds']:.2f} s, reference "
                     f"{e['reference_seconds']:.2f} s")
        if "ms" in e:
            lines.append("  " + ms_line(e["ms"]))
        if "blends" in e:
            others = e["blends"]["vs_ours"].items()
            lines.append("  other blends vs ours: " + ", ".join(f"{b} {d:.2%}" for b, d in others))
    return lines


def ms_line(m: dict) -> str:
    return (f"multiple scattering vs Monte Carlo: network {m['network_vs_truth']:.2%}, SS only "
            f"{m['single_vs_truth']:.2%}, Cycles {m['cycles_vs_truth']:.2%} (Monte Carlo noise "
            f"{m['truth_noise']:.2%}, {m['truth_pixels']} px x {m['truth_paths']} paths)")


def summary_lines(report: dict) -> str:
    lines = [f"{report['model']} {report['label']}:"]
    for form, entries in report["forms"].items():
        lines += [f"  {form:5s} {line}" for line in scene_lines(entries)]
    return "\n".join(lines)


def show_side_by_side(context, entries: dict, out_dir: str):
    """Load the first scene's side-by-side picture (with multiple scattering its ``ms_picture``, with other blends
    its ``blends_picture``) as the image
    "Lamina Compare" and show it in an Image Editor."""
    import bpy

    first = next(iter(entries.values()))
    path = first["files"]["side_by_side"]
    for key, picture in (("ms", "ms_picture"), ("blends", "blends_picture")):
        if key in first:
            path = first[key]["files"][picture]
    old = bpy.data.images.get("Lamina Compare")
    if old is not None:  # Lamina's own picture from a previous comparison
        bpy.data.images.remove(old)
    image = bpy.data.images.load(path)
    image.name = "Lamina Compare"
    image.pack()  # survives the temporary folder and a saved file
    for area in context.screen.areas if context.screen else ():
        if area.type == "IMAGE_EDITOR":
            area.spaces.active.image = image
            break
    return image


# ------------------------------------------------------------------------------------------------ demo


def demo(forms, scenes, samples: int, resolution: int, seed: int, out_dir: str, model_id: str = "spongecake"):
    """Compare every preset and write ``index.html`` (what a new user looks at first)."""
    reports = []
    for name in presets.names(model_id):
        p = MODELS[model_id].params_from_dict(presets.load(model_id, name))
        print(f"lamina: {name}…", flush=True)
        report = compare_params(model_id, p, forms, scenes, samples, resolution, seed, os.path.join(out_dir, name),
                                label=name)
        print(summary_lines(report), flush=True)
        reports.append(report)
    write_text_atomic(os.path.join(out_dir, "index.html"), index_html(reports, model_id))
    write_png(os.path.join(out_dir, "overview.png"), overview(reports, out_dir))
    return reports


def overview(reports, out_dir: str, form: str = "osl", scene: str = "sphere") -> np.ndarray:
    """The side-by-side pictures of one scene for every preset, stacked top to bottom in preset order."""
    rows = [read_png(os.path.join(out_dir, r["label"], r["forms"][form][scene]["files"]["side_by_side"]))
            for r in reports if form in r["forms"] and scene in r["forms"][form]]
    width = max(r.shape[1] for r in rows)
    gap = np.zeros((4, width, 3), dtype=np.uint8)
    padded = [np.pad(r[..., :3], ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    return np.concatenate([x for r in padded for x in (r, gap)][:-1], axis=0)


def index_html(reports, model_id: str) -> str:
    rows = []
    for r in reports:
        name = r["label"]
        rows.append(f"<h2>{html.escape(name)}</h2><p>{html.escape(presets.description(model_id, name))}</p>")
        rows.append("<table><tr><th>form</th><th>scene</th><th>rel. RMSE</th><th>mapping alone</th>"
                    "<th>Cycles s</th><th>reference s</th><th>Cycles | reference | error</th></tr>")
        for form, entries in r["forms"].items():
            for scene, e in entries.items():
                img = html.escape(f"{name}/{e['files']['side_by_side']}")
                rows.append(f"<tr><td>{form}</td><td>{scene}</td><td>{e['rel_rmse']:.2%}</td>"
                            f"<td>{e['mapping_rel_rmse']:.2%}</td><td>{e['cycles_seconds']:.2f}</td>"
                            f"<td>{e['reference_seconds']:.2f}</td><td><img src=\"{img}\"></td></tr>")
        rows.append("</table>")
    style = ("body{font-family:sans-serif;background:#222;color:#ddd}td,th{padding:4px 8px}"
             "img{image-rendering:pixelated;height:128px}")
    return (f"<!doctype html><html><head><meta charset=utf-8><title>Lamina {model_id} presets</title>"
            f"<style>{style}</style></head><body><h1>Lamina: {model_id} presets, Cycles vs reference</h1>"
            f"<p>Samples {reports[0]['samples']}, resolution {reports[0]['resolution']}, seed {reports[0]['seed']}. "
            f"Relative RMSE = RMSE / mean of the reference over the object; 'mapping alone' is the noise-free "
            f"error of the form's closures against the reference (docs/accuracy.md).</p>"
            + "\n".join(rows) + "</body></html>")
