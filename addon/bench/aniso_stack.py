"""Anisotropic stacks' sections of the benchmark documents: the model (``reference.aniso_stack``, Belcour's adding
loop with covariances) against the Monte Carlo ground truth through the explicit stack
(``reference.aniso_stack_truth``) on a grid of random two-interface stacks, per exit lobe — its energy, the axis
and the widths of its projected distribution — and speed: the covariance loop against the scalar one, reference
throughput, one model sample against one ground-truth path, and Cycles render times.

A model lobe's statistics are those of the light it reflects: directions drawn from the lobe (VNDF sampling,
``lobe_sample``) weighted by value × cos / pdf, projected on the surface plane, exactly as the ground truth
projects the directions its paths leave in (``exit_lobes``; lobes are labelled by the interface that reflected
last). Axis: the major eigenvector of the channel-mean covariance (compared where the truth's eigenvalues differ
by at least ``AXIS_MIN_RATIO``); widths: the square roots of both eigenvalues.
"""
from __future__ import annotations

import math
import time

import numpy as np

from .. import presets
from ..models import aniso_stack as model
from ..models.metals import METALS
from ..reference import aniso_stack as reference
from ..reference import aniso_stack_truth as truth
from ..reference.frames import spherical
from .common import approximation_rows, pct, preset_render_times, preset_rows, reference_throughput, timed

MODEL = model.ID
GRID_STACKS = 200
GRID_VIEWS = (0.0, 30.0, 60.0)  # view angles (degrees); the paper admits errors at the rim (60 here)
GRID_PATHS = 20_000
MODEL_SAMPLES = 20_000
AXIS_MIN_RATIO = 1.5  # truth eigenvalue ratio above which a lobe's axis is compared
HARD = (0.3, 1.7)  # α and IOR above which the paper admits non-elliptical lobes (high roughness and IOR)
ENERGY_FLOOR = 0.01  # lobes carrying less than this (channel mean) are left out of the lobe comparisons


def grid_stack(rng) -> dict:
    """A random coat over a metal: α 0.02-0.5 (log-uniform), αx/αy 1-10, coat IOR 1.2-2, tangents 0-90° apart,
    absorption in half of them."""
    def interface(kind, **extra):
        alpha = math.exp(rng.uniform(math.log(0.02), math.log(0.5)))
        ratio = rng.uniform(1.0, 10.0)
        return {"type": kind, "alpha": [alpha, alpha / ratio], **extra}

    top = interface("dielectric", ior=float(rng.uniform(1.2, 2.0)), rotation=float(rng.uniform(0.0, 180.0)))
    ior, k = METALS[("gold", "aluminium", "copper", "silver")[rng.integers(4)]]
    bottom = interface("conductor", ior=list(ior), k=list(k),
                       rotation=top["rotation"] + float(rng.uniform(0.0, 90.0)))
    absorbing = rng.random() < 0.5
    medium = {"sigma_a": [float(x) for x in rng.uniform(0.0, 1.0, 3)] if absorbing else [0.0] * 3, "depth": 1.0}
    return {"interfaces": [top, bottom], "media": [medium]}


def _view(theta_deg: float, phi_deg: float):
    t, f = math.radians(theta_deg), math.radians(phi_deg)
    return spherical(np.array([math.cos(t)]), np.array([f]))[0]


def model_lobe_stats(p, lobe, wo_n, rng) -> dict:
    """Energy (3,), mean (3, 2) and covariance (3, 2, 2) of the projected directions one model lobe (computed for
    the N views ``wo_n``, all the same) reflects."""
    n = len(wo_n)
    wi = reference.lobe_sample(lobe, wo_n, rng.random(n), rng.random(n))
    density = reference.lobe_pdf(lobe, wi, wo_n)
    value = reference.lobe_value(p, lobe, wi, wo_n)
    ok = (density > 0) & (wi[:, 2] > 0)
    weight = np.where(ok[:, None], value * np.abs(wi[:, 2:3]) / np.where(ok, density, 1.0)[:, None], 0.0)
    energy = weight.mean(axis=0)
    xy = wi[:, :2]
    mean = (weight[:, :, None] * xy[:, None, :]).mean(axis=0) / np.maximum(energy, 1e-300)[:, None]
    d = xy[:, None, :] - mean[None]
    cov = (weight[:, :, None, None] * d[..., :, None] * d[..., None, :]).mean(axis=0)
    return {"energy": energy, "mean": mean, "cov": cov / np.maximum(energy, 1e-300)[:, None, None]}


