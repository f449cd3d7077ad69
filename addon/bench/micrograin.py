"""``make bench``, micrograin sections of docs/accuracy.md and docs/benchmarks.md (measured in one run).

Accuracy: the reference's geometric terms against the explicit grain simulation (``reference.micrograin_truth``),
its Λ against the paper's truncated series and the GGX stand-in (Fig. 10), each named approximation of the Cycles
mapping isolated, every preset per scene and form (noise-free numpy predictions of what Cycles renders; the
Blender tests check Cycles renders them), and how far the linear mix by τ0 (Fig. 14) and d'Eon et al.'s
weighting (Eq. 26) are from ours. Speed: the reference's throughput and Cycles render times of a porous layer over
a Principled BSDF against the Principled BSDF alone.
"""
from __future__ import annotations

import math

import numpy as np

from .. import presets
from ..models import micrograin as model
from ..nodes import micrograin as mapping
from ..reference import micrograin as reference
from ..reference import micrograin_truth as truth
from ..reference import scenes as ref_scenes
from ..reference import metrics
from ..reference.frames import spherical
from .common import (approximation_rows, fastest_renders, pct, preset_rows,
                    reference_throughput)

MODEL = model.ID
TAU_GRID = ((0.2, 0.5, 0.9), (0.3, 1.0), (0.0, 30.0, 60.0, 80.0))  # τ0, β, θ of the Fig. 9 claim


def _short(config: dict) -> str:
    grain, bulk = config.get("grain", {}), config.get("bulk", {})
    shape = " ".join(f"{k}={config[k]}" for k in ("filling_factor", "anfractuosity", "gaf") if k in config)
    return f"{shape} / grain {grain.get('type', 'diffuse')} / bulk {bulk.get('type', 'diffuse')}"


def tau_plus_rows(n_rays: int = 200_000) -> list[dict]:
    rows = []
    for tau0 in TAU_GRID[0]:
        for beta in TAU_GRID[1]:
            for theta in TAU_GRID[2]:
                c = math.cos(math.radians(theta))
                sim, se = truth.visible_filling(tau0, beta, c, n_rays, seed=len(rows))
                rows.append({"tau0": tau0, "beta": beta, "theta": theta, "sim": sim, "se": se,
                             "model": float(reference.tau_plus(np.array([c]), tau0, beta)[0])})
    return rows


def lambda_rows() -> list[dict]:
    """Max |G1 error| over θ ≤ 89° of the paper's five-term series (float64 and float32), GGX(α̃) and the float32
    scheme, against the exact Λ."""
    theta = np.radians(np.linspace(0.0, 89.0, 891))
    w = spherical(np.cos(theta), np.zeros_like(theta))
    rows = []
    for tau0 in (0.5, 0.9, 0.98):
        for beta in (0.3, 1.0):
            exact = 1.0 / (1.0 + reference.smith_lambda(w, tau0, beta))

            def err(lam):
                with np.errstate(invalid="ignore", over="ignore"):
                    g = 1.0 / (1.0 + np.asarray(lam, dtype=np.float64))
                return float(np.nanmax(np.abs(g - exact))) if np.isfinite(g).all() else math.inf

            rows.append({"tau0": tau0, "beta": beta,
                         "paper": err(reference.smith_lambda_paper(w, tau0, beta)),
                         "paper32": err(reference.smith_lambda_paper(w.astype(np.float32), tau0, beta)),
                         "ggx": err(1.0 / reference.g1(w, tau0, beta, "ggx") - 1.0),
                         "scheme32": err(reference.smith_lambda_float32(w[:, 2].astype(np.float32),
                                                                         np.float32(tau0), np.float32(beta)))})
    return rows


