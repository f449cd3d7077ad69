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
# (preset, scale, shape): 4.4, 10 and 10.7 mfp across the sphere; a thick tile, a torus and Suzanne (thin parts, not
# convex)
CASES = (("cloud", 0.5, "sphere"), ("candle", 0.1, "sphere"), ("milk", 0.25, "sphere"), ("oil", 0.05, "sphere"),
         ("cloud", 0.5, "box"), ("milk", 0.25, "box"), ("milk", 0.25, "torus"), ("milk", 0.25, "suzanne"))


EQUAL_ERROR_SAMPLES = 4096  # the most samples Cycles' full path tracing gets to reach the bake's error


@lru_cache(maxsize=2)
def measure(samples: int) -> list[dict]:
    from ..operators import medium_compare

    sizes = medium_compare.Sizes(samples=samples, equal_error_samples=EQUAL_ERROR_SAMPLES)
    return [medium_compare.compare_medium(model.params_from_dict({**presets.load(MODEL, name), "scale": scale}),
                                          sizes, label=f"{name} ×{scale:g}", shape=shape)
            for name, scale, shape in CASES]


def view_fit_rows(views=(0.0, 45.0, 75.0), points: int = 400) -> list[dict]:
    """The bake's linear fit in the direction against the gather itself along each view (numpy, no Cycles): the
    error a camera anywhere sees (the bake belongs to no camera). The cloud on the unit sphere (the bake's tables,
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
                      images=nm.boundary(p.albedo[1], p.g))
        direct = g["double"] + g["multiple"]
        rows.append({"angle": angle, "mean": float(baked.mean() / direct.mean() - 1.0),
                     "rel_rmse": float(np.sqrt(np.mean((baked - direct) ** 2)) / direct.mean())})
    return rows


@lru_cache(maxsize=1)
def spacing_rows(points: int = 3000, spacings=(0.25, 0.5, 1.0, 2.0), large: int = 100_000) -> list[dict]:
    """The bake gathering at points ``spacing`` mean free paths apart and spreading to the rest
    (``bake.neural_medium.gathering_points``, ``spread``) against gathering at every point: ``points`` on the unit
    sphere (a Fibonacci lattice), the scene's sun, the bake's tables, the radiance along the normal; and the time
    of a bake of ``large`` points at the default spacing. Grey media (the green channel's albedo)."""
    import time

    import numpy as np

    from ..bake import neural_medium as nb
    from ..reference import neural_medium_truth as truth
    from ..reference import scenes as S

    def bake(p, tables, x, settings):
        start = time.perf_counter()
        h = nb.gathering_spacing(p, settings)
        chosen = nb.gathering_points(x, x, h)
        part = nb.bake_points(p, tables, truth.Sphere(), beams, x[chosen], x[chosen], settings)
        return nb.spread(part, x[chosen], x[chosen], x, x, h), len(chosen), time.perf_counter() - start

    beams = [nm.Beams.join([nm.sun_beams(truth.Sphere(), S.sphere_scene().suns[0], nb.Settings().cells)])] * 3
    rows = []
    for name, scale in (("cloud", 0.5), ("milk", 0.25)):
        p = model.params_from_dict({**presets.load(MODEL, name), "scale": scale})
        p = model.params_from_dict({**p.to_dict(), "sigma_s": [p.sigma_s[1]] * 3, "sigma_a": [p.sigma_a[1]] * 3})
        tables, x = nb.channel_tables(p), _lattice(points)
        full, _, full_seconds = bake(p, tables, x, nb.Settings(spacing=0.0))
        ref = nb.evaluate(full, x)[:, 1]
        row = {"label": f"{name} ×{scale:g}", "mfp": p.mean_free_path[1], "points": points,
               "seconds": full_seconds, "spacings": []}
        for spacing in spacings:
            out, gathered, seconds = bake(p, tables, x, nb.Settings(spacing=spacing))
            got = nb.evaluate(out, x)[:, 1]
            row["spacings"].append({"spacing": spacing, "gathered": gathered, "seconds": seconds,
                                    "mean": float(got.mean() / ref.mean() - 1.0),
                                    "rel_rmse": float(np.sqrt(np.mean((got - ref) ** 2)) / ref.mean())})
        _, gathered, seconds = bake(p, tables, _lattice(large), nb.Settings())
        row["large"] = {"points": large, "gathered": gathered, "seconds": seconds, "beams": len(beams[1])}
        rows.append(row)
    return rows


GRID_SETTINGS = ((0.5, 1.0), (1.0, 1.0), (1.0, 2.0))  # (angle in radians, cube side in mfp) of the VRL grid


@lru_cache(maxsize=1)
def grid_rows(points: int = 1200, cells: int = 32) -> list[dict]:
    """The paper's grid of representative beams (``reference.neural_medium.beam_grid``) against every beam: the
    bake's tables and boundary images, ``points`` on the unit sphere (a Fibonacci lattice) gathering along the
    normal, the scene's sun as ``cells`` x ``cells`` beams; grey media (the green channel)."""
    import time

    import numpy as np

    from ..bake import neural_medium as nb
    from ..reference import neural_medium_truth as truth
    from ..reference import scenes as S

    x = _lattice(points)
    beams = nm.sun_beams(truth.Sphere(), S.sphere_scene().suns[0], cells)
    rows = []
    for name, scale in (("milk", 0.25), ("milk", 0.05)):
        p = model.params_from_dict({**presets.load(MODEL, name), "scale": scale})
        tables, ell = nb.channel_tables(p)[1], p.mean_free_path[1]

        def run(grid):
            start = time.perf_counter()
            g = nm.gather(tables, ell, truth.Sphere(), beams, x * (1.0 + 1e-4), -x, steps=nb.Settings.steps,
                          images=nm.boundary(p.albedo[1], p.g), grid=grid)
            return g["double"] + g["multiple"], time.perf_counter() - start

        every, seconds = run(None)
        row = {"label": f"{name} ×{scale:g}", "across": 2.0 / ell, "beams": len(beams), "seconds": seconds,
               "grids": []}
        for angle, cube in GRID_SETTINGS:
            got, t = run(nm.beam_grid(beams, cube * ell, angle))
            row["grids"].append({"angle": angle, "cube": cube, "seconds": t,
                                 "mean": float(got.mean() / every.mean() - 1),
                                 "rel_rmse": float(np.sqrt(np.mean((got - every) ** 2)) / every.mean())})
        rows.append(row)
    return rows


@lru_cache(maxsize=1)
def segment_rows(points: int = 1200, cells: int = 16) -> list[dict]:
    """The paper's accumulated segments (``reference.neural_medium.segment_table`` with Eq. 5's weight) against the
    bake's quadrature along each camera segment: ``points`` on the unit sphere gathering along the normal, the
    scene's sun as ``cells`` x ``cells`` beams, the bake's tables and images; grey media (the green channel)."""
    import time

    import numpy as np

    from ..bake import neural_medium as nb
    from ..reference import neural_medium_truth as truth
    from ..reference import scenes as S

    x = _lattice(points)
    beams = nm.sun_beams(truth.Sphere(), S.sphere_scene().suns[0], cells)
    rows = []
    for name, scale in (("cloud", 0.5), ("milk", 0.25), ("milk", 0.05)):
        p = model.params_from_dict({**presets.load(MODEL, name), "scale": scale})
        tables, ell = nb.channel_tables(p)[1], p.mean_free_path[1]
        start = time.perf_counter()
        segments = {kind: nm.segment_table(t) for kind, t in tables.items()}
        build = time.perf_counter() - start
        timed = []
        for t in (tables, segments):
            start = time.perf_counter()
            g = nm.gather(t, ell, truth.Sphere(), beams, x * (1.0 + 1e-4), -x, steps=nb.Settings.steps,
                          images=nm.boundary(p.albedo[1], p.g))
            timed.append((g["double"] + g["multiple"], time.perf_counter() - start))
        (exact, seconds), (got, segment_seconds) = timed
        rows.append({"label": f"{name} ×{scale:g}", "across": 2.0 / ell, "seconds": seconds,
                     "segment_seconds": segment_seconds, "build": build,
                     "mean": float(got.mean() / exact.mean() - 1.0),
                     "rel_rmse": float(np.sqrt(np.mean((got - exact) ** 2)) / exact.mean())})
    return rows


def _lattice(n: int):
    """``n`` points of a Fibonacci lattice on the unit sphere."""
    import math

    import numpy as np

    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r, phi = np.sqrt(1.0 - z * z), math.pi * (1.0 + 5 ** 0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def grid_lines() -> list[str]:
    lines = ["| medium (scale) | mfp across | beams | grid: angle, cube | time | speed-up | mean | rel. RMSE |",
             "|---|---|---|---|---|---|---|---|"]
    for r in grid_rows():
        lines.append(f"| {r['label']} | {r['across']:.1f} | {r['beams']} | off (every beam) | {r['seconds']:.1f} s | "
                     "1× | — | — |")
        lines += [f"| {r['label']} | {r['across']:.1f} | {r['beams']} | {g['angle']:g} rad, {g['cube']:g} mfp | "
                  f"{g['seconds']:.1f} s | {r['seconds'] / g['seconds']:.1f}× | {g['mean']:+.1%} | "
                  f"{pct(g['rel_rmse'])} |" for g in r["grids"]]
    return lines


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
           "reconstructs over the Monte Carlo table's, minus 1, the paper's measure). The bake uses the multiple "
           "network and double scattering by quadrature (`reference.neural_medium.double_table`; the double network "
           "is kept for comparison; both measured against the Monte Carlo tables and in a render by `python -m "
           "training.medium_network_check`, docs/training.md):", "", *network_lines(), "",
           f"What Cycles renders ({s.resolution} px, {s.samples} samples, the comparison scene's sun; `lamina "
           "compare-medium --shape ...`) against Cycles' own full volumetric path tracing "
           f"({s.full_bounces} volume bounces) and, for the sphere (a 64 × 32 mesh) and the box (1.6 × 1.6 × 0.5 "
           f"units), the numpy ground truth (`reference/neural_medium_truth.py`, {s.truth_paths} paths per pixel, all "
           "orders; its own noise in the last column). The torus (radii 0.65 and 0.3) and Suzanne (her head, eye "
           "sockets closed, 1.9 units wide) have no numpy truth. The bake: "
           f"double scattering by quadrature and the multiple network's table, {s.bake.cells} × {s.bake.cells} beams "
           f"per lamp, {s.bake.steps} steps per ray, "
           "multiple scattering with the boundary's image sources, gathered at points "
           f"{s.bake.spacing:g} mean free paths apart, linear in the direction per vertex. \"mfp\" is "
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
    out += ["", "The bake gathers at surface points about half a mean free path apart (`bake-medium --spacing`, the "
                "Bake dialog's Point spacing) and spreads their light to the other vertices (inverse-square "
                "weights of the four nearest gathered points facing the same way). Against gathering at every "
                "point (numpy, a 3000-point unit sphere, the sun, radiance along the normal):", "",
            "| medium (scale) | mfp (units) | spacing (mfp) | points gathered | time | mean | rel. RMSE |",
            "|---|---|---|---|---|---|---|"]
    for r in spacing_rows():
        out.append(f"| {r['label']} | {r['mfp']:.3f} | 0 (every point) | {r['points']} | {r['seconds']:.1f} s | "
                   f"— | — |")
        out += [f"| {r['label']} | {r['mfp']:.3f} | {step['spacing']:g} | {step['gathered']} | "
                f"{step['seconds']:.1f} s | {step['mean']:+.1%} | {pct(step['rel_rmse'])} |" for step in r["spacings"]]
    out += ["", "The paper's grid of representative beams (Sec. 4.3, one level; `bake-medium --grid-angle`, off by "
                "default): beams sorted into cubes, a cube seen from a chunk of gathering rays under less than the "
                "angle gathered through one beam of its summed power at its members' mean entry and direction "
                "(their images' means for the boundary), the rays ordered along a Z curve so that a chunk is "
                "compact. Against every beam (numpy, a 1200-point unit sphere gathering along the normal, the sun "
                "as 32 × 32 beams, the bake's tables and images):", "", *grid_lines(),
            "", "The paper's accumulated camera segments (Sec. 3.7: each table integrated along 5 mean free paths "
                "of camera ray, `reference.neural_medium.segment_table`, looked up once where a camera segment "
                "enters and scaled by Eq. 5's weight, read as (1 − e^−τ) / (1 − e^−5) for a segment τ mean free "
                "paths long) against the bake's quadrature along the segment (12 points; numpy, a 1200-point unit "
                "sphere gathering along the normal, 16 × 16 beams of the sun):", "",
            "| medium (scale) | mfp across | quadrature | segment tables: build, gather | mean | rel. RMSE |",
            "|---|---|---|---|---|---|",
            *[f"| {r['label']} | {r['across']:.1f} | {r['seconds']:.1f} s | {r['build']:.1f} s, "
              f"{r['segment_seconds']:.1f} s | {r['mean']:+.1%} | {pct(r['rel_rmse'])} |" for r in segment_rows()]]
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
           "table reconstruction | bake: points (gathered), beams, time | points per second |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f, b = r["forms"], r["bake"]
        single, baked, full = f[SINGLE]["seconds"], f[BAKED]["seconds"], f[FULL]["seconds"]
        out.append(f"| {r['label']}, {r['shape']} | {single:.2f} s | {baked:.2f} s | {baked / single:.2f}× | "
                   f"{full:.2f} s | {full / baked:.1f}× | {f[SUBSURFACE]['seconds']:.2f} s | "
                   f"{b['tables_seconds']:.1f} s | {b['points']} ({b['gathered']}), {b['beams']}, "
                   f"{b['bake_seconds']:.1f} s | "
                   f"{b['points'] / b['bake_seconds']:.0f} |")
    out += ["", "Cycles' full path tracing at more samples (doubling, up to "
                f"{EQUAL_ERROR_SAMPLES}) until its relative RMSE against the numpy truth is at most the bake's (the "
                "truth's own noise is part of both):", "",
            "| medium | single + bake: rel. RMSE, time | full path tracing: samples, rel. RMSE, time | full ÷ "
            "(single + bake) at equal error |", "|---|---|---|---|"]
    for r in rows:
        e = r["full_at_bake_error"]
        if e is None:
            continue
        baked = r["forms"][BAKED]["seconds"]
        reached = "" if e["reached"] else f" (not reached at {e['samples']})"
        out.append(f"| {r['label']}, {r['shape']} | {pct(e['target'])}, {baked:.2f} s | {e['samples']}, "
                   f"{pct(e['rel_rmse'])}, {e['seconds']:.2f} s{reached} | {e['seconds'] / baked:.1f}× |")
    out += ["", "A bake of 100 000 points (a unit sphere, the default half mean free path between gathering points, "
                "one sun; numpy, without Blender):", "",
            "| medium | points | gathered | beams | time | points per second |", "|---|---|---|---|---|---|"]
    for r in spacing_rows():
        g = r["large"]
        out.append(f"| {r['label']} | {g['points']:,} | {g['gathered']:,} | {g['beams']} | {g['seconds']:.1f} s | "
                   f"{g['points'] / g['seconds']:,.0f} |")
    return "\n".join(out + [""])
