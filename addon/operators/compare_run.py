"""Comparison runs shared by the operator, the CLI, the demo (``demo``) and the benchmarks (bpy).

A run renders a Lamina material with Cycles and with the bundled reference on the standard scenes
(``reference.scenes``) and also measures the mapping alone: the numpy prediction of what the form renders
against the reference, which separates the approximation's error from Cycles' sampling noise.

With multiple scattering (``ms``: an ``reference.spongecake_truth.TruthSettings``) a run compares three things per scene:
single scattering alone (the closed-form reference), SS + MS from the network (the material with the flag on,
rendered by Cycles and by the reference) and SS + MS from Monte Carlo (the closed-form single scattering plus
the random walk's orders >= 2 at sampled pixels, ``reference.spongecake_truth``). The entries gain an ``ms`` dict.

A model whose mapping declares ``PRINCIPLED`` (``nodes.principled.Counterpart``: thin coats, anisotropic stacks) can
also be compared with what an artist would otherwise use, Blender's Principled BSDF set up from the same parameters
(``principled``: the mapping's ``principled_settings``; entries gain a ``principled`` dict), and a model with a
``reference.<model>_truth`` with the Monte Carlo ground truth of its light paths at sampled pixels (``truth``: a
``CoatTruth``; entries gain a ``truth`` dict).
"""
from __future__ import annotations

import importlib
import json
import os
import time
from dataclasses import dataclass

import numpy as np

from ..bake.exr import atomic_path, read_exr, write_exr, write_png
from ..models import MODELS
from ..nodes import MAPPINGS, choice, predicted_image, principled_counterpart
from ..nodes import material as lamina_material
from ..reference import metrics, montecarlo, truth_module
from ..reference import spongecake_truth as ms_truth
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
    return any(prm.name == "multiple_scattering" for prm in getattr(MODELS[model_id], "STACK", ()))


def has_blends(model_id: str) -> bool:
    return hasattr(reference_module(model_id), "BLENDS")


def has_principled(model_id: str) -> bool:
    return principled_counterpart(model_id) is not None