def grain_albedo_fit() -> dict:
    """Largest |E_spec error| of the Cycles forms' fit (``nodes.micrograin.ALBEDO_FIT``) and of the smooth
    interface's F(μ) against the reference's tabulated albedo, over the fit's range."""
    from ..nodes.expr import NumpyBackend

    mu = np.linspace(0.02, 1.0, 25)
    b = NumpyBackend(np.zeros((len(mu), 3)), {})
    worst = {"fit": 0.0, "fresnel": 0.0}
    for tau0 in (0.05, 0.4, 0.7, 0.9, 0.98):
        for beta in (0.1, 0.3, 0.6, 1.0):
            for eta in (1.3, 1.5, 2.0, 2.5):
                exact = reference.specular_albedo(mu, tau0, beta, eta)
                alpha = np.full_like(mu, model.equivalent_roughness(tau0, beta))
                fit = mapping.specular_albedo_fit(b, mu, np.full_like(mu, eta), alpha)
                fresnel = mapping.fresnel_dielectric(b, mu, np.full_like(mu, eta))
                worst["fit"] = max(worst["fit"], float(np.abs(fit - exact).max()))
                worst["fresnel"] = max(worst["fresnel"], float(np.abs(fresnel - exact).max()))
    return worst


def view_weight_alternatives(resolution: int) -> list[dict]:
    """Each preset with w⁺ = 1 − g(θi) g(θo) (g = sqrt(1 − τβ)) replaced by a view-only stand-in and everything
    else exact: "mirror" g(θi) → g(θo) (what the Cycles forms do: exact at the specular configuration), "average"
    g(θi) → ḡ, its cosine-weighted mean (exact in a white furnace over a diffuse bulk, never at the specular
    configuration). Relative RMSE against the reference."""
    rows = []
    for name in presets.names(MODEL):
        p = model.params_from_dict(presets.load(MODEL, name))

        def g(c):
            return np.sqrt(1.0 - reference.tau_beta(c, p.filling_factor, p.anfractuosity))

        stand_ins = {"mirror": g, "average": lambda c: np.full_like(c, reference.hemispherical_mean(g))}
        for spec in ref_scenes.default_scenes(resolution):
            if spec.name == "backlit":
                continue
            mask = ref_scenes.scene_mask(spec)
            exact = ref_scenes.reference_image(spec, lambda wi, wo: reference.eval(p, wi, wo))
            row = {"preset": name, "scene": spec.name}
            for variant, g_light in stand_ins.items():
                def f(wi, wo, _g=g_light):
                    out = reference.eval(p, wi, wo)
                    both = (wi[:, 2] > 0) & (wo[:, 2] > 0)
                    grains, bulk = reference.reflection_terms(p, wi[both], wo[both])
                    keep = (g(wo[both, 2]) * _g(wo[both, 2]))[:, None]
                    out[both] = (1.0 - keep) * grains + keep * bulk
                    return out

                row[variant] = metrics.rel_rmse(ref_scenes.reference_image(spec, f), exact, mask)
            rows.append(row)
    return rows


def blend_differences(resolution: int) -> list[dict]:
    """Relative RMSE of the reference with the linear mix and d'Eon's weighting against ours, per preset."""
    rows = []
    for name in presets.names(MODEL):
        p = model.params_from_dict(presets.load(MODEL, name))
        for spec in ref_scenes.default_scenes(resolution):
            if spec.name not in ("sphere", "plane"):
                continue
            mask = ref_scenes.scene_mask(spec)
            images = {b: ref_scenes.reference_image(spec, lambda wi, wo, _b=b: reference.eval(p, wi, wo, blend=_b))
                      for b in reference.BLENDS}
            rows.append({"preset": name, "scene": spec.name,
                         **{b: metrics.rel_rmse(images[b], images["ours"], mask) for b in reference.BLENDS[1:]}})
    return rows


def accuracy(sizes) -> str:
    """The micrograin sections of docs/accuracy.md (``bench.Sizes``)."""
    return accuracy_markdown(sizes.resolution)


def speed(sizes) -> str:
    """The micrograin sections of docs/benchmarks.md (``bench.Sizes``)."""
    return speed_markdown(sizes.timing_samples, sizes.timing_resolution)


