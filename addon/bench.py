"""``make bench``: writes docs/accuracy.md and docs/benchmarks.md from measurements taken in one run.

Accuracy (no sampling noise): each named approximation of the Cycles mapping, and each preset, measured as the
relative RMSE of the form's numpy prediction against the reference on the comparison scenes. Tests check that
Cycles renders these predictions (tests/blender/test_cycles_vs_prediction.py), so the numbers are what an
artist gets. Reference vs Monte Carlo ground truth is measured on the presets too.
Speed: reference throughput, and Cycles render times of node group : OSL : Principled BSDF from one run.
"""
from __future__ import annotations

import datetime
import os
import time

import numpy as np

from . import presets
from .models import spongecake as model
from .nodes import predicted_image
from .nodes import spongecake as mapping
from .reference import metrics
from .reference import scenes as ref_scenes
from .reference import spongecake as reference

MODEL = model.ID
ACCURACY_SCENES = ("sphere", "plane", "backlit", "furnace")
# The furnace reference needs the directional albedo per pixel; this many samples per pixel (MIS) keep
# its noise near 1%, below the approximations measured here.
ALBEDO_SAMPLES = 2048


def _scenes(resolution: int):
    """The comparison scenes; the furnace at half resolution (its reference costs an albedo per pixel)."""
    scenes = [s for s in ref_scenes.default_scenes(resolution) if s.name in ACCURACY_SCENES]
    return [s.with_resolution(resolution // 2, resolution // 4) if s.kind == "furnace" else s for s in scenes]


def mapping_errors(p, resolution: int) -> dict:
    """{form: {scene: rel RMSE of the prediction vs the reference}} plus the reference's mean per scene."""
    out = {"osl": {}, "nodes": {}, "mean": {}}
    for spec in _scenes(resolution):
        ref = ref_scenes.reference_image(spec, lambda wi, wo: reference.eval(p, wi, wo),
                                         bsdf_albedo=lambda wo: reference.furnace_albedo(p, wo, n=ALBEDO_SAMPLES))
        mask = ref_scenes.scene_mask(spec)
        out["mean"][spec.name] = float(ref[mask].mean())
        for form in ("osl", "nodes"):
            out[form][spec.name] = metrics.rel_rmse(predicted_image(MODEL, p, form, spec), ref, mask)
    return out


def ground_truth_error(p, n_dirs: int = 4, n_paths: int = 20000, seed: int = 1) -> float:
    """Mean relative error of the analytic single scattering vs the random walk's order-1 estimate."""
    mu = (np.arange(n_dirs) + 0.5) / n_dirs
    phi = np.linspace(0.0, 2.0 * np.pi, n_dirs, endpoint=False)
    m, f = np.meshgrid(mu, phi)
    s = np.sqrt(1.0 - m**2)
    d = np.stack([s * np.cos(f), s * np.sin(f), m], axis=-1).reshape(-1, 3)
    wi = np.repeat(d, len(d), axis=0)
    wo = np.tile(d, (len(d), 1))
    single, _ = reference.ground_truth(p, wi, wo, n_paths=n_paths, seed=seed)
    analytic = reference.eval(p, wi, wo)
    return float(np.abs(analytic - single).mean() / np.abs(single).mean())


def reference_throughput(p, n: int = 200_000, repeats: int = 3) -> float:
    rng = np.random.default_rng(0)

    def dirs():
        v = rng.normal(size=(n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        return v

    wi, wo = dirs(), dirs()
    best = min(_timed(lambda: reference.eval(p, wi, wo)) for _ in range(repeats))
    return n / best


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def render_times(samples: int, resolution: int, repeats: int = 3) -> list[dict]:
    """Cycles render time of each preset as node group, OSL and a Principled BSDF with a similar lobe count
    (the fastest of ``repeats`` renders each, which damps the machine's noise)."""
    from .operators import blend_io
    from .operators.cycles_render import render_cycles
    from .nodes import material as lamina_material
    import bpy

    spec = ref_scenes.sphere_scene(resolution=resolution)
    rows = []
    for name in presets.names(MODEL):
        p = model.params_from_dict(presets.load(MODEL, name))
        before = blend_io.snapshot()
        try:
            materials = {form: lamina_material.new_material(MODEL, p, form) for form in ("nodes", "osl")}
            materials["principled"] = principled_like(p)
            path = os.path.join(bpy.app.tempdir, "bench.exr")
            times = {name: min(render_cycles(mat, spec, samples, 0, path)[1] for _ in range(repeats))
                     for name, mat in materials.items()}
        finally:
            blend_io.remove_new_data(before)
        rows.append({"preset": name, **times})
    return rows


def principled_like(p):
    """A Principled BSDF with about as many lobes as the stack: specular + coat per extra layer, sheen for
    fibers, transmission when the stack transmits."""
    import bpy

    mat = bpy.data.materials.new("Lamina bench principled")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.5
    if len(p.layers) > 1:
        bsdf.inputs["Coat Weight"].default_value = 1.0
    if any(layer.type == "fiber" for layer in p.layers):
        bsdf.inputs["Sheen Weight"].default_value = 1.0
    if p.substrate is None:
        bsdf.inputs["Transmission Weight"].default_value = 0.5
    return mat


# ------------------------------------------------------------------------------------------------ docs


def _pct(x: float) -> str:
    return f"{100 * x:.1f}%" if np.isfinite(x) else "n/a"


def accuracy_markdown(resolution: int) -> str:
    lines = ["# Accuracy of the Cycles forms", "",
             f"Generated by `make bench` (`python -m addon.cli bench --resolution {resolution} ...`, "
             f"{datetime.date.today().isoformat()}); do not edit by hand.", "",
             "Errors are relative RMSE (RMSE ÷ mean of the reference over the object) of what a form renders "
             "against the float64 reference, on the comparison scenes of docs/architecture.md at "
             f"{resolution} px, computed from the mapping's numpy prediction (no sampling noise; the Blender tests "
             "check that Cycles renders this prediction). A scene whose reference is nearly black (e.g. backlit "
             "for opaque stacks) inflates relative errors: its reference mean is listed.", "",
             "## Named approximations, each isolated", "",
             "| approximation | what it does | configuration | scene | ref. mean | OSL | node group |",
             "|---|---|---|---|---|---|---|"]
    for name, (what, config) in mapping.APPROXIMATIONS.items():
        p = model.params_from_dict(config)
        errs = mapping_errors(p, resolution)
        for scene in ACCURACY_SCENES:
            lines.append(f"| {name} | {what} | `{_short(config)}` | {scene} | {errs['mean'][scene]:.4f} | "
                         f"{_pct(errs['osl'][scene])} | {_pct(errs['nodes'][scene])} |")
    lines += ["", "## Presets", "",
              "Reference vs ground truth: mean relative error of the analytic single scattering against the "
              "order-1 part of an independent random walk (4×4 × 4×4 direction pairs, 20 000 paths each).", "",
              "| preset | scene | ref. mean | OSL | node group |", "|---|---|---|---|---|"]
    gt_rows = []
    for name in presets.names(MODEL):
        p = model.params_from_dict(presets.load(MODEL, name))
        errs = mapping_errors(p, resolution)
        for scene in ACCURACY_SCENES:
            lines.append(f"| {name} | {scene} | {errs['mean'][scene]:.4f} | {_pct(errs['osl'][scene])} | "
                         f"{_pct(errs['nodes'][scene])} |")
        gt_rows.append(f"| {name} | {_pct(ground_truth_error(p))} |")
    lines += ["", "| preset | reference vs ground truth (single scattering) |", "|---|---|", *gt_rows, ""]
    return "\n".join(lines)


def _short(config: dict) -> str:
    parts = []
    for layer in config["layers"]:
        extra = {k: v for k, v in layer.items() if k not in ("type", "albedo")}
        parts.append(f"{layer['type']} " + " ".join(f"{k}={v}" for k, v in extra.items()))
    if config.get("substrate"):
        parts.append(f"substrate {config['substrate']['type']}")
    return " / ".join(parts)


def benchmarks_markdown(samples: int, resolution: int) -> str:
    fabric = model.params_from_dict(presets.load(MODEL, "fabric"))
    rate = reference_throughput(fabric)
    rows = render_times(samples, resolution)
    lines = ["# Benchmarks", "",
             f"Generated by `make bench` (`python -m addon.cli bench --samples {samples} ...`, "
             f"{datetime.date.today().isoformat()}) on this machine "
             f"({os.cpu_count()} CPU cores); do not edit by hand. Ratios come from one run.", "",
             f"Reference `spongecake.eval`, 2-layer fabric, float64: **{rate / 1e6:.2f} M evals/s**.", "",
             f"Cycles CPU render of the sphere scene, {resolution}×{resolution} px, {samples} samples, fastest of "
             "3 renders, no bounces (OSL scenes enable the OSL shading system, as users must). The Principled BSDF "
             "material has about the same lobe count (coat for a second layer, sheen for fibers, "
             "transmission when nothing blocks the back).", "",
             "| preset | node group s | OSL s | Principled s | node group : Principled | OSL : node group |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['preset']} | {r['nodes']:.2f} | {r['osl']:.2f} | {r['principled']:.2f} | "
                     f"{r['nodes'] / r['principled']:.2f} | {r['osl'] / r['nodes']:.2f} |")
    return "\n".join(lines) + "\n"


def sheen_alternative(samples: int, resolution: int) -> str:
    """Fibers along the normal: Cycles' Microfiber Sheen BSDF (a fit to such fibers, with multiple scattering)
    against the reference's single scattering, at the best constant scale, next to Lamina's Lambert lobe."""
    import bpy

    from .nodes import material as lamina_material
    from .operators import blend_io
    from .operators.cycles_render import render_cycles

    lines = ["", "## Fibers along the normal: Cycles' Sheen closure as an alternative", "",
             "Cycles' Microfiber Sheen BSDF is a fit to fibers standing along the normal, so it was measured as "
             "an alternative for the `fiber-along-normal` lobe: the best constant scale k is fitted per row "
             "(the closure's own normalisation differs from single scattering). Relative RMSE in Cycles, "
             f"{samples} samples.", "",
             "| layer (fiber α = 0.2 along n) | sheen roughness | k | sphere | plane | Lamina node group sphere | plane |",
             "|---|---|---|---|---|---|---|"]
    specs = [ref_scenes.sphere_scene(resolution=resolution), ref_scenes.plane_scene(resolution=(resolution, resolution // 2))]
    tmp = os.path.join(bpy.app.tempdir, "bench_sheen.exr")
    for thickness in (0.5, 5.0):
        p = model.params_from_dict(_fiber_along_n(thickness))
        refs = [ref_scenes.reference_image(s, lambda wi, wo: reference.eval(p, wi, wo)) for s in specs]
        masks = [ref_scenes.scene_mask(s) for s in specs]
        before = blend_io.snapshot()
        try:
            lamina = [render_cycles(lamina_material.new_material(MODEL, p, "nodes"), s, samples, 0, tmp)[0] for s in specs]
            ours = [metrics.rel_rmse(img, r, m) for img, r, m in zip(lamina, refs, masks)]
            for roughness in (0.2, 0.45, 0.7):
                mat = _sheen_material(roughness)
                imgs = [render_cycles(mat, s, samples, 0, tmp)[0] for s in specs]
                k = sum((i[m] * r[m]).sum() for i, r, m in zip(imgs, refs, masks)) / \
                    sum((i[m] ** 2).sum() for i, m in zip(imgs, masks))
                errs = [metrics.rel_rmse(k * i, r, m) for i, r, m in zip(imgs, refs, masks)]
                lines.append(f"| Tρ = {thickness} | {roughness} | {k:.3f} | {_pct(errs[0])} | {_pct(errs[1])} | "
                             f"{_pct(ours[0])} | {_pct(ours[1])} |")
        finally:
            blend_io.remove_new_data(before)
    return "\n".join(lines) + "\n"


def _fiber_along_n(thickness: float) -> dict:
    return {"layers": [{"type": "fiber", "roughness": 0.2, "thickness": thickness, "albedo": [1, 1, 1],
                        "orientation": [0, 0, 1]}]}


def _sheen_material(roughness: float):
    from .nodes.material import empty_material

    mat, tree, out = empty_material("Lamina bench sheen")
    sheen = tree.nodes.new("ShaderNodeBsdfSheen")
    sheen.distribution = "MICROFIBER"
    sheen.inputs["Roughness"].default_value = roughness
    sheen.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    tree.links.new(sheen.outputs[0], out.inputs["Surface"])
    return mat


def overview_picture(path: str, samples: int, resolution: int) -> None:
    """docs/images/overview.png: every preset's sphere, OSL form | reference | error, top to bottom."""
    import tempfile

    from .bake.exr import read_png, write_png
    from .operators import compare_run

    with tempfile.TemporaryDirectory(prefix="lamina_bench_") as tmp:
        compare_run.demo(["osl"], ["sphere"], samples, resolution, 0, tmp)
        write_png(path, read_png(os.path.join(tmp, "overview.png")))


def run(out_dir: str, samples: int = 64, resolution: int = 64) -> None:
    from .operators.compare_run import write_text_atomic

    os.makedirs(out_dir, exist_ok=True)
    overview_picture(os.path.join(out_dir, "images", "overview.png"), samples * 2, resolution * 2)
    write_text_atomic(os.path.join(out_dir, "accuracy.md"),
                      accuracy_markdown(resolution) + sheen_alternative(samples * 2, resolution))
    print(f"lamina: wrote {os.path.join(out_dir, 'accuracy.md')}", flush=True)
    write_text_atomic(os.path.join(out_dir, "benchmarks.md"), benchmarks_markdown(samples * 2, resolution * 4))
    print(f"lamina: wrote {os.path.join(out_dir, 'benchmarks.md')}", flush=True)
