"""SpongeCake's sections of the benchmark documents: named approximations, presets and reference vs ground truth,
the sheen alternative, multiple scattering (``MsSizes``; ``bench --no-ms`` leaves it out: the networks against
Monte Carlo on the held-out validation set and on the paper's failure case, a white furnace of non-absorbing
stacks, rendered SS + MS vs Monte Carlo on presets (``reference.spongecake_truth``), render time with MS on vs off; the bake
time per megapixel is ``bake_speed``'s), reference throughput and Cycles render times against a Principled BSDF."""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .. import presets
from ..bake.validation import ALBEDO_PATHS
from ..models import spongecake as model
from ..nodes import spongecake as mapping
from ..reference import metrics
from ..reference import scenes as ref_scenes
from ..reference import spongecake as reference
from .common import (ACCURACY_SCENES, SAMPLING_FACTOR, approximation_header, approximation_rows, compared,
                     comparison_scenes, fitted_speed_section, mapping_errors, mapping_section, paired_render_times, pct,
                     per_point_nodes, preset_render_times, ratio_cells, reference_throughput)

MODEL = model.ID


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


# ------------------------------------------------------------------------------------------------ docs


def accuracy(sizes) -> str:
    """SpongeCake's sections of docs/accuracy.md (``bench.Sizes``)."""
    out = accuracy_markdown(sizes.resolution) + sheen_alternative(sizes.resolution)
    return out + (ms_accuracy_markdown(sizes.ms, sizes.samples, sizes.resolution) if sizes.ms is not None else "")


def speed(sizes) -> str:
    """SpongeCake's sections of docs/benchmarks.md (``bench.Sizes``)."""
    out = benchmarks_markdown(sizes.timing_samples, sizes.timing_resolution)
    if sizes.ms is not None:
        out += ms_speed_markdown(sizes.ms, sizes.timing_samples, sizes.timing_resolution)
    return out