def accuracy_markdown(resolution: int) -> str:
    lines = ["", "# Micrograin porous layer", "",
             "## Geometric terms vs an explicit simulation of the grains", "",
             "The visible filling factor τ⁺(θ) (Eq. 22) against ray casting into random half-ellipsoid grains "
             "(Poisson centres, `addon.reference.micrograin_truth.visible_filling`, 200 000 rays per point): the "
             "paper's Fig. 9 claim, reproduced.", "",
             "| τ0 | β | θ | simulation ± s.e. | Eq. 22 | difference |", "|---|---|---|---|---|---|"]
    rows = tau_plus_rows()
    for r in rows:
        lines.append(f"| {r['tau0']} | {r['beta']} | {r['theta']:.0f}° | {r['sim']:.4f} ± {r['se']:.4f} | "
                     f"{r['model']:.4f} | {r['sim'] - r['model']:+.4f} |")
    worst = max(abs(r["sim"] - r["model"]) for r in rows)
    lines += ["", f"Largest difference: **{worst:.4f}** (the issue asks for ≤ 0.01).", "",
              "Visible normals at oblique views against the microfacet prediction G1 ⟨ω, m⟩ D(m) / cos θ with the "
              "exact Smith G1 of the micrograin NDF (`oblique_normals_check`, 400 000 rays): total variation "
              "distance between the binned distributions. At normal view the simulated normals follow D cos θm "
              "(chi-square, tests/unit/test_micrograin_truth.py). The gap at grazing views is the Smith "
              "assumption's (masking correlates with height), the margin the paper admits for its GAF.", "",
              "| τ0 | β | TV at 30° | TV at 60° | TV at 80° |", "|---|---|---|---|---|"]
    for tau0 in (0.2, 0.9):
        for beta in (0.5, 1.0):
            tv = [truth.oblique_normals_check(tau0, beta, t)["total_variation"] for t in (30.0, 60.0, 80.0)]
            lines.append(f"| {tau0} | {beta} | " + " | ".join(f"{x:.3f}" for x in tv) + " |")
    lines += ["", "## Λ (Eq. 25): exact series, the paper's five terms, GGX(α̃), the float32 scheme", "",
              "Largest |G1 error| over θ ≤ 89° against the exact Λ (`reference.micrograin.smith_lambda`, within "
              "1e-8 of a brute-force integral of the NDF in the tests). The paper's five-term series cancels "
              "catastrophically in "
              "float32 (inf: NaN or overflow); the float32 scheme (`smith_lambda_float32`) is what both Cycles "
              "forms evaluate.", "",
              "| τ0 | β | paper n=4 (float64) | paper n=4 (float32) | GGX(α̃) | float32 scheme |",
              "|---|---|---|---|---|---|"]
    for r in lambda_rows():
        lines.append(f"| {r['tau0']} | {r['beta']} | {r['paper']:.2e} | {r['paper32']:.2e} | {r['ggx']:.2e} | "
                     f"{r['scheme32']:.2e} |")
    fit = grain_albedo_fit()
    lines += ["", "## Dielectric grains' specular albedo", "",
              "T̄ = t(θi) t(θo), t = 1 − E_spec (research notes §3): the reference tabulates E_spec per parameter "
              "set; the Cycles forms use a three-coefficient fit (`nodes.micrograin.ALBEDO_FIT`). Largest |error| "
              "of E_spec over τ0 ∈ [0.05, 0.98], β ∈ [0.1, 1], η ∈ [1.3, 2.5], cos θ ∈ [0.02, 1]: fit "
              f"**{fit['fit']:.3f}**, the smooth interface's F(θ) {fit['fresnel']:.3f}."]
    lines += ["", "## Named approximations of the Cycles mapping, each isolated", "",
              "Relative RMSE of the form's numpy prediction against the reference (as in the SpongeCake sections).",
              "", "| approximation | what it does | configuration | scene | ref. mean | OSL | node group |",
              "|---|---|---|---|---|---|---|"]
    lines += approximation_rows(model, mapping.APPROXIMATIONS, resolution, _short)
    lines += preset_rows(model, resolution)
    lines += ["", "## The view-only stand-in for w⁺", "",
              "w⁺ = 1 − g(θi) g(θo) needs the light direction, which a closure weight cannot see. Candidates for "
              "g(θi), each alone (everything else exact): the mirror configuration g(θo), which the Cycles forms "
              "use because it is exact at the specular configuration (where glossy bulks and grains send their "
              "light), and the cosine-weighted mean ḡ, which is right on average for matte bulks.", "",
              "| preset | bulk | scene | mirror g(θo) | mean ḡ |", "|---|---|---|---|---|"]
    for r in view_weight_alternatives(resolution):
        bulk = model.params_from_dict(presets.load(MODEL, r["preset"])).bulk.type
        lines.append(f"| {r['preset']} | {bulk} | {r['scene']} | {pct(r['mirror'])} | {pct(r['average'])} |")
    lines += ["", "## Other blending weights against ours (the paper's Fig. 14 and Eq. 26)", "",
              "Relative RMSE of the reference with the linear mix by τ0 and with d'Eon et al.'s weighting "
              "(w_A = τ0, our reading of Eq. 26) against the reference with w⁺: what `lamina compare --blends` "
              "shows side by side.", "", "| preset | scene | linear mix | d'Eon |", "|---|---|---|---|"]
    for r in blend_differences(resolution):
        lines.append(f"| {r['preset']} | {r['scene']} | {pct(r['linear'])} | {pct(r['deon'])} |")
    return "\n".join(lines) + "\n"