def _axis_and_widths(cov) -> tuple[float, float, float]:
    """(major axis angle in degrees mod 180, sqrt λmax, sqrt λmin) of the channel-mean covariance."""
    c = np.nanmean(cov, axis=0)
    values, vectors = np.linalg.eigh(c)
    major = vectors[:, 1]
    return (math.degrees(math.atan2(major[1], major[0])) % 180.0, math.sqrt(max(values[1], 0.0)),
            math.sqrt(max(values[0], 0.0)))


def _axis_gap(a: float, b: float) -> float:
    d = abs(a - b) % 180.0
    return min(d, 180.0 - d)


def case_of(stack: dict, theta: float) -> str:
    """"rim" (the largest view angle), "hard" (α and IOR above ``HARD``: lobes that are not elliptical), else
    "main"."""
    if theta >= max(GRID_VIEWS):
        return "rim"
    alpha = max(max(i["alpha"]) for i in stack["interfaces"])
    return "hard" if alpha > HARD[0] and stack["interfaces"][0]["ior"] > HARD[1] else "main"


def grid_rows(n_stacks: int = GRID_STACKS, paths: int = GRID_PATHS, seed: int = 21) -> list[dict]:
    """Model vs ground truth per (stack, view) and exit lobe: relative errors of the directional albedo and the
    lobe energies, the axis gap (degrees) and the relative width errors, with the case (``case_of``)."""
    rng = np.random.default_rng(seed)
    rows = []
    for s in range(n_stacks):
        stack = grid_stack(rng)
        p = model.params_from_dict(stack)
        for theta in GRID_VIEWS:
            wo = _view(theta, float(rng.uniform(0.0, 360.0)))
            t = truth.exit_lobes(p, wo, n_paths=paths, seed=seed + s)
            wo_n = np.tile(wo, (MODEL_SAMPLES, 1))
            row = {"case": case_of(stack, theta), "theta": theta,
                   "albedo": _rel(reference.directional_albedo(p, wo[None])[0].mean(), t["all"]["energy"].mean()),
                   "lobes": []}
            for lobe in reference.lobes_at(p, wo_n):
                m = model_lobe_stats(p, lobe, wo_n, rng)
                tj = t["interfaces"][lobe.interface]
                if np.nanmean(tj["energy"]) < ENERGY_FLOOR:
                    continue
                axis_m, major_m, minor_m = _axis_and_widths(m["cov"])
                axis_t, major_t, minor_t = _axis_and_widths(tj["cov"])
                row["lobes"].append({
                    "interface": lobe.interface,
                    "energy": _rel(m["energy"].mean(), tj["energy"].mean()),
                    "axis": _axis_gap(axis_m, axis_t) if major_t >= AXIS_MIN_RATIO * max(minor_t, 1e-12) else None,
                    "major": _rel(major_m, major_t), "minor": _rel(minor_m, minor_t)})
            rows.append(row)
    return rows


def _rel(a: float, b: float) -> float:
    return (a - b) / b if b > 0 else float("nan")


def summary(rows: list[dict]) -> dict:
    """Per case and for all: median and 90th percentile of |albedo|, |energy|, axis gap, |major|, |minor| errors."""
    out = {}
    for case in ("main", "rim", "hard", "all"):
        chosen = [r for r in rows if case in (r["case"], "all")]
        lobes = [lobe for r in chosen for lobe in r["lobes"]]
        series = {"albedo": [abs(r["albedo"]) for r in chosen],
                  "energy": [abs(x["energy"]) for x in lobes],
                  "axis": [x["axis"] for x in lobes if x["axis"] is not None],
                  "major": [abs(x["major"]) for x in lobes], "minor": [abs(x["minor"]) for x in lobes]}
        out[case] = {"views": len(chosen), "lobes": len(lobes),
                     **{k: (float(np.nanmedian(v)), float(np.nanpercentile(v, 90))) if v else (math.nan, math.nan)
                        for k, v in series.items()}}
    return out