def principled_settings(model_id: str, p) -> dict:
    """The mapping's Principled BSDF inputs for ``p`` as JSON values (tuples as lists)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in MAPPINGS[model_id].principled_settings(p).items()}


def has_truth(model_id: str) -> bool:
    return truth_module(model_id) is not None


OPAQUE = ("no light passes through this material (an opaque base, substrate or bulk, or layers too thick to "
          "cross): the scene would be black")


def inapplicable_scenes(p) -> dict[str, str]:
    """The standard scenes that show nothing of ``p``, with the reason: the backlit one where no light passes
    (``p.transmits``: an opaque base, substrate or bulk, or layers too thick)."""
    return {} if getattr(p, "transmits", True) else {"backlit": OPAQUE}


def default_scene_names(p) -> list[str]:
    """The standard scenes worth rendering for ``p``: all of them but ``inapplicable_scenes``."""
    return [s for s in SCENES if s not in inapplicable_scenes(p)]


@dataclass(frozen=True)
class CoatTruth:
    """How much Monte Carlo the thin coat's ground truth gets: ``paths`` per sampled pixel (one call of
    ``ground_truth`` per pixel: every pixel has its own view), every ``stride``-th row and column."""

    paths: int = 2000
    stride: int = 4
    seed: int = 0

    def __post_init__(self):
        if self.paths < 16 or self.stride < 1:
            raise ValueError(f"paths must be ≥ 16 and stride ≥ 1, got {self.paths} and {self.stride}")


# Samples per pixel of the reference's directional albedo (furnace scene): ~0.7% relative noise.
ALBEDO_SAMPLES = 4096


def reference_functions(model_id: str, p):
    """(eval, albedo) of the exact reference for ``p``: what every comparison measures against."""
    ref = reference_module(model_id)
    return (lambda wi, wo: ref.eval(p, wi, wo)), (lambda wo: ref.furnace_albedo(p, wo, n=ALBEDO_SAMPLES))


def compare_material(mat, scenes, samples: int, resolution: int, seed: int, out_dir: str, progress=None,
                     reference_cache: dict | None = None, ms: ms_truth.TruthSettings | None = None,
                     blends: bool = False, principled: bool = False, truth: CoatTruth | None = None) -> dict:
    """Cycles vs reference for an existing Lamina material (it is assigned to temporary objects, never edited).
    ``scenes``: names of standard scenes (at ``resolution``) or ``Scene`` objects.
    ``reference_cache`` lets several forms of the same parameters share the reference renders (and, with ``ms``,
    the single-scattering images and the Monte Carlo ground truth).
    ``blends``: also render the reference with the model's other blending weights (micrograin: the linear mix by
    τ0 of the paper's Fig. 14 and d'Eon et al.'s weighting, Eq. 26) beside ours (``blend_comparison``).
    ``ms``: compare with multiple scattering (module docstring). A material whose flag is off is compared
    through a temporary copy with the flag on, removed again afterwards.
    ``principled``: also render Blender's Principled BSDF set up from the parameters (``principled_comparison``);
    ``truth``: also measure against the Monte Carlo ground truth at sampled pixels (``truth_comparison``)."""
    model_id, p = lamina_material.current_params(mat)
    if ms is not None and not p.multiple_scattering:
        p_on = with_multiple_scattering(model_id, p)
        before = blend_io.snapshot()
        try:
            tmp = lamina_material.new_material(model_id, p_on, lamina_material.form_of(mat),
                                               name=f"{mat.name} (multiple scattering)")
            return compare_material(tmp, scenes, samples, resolution, seed, out_dir, progress, reference_cache, ms,
                                    blends, principled, truth)
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
        approx = predicted_image(model_id, p, form, spec, lamina_material.fit_of(mat))
        report[spec.name]["mapping_rel_rmse"] = metrics.rel_rmse(approx, reference, ref_scenes.scene_mask(spec))
        if ms is not None:
            cycles = read_exr(report[spec.name]["files"]["cycles"], "RGB")
            report[spec.name]["ms"] = ms_comparison(model_id, p, spec, cycles, reference, ms, out_dir, cache)
        if blends:
            cycles = read_exr(report[spec.name]["files"]["cycles"], "RGB")
            report[spec.name]["blends"] = blend_comparison(model_id, p, spec, cycles, reference, out_dir, cache)
        if principled:
            cycles = read_exr(report[spec.name]["files"]["cycles"], "RGB")
            report[spec.name]["principled"] = principled_comparison(
                model_id, p, spec, cycles, reference, report[spec.name]["samples"], seed, out_dir, cache)
        if truth is not None:
            cycles = read_exr(report[spec.name]["files"]["cycles"], "RGB")
            principled_image = (read_exr(report[spec.name]["principled"]["files"]["principled"], "RGB")
                                if principled else None)
            report[spec.name]["truth"] = truth_comparison(model_id, p, spec, cycles, reference, truth, out_dir, cache,
                                                          principled_image)
    return report


def principled_comparison(model_id: str, p, spec, cycles, reference, samples: int, seed: int, out_dir: str,
                          cache: dict) -> dict:
    """Blender's Principled BSDF set up from ``p`` (the mapping's ``principled_settings``), rendered by Cycles on the
    same scene with the same samples and seed (once per scene: it does not depend on the form), against the
    reference: its relative RMSE beside the form's, ``<scene>_principled.exr`` and ``<scene>_principled.png`` =
    ``principled_panels`` (one exposure, one heat scale)."""
    counterpart = principled_counterpart(model_id)
    if counterpart is None:
        raise ValueError(f"{model_id} has no Principled BSDF counterpart")
    stem = compare_core.safe_file_stem(spec.name)
    files = {"principled": os.path.join(out_dir, f"{stem}_principled.exr"),
             "principled_picture": os.path.join(out_dir, f"{stem}_principled.png")}
    key = f"{spec.name}/principled"
    if key not in cache:
        from .cycles_render import render_cycles

        before = blend_io.snapshot()
        try:
            mat = lamina_material.principled_material(model_id, p, name=f"Lamina compare {counterpart.label}")
            cache[key] = render_cycles(mat, spec, samples, seed, files["principled"])
        finally:
            blend_io.remove_new_data(before)
    image, seconds = cache[key]
    write_exr(files["principled"], image)
    mask = ref_scenes.scene_mask(spec)
    write_png(files["principled_picture"], comparison_picture([cycles, reference, image], reference, mask))
    return {
        "rel_rmse": metrics.rel_rmse(image, reference, mask),
        "rmse": metrics.rmse(image, reference, mask),
        "max_abs_error": metrics.max_abs_error(image, reference, mask),
        "lamina_rel_rmse": metrics.rel_rmse(cycles, reference, mask),
        "cycles_seconds": seconds,
        "settings": principled_settings(model_id, p),
        "label": counterpart.label,
        "panels": list(principled_panels(counterpart.label)),
        "files": files,
    }


def principled_panels(label: str) -> tuple[str, ...]:
    """The Principled picture's panels; ``label`` (the mapping's ``PRINCIPLED.label``) is the third."""
    return "Lamina (Cycles)", "reference", label, "error Lamina", "error Principled"


def comparison_picture(images, reference, mask, heat_mask=None, gap: int = 2) -> np.ndarray:
    """``images`` side by side (uint8) at the reference's exposure, then the error map of every image but the
    reference itself (those not ``reference``) against it, one heat scale (``metrics.HEAT_SCALE``);
    ``heat_mask`` limits the error maps (default ``mask``)."""
    heat_mask = mask if heat_mask is None else heat_mask
    exposure = metrics.auto_exposure(reference, mask)
    panels = [metrics.tonemap(x, exposure) for x in images]
    vmax = None
    for x in images:
        if x is reference:
            continue
        heat, vmax = metrics.heat_map(x, reference, heat_mask, vmax=vmax)
        panels.append(np.round(heat * 255).astype(np.uint8))
    sep = np.full((panels[0].shape[0], gap, 3), 255, dtype=np.uint8)
    return np.concatenate([x for panel in panels for x in (panel, sep)][:-1], axis=1)


def coat_truth_image(model_id: str, p, spec, settings: CoatTruth) -> dict:
    """The Monte Carlo ground truth of ``spec`` at sampled pixels (``montecarlo.sampled_pixels``): per pixel, the
    sum over orders of ``ground_truth(p, wi, wo)`` times the sun's irradiance and |cos θi| (a closed sphere blocks
    light from below its surface, like ``scenes.reference_image``), or for the furnace the environment times
    ``ground_truth_albedo``'s reflected and transmitted energy. Returns ``image`` (H x W x 3, the nearest sample's
    value elsewhere, for pictures only), ``noise`` (standard error, 0 off the samples), ``samples`` (H x W bool),
    ``seconds``."""
    truth = truth_module(model_id)
    t0 = time.perf_counter()
    g = ref_scenes.pixel_geometry(spec)
    h, w = spec.height, spec.width
    samples = montecarlo.sampled_pixels(spec, settings.stride)
    rows, cols = np.nonzero(samples)
    wo_l = ref_scenes.to_local(g["wo"][rows, cols], g["t"][rows, cols], g["b"][rows, cols], g["n"][rows, cols])
    value = np.zeros((len(rows), 3))
    var = np.zeros((len(rows), 3))
    for j in range(len(rows)):
        seed = int(np.random.SeedSequence([settings.seed, j]).generate_state(1)[0])
        if spec.kind == "furnace":
            a = truth.ground_truth_albedo(p, wo_l[j], n_paths=settings.paths, seed=seed)
            value[j] = spec.environment * (a["reflection"].sum(axis=0) + a["transmission"].sum(axis=0))
            se = a["stderr"]["reflection"] ** 2 + a["stderr"]["transmission"] ** 2
            var[j] = spec.environment ** 2 * se.sum(axis=0)
            continue
        r, c = rows[j], cols[j]
        wi = np.stack([ref_scenes.to_local(np.asarray(sun.direction, dtype=float), g["t"][r, c], g["b"][r, c],
                                           g["n"][r, c]) for sun in spec.suns])
        lit = (wi[:, 2] > 0.0) | (spec.kind != "sphere")
        scale = np.where(lit, np.abs(wi[:, 2]), 0.0) * np.array([sun.irradiance for sun in spec.suns])
        if not scale.any():
            continue
        # one walk serves every sun (their noise, correlated through the shared paths, is added as if independent)
        f, se = truth.ground_truth(p, wi, wo_l[j], n_paths=settings.paths, seed=seed)
        value[j] = (f.sum(axis=0) * scale[:, None]).sum(axis=0)
        var[j] = ((se ** 2).sum(axis=0) * scale[:, None] ** 2).sum(axis=0)
    image = np.zeros((h, w, 3))
    noise = np.zeros((h, w, 3))
    image[rows, cols], noise[rows, cols] = value, np.sqrt(var)
    hit = np.argwhere(g["hit"])
    if len(rows):
        nearest = montecarlo.nearest(hit.astype(float), np.stack([rows, cols], axis=1).astype(float))
        image[hit[:, 0], hit[:, 1]] = value[nearest]
        image[rows, cols] = value
    return {"image": image, "noise": noise, "samples": samples, "seconds": time.perf_counter() - t0}


TRUTH_PANELS = ("Lamina (Cycles)", "reference", "Monte Carlo", "error Lamina", "error reference")


def truth_comparison(model_id: str, p, spec, cycles, reference, settings: CoatTruth, out_dir: str, cache: dict,
                     principled=None) -> dict:
    """The form (Cycles), the analytic reference and (given) the Principled BSDF against the Monte Carlo ground
    truth of the same light paths (``coat_truth_image``; the same number of bounces), over its sampled pixels:
    relative RMSEs, its noise on the same scale, ``<scene>_ground_truth.exr`` and ``<scene>_truth.png``
    (``TRUTH_PANELS``: error maps over the sampled pixels)."""
    if not has_truth(model_id):
        raise ValueError(f"no Monte Carlo ground truth for {model_id} (reference.{model_id}_truth)")
    key = f"{spec.name}/coat truth"
    if key not in cache or cache[key][1] != settings:
        cache[key] = (coat_truth_image(model_id, p, spec, settings), settings)
    mc = cache[key][0]
    samples = mc["samples"]
    stem = compare_core.safe_file_stem(spec.name)
    files = {"ground_truth": os.path.join(out_dir, f"{stem}_ground_truth.exr"),
             "truth_picture": os.path.join(out_dir, f"{stem}_truth.png")}
    write_exr(files["ground_truth"], mc["image"])
    mask = ref_scenes.scene_mask(spec)
    images = [cycles, reference, mc["image"]]
    picture = comparison_picture(images, mc["image"], mask, heat_mask=samples)
    write_png(files["truth_picture"], picture)
    out = {
        "cycles_vs_truth": metrics.rel_rmse(cycles, mc["image"], samples),
        "reference_vs_truth": metrics.rel_rmse(reference, mc["image"], samples),
        "truth_noise": montecarlo.relative_noise(mc["image"], mc["noise"], samples),
        "truth_pixels": int(samples.sum()),
        "truth_paths": settings.paths,
        "truth_stride": settings.stride,
        "truth_seconds": mc["seconds"],
        "panels": list(TRUTH_PANELS),
        "files": files,
    }
    if principled is not None:
        out["principled_vs_truth"] = metrics.rel_rmse(principled, mc["image"], samples)
    return out


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
    Carlo, one exposure and one heat scale, ``metrics.HEAT_SCALE`` of the ground truth's mean). Errors against the
    Monte Carlo are taken over its sampled pixels only."""
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
        "truth_noise": montecarlo.relative_noise(truth, truth_ms["noise"], samples),
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
                   label: str = "custom", ms: ms_truth.TruthSettings | None = None, blends: bool = False,
                   principled: bool = False, truth: CoatTruth | None = None, mapping: str = "analytic") -> dict:
    """Build a temporary material per form, compare it, remove it again; write ``report.json``.
    With ``ms`` the materials have multiple scattering on and every scene is also compared with the Monte
    Carlo ground truth (``compare_material``); ``report["ms"]`` records the ground truth's settings.
    ``scenes`` None: ``default_scene_names(p)``. ``principled`` / ``truth``: see ``compare_material``
    (``report["principled"]`` records the Principled settings, ``report["truth"]`` the ground truth's).
    ``mapping``: the materials' (``nodes.MAPPING_KINDS``); ``report["mappings"][form]`` records which one each form
    uses and both mappings' predicted errors on the comparison scenes (models with a fitted mapping)."""
    scenes = default_scene_names(p) if scenes is None else scenes
    if ms is not None:
        p = with_multiple_scattering(model_id, p)
    report = {"model": model_id, "label": label, "params": p.to_dict(), "samples": samples,
              "resolution": resolution, "seed": seed, "mapping": mapping, "forms": {}, "mappings": {}}
    if ms is not None:
        report["ms"] = {"paths": ms.paths, "albedo_paths": ms.albedo_paths, "stride": ms.stride,
                        "max_depth": ms.max_depth, "seed": ms.seed}
    if principled:
        counterpart = principled_counterpart(model_id)
        if counterpart is None:
            raise ValueError(f"{model_id} has no Principled BSDF counterpart")
        report["principled"] = {"label": counterpart.label, "settings": principled_settings(model_id, p),
                                "mapping": counterpart.mapping}
    if truth is not None:
        report["truth"] = {"paths": truth.paths, "stride": truth.stride, "seed": truth.seed}
    references = {}
    for form in forms:
        before = blend_io.snapshot()
        try:
            mat = lamina_material.new_material(model_id, p, form, name=f"Lamina compare {label}", mapping=mapping)
            entries = compare_material(mat, scenes, samples, resolution, seed, os.path.join(out_dir, form),
                                       reference_cache=references, ms=ms, blends=blends, principled=principled,
                                       truth=truth)
            record = lamina_material.fit_record(mat)
            if record is not None:
                report["mappings"][form] = record_summary(record)
        finally:
            blend_io.remove_new_data(before)
        report["forms"][form] = {scene: _json_entry(e, out_dir) for scene, e in entries.items()}
    write_text_atomic(os.path.join(out_dir, "report.json"), json.dumps(report, indent=2))
    return report