def render_times(samples: int, resolution: int, repeats: int = 3) -> list[dict]:
    """Cycles render time of each preset's porous layer over a Principled BSDF (both forms, both GAFs) and of
    the Principled BSDF alone."""
    from ..nodes import material as lamina_material

    def materials(name):
        data = {**presets.load(MODEL, name), "bulk": {"type": model.WRAPPED}}
        out = {"principled": lamina_material.principled_material(MODEL, model.params_from_dict(data))}
        for form in ("nodes", "osl"):
            for gaf in model.GAF_TYPES:
                p = model.params_from_dict({**data, "gaf": gaf})
                out[f"{form} {gaf}"] = lamina_material.new_material(MODEL, p, form)
                _plug_principled(out[f"{form} {gaf}"], p)
        return out

    return fastest_renders(presets.names(MODEL), materials, samples, resolution, repeats)


def _plug_principled(mat, p) -> None:
    """Feed the layer's Bulk input with the Principled BSDF it is timed against (``mapping.principled_settings``)."""
    from ..nodes import material as lamina_material

    bsdf = lamina_material.principled_node(mat.node_tree, mapping.principled_settings(p))
    mat.node_tree.links.new(bsdf.outputs[0], lamina_material.shader_node(mat).inputs["Bulk"])


def speed_markdown(samples: int, resolution: int) -> str:
    rate = reference_throughput(model.params_from_dict(presets.load(MODEL, "rust_on_metal")), MODEL)
    rows = render_times(samples, resolution)
    lines = ["", "## Micrograin porous layer", "",
             f"Reference `micrograin.eval`, rust_on_metal (conductor grains over a rough metal), float64: "
             f"**{rate / 1e6:.2f} M evals/s**.", "",
             f"Cycles CPU render of the sphere scene, {resolution}×{resolution} px, {samples} samples, fastest of 3: "
             "each preset's porous layer over a Principled BSDF (its Bulk input) against that Principled BSDF "
             "alone, node group and OSL, with the micrograin GAF (series: float32 Λ in the shader) or GGX's.", "",
             "| preset | Principled s | nodes series : Principled | nodes ggx : Principled | OSL series : Principled "
             "| OSL ggx : Principled |", "|---|---|---|---|---|---|"]
    for r in rows:
        base = r["principled"]
        lines.append(f"| {r['preset']} | {base:.2f} | " + " | ".join(
            f"{r[k] / base:.2f}" for k in ("nodes series", "nodes ggx", "osl series", "osl ggx")) + " |")
    return "\n".join(lines) + "\n"
