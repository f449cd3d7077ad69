"""The neural medium's sections of docs/accuracy.md and docs/benchmarks.md: the shipped networks (size, energy
ratios from their manifests), and on the comparison sphere (48 px) what Cycles renders with Lamina's bake against
the numpy ground truth and Cycles' own full volumetric path tracing, with render and bake times from the same run.

The numpy truths are cached by content hash (``LAMINA_CACHE``/neural-medium-truth): a second ``make bench`` reuses
them."""
from __future__ import annotations

import hashlib
import json
import os
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from .. import presets
from ..bake import neural_medium as nb
from ..models import neural_medium as model
from ..reference import metrics
from ..reference import neural_medium as nm
from ..reference import neural_medium_truth as truth
from ..reference import scenes as S
from .common import pct

MODEL = model.ID
CASES = (("cloud", 0.5), ("candle", 0.1), ("milk", 0.25))  # (preset, scale): 4.4, 10 and 10.7 mfp across
RESOLUTION = 48
TRUTH_PATHS = 1024
FULL_BOUNCES = 1024
SETTINGS = nb.Settings()
CACHE = Path(os.environ.get("LAMINA_CACHE", Path.home() / ".cache" / "lamina")) / "neural-medium-truth"


def scene():
    return S.sphere_scene(resolution=RESOLUTION, sphere_segments=64, sphere_rings=32)


def medium(name: str, scale: float):
    return model.params_from_dict({**presets.load(MODEL, name), "scale": scale})


def cached_truth(p, spec) -> dict:
    """The numpy truth of ``p`` on the sphere (total and its noise, per order group), cached by content hash."""
    key = hashlib.sha256(json.dumps([p.to_dict(), RESOLUTION, TRUTH_PATHS, 1],
                                    sort_keys=True).encode()).hexdigest()[:16]
    path = CACHE / f"{key}.npz"
    if path.exists():
        with np.load(path) as f:
            return {k: f[k] for k in f.files}
    t = truth.render(p, truth.Sphere(), spec, TRUTH_PATHS, seed=1)
    out = {"total": t["total"], "order1": t["order1"], "mask": t["mask"],
           "noise": np.sqrt(sum(t["noise"][g] ** 2 for g in truth.GROUPS))}
    CACHE.mkdir(parents=True, exist_ok=True)
    from ..bake.exr import atomic_path

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **out)
    return out


@lru_cache(maxsize=2)
def measure(samples: int) -> list[dict]:
    """Per case: Cycles single scattering, single scattering + bake, full path tracing, against the numpy truth."""
    import bpy

    from ..nodes import neural_medium as medium_nodes
    from ..operators import blend_io, medium_bake
    from ..operators.cycles_render import render_cycles

    spec = scene()
    path = os.path.join(bpy.app.tempdir, "bench_medium.exr")
    rows = []
    for name, scale in CASES:
        p = medium(name, scale)
        t = cached_truth(p, spec)
        mask = S.scene_mask(spec) & t["mask"]
        before = blend_io.snapshot()
        bake_info = {}

        def bake(scene_, obj, p=p, info=bake_info):
            scene_.view_layers[0].update()
            start = time.perf_counter()
            tables = nb.channel_tables(p)
            info["tables_s"] = time.perf_counter() - start
            result = medium_bake.run(obj, scene_, scene_.view_layers[0].depsgraph, p, SETTINGS, tables=tables)
            info.update(result["record"])
            info["bake_s"] = time.perf_counter() - start - info["tables_s"]

        try:
            mat = medium_nodes.new_material(p)
            images = {"single scattering": render_cycles(mat, spec, samples, 0, path),
                      "single + Lamina bake": render_cycles(mat, spec, samples, 0, path, prepare=bake),
                      f"Cycles, {FULL_BOUNCES} bounces": render_cycles(mat, spec, samples, 0, path,
                                                                       bounces=FULL_BOUNCES)}
        finally:
            blend_io.remove_new_data(before)
        ref = t["total"]
        noise = float(np.sqrt(np.mean(t["noise"][mask] ** 2)) / ref[mask].mean())
        row = {"case": f"{name} ×{scale:g}", "across": float(truth.optical_depth(p, 2.0).mean()),
               "albedo": float(np.mean(p.albedo)), "truth_noise": noise, "bake": bake_info, "forms": {}}
        full = images[f"Cycles, {FULL_BOUNCES} bounces"][0]
        for label, (img, seconds) in images.items():
            row["forms"][label] = {"energy": float(img[mask].mean() / ref[mask].mean() - 1.0),
                                   "rel_rmse": float(metrics.rel_rmse(img, ref, mask)),
                                   "vs_cycles": float(metrics.rel_rmse(img, full, mask)), "seconds": seconds}
        rows.append(row)
    return rows