REPORT_KEYS = ("rmse", "rel_rmse", "max_abs_error", "mapping_rel_rmse", "cycles_seconds", "reference_seconds",
               "reference_cached", "samples", "worst_pixels", "files", "ms", "blends", "principled", "truth")


def _json_entry(entry: dict, out_dir: str) -> dict:
    out = {k: entry[k] for k in REPORT_KEYS if k in entry}
    out["files"] = {k: os.path.relpath(v, out_dir) for k, v in entry["files"].items()}
    out["worst_pixels"] = [[int(r), int(c), [float(x) for x in a], [float(x) for x in b]]
                           for r, c, a, b in entry["worst_pixels"]]
    for key in ("ms", "blends", "principled", "truth"):
        if key in entry:
            out[key] = {**entry[key], "files": {k: os.path.relpath(v, out_dir) for k, v in entry[key]["files"].items()}}
    return out


def scene_lines(entries: dict) -> list[str]:
    lines = []
    for scene, e in entries.items():
        reference = "cached" if e["reference_cached"] else f"{e['reference_seconds']:.3g} s"
        lines.append(f"{scene}: RMSE {e['rmse']:.3g}, rel. RMSE {e['rel_rmse']:.2%} (mapping alone "
                     f"{e['mapping_rel_rmse']:.2%}), Cycles {e['cycles_seconds']:.3g} s, reference {reference}")
        if "ms" in e:
            lines.append("  " + ms_line(e["ms"]))
        if "blends" in e:
            others = e["blends"]["vs_ours"].items()
            lines.append("  other blends vs ours: " + ", ".join(f"{b} {d:.2%}" for b, d in others))
        if "principled" in e:
            pr = e["principled"]
            lines.append(f"  {pr['label']} vs reference: rel. RMSE {pr['rel_rmse']:.2%} (Lamina {e['rel_rmse']:.2%})")
        if "truth" in e:
            lines.append("  " + truth_line(e["truth"]))
    return lines


