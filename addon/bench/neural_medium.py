"""The neural medium's sections of docs/accuracy.md and docs/benchmarks.md: the shipped networks (size, energy
ratios from their manifests), and on the comparison sphere what Cycles renders with Lamina's bake against the numpy
ground truth and Cycles' own full volumetric path tracing, with render and bake times from the same run
(``operators.medium_compare``; its truths are cached by content hash, so a second ``make bench`` reuses them)."""
from __future__ import annotations

from functools import lru_cache

from .. import presets
from ..models import neural_medium as model
from ..reference import neural_medium as nm
from .common import pct

MODEL = model.ID
# (preset, scale, shape): 4.4, 10 and 10.7 mfp across the sphere; a thick tile and a torus (thin parts, not convex)
CASES = (("cloud", 0.5, "sphere"), ("candle", 0.1, "sphere"), ("milk", 0.25, "sphere"), ("oil", 0.05, "sphere"),
         ("cloud", 0.5, "box"), ("milk", 0.25, "box"), ("milk", 0.25, "torus"))


@lru_cache(maxsize=2)
def measure(samples: int) -> list[dict]:
    from ..operators import medium_compare

    sizes = medium_compare.Sizes(samples=samples)
    return [medium_compare.compare_medium(model.params_from_dict({**presets.load(MODEL, name), "scale": scale}),
                                          sizes, label=f"{name} ×{scale:g}", shape=shape)
            for name, scale, shape in CASES]