def network_lines() -> list[str]:
    lines = ["| network | float32 size | training materials, samples | minutes | energy ratio: training (mean, worst) "
             "| off the grid (mean, worst) |", "|---|---|---|---|---|---|"]
    for kind in nm.KINDS:
        net = nm.network(kind)
        m = net.manifest
        size = 4 * sum(w.size + b.size for w, b in zip(net.weights, net.biases))
        e = m["energy_ratio"]
        lines.append(f"| {kind} | {size / 1024:.1f} KB | {len(m['data']['materials'])}, {m['data']['samples']:,} | "
                     f"{m['minutes']:g} | {pct(e['training']['mean_abs'])}, {pct(e['training']['worst_abs'])} | "
                     f"{pct(e['off_grid']['mean_abs'])}, {pct(e['off_grid']['worst_abs'])} |")
    return lines


def accuracy(sizes) -> str:
    rows = measure(sizes.samples)
    out = ["## Neural media (neural_medium)", "",
           "The shipped networks (`make medium-networks`; the energy ratio is the power of the table a network "
           "reconstructs over the Monte Carlo table's, minus 1, the paper's measure):", "", *network_lines(), "",
           f"What Cycles renders on the comparison sphere ({RESOLUTION} px, a 64 × 32 mesh, {sizes.samples} samples, "
           f"the scene's sun) against the numpy ground truth (`reference/neural_medium_truth.py`, {TRUTH_PATHS} "
           "paths per pixel, all orders; its own noise in the last column) and against Cycles' full volumetric path "
           f"tracing ({FULL_BOUNCES} volume bounces). The bake: the networks' tables, gathered from "
           f"{SETTINGS.cells} × {SETTINGS.cells} beams per lamp, {SETTINGS.steps} steps per ray, multiple scattering "
           "with the boundary's image sources, fitted linearly in the direction per vertex.", "",
           "| medium (scale) | mfp across | albedo | form | energy vs truth | rel. RMSE vs truth | rel. RMSE vs "
           "Cycles full | truth noise |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for label, f in r["forms"].items():
            out.append(f"| {r['case']} | {r['across']:.1f} | {r['albedo']:.3f} | {label} | {f['energy']:+.1%} | "
                       f"{pct(f['rel_rmse'])} | {pct(f['vs_cycles'])} | {pct(r['truth_noise'])} |")
    out += ["", "Not measured yet: a slab and a mesh such as Suzanne, Cycles' random-walk subsurface scattering of "
                "the same medium, a camera moved after the bake, low albedo (oil).", ""]
    return "\n".join(out)


def speed(sizes) -> str:
    rows = measure(sizes.samples)
    out = ["## Neural media (neural_medium)", "",
           f"Render times of the accuracy section's sphere ({RESOLUTION} px, {sizes.samples} samples) and the bake "
           "of its 1 986 vertices, from the same run.", "",
           "| medium | single scattering | + bake | ratio | full path tracing | full / (single + bake) | table "
           "reconstruction | bake (beams) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f = r["forms"]
        single, baked = f["single scattering"]["seconds"], f["single + Lamina bake"]["seconds"]
        full = f[f"Cycles, {FULL_BOUNCES} bounces"]["seconds"]
        b = r["bake"]
        out.append(f"| {r['case']} | {single:.2f} s | {baked:.2f} s | {baked / single:.2f}× | {full:.2f} s | "
                   f"{full / baked:.1f}× | {b['tables_s']:.1f} s | {b['bake_s']:.1f} s ({b['beams']}) |")
    return "\n".join(out + [""])