PRESET_TRUTH = {"paths": 2000, "stride": 4}  # ground truth per sampled sphere pixel in the preset table


def preset_truth_rows(resolution: int, paths: int = PRESET_TRUTH["paths"],
                      stride: int = PRESET_TRUTH["stride"]) -> list[dict]:
    """Each preset's model (the float64 reference) against the Monte Carlo ground truth on the sphere scene, at
    every ``stride``-th pixel (``compare --truth`` of the sphere): relative RMSE over all channels and per channel,
    the truth's own noise in the same units, the mean directional albedos at normal view."""
    from ..operators.compare_run import CoatTruth, coat_truth_image, scene_specs
    from ..reference.metrics import rel_rmse
    from ..reference.montecarlo import relative_noise
    from ..reference.scenes import reference_image

    spec = scene_specs(["sphere"], resolution)[0]
    rows = []
    for name in presets.names(MODEL):
        p = model.params_from_dict(presets.load(MODEL, name))
        mc = coat_truth_image(MODEL, p, spec, CoatTruth(paths=paths, stride=stride))
        image, at = reference_image(spec, lambda wi, wo, p=p: reference.eval(p, wi, wo)), mc["samples"]
        normal = np.array([[0.0, 0.0, 1.0]])
        rows.append({"preset": name, "all": rel_rmse(image, mc["image"], at),
                     "channels": [rel_rmse(image[..., c], mc["image"][..., c], at) for c in range(3)],
                     "noise": relative_noise(mc["image"], mc["noise"], at),
                     "albedo": (float(reference.directional_albedo(p, normal)[0].mean()),
                                float(truth.ground_truth_albedo(p, normal[0], n_paths=20_000, seed=3)["reflection"].sum(axis=0).mean()))})
    return rows


def preset_truth_section(resolution: int) -> list[str]:
    rows = preset_truth_rows(resolution)
    lines = ["", "## Presets against the ground truth", "",
             f"The sphere scene at {resolution} px, model (float64 reference) against the ground truth at every "
             f"{PRESET_TRUTH['stride']}th pixel ({PRESET_TRUTH['paths']:,} paths each; `compare --truth`): relative "
             "RMSE over the three channels and per channel, the truth's noise in the same units, and the directional "
             "albedo at normal view (channel mean, model / truth with 20,000 paths). The paper's \"metal\" (n + ik = "
             "1 + 1i, 1, 1) is a conductor in red only: in green and blue it is a dielectric of relative IOR 0.67 under "
             "the coat that reflects by total internal reflection alone, where the two-node FGD rule of conductors "
             "(`reference/aniso_stack_tables.py`) and the model's energy transfer are furthest from the physical "
             "stack.", "",
             "| preset | model vs truth | R / G / B | truth noise | albedo at 0°, model / truth |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['preset']} | {pct(r['all'])} | {' / '.join(pct(c) for c in r['channels'])} | "
                     f"{pct(r['noise'])} | {r['albedo'][0]:.3f} / {r['albedo'][1]:.3f} |")
    return lines