def accuracy_markdown(resolution: int) -> str:
    lines = ["# SpongeCake", "",
             "## Named approximations, each isolated", "",
             "The fitted column: the OSL form's fitted mapping (`nodes.fitted`: the closures rescaled per view, a few "
             "added) of the same configuration.", "", *approximation_header(MODEL, short=True)]
    lines += approximation_rows(model, mapping.APPROXIMATIONS, resolution, _short)
    lines += ["", "## Presets", "",
              "Reference vs ground truth: mean relative error of the analytic single scattering against the "
              "order-1 part of an independent random walk (4×4 × 4×4 direction pairs, 20 000 paths each).", "",
              "| preset | scene | ref. mean | OSL | node group |", "|---|---|---|---|---|"]
    gt_rows = []
    for name in presets.names(MODEL):
        p = model.params_from_dict(presets.load(MODEL, name))
        errs = mapping_errors(p, resolution, MODEL)
        for scene in ACCURACY_SCENES:
            lines.append(f"| {name} | {scene} | {errs['mean'][scene]:.4f} | {pct(errs['osl'][scene])} | "
                         f"{pct(errs['nodes'][scene])} |")
        gt_rows.append(f"| {name} | {pct(ground_truth_error(p))} |")
    lines += ["", "| preset | reference vs ground truth (single scattering) |", "|---|---|", *gt_rows]
    lines += mapping_section(model, resolution) + [""]
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
    rate = reference_throughput(fabric, MODEL)
    rows = preset_render_times(MODEL, samples, resolution)
    lines = ["## SpongeCake", "",
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
    lines += fitted_speed_section(MODEL, samples, resolution)
    return "\n".join(lines) + "\n"


def sheen_alternative(resolution: int) -> str:
    """Fibers along the normal: Cycles' Microfiber Sheen BSDF (a fit to such fibers, with multiple scattering)
    against the reference's single scattering, as Cycles renders it (``closures_np.sheen``, checked against Cycles
    in tests/blender/test_cycles_facts.py): at the best constant scale, and alone with an RGB table over the view
    (``fitted.fit`` with the sheen as its only closure), next to Lamina's analytic and fitted mappings."""
    from ..nodes import choice, closures_np, fitted, predicted_image

    lines = ["", "## Fibers along the normal: Cycles' Sheen closure as an alternative", "",
             "Cycles' Microfiber Sheen BSDF is a fit to fibers standing along the normal, so it was measured as "
             "an alternative for the `fiber-along-normal` lobe, as Cycles renders it (`nodes.closures_np.sheen`, "
             "Cycles' own table; no sampling noise): at the best constant scale k per row (the closure's own "
             "normalisation differs from single scattering), and alone with an RGB weight table over the view as the "
             "fitted mapping carries one (`nodes.fitted`, the sheen its only closure). Lamina: the OSL form's "
             "analytic and fitted mappings of the same layer.", "",
             "| layer (fiber α = 0.2 along n) | sheen roughness | k | sphere | plane | view table: sphere | plane |",
             "|---|---|---|---|---|---|---|"]
    specs = [ref_scenes.sphere_scene(resolution=resolution),
             ref_scenes.plane_scene(resolution=(resolution, resolution // 2))]
    masks = [ref_scenes.scene_mask(s) for s in specs]
    lamina = []
    for thickness in (0.5, 5.0):
        p = model.params_from_dict(_fiber_along_n(thickness))
        refs = [ref_scenes.reference_image(s, lambda wi, wo: reference.eval(p, wi, wo)) for s in specs]

        def errors(images):
            return [pct(metrics.rel_rmse(i, r, m)) for i, r, m in zip(images, refs, masks)]

        problem = choice.fit_problem(MODEL, p, "osl")
        atoms = [False] * (1 + max(fitted.atom_groups(problem[0])))
        for roughness in (0.2, 0.45, 0.7):
            imgs = [ref_scenes.reference_image(s, lambda wi, wo: closures_np.sheen(wi, wo, roughness)) for s in specs]
            k = sum((i[m] * r[m]).sum() for i, r, m in zip(imgs, refs, masks)) / \
                sum((i[m] ** 2).sum() for i, m in zip(imgs, masks))
            alone = fitted.fit(*problem, "osl", extras=[("sheen", {"roughness": roughness})], atoms=atoms)
            tabled = errors([predicted_image(MODEL, p, "osl", s, alone) for s in specs])
            lines.append(f"| Tρ = {thickness} | {roughness} | {k:.3f} | {' | '.join(errors([k * i for i in imgs]))} | "
                         f"{' | '.join(tabled)} |")
        ours = choice.choose(MODEL, p, "osl", "fitted").fit
        lamina.append(f"| Tρ = {thickness} | {' | '.join(errors([predicted_image(MODEL, p, 'osl', s) for s in specs]))}"
                      f" | {' | '.join(errors([predicted_image(MODEL, p, 'osl', s, ours) for s in specs]))} |")
    lines += ["", "| layer | Lamina analytic: sphere | plane | Lamina fitted: sphere | plane |", "|---|---|---|---|---|",
              *lamina]
    return "\n".join(lines) + "\n"


def _fiber_along_n(thickness: float) -> dict:
    return {"layers": [{"type": "fiber", "roughness": 0.2, "thickness": thickness, "albedo": [1, 1, 1],
                        "orientation": [0, 0, 1]}]}


# ------------------------------------------------------------------------------------ multiple scattering


@dataclass(frozen=True)
class MsSizes:
    """How much work the multiple-scattering sections do (``bench --ms-*`` options)."""

    validation: str = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                                   "tests", "data", "spongecake_ms_validation")
    energy_validation: str = os.path.join(os.path.dirname(validation), "spongecake_ms_energy_validation.npz")
    returned_light_paths: int = ALBEDO_PATHS  # random-walk paths per view of the held-out set's returned light
    failure_paths: int = 4000  # random-walk paths per wi for the low-roughness fiber configurations
    failure_wi: int = 4  # a square number: incident directions per configuration
    failure_wo: int = 64  # twice a square number: outgoing directions over the sphere
    furnace_configs: int = 6  # random non-absorbing stacks per layer count
    furnace_samples: int = 32768  # directional-albedo samples per wo (the model's own estimate; ~0.1% noise)
    furnace_paths: int = 20000  # random-walk paths per wo (ground-truth albedo)
    presets: tuple = ("fabric", "window_shade")
    truth: object = None  # spongecake_truth.TruthSettings of the rendered comparison (None: RENDER_TRUTH)
    speed_repeats: int = 5
    bake_size: int = 512  # texels per side of the synthetic texture for bake timing
    seed: int = 7


MS_DEFAULT = MsSizes()
# Rendered comparison: 4000 paths per light direction at every 3rd pixel (sphere ~190 pixels at 48 px).
RENDER_TRUTH = dict(paths=4000, albedo_paths=4000, stride=3)
# The paper's failure case (Sec. 5.3): low-roughness fibers in the tangent plane.
FAILURE_CASES = tuple(
    [(f"fiber α={a} Tρ={t}", [{"type": "fiber", "roughness": a, "thickness": t, "albedo": [0.9] * 3,
                                "orientation": [1, 0, 0]}]) for a in (0.05, 0.1) for t in (1.0, 3.0)]
    + [("fiber α=0.05 Tρ=1 over fiber α=0.1 Tρ=3",
        [{"type": "fiber", "roughness": 0.05, "thickness": 1.0, "albedo": [0.9] * 3, "orientation": [1, 0, 0]},
         {"type": "fiber", "roughness": 0.1, "thickness": 3.0, "albedo": [0.9] * 3, "orientation": [1, 0, 0]}])])
FURNACE_THETAS = (0.0, 45.0, 75.0, 85.0)  # view angles of the white furnace (degrees; 85 = grazing)
FURNACE_AZIMUTHS = (30.0, 120.0, 210.0, 300.0)  # view azimuths of oriented stacks in the white furnace (degrees)
FURNACE_THICKNESS = (0.05, 8.0)  # optical thickness of the white furnace's random layers (log-uniform)


def _manifest(n_layers: int) -> dict:
    from ..bake import spongecake as ms

    try:
        return ms.network(n_layers).manifest
    except FileNotFoundError:
        return {}


def weights_note() -> str:
    """One sentence on the shipped networks from their manifests (flags placeholder weights)."""
    parts = []
    for n in (1, 2):
        m = _manifest(n)
        if not m:
            parts.append(f"{n}-layer network missing")
            continue
        placeholder = " — placeholder weights from a tiny run" if m.get("training_configs", 0) < 100 else ""
        noise = m.get("dataset_noise", {})
        noise_note = (f", {m.get('paths_per_wi', '?')} paths per wi: Monte Carlo standard error "
                      f"{noise['ms_relative_se']:.0%} RMS per pair relative to the mean lobe, the walk's order 1 "
                      f"within {noise['order1_relative_mae']:.1%} of the closed form" if noise else "")
        parts.append(f"{n}-layer network trained on {m.get('training_configs', '?')} configurations × "
                     f"{m.get('pairs_per_config', '?')} direction pairs{noise_note} ({m.get('date', '?')}, "
                     f"{m.get('code_version', '?')}, {m.get('training_seconds', '?')} s){placeholder}")
    return "; ".join(parts) + "."


def validation_errors(folder: str, light_paths: int, workers: int = os.cpu_count() or 1) -> dict:
    """{(layers, energy scale on): lobe_errors} of the shipped networks on the held-out Monte Carlo set (absent: not
    there), with and without the energy scale (``reference.spongecake.energy_tables``), each with the mean error of
    the light returned at the stored views (``validation.returned_light``, ``light_paths`` per view). Each layer
    count is scored in a process of its own (``workers`` at a time): the energy scale's tables take seconds per
    stack."""
    from multiprocessing import Pool

    with Pool(max(1, workers)) as pool:
        parts = pool.starmap(_layer_count_errors, [(folder, n, light_paths) for n in range(1, model.MAX_LAYERS + 1)])
    return {key: scores for part in parts for key, scores in part.items()}


def _layer_count_errors(folder: str, n: int, light_paths: int) -> dict:
    """``validation_errors`` of one layer count ({} where the set has none)."""
    from ..bake import validation

    try:
        data = validation.load_shards(folder, n)
    except FileNotFoundError:
        return {}
    out = {}
    meta, light = data["meta"][0], validation.returned_light(data, light_paths)
    for energy in (True, False):
        scores = validation.lobe_errors(data, validation.predicted_lobes(data, energy=energy))
        scores.update(paths=meta.get("paths"), n_wi=meta.get("n_wi"), n_wo=meta.get("n_wo"),
                      returned_light_error=float(validation.returned_light_errors(light, energy).mean()),
                      walk_noise=float(np.mean([r["walk_noise"] for r in light])))
        out[n, energy] = scores
    return out


def _stratified_hemisphere(rng, n: int) -> np.ndarray:
    side = int(round(np.sqrt(n)))
    i, j = np.divmod(np.arange(side * side), side)
    cos_t = np.maximum(1.0 - (i + rng.random(side * side)) / side, 1e-3)
    phi = 2.0 * np.pi * (j + rng.random(side * side)) / side
    s = np.sqrt(1.0 - cos_t**2)
    return np.stack([s * np.cos(phi), s * np.sin(phi), cos_t], axis=1)


def lobe_data(p, n_wi: int, n_wo: int, paths: int, seed: int) -> dict:
    """One configuration in the validation set's format: the walk's orders >= 2 on stratified directions,
    from two independent halves of ``paths`` (``ms_half_diff`` = half their difference)."""
    from ..bake import layer_rows

    rng = np.random.default_rng(seed)
    wi = _stratified_hemisphere(rng, n_wi)
    wo = np.concatenate([_stratified_hemisphere(rng, n_wo // 2),
                         _stratified_hemisphere(rng, n_wo // 2) * np.array([1.0, 1.0, -1.0])])
    big_wi, big_wo = np.repeat(wi, len(wo), axis=0), np.tile(wo, (len(wi), 1))
    halves = [reference.ground_truth(p, big_wi, big_wo, n_paths=paths // 2, seed=seed + h, max_depth=64)[1]
              for h in (0, 1)]
    shape = (1, len(wi), len(wo), 3)
    return {"rows": layer_rows.stack_rows(p)[None], "wi": wi[None], "wo": wo[None],
            "ms": (0.5 * (halves[0] + halves[1])).reshape(shape),
            "ms_half_diff": (0.5 * (halves[0] - halves[1])).reshape(shape)}


def failure_case_errors(sizes: MsSizes) -> list[dict]:
    """The network's lobe error on low-roughness in-plane fibers against a fresh random walk."""
    from ..bake import validation

    rows = []
    for i, (label, layers) in enumerate(FAILURE_CASES):
        p = model.params_from_dict({"layers": layers, "multiple_scattering": True})
        data = lobe_data(p, sizes.failure_wi, sizes.failure_wo, sizes.failure_paths, sizes.seed + 101 * i)
        scores = validation.lobe_errors(data)
        rows.append({"label": label, "layers": len(layers), **{k: v for k, v in scores.items() if k != "per_config"}})
    return rows


def _white_layer(rng) -> dict:
    kind = rng.choice(model.LAYER_TYPES, p=(0.4, 0.4, 0.2))
    if kind == "hg":
        rough, orient = float(rng.uniform(-0.8, 0.8)), [0.0, 0.0, 1.0]
    else:
        rough = float(np.exp(rng.uniform(np.log(0.05), np.log(1.0))))
        u, ct, phi = rng.random(), rng.random(), 2.0 * np.pi * rng.random()
        st = np.sqrt(1.0 - ct * ct)
        tilted = [st * np.cos(phi), st * np.sin(phi), ct]
        in_plane = [np.cos(phi), np.sin(phi), 0.0]
        if kind == "surface":
            orient = [0.0, 0.0, 1.0] if u < 0.5 else tilted
        else:
            orient = in_plane if u < 0.4 else ([0.0, 0.0, 1.0] if u < 0.6 else tilted)
    return {"type": str(kind), "roughness": rough, "albedo": [1.0, 1.0, 1.0], "f0": [1.0, 1.0, 1.0],
            "thickness": float(np.exp(rng.uniform(np.log(FURNACE_THICKNESS[0]), np.log(FURNACE_THICKNESS[1])))),
            "orientation": [float(x) for x in orient]}


def white_furnace_configs(n_configs: int, seed: int) -> list[dict]:
    """Seeded random non-absorbing stacks (albedo 1, f0 1, no substrate, no delta): ``n_configs`` of each
    layer count, 1 to ``model.MAX_LAYERS``."""
    rng = np.random.default_rng(seed)
    return [{"layers": [_white_layer(rng) for _ in range(n)]} for n in range(1, model.MAX_LAYERS + 1)
            for _ in range(n_configs)]


def furnace_views(oriented: bool) -> list[tuple[float, float]]:
    """(θo, φo) in degrees of the white furnace's views: each of ``FURNACE_THETAS``, at every one of
    ``FURNACE_AZIMUTHS`` where a layer is oriented off the normal (the first only along the normal and for isotropic
    stacks, which do not depend on the azimuth)."""
    return [(t, phi) for t in FURNACE_THETAS for phi in (FURNACE_AZIMUTHS if oriented and t > 0 else FURNACE_AZIMUTHS[:1])]


def _directions(views) -> np.ndarray:
    t, phi = (np.radians([v[i] for v in views]) for i in (0, 1))
    return np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)], axis=1)


def white_furnace(sizes: MsSizes) -> list[dict]:
    """Per configuration and view direction: the energy a white furnace returns, counting the unscattered light
    (the Dirac part, so a non-absorbing stack must give exactly 1): SS + MS from the model, SS alone, the random
    walk's total (its own shortfall from 1 is truncation at 64 orders plus noise), and SS + MS as each Cycles form
    renders it (its numpy prediction with the Dirac as transparency; the node group's differs from OSL's by its
    merged fiber lobes, [ms-merged-fiber-lobe], and its own budget)."""
    from ..bake.spongecake import predict
    from ..nodes import _backend
    from ..nodes.closures_np import SHARP_ALBEDO
    from ..nodes.expr import closure_furnace

    out = []
    for i, config in enumerate(white_furnace_configs(sizes.furnace_configs, sizes.seed)):
        p = model.params_from_dict({**config, "multiple_scattering": True})
        views = furnace_views(model.anisotropic(p))
        wo = _directions(views)
        lit = model.params_from_dict({**config, "multiple_scattering": True, "delta_transmission": True})
        cycles, nodes = (closure_furnace(lambda w, q=lit, f=form: _backend(model.ID, q, f, w), wo,
                                         quadratures=SHARP_ALBEDO) for form in ("osl", "nodes"))
        p_ss = model.params_from_dict(config)
        through = reference.delta_transmittance(model.params_from_dict({**config, "delta_transmission": True}), wo)
        twice = [reference.directional_albedo(p, wo, n=sizes.furnace_samples // 2, seed=i + 10_000 * h)
                 for h in (0, 1)]  # two halves: their difference is the estimate's own noise
        a_ms = 0.5 * (twice[0] + twice[1]) + through
        a_ss = reference.directional_albedo(p_ss, wo, n=sizes.furnace_samples, seed=i) + through
        truth = sum(reference.ground_truth_albedo(p_ss, wo, n_paths=sizes.furnace_paths, seed=1000 + i))
        network = a_ss + reference.network_albedo(p, predict(p), wo)  # the network's lobes before the energy scale
        for k, (theta, phi) in enumerate(views):
            out.append({"config": i, "layers": len(config["layers"]), "theta": theta, "phi": phi,
                        "oriented": model.anisotropic(p),
                        "ss_ms": float(a_ms[k].mean()), "ss": float(a_ss[k].mean()),
                        "truth": float(truth[k].mean()), "cycles": float(cycles[k].mean()),
                        "nodes": float(nodes[k].mean()),
                        "network": float(network[k].mean()),
                        "ss_ms_noise": float(0.5 * np.abs(twice[0][k] - twice[1][k]).mean())})
    return out


FURNACE_REPEATS = 6  # more estimates of the largest case's view: its two halves' difference alone says little


def repeated_estimates(sizes: MsSizes, case: dict) -> np.ndarray:
    """``FURNACE_REPEATS`` more independent estimates of SS + MS plus the unscattered light at the white-furnace case
    ``case`` (a row of ``white_furnace``), ``sizes.furnace_samples`` samples each, seeds of their own."""
    config = white_furnace_configs(sizes.furnace_configs, sizes.seed)[case["config"]]
    p = model.params_from_dict({**config, "multiple_scattering": True})
    wo = _directions([(case["theta"], case["phi"])])
    through = reference.delta_transmittance(model.params_from_dict({**config, "delta_transmission": True}), wo)
    return np.array([float((reference.directional_albedo(p, wo, n=sizes.furnace_samples, seed=20_000 + k)
                            + through).mean()) for k in range(FURNACE_REPEATS)])


DENSE_THETAS = tuple(float(t) for t in range(0, 89, 4))  # the Cycles form's furnace on a denser grid (degrees)
DENSE_AZIMUTHS = 72  # of view azimuths (uniform from 0; oriented stacks only)


def dense_cycles_furnace(sizes: MsSizes, form: str) -> np.ndarray:
    """(stacks, views) the form's white furnace (its numpy prediction, the Dirac as transparency) of the furnace
    bench's stacks on ``DENSE_THETAS`` × ``DENSE_AZIMUTHS`` views (one azimuth for isotropic stacks): between the
    azimuths and angles of the energy tables, where their interpolation is what counts."""
    from ..nodes import _backend
    from ..nodes.closures_np import SHARP_ALBEDO
    from ..nodes.expr import closure_furnace

    out = []
    for config in white_furnace_configs(sizes.furnace_configs, sizes.seed):
        lit = model.params_from_dict({**config, "multiple_scattering": True, "delta_transmission": True})
        azimuths = np.arange(DENSE_AZIMUTHS) * (360.0 / DENSE_AZIMUTHS) if model.anisotropic(lit) else [0.0]
        wo = _directions([(t, phi) for t in DENSE_THETAS for phi in azimuths])
        out.append(closure_furnace(lambda w, q=lit: _backend(model.ID, q, form, w), wo,
                                   quadratures=SHARP_ALBEDO).mean(axis=1))
    return np.concatenate(out)


def furnace_summary(rows: list[dict]) -> dict:
    """Mean and worst |1 - a| and |a - truth| for SS + MS, SS only, the OSL form's and the node group's SS + MS and
    SS + the network's lobes before the energy scale, and the walk's |1 - truth|."""
    a = {k: np.array([r[k] for r in rows]) for k in ("ss_ms", "ss", "truth", "cycles", "nodes", "network")}
    out = {}
    for name in ("ss_ms", "ss", "cycles", "nodes", "network"):
        e1, et = np.abs(1.0 - a[name]), np.abs(a[name] - a["truth"])
        out[name] = {"mean_vs_1": float(e1.mean()), "worst_vs_1": float(e1.max()),
                     "mean_vs_truth": float(et.mean()), "worst_vs_truth": float(et.max()),
                     "max": float(a[name].max()), "gain_share": float(np.mean(a[name] > 1.005))}
    e = np.abs(1.0 - a["truth"])
    out["truth"] = {"mean_vs_1": float(e.mean()), "worst_vs_1": float(e.max())}
    out["ss_ms"]["noise"] = float(np.sqrt(np.mean([r.get("ss_ms_noise", 0.0) ** 2 for r in rows])))
    return out


FURNACE_GOAL = (0.03, 0.10, 1.005)  # mean and worst |1 - a| of SS + MS, and its largest a (issue 15)


def rendered_ms_errors(name: str, sizes: MsSizes, samples: int, resolution: int) -> dict:
    """{scene: ms entry per form} of ``compare_material`` with multiple scattering, on the accuracy scenes."""
    import tempfile

    from ..reference.spongecake_truth import TruthSettings
    from ..nodes import material as lamina_material
    from ..operators import blend_io, compare_run

    truth = sizes.truth or TruthSettings(**RENDER_TRUTH, seed=sizes.seed)
    p = model.params_from_dict({**presets.load(MODEL, name), "multiple_scattering": True})
    specs = comparison_scenes(resolution)
    cache, out = {}, {}
    with tempfile.TemporaryDirectory(prefix="lamina_bench_ms_") as tmp:
        for form in ("nodes", "osl"):
            before = blend_io.snapshot()
            try:
                mat = lamina_material.new_material(MODEL, p, form)
                report = compare_run.compare_material(mat, specs, samples, resolution, 0, os.path.join(tmp, form),
                                                      reference_cache=cache, ms=truth)
            finally:
                blend_io.remove_new_data(before)
            for scene, entry in report.items():
                out.setdefault(scene, {})[form] = entry["ms"]
    return out


def ms_render_times(names, samples: int, resolution: int, repeats: int) -> list[dict]:
    """Cycles render time of each preset with and without multiple scattering, both forms, on the sphere scene
    (``paired_render_times``: at ``samples`` and at ``SAMPLING_FACTOR`` times as many, in ``repeats`` rounds). Per
    preset and form, ``compared``: with multiple scattering against without; ``per_point_nodes``: the node group's
    count without and with it."""
    from ..nodes import material as lamina_material

    counts = {}

    def materials(name):
        data = presets.load(MODEL, name)
        mats = {(form, ms): lamina_material.new_material(
                    MODEL, model.params_from_dict({**data, "multiple_scattering": ms}), form)
                for form in ("nodes", "osl") for ms in (False, True)}
        counts[name] = tuple(per_point_nodes(mats["nodes", ms]) for ms in (False, True))
        return mats

    return [{"preset": r["preset"], "per_point_nodes": counts[r["preset"]],
             **{form: compared(r, (form, True), (form, False)) for form in ("nodes", "osl")}}
            for r in paired_render_times(names, materials, samples, resolution, repeats)]


# Texture-driven materials whose energy budget follows one input (``nodes.spongecake.TexelEnergy``): label, layers
# (the Lamina node's values), the driven (layer, parameter) and the texture's range.
_FLAKES = {"type": "surface", "roughness": 0.3, "thickness": 1.0, "albedo": [0.8] * 3}
DRIVEN_CASES = (
    ("surface flakes α 0.3, albedo 0.8; thickness 0.3–8", [_FLAKES], (0, "thickness"), (0.3, 8.0)),
    ("white surface flakes α 0.3; thickness 0.05–8", [{**_FLAKES, "albedo": [1.0] * 3}], (0, "thickness"),
     (0.05, 8.0)),
    ("hg Tρ 2, albedo 0.9; g −0.5–0.8", [{"type": "hg", "roughness": 0.3, "thickness": 2.0, "albedo": [0.9] * 3}],
     (0, "roughness"), (-0.5, 0.8)),
    ("surface flakes Tρ 0.5 over hg g 0.5 Tρ 2, albedo 0.9; flake α 0.05–1",
     [{**_FLAKES, "thickness": 0.5, "albedo": [0.9] * 3},
      {"type": "hg", "roughness": 0.5, "thickness": 2.0, "albedo": [0.9] * 3}], (0, "roughness"), (0.05, 1.0)),
    ("surface flakes α 0.3, Tρ 1; albedo 0.2–0.99 (colours)", [_FLAKES], (0, "albedo"), (0.2, 0.99)),
    ("the same over hg g 0.5 Tρ 2, albedo 0.9; top albedo 0.2–0.99 (colours)",
     [_FLAKES, {"type": "hg", "roughness": 0.5, "thickness": 2.0, "albedo": [0.9] * 3}], (0, "albedo"), (0.2, 0.99)),
)
DRIVEN_SUBSTEPS = 4  # the measured values: the tabulated ones and 3 between each two


def driven_energy_rows(form: str) -> list[dict]:
    """Per ``DRIVEN_CASES`` case: how far the multiple scattering that the ``MS Energy`` table following the texels
    (looked up at a texel's value) gives is from what the table of the texel's own values as a material would give,
    against one table for the Lamina node's values (the alternative without ``TexelEnergy``). Per measured value:
    the multiple scattering's albedo max(e − 1, 0) E(ωo) (E its closures' albedo) at the table's rows, the absolute
    difference (a share of the light received) and the sum over rows of the difference over the sum of the texel's
    own; and for non-absorbing stacks the form's white furnace of texels between the tabulated values."""
    from ..nodes import predicted_furnace
    from ..nodes.closures_np import SHARP_ALBEDO

    out = []
    for label, layers, key, span in DRIVEN_CASES:
        p = model.params_from_dict({"layers": layers, "multiple_scattering": True, "delta_transmission": True})
        texels = mapping.texel_energy(p, {key: span})
        table, material = mapping.budget_table(p, form, texels), mapping.budget_table(p, form, mapping.TexelEnergy())
        rows = np.asarray(model.view_table_cosines(table.shape[0]))
        wo = reference.spherical(rows, np.zeros_like(rows))
        socket = texels.axis.socket
        errors = {"driven": ([], []), "material": ([], [])}
        for v in _measured_values(texels.axis):
            texel = mapping.with_values(p, {**mapping.input_values(p), socket: v})
            lobes = mapping.ms_closure_albedo(texel, wo, form)
            own = np.maximum(mapping.budget_table(texel, form).at(wo) - 1.0, 0.0) * lobes
            for name, budget in (("driven", table.at(wo, {socket: v})), ("material", material.at(wo))):
                difference = np.abs(np.maximum(budget - 1.0, 0.0) * lobes - own)
                errors[name][0].append(difference.max())
                errors[name][1].append(difference.sum() / max(own.sum(), 1e-12))
        row = {"label": label, "form": form, "values": len(texels.axis.values),
               **{f"{name}_{kind}": np.asarray(e[i]) for name, e in errors.items()
                  for i, kind in enumerate(("absolute", "relative"))}}
        if all(layer["albedo"] == [1.0] * 3 for layer in layers):
            views = reference.spherical(np.cos(np.radians(FURNACE_THETAS)), np.zeros(len(FURNACE_THETAS)))
            between = texels.axis.finer(2)[1::2]
            row["furnace"] = np.concatenate([predicted_furnace(
                MODEL, mapping.with_values(p, {**mapping.input_values(p), socket: texels.axis.value(v)}), form,
                texels=texels, quadratures=SHARP_ALBEDO)(views) for v in between])
        out.append(row)
    return out


def _measured_values(axis) -> list:
    """The axis' values ``DRIVEN_SUBSTEPS`` times finer; for a colour, colours: the i-th holds the i-th, the (i + n/3)-th
    and the (i + 2n/3)-th of the n values in its channels (each value in each channel once, with others beside it)."""
    values = axis.finer(DRIVEN_SUBSTEPS)
    if not axis.channels:
        return list(values)
    n = len(values)
    return [tuple(values[(i + k * n // 3) % n] for k in range(3)) for i in range(n)]


def driven_energy_markdown() -> list[str]:
    lines = ["", "### Texture-driven stacks: the energy budget per texel", "",
             "Where a texture drives one layer input of an isotropic stack (a thickness, roughness or albedo), the `MS "
             "Energy` table has a column "
             f"per tabulated value of that input ({mapping.DRIVEN_ENERGY_VALUES} over the texture's range, computed "
             f"{mapping.DRIVEN_ENERGY_SUBSTEPS}× finer and made safe between them; `nodes.spongecake.TexelEnergy`) and "
             "is looked up at the texel's value. Measured at the tabulated values and "
             f"{DRIVEN_SUBSTEPS - 1} more between each two: the light the multiple-scattering closures return, "
             "max(e − 1, 0) times their albedo, at the table's 32 rows, against what the table of the texel's own "
             "values as a material gives: the largest difference (a share of the light received) and, per value, "
             "the summed difference over the texel's own sum (relative). An albedo's table is tabulated at greys and "
             "each channel looked up at its own value; it is measured at colours (each measured value in each "
             "channel, the others beside it a third and two thirds of the values further), so the error includes "
             "the lobe network's coupling of the channels. Beside it, what such a material renders without the "
             "columns (several inputs driven, an orientation, an oriented stack): one table for the Lamina node's "
             "values, without the energy fraction (each texel keeps its lobes' own energy).", "",
             "| texture-driven stack | form | values | per-texel table: largest difference | relative, mean | "
             "worst | one table: largest difference | relative, mean | worst | "
             "white furnace between the values: mean \\|1 − a\\| | largest a |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for form in ("osl", "nodes"):
        for r in driven_energy_rows(form):
            furnace = r.get("furnace")
            white = (f"{pct(np.mean(np.abs(1.0 - furnace)))} | {furnace.max():.4f}" if furnace is not None
                     else "not applicable | not applicable")
            cells = [f"{r[f'{name}_absolute'].max():.4f} | {pct(r[f'{name}_relative'].mean())} | "
                     f"{pct(r[f'{name}_relative'].max())}" for name in ("driven", "material")]
            lines.append(f"| {r['label']} | {'OSL' if form == 'osl' else 'node group'} | {r['values']} | "
                         f"{' | '.join(cells)} | {white} |")
    return lines


def ms_accuracy_markdown(sizes: MsSizes, samples: int, resolution: int) -> str:
    from ..bake import validation
    from ..bake.spongecake import NETWORK_LAYERS

    lines = ["", "## Multiple scattering", "",
             "The network's lobes (Sec. 5) against the reference's independent random walk (orders ≥ 2). "
             + weights_note(), ""]
    # --- held-out validation set
    val = validation_errors(sizes.validation, sizes.returned_light_paths)
    lines += ["### Network vs Monte Carlo, held-out validation set", "",
              "`addon.bake.validation.lobe_errors` on `tests/data/spongecake_ms_validation` (independent seed, "
              "never trained on): relative L1 error of f_ms |cos θo| summed over each configuration's direction "
              "pairs, its relative energy error (of that sum, which follows the lobes' shape as much as their "
              "energy), and the Monte Carlo noise of the data (relative L1 of the standard error) for scale. "
              "Light returned: the relative L1 error of the multiple-scattering albedo at each configuration's "
              "stored views against an independent random walk's "
              f"({sizes.returned_light_paths} paths per view; `validation.returned_light`), the energy itself, and "
              "that walk's own noise (the same measure, estimated from its two halves). The standard error of the "
              "mean (the configurations' spread over √count) says how far the set's mean may lie from the mean over "
              "every stack the dataset draws. "
              "Stacks of 3 and 4 layers go through the two-layer network, grouped (docs/training.md); their energy "
              "scale follows energy fraction networks of their own, as for 1 and 2 layers.",
              ""]
    if val:
        lines += ["| layers | energy scale | configs | pairs × paths | mean ± its standard error | median | worst | "
                  "mean energy error | light returned | walk noise | Monte Carlo noise |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for (n, energy), v in val.items():
            layers = f"{n} (grouped)" if n > NETWORK_LAYERS else n
            lines.append(f"| {layers} | {'yes' if energy else 'no (the network alone)'} | {v['configs']} | "
                         f"{v['n_wi']}×{v['n_wo']} × {v['paths']} | "
                         f"{pct(v['mean_relative_lobe_error'])} ± {pct(v['standard_error_of_mean'])} | "
                         f"{pct(v['median_relative_lobe_error'])} | "
                         f"{pct(v['worst_relative_lobe_error'])} | {pct(v['mean_relative_energy_error'])} | "
                         f"{pct(v['returned_light_error'])} | {pct(v['walk_noise'])} | "
                         f"{pct(v['mean_monte_carlo_noise'])} |")
    else:
        lines.append("Not measured: the validation set is missing (`make validation-set`).")
    lines += ["", "### Energy fraction network, held-out energy set", "",
              "`addon.bake.validation.energy_errors` on `tests/data/spongecake_ms_energy_validation.npz` (independent "
              "seed, never trained on; the random walk's tally of the light leaving by orders ≥ 2, 16 wi × 16000 "
              "paths per stack): the network's share q of what single scattering and the Dirac leave, times that "
              "leftover from the reference, against the walk, per stack summed over wi and channels "
              "(docs/training.md, *The energy fraction network*); per view: each view's own error, summed "
              "(`validation.per_view_energy_errors`: views' errors of opposite signs do not cancel; it holds the "
              "walk's noise too). The model: the same measure of the reference's "
              "multiple scattering at each wi (the network's lobes' albedo there times the energy scale at that "
              "view, `validation.model_energy_errors`), with the energy fraction and without it (the lobes' own "
              "energy, at most what single scattering leaves: what stacks of 1 and 2 layers rendered before MS_VERSION "
              "10, and of 3 and 4 layers before 13). Mean / median / worst.", ""]
    if os.path.exists(sizes.energy_validation):
        lines += ["| layers | stacks | network: mean energy error | median | worst | per view | the model with the "
                  "fraction | the model without it |", "|---|---|---|---|---|---|---|---|"]

        def triple(v):
            return " / ".join(pct(v[f"{k}_relative_energy_error"]) for k in ("mean", "median", "worst"))

        for n in range(1, model.MAX_LAYERS + 1):
            without = validation.model_energy_errors(sizes.energy_validation, n, fraction=False)
            v = validation.energy_errors(sizes.energy_validation, n)
            with_fraction = validation.model_energy_errors(sizes.energy_validation, n)
            lines.append(f"| {n} | {v['configs']} | {pct(v['mean_relative_energy_error'])} | "
                         f"{pct(v['median_relative_energy_error'])} | {pct(v['worst_relative_energy_error'])} | "
                         f"{pct(v['mean_per_view_energy_error'])} | {triple(with_fraction)} | {triple(without)} |")
    else:
        lines.append("Not measured: the energy validation set is missing (`python -m training.energy_train "
                     "--validation-set FILE`).")
    # --- failure case
    fail = failure_case_errors(sizes)
    lines += ["", "### The paper's failure case: low-roughness fibers", "",
              "Fibers in the tangent plane with α ≤ 0.1 (albedo 0.9) have sharp multiply-scattered highlights that "
              "the network's single extra lobe cannot follow (the paper's Sec. 5 limitation). Same error measure "
              f"against a fresh random walk ({sizes.failure_wi} × {sizes.failure_wo} direction pairs, "
              f"{sizes.failure_paths} paths per wi).", "",
              "| configuration | lobe error | energy error | Monte Carlo noise |", "|---|---|---|---|"]
    for r in fail:
        lines.append(f"| {r['label']} | {pct(r['mean_relative_lobe_error'])} | "
                     f"{pct(r['mean_relative_energy_error'])} | {pct(r['mean_monte_carlo_noise'])} |")
    # --- white furnace
    rows = white_furnace(sizes)
    summ = {"all": furnace_summary(rows)}
    for n in range(1, model.MAX_LAYERS + 1):
        summ[f"{n} layer{'s' if n > 1 else ''}"] = furnace_summary([r for r in rows if r["layers"] == n])
    summ["isotropic layers"] = furnace_summary([r for r in rows if not r["oriented"]])
    summ["a layer oriented off the normal"] = furnace_summary([r for r in rows if r["oriented"]])
    goal_mean, goal_worst, goal_max = FURNACE_GOAL

    def met(name):
        sm = summ["all"][name]
        return sm["mean_vs_1"] <= goal_mean and sm["worst_vs_1"] <= goal_worst and sm["max"] <= goal_max

    lines += ["", "### White furnace: energy conservation of non-absorbing stacks", "",
              f"{sizes.furnace_configs} random stacks of each layer count 1–{model.MAX_LAYERS} (seed {sizes.seed}; "
              f"albedo 1, f0 1, no substrate; flake α in [0.05, 1], hg g in [-0.8, 0.8], Tρ in "
              f"[{FURNACE_THICKNESS[0]:g}, {FURNACE_THICKNESS[1]:g}]; surface flakes along the normal or tilted, fibers "
              f"in the tangent plane, along the normal or tilted), each seen from θo = "
              f"{', '.join(f'{t:g}°' for t in FURNACE_THETAS)} (azimuth {FURNACE_AZIMUTHS[0]:g}°; stacks with a layer "
              f"oriented off the normal at azimuths {', '.join(f'{a:g}°' for a in FURNACE_AZIMUTHS)} too, so they "
              "count more views). The energy returned counts the "
              "unscattered light (the Dirac part), so the exact answer is 1. SS + MS: the model's directional albedo "
              f"with the network and its energy scale ({sizes.furnace_samples} samples per direction; its own noise, "
              f"from two halves: {pct(summ['all']['ss_ms']['noise'])} RMS) plus the unscattered light; OSL, node group: "
              "the same as each Cycles form renders it (numpy prediction; its GGX lobes by their own quadrature; the "
              "node group merges each fiber layer's lobe with the network's, [ms-merged-fiber-lobe]; each form's "
              "energy budget is computed on its own prediction); Monte Carlo: the "
              f"random walk's total ({sizes.furnace_paths} paths; short of 1 only by truncation at 64 orders, since "
              f"every path keeps weight 1); network alone: SS plus the network's lobes before the energy scale (exact "
              f"albedos). Goal for SS + MS (issue 15): mean |1 − a| ≤ {pct(goal_mean)}, worst ≤ "
              f"{pct(goal_worst)}, never above {goal_max:g}.",
              "",
              "| stacks | SS + MS mean \\|1 − a\\| | worst | largest a | OSL mean \\|1 − a\\| | worst | largest a | "
              "node group mean \\|1 − a\\| | worst | largest a | "
              "SS + MS vs Monte Carlo mean | SS only mean \\|1 − a\\| | Monte Carlo mean \\|1 − a\\| | "
              "network alone mean \\|1 − a\\| | worst | largest a |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for label, sm in summ.items():
        lines.append(f"| {label} | {pct(sm['ss_ms']['mean_vs_1'])} | {pct(sm['ss_ms']['worst_vs_1'])} | "
                     f"{sm['ss_ms']['max']:.4f} | {pct(sm['cycles']['mean_vs_1'])} | "
                     f"{pct(sm['cycles']['worst_vs_1'])} | {sm['cycles']['max']:.4f} | "
                     f"{pct(sm['nodes']['mean_vs_1'])} | {pct(sm['nodes']['worst_vs_1'])} | {sm['nodes']['max']:.4f} | "
                     f"{pct(sm['ss_ms']['mean_vs_truth'])} | {pct(sm['ss']['mean_vs_1'])} | "
                     f"{pct(sm['truth']['mean_vs_1'])} | {pct(sm['network']['mean_vs_1'])} | "
                     f"{pct(sm['network']['worst_vs_1'])} | {sm['network']['max']:.3f} |")
    worst_view = max(rows, key=lambda r: abs(1.0 - r["ss_ms"]))
    largest = max(rows, key=lambda r: r["ss_ms"])
    again = repeated_estimates(sizes, largest)
    lines += ["", f"Goal {'met' if met('ss_ms') else '**not met**'} in the reference (mean "
              f"{pct(summ['all']['ss_ms']['mean_vs_1'])}, worst {pct(summ['all']['ss_ms']['worst_vs_1'])}, largest "
              f"{summ['all']['ss_ms']['max']:.4f}; above {goal_max:g} in {pct(summ['all']['ss_ms']['gain_share'])} of the "
              f"(stack, view) cases), {'met' if met('cycles') else '**not met**'} in the OSL form (mean "
              f"{pct(summ['all']['cycles']['mean_vs_1'])}, worst {pct(summ['all']['cycles']['worst_vs_1'])}, largest "
              f"{summ['all']['cycles']['max']:.4f}), {'met' if met('nodes') else '**not met**'} in the node group (mean "
              f"{pct(summ['all']['nodes']['mean_vs_1'])}, worst {pct(summ['all']['nodes']['worst_vs_1'])}, largest "
              f"{summ['all']['nodes']['max']:.4f}). The worst case is a {worst_view['layers']}-layer stack seen at θo = "
              f"{worst_view['theta']:.0f}°, φo = {worst_view['phi']:.0f}°. The largest a, a {largest['layers']}-layer "
              f"stack at θo = {largest['theta']:.0f}°, φo = {largest['phi']:.0f}°: {FURNACE_REPEATS} more independent "
              f"estimates of that view ({sizes.furnace_samples} samples each) give {again.mean():.4f} ± "
              f"{again.std(ddof=1):.4f} (their mean ± one estimate's standard deviation; the largest of them "
              f"{again.max():.4f}). The energy scale (reference module docstring, [ms-energy]) gives "
              f"isotropic white stacks 1 less its margin ({pct(model.ENERGY_MARGIN)}, for the noise of its estimates) "
              "at its knots; where a layer is oriented off the normal the reference tabulates the scale over the "
              "view's azimuth too. Between the knots the reference interpolates bilinearly less an estimate of the "
              "interpolation's error where the table is convex, so that a view between knots takes no more than "
              "they allow. The Cycles forms look the scale up in a table over asin(√μ), and the azimuth for an "
              "oriented stack (a packed float image, bilinear), without that estimate; an "
              "energy budget (training.md) caps their single scattering where it alone returns more than it "
              "receives, and the tables are lowered where interpolating between their rows would exceed them."]
    dense = {form: dense_cycles_furnace(sizes, form) for form in ("osl", "nodes")}
    lines += ["", f"The Cycles forms on a denser grid of views (θo {DENSE_THETAS[0]:g}° to {DENSE_THETAS[-1]:g}° in "
              f"steps of {DENSE_THETAS[1] - DENSE_THETAS[0]:g}°; oriented stacks at {DENSE_AZIMUTHS} azimuths; "
              f"{dense['osl'].size} (stack, view) cases): "
              + "; ".join(f"{label} mean |1 − a| {pct(np.mean(np.abs(1.0 - a)))}, worst {pct(np.max(np.abs(1.0 - a)))}, "
                          f"largest {a.max():.4f}, above {goal_max:g} in {pct(np.mean(a > goal_max))} of the cases"
                          for label, a in (("OSL", dense["osl"]), ("node group", dense["nodes"]))) + "."]
    lines += driven_energy_markdown()
    # --- rendered
    from ..reference.spongecake_truth import TruthSettings

    truth = sizes.truth or TruthSettings(**RENDER_TRUTH, seed=sizes.seed)
    lines += ["", "### Rendered: SS + MS vs Monte Carlo on the presets", "",
              f"Relative RMSE against the Monte Carlo ground truth (closed-form single scattering + the walk's orders "
              f"≥ 2) on the comparison scenes at {resolution} px, over the pixels where the walk ran (one "
              f"in {truth.stride}×{truth.stride}; {truth.paths} paths per light direction, furnace "
              f"{truth.albedo_paths} per pixel); its noise, in the same units, is the floor of every error in the "
              f"row. Network: the reference with the network's lobes; node group / OSL: Cycles, {samples} samples, "
              "with multiple scattering on (their errors include the mapping's approximations and Cycles' noise). "
              "The last two columns measure Cycles against the network reference instead.", "",
              "| preset | scene | MS share | SS only | network | node group | OSL | Monte Carlo noise | node group vs "
              "network | OSL vs network |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name in sizes.presets:
        for scene, forms in rendered_ms_errors(name, sizes, samples, resolution).items():
            n, o = forms["nodes"], forms["osl"]
            lines.append(f"| {name} | {scene} | {pct(n['ms_share'])} | {pct(n['single_vs_truth'])} | "
                         f"{pct(n['network_vs_truth'])} | {pct(n['cycles_vs_truth'])} | {pct(o['cycles_vs_truth'])} | "
                         f"{pct(n['truth_noise'])} | {pct(n['cycles_vs_network'])} | {pct(o['cycles_vs_network'])} |")
    return "\n".join(lines) + "\n"


def ms_speed_markdown(sizes: MsSizes, samples: int, resolution: int) -> str:
    rows = ms_render_times(sizes.presets, samples, resolution, sizes.speed_repeats)
    lines = ["", "## Multiple scattering", "",
             f"Cycles CPU render of the sphere scene, {resolution}×{resolution} px, the same material with multiple "
             f"scattering off and on, renders alternating, fastest of {sizes.speed_repeats}; the ratio of the fastest "
             "renders, and the range of the ratios of each round's pair (how far one measurement of this ratio moves "
             "on this machine). Goal: SS + MS ≤ 1.5× SS (the paper reports 1.44×).", "",
             f"Whole render at {samples} samples (scene sync, shader compilation, kernel set-up and sampling):", "",
             "| preset | node group SS s | SS + MS s | ratio | per round | OSL SS s | SS + MS s | ratio | per round |",
             "|---|---|---|---|---|---|---|---|---|"]
    lines += [_speed_row(r, "") for r in rows]
    more = SAMPLING_FACTOR * samples
    lines += ["", f"Sampling alone: the time of {more - samples} samples, each round's render at {more} samples less its "
              f"render at {samples} (the set-up is the same in both and cancels; what shading the material costs), the "
              "median over the rounds; the ratio is the median of the rounds' ratios:", "",
              "| preset | node group SS s | SS + MS s | ratio | per round | OSL SS s | SS + MS s | ratio | per round |",
              "|---|---|---|---|---|---|---|---|---|"]
    lines += [_speed_row(r, "sampling") for r in rows]
    lines += ["", "What the node group computes at each shading point (`bench.common.per_point_nodes`: its arithmetic "
              "nodes that depend on the view, the geometry or a texture; Cycles folds the rest into constants), a "
              "count that does not move between runs:", "",
              "| preset | node group SS | SS + MS | ratio |", "|---|---|---|---|"]
    lines += [f"| {r['preset']} | {r['per_point_nodes'][0]} | {r['per_point_nodes'][1]} | "
              f"{r['per_point_nodes'][1] / r['per_point_nodes'][0]:.2f} |" for r in rows]
    return "\n".join(lines) + "\n"


def _speed_row(r: dict, kind: str) -> str:
    """One preset's row of ``ms_speed_markdown``: ``kind`` "" (whole renders) or "sampling"."""
    return "| " + " | ".join([r["preset"]] + ratio_cells(r["nodes"], kind) + ratio_cells(r["osl"], kind)) + " |"