def view_fit_rows(views=(0.0, 45.0, 75.0), points: int = 400) -> list[dict]:
    """The bake's linear fit in the direction against the gather itself along each view (numpy, no Cycles): the
    error a camera anywhere sees (the bake belongs to no camera). The cloud on the unit sphere (the networks' tables,
    boundary images), points on the half the view sees, the scene's sun."""
    import math

    import numpy as np

    from ..bake import neural_medium as nb
    from ..reference import neural_medium_truth as truth
    from ..reference import scenes as S

    p = model.params_from_dict({**presets.load(MODEL, "cloud"), "scale": 0.5})
    tables, settings = nb.channel_tables(p), nb.Settings()
    sun = S.sphere_scene().suns[0]
    beams = [nm.Beams.join([nm.sun_beams(truth.Sphere(), sun, settings.cells)])] * 3
    rng = np.random.default_rng(5)
    rows = []
    for angle in views:
        view = np.array([math.sin(math.radians(angle)), 0.0, math.cos(math.radians(angle))])
        n = rng.normal(size=(4 * points, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        n = n[n @ view > 0.05][:points]  # what the view sees, not its silhouette
        baked = nb.evaluate(nb.bake_points(p, tables, truth.Sphere(), beams, n, n, settings),
                            np.tile(view, (len(n), 1)))[:, 1]
        g = nm.gather(tables[1], p.mean_free_path[1], truth.Sphere(), beams[1], n + 1e-4 * view,
                      np.tile(-view, (len(n), 1)), steps=settings.steps,
                      images=nm.extrapolation_distance(p.albedo[1], p.g))
        direct = g["double"] + g["multiple"]
        rows.append({"angle": angle, "mean": float(baked.mean() / direct.mean() - 1.0),
                     "rel_rmse": float(np.sqrt(np.mean((baked - direct) ** 2)) / direct.mean())})
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
    from ..operators.medium_compare import Sizes

    rows, s = measure(sizes.samples), Sizes(samples=sizes.samples)
    out = ["## Neural media (neural_medium)", "",
           "The shipped networks (`make medium-networks`; the energy ratio is the power of the table a network "
           "reconstructs over the Monte Carlo table's, minus 1, the paper's measure):", "", *network_lines(), "",
           f"What Cycles renders ({s.resolution} px, {s.samples} samples, the comparison scene's sun; `lamina "
           "compare-medium --shape ...`) against Cycles' own full volumetric path tracing "
           f"({s.full_bounces} volume bounces) and, for the sphere (a 64 × 32 mesh) and the box (1.6 × 1.6 × 0.5 "
           f"units), the numpy ground truth (`reference/neural_medium_truth.py`, {s.truth_paths} paths per pixel, all "
           "orders; its own noise in the last column). The torus (radii 0.65 and 0.3) has no numpy truth. The bake: "
           f"the networks' tables, {s.bake.cells} × {s.bake.cells} beams per lamp, {s.bake.steps} steps per ray, "
           "multiple scattering with the boundary's image sources, linear in the direction per vertex. \"mfp\" is "
           "the mean free paths per 2 scene units (the sphere's diameter).", "",
           "| medium (scale) | shape | mfp | form | energy vs Cycles full | rel. RMSE vs Cycles full | energy vs "
           "truth | rel. RMSE vs truth | PSNR vs truth | truth noise |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for label, f in r["forms"].items():
            if r["truth"] is None:
                numpy = "n/a | n/a | n/a | n/a"
            else:
                numpy = (f"{f['energy_error']:+.1%} | {pct(f['rel_rmse'])} | {f['psnr']:.1f} dB | "
                         f"{pct(r['truth']['relative_noise'])}")
            out.append(f"| {r['label']} | {r['shape']} | {r['mean_free_paths_across']:.1f} | {label} | "
                       f"{f['energy_vs_full']:+.1%} | {pct(f['rel_rmse_vs_full'])} | {numpy} |")
    out += ["", "The bake is linear in the view direction per vertex and belongs to no camera: against the gather "
                "itself along each view (numpy, the cloud ×0.5 on the unit sphere, points the view sees), the fit's "
                "error wherever the camera is:", "",
            "| view tilted from +z towards +x (the sun's side) | mean | rel. RMSE |", "|---|---|---|"]
    out += [f"| {r['angle']:g}° | {r['mean']:+.1%} | {pct(r['rel_rmse'])} |" for r in view_fit_rows()]
    notes = sorted({f"{r['label']}: {n}" for r in rows for n in r["subsurface_notes"]})
    out += ["", "Cycles' random-walk subsurface scattering is a Principled BSDF set up to walk in the same medium "
                "(`nodes/subsurface_np.py`: radius 1 / (σt (1 − g)), the Base Color whose Cycles remap is the "
                "albedo, IOR 1, no specular layer). It differs from the volume by construction: light leaves "
                "through a Lambertian closure where the walk exits, and enters where the camera's walk starts, "
                "instead of crossing an index-matched boundary. What it could not match:", "",
            *([f"- {n}" for n in notes] or ["- nothing"]), ""]
    return "\n".join(out)


def speed(sizes) -> str:
    from ..operators.medium_compare import BAKED, FULL, SINGLE, SUBSURFACE

    rows = measure(sizes.samples)
    out = ["## Neural media (neural_medium)", "",
           f"Render times of the accuracy section's sphere ({sizes.samples} samples) and its bake, from the same "
           "run.", "",
           "| medium | single scattering | + bake | ratio | full path tracing | full ÷ (single + bake) | random-walk SSS | "
           "table reconstruction | bake: points, beams, time | points per second |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f, b = r["forms"], r["bake"]
        single, baked, full = f[SINGLE]["seconds"], f[BAKED]["seconds"], f[FULL]["seconds"]
        out.append(f"| {r['label']}, {r['shape']} | {single:.2f} s | {baked:.2f} s | {baked / single:.2f}× | "
                   f"{full:.2f} s | {full / baked:.1f}× | {f[SUBSURFACE]['seconds']:.2f} s | "
                   f"{b['tables_seconds']:.1f} s | {b['points']}, {b['beams']}, {b['bake_seconds']:.1f} s | "
                   f"{b['points'] / b['bake_seconds']:.0f} |")
    return "\n".join(out + [""])