def accuracy(sizes) -> str:
    """The anisotropic-stack sections of docs/accuracy.md (``bench.Sizes``)."""
    s = summary(grid_rows())
    lines = ["", "# Anisotropic stacks", "",
             "## The model against the Monte Carlo ground truth through the explicit stack", "",
             f"{GRID_STACKS} random stacks (a dielectric coat of IOR 1.2-2 over gold, aluminium, copper or silver; "
             "α 0.02-0.5, αx/αy 1-10 on both interfaces, tangents 0-90° apart, absorption σa ∈ [0, 1]³ over depth 1 "
             f"in half of them), each seen at {', '.join(f'{t:g}°' for t in GRID_VIEWS)} (random azimuth); "
             f"{GRID_PATHS:,} ground-truth paths per view, {MODEL_SAMPLES:,} samples per model lobe "
             "(`addon/bench/aniso_stack.py`). Per exit lobe (the light whose last reflection was at that interface, "
             f"lobes above {ENERGY_FLOOR} energy): energy, the projected distribution's major axis (where the truth's "
             f"axes differ by ≥ {AXIS_MIN_RATIO}×) and widths (square roots of its eigenvalues). Cases: *rim* the "
             f"{max(GRID_VIEWS):g}° views, *hard* α > {HARD[0]} with a coat IOR > {HARD[1]} (lobes the paper says "
             "are not elliptical), *main* the rest. Median / 90th percentile of the absolute errors:", "",
             "| case | views | lobes | directional albedo | lobe energy | axis (°) | major width | minor width |",
             "|---|---|---|---|---|---|---|---|"]
    for case, v in s.items():
        lines.append(f"| {case} | {v['views']} | {v['lobes']} | {pct(v['albedo'][0])} / {pct(v['albedo'][1])} | "
                     f"{pct(v['energy'][0])} / {pct(v['energy'][1])} | {v['axis'][0]:.1f} / {v['axis'][1]:.1f} | "
                     f"{pct(v['major'][0])} / {pct(v['major'][1])} | {pct(v['minor'][0])} / {pct(v['minor'][1])} |")
    return "\n".join(lines + preset_truth_section(sizes.resolution) + mapping_section(sizes.resolution)) + "\n"


def mapping_section(resolution: int) -> list[str]:
    """The Cycles mapping against the model: each named approximation on its isolating configuration (Blender 4.2's
    node group, which has no Metallic BSDF node, predicted as 4.2 builds it), then every preset."""
    from ..nodes import aniso_stack as mapping
    from ..nodes.expr import NumpyBackend

    lines = ["", "## Named approximations of the Cycles mapping", "",
             "Relative RMSE of the form's numpy prediction against the model (the float64 reference) on a "
             "configuration chosen to feature each approximation; Cycles renders these predictions "
             "(tests/blender/test_aniso_stack_cycles.py). The Blender 4.2 row predicts the node group as Blender 4.2 "
             "builds it; the others as 4.3+ does.", "",
             "| approximation | what it does | scene | ref. mean | OSL | node group |", "|---|---|---|---|---|---|"]
    blender_42 = "top-fresnel-mean-blender-4.2"
    rows = approximation_rows(model, {k: v for k, v in mapping.APPROXIMATIONS.items() if k != blender_42}, resolution)
    NumpyBackend.metallic_node = False
    try:
        rows += approximation_rows(model, {blender_42: mapping.APPROXIMATIONS[blender_42]}, resolution)
    finally:
        NumpyBackend.metallic_node = True
    return lines + rows + preset_rows(model, resolution)


# ------------------------------------------------------------------------------------------ speed


def loop_cost(n: int = 20000, repeats: int = 3) -> dict:
    """Seconds per view of the covariance loop (``lobes``) and the scalar one (``isotropic_lobes``), 2 and 4
    interfaces (the paper: +2.5% for the anisotropic extension)."""
    out = {}
    cos_o = np.linspace(0.05, 1.0, n)
    for count in (2, 4):
        stack = {"interfaces": [{"type": "dielectric", "ior": 1.5, "alpha": [0.2, 0.05], "rotation": 30.0 * j}
                                for j in range(count - 1)] + [{"type": "conductor", "alpha": [0.3, 0.1]}]}
        p = model.params_from_dict(stack)
        out[count] = {name: min(timed(lambda f=f: f(reference.F64, p, cos_o, n)) for _ in range(repeats)) / n
                      for name, f in (("anisotropic", reference.lobes), ("isotropic", reference.isotropic_lobes))}
    return out