def truth_line(t: dict) -> str:
    principled = f", Principled {t['principled_vs_truth']:.2%}" if "principled_vs_truth" in t else ""
    return (f"vs Monte Carlo: reference {t['reference_vs_truth']:.2%}, Cycles {t['cycles_vs_truth']:.2%}"
            f"{principled} (noise {t['truth_noise']:.2%}, {t['truth_pixels']} px x {t['truth_paths']} paths)")


def ms_line(m: dict) -> str:
    return (f"multiple scattering vs Monte Carlo: network {m['network_vs_truth']:.2%}, SS only "
            f"{m['single_vs_truth']:.2%}, Cycles {m['cycles_vs_truth']:.2%} (Monte Carlo noise "
            f"{m['truth_noise']:.2%}, {m['truth_pixels']} px x {m['truth_paths']} paths)")


def summary_lines(report: dict) -> str:
    lines = [f"{report['model']} {report['label']}:"]
    for form, entries in report["forms"].items():
        if form in report.get("mappings", {}):
            lines.append(f"  {form:5s} {choice.describe(report['mappings'][form])}")
        lines += [f"  {form:5s} {line}" for line in scene_lines(entries)]
    return "\n".join(lines)


def record_summary(record: dict) -> dict:
    """What a report keeps of a material's mapping record (``fit_record``): which one renders, both predicted
    errors, and a note (e.g. linked inputs)."""
    return {"used": record["used"], "predicted_error": record["error"],
            **({"note": record["note"]} if "note" in record else {})}



def show_side_by_side(context, entries: dict, out_dir: str):
    """Load the first scene's side-by-side picture (with multiple scattering its ``ms_picture``, with other blends
    its ``blends_picture``) as the image
    "Lamina Compare" and show it in an Image Editor."""
    import bpy

    first = next(iter(entries.values()))
    path = first["files"]["side_by_side"]
    for key, picture in (("ms", "ms_picture"), ("blends", "blends_picture"), ("truth", "truth_picture"),
                         ("principled", "principled_picture")):
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