def sample_cost(n: int = 20000, repeats: int = 3, runs: int = 8) -> dict:
    """Seconds per sample of the model (``sample``: every lobe computed, one direction drawn) and per ground-truth
    path (a walk through the explicit stack), metallic paint seen at 30°; and at equal time (as many paths as the
    model's ``n`` samples take), the relative standard error of each one's directional albedo estimate (channel
    mean), from the spread over ``runs`` seeds."""
    p = model.params_from_dict(presets.load(MODEL, "metallic_paint"))
    wo = _view(30.0, 0.0)
    views = np.tile(wo, (n, 1))
    rngs = [np.random.default_rng(seed) for seed in range(runs)]
    model_s = min(timed(lambda: reference.sample(p, views, rngs[0].random((n, 3)))) for _ in range(repeats)) / n
    t0 = time.perf_counter()
    truth.ground_truth_albedo(p, wo, n_paths=n, seed=1)
    truth_s = (time.perf_counter() - t0) / n
    paths = max(16, int(n * model_s / truth_s))
    model_albedo = [reference.sample(p, views, rng.random((n, 3))).weight.mean() for rng in rngs]
    truth_albedo = [truth.ground_truth_albedo(p, wo, n_paths=paths, seed=10 + seed)["reflection"].sum(axis=0).mean()
                    for seed in range(runs)]
    return {"model": model_s, "truth": truth_s, "samples": n, "paths": paths,
            "model_error": float(np.std(model_albedo, ddof=1) / np.mean(model_albedo)),
            "truth_error": float(np.std(truth_albedo, ddof=1) / np.mean(truth_albedo))}


def speed(sizes) -> str:
    """The anisotropic-stack sections of docs/benchmarks.md (``bench.Sizes``)."""
    two = model.params_from_dict({})
    rate = reference_throughput(two, MODEL)
    loop = loop_cost()
    cost = sample_cost()
    lines = ["", "## Anisotropic stacks", "",
             f"Reference `aniso_stack.eval`, the default coat over gold (2 interfaces), float64: **{rate / 1e6:.2f} M "
             "evals/s** (goal ≥ 2 M/s).", "",
             "The adding loop per view, covariances against Belcour's scalar variances (the paper: +2.5%):", "",
             "| interfaces | anisotropic µs | isotropic µs | ratio |", "|---|---|---|---|"]
    for count, c in loop.items():
        lines.append(f"| {count} | {1e6 * c['anisotropic']:.2f} | {1e6 * c['isotropic']:.2f} | "
                     f"{c['anisotropic'] / c['isotropic']:.2f} |")
    lines += ["", f"One model sample {1e6 * cost['model']:.2f} µs against one ground-truth path "
              f"{1e6 * cost['truth']:.2f} µs ({cost['truth'] / cost['model']:.1f}×; the paper, 2048 spp per frame: "
              "45.1 vs 587.8 ms). At equal time (the model's "
              f"{cost['samples']:,} samples against {cost['paths']:,} ground-truth paths), the relative standard error "
              f"of the directional albedo each estimates: model {pct(cost['model_error'])}, ground truth "
              f"{pct(cost['truth_error'])} (8 seeds; the model's own error against the stack is in docs/accuracy.md).",
              "",
              f"Cycles CPU render of the sphere scene, {sizes.timing_resolution}×{sizes.timing_resolution} px, "
              f"{sizes.timing_samples} samples, fastest of 3, against the Principled BSDF set up from the stack "
              "(anisotropic metal + coat; goal for 2-interface stacks: node group ≤ 1.2×):", "",
              "| preset | interfaces | node group s | OSL s | Principled s | node group : Principled | "
              "OSL : Principled |", "|---|---|---|---|---|---|---|"]
    for r in preset_render_times(MODEL, sizes.timing_samples, sizes.timing_resolution):
        count = len(presets.load(MODEL, r["preset"])["interfaces"])
        lines.append(f"| {r['preset']} | {count} | {r['nodes']:.2f} | {r['osl']:.2f} | {r['principled']:.2f} | "
                     f"{r['nodes'] / r['principled']:.2f} | {r['osl'] / r['principled']:.2f} |")
    return "\n".join(lines) + "\n"
