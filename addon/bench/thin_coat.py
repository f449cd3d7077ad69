"""``make bench``, thin-coat sections (ENDF model): the vMF kit and joint warping against brute force, Eq. 8
against the exact masking integral, the analytic model against the Monte Carlo ground truth per bounce order
(``reference.thin_coat_truth``), its reciprocity, the Cycles mapping's named approximations and presets, and
speed: render time against the bounce count, node group : OSL : Principled coat, and the ground truth's cost per
sample against the model's (the paper's Table 2, in kind).
"""
from __future__ import annotations

import itertools

import numpy as np

from .. import presets
from ..models import thin_coat as model
from ..reference import thin_coat as reference
from ..reference import thin_coat_truth as truth
from ..reference import vmf, warping
from ..reference.frames import spherical
from .common import (approximation_header, approximation_rows, driven_section, fastest_renders,
                     fitted_speed_section, mapping_section, pct, preset_render_times, preset_rows,
                     reference_throughput, timed)

MODEL = model.ID
# The grid: κ1, κ2 ∈ {10, 1e3, 1e6}, η ∈ {1.2, 1.5, 2}, without and with absorption.
KAPPAS = (10.0, 1e3, 1e6)
ETAS = (1.2, 1.5, 2.0)
ABSORPTION = (0.0, 0.5)  # σa (all channels) with depth 1
VIEWS = (0.0, 60.0)  # view angles of the ground-truth comparison (degrees)
GT_PATHS = 40_000
# Texture-driven fits measured between tabulated values: (preset, input, least and greatest texture value).
DRIVEN_CASES = (("amber_lacquer", "Absorption", 0.0, 2.0), ("rough_over_smooth", "Depth", 0.1, 1.0))


def _view(theta_deg: float):
    return spherical(np.array([np.cos(np.radians(theta_deg))]), np.array([0.0]))


def _grid_params():
    for k1, k2, eta, sigma in itertools.product(KAPPAS, KAPPAS, ETAS, ABSORPTION):
        yield model.params_from_dict({"kappa_top": k1, "kappa_bottom": k2, "eta": eta, "bounces": 4,
                                      "sigma_a": [sigma] * 3, "depth": 1.0})


# ------------------------------------------------------------------------------------------ building blocks


def vmf_kit_rows(n: int = 1_000_000, seed: int = 3) -> dict:
    """Worst relative round-trip error of A3 and 1 − A3 through their inverses over κ ∈ [1e-3, 1e6], and the
    moment-matched convolution (Eq. 18) against Monte Carlo rotations of lobes around lobes."""
    kappa = np.logspace(-3, 6, 400)
    trip = max(np.max(np.abs(vmf.kappa_from_a3(vmf.a3(kappa)) / kappa - 1.0)),
               np.max(np.abs(vmf.kappa_from_complement(vmf.mean_cosine_complement(kappa)) / kappa - 1.0)))
    rng = np.random.default_rng(seed)
    rows = []
    for k1, k2 in ((5.0, 20.0), (100.0, 100.0), (1e4, 30.0)):
        u = rng.random((4, n))
        first = vmf.sample(np.full(n, k1), u[0], u[1])
        second = vmf.sample_around(first, np.full(n, k2), u[2], u[3])
        _, measured = warping.sample_moments(second)
        rows.append({"k1": k1, "k2": k2, "convolve": float(vmf.convolve(k1, k2)), "mc": float(measured)})
    return {"round_trip": float(trip), "convolution": rows, "samples": n}


def masking_rows() -> list[dict]:
    """Eq. 8's a cos(b arccos(cos θ)) against the exact ∫⟨v, m⟩M dm, and the G1 each gives."""
    rows = []
    for kappa in (1e-3, 1.0, 10.0, 100.0, 1e3, 1e6):
        for theta in (0.0, 30.0, 60.0, 80.0, 89.0):
            c = np.array([np.cos(np.radians(theta))])
            exact = truth.projected_area_exact(c, kappa)[0]
            approx = reference.projected_area(reference.F64, c, np.asarray(kappa))[0]
            rows.append({"kappa": kappa, "theta": theta, "exact": float(exact), "eq8": float(approx),
                         "g1_exact": float(truth.smith_g1(c, kappa)[0]),
                         "g1_eq8": float(reference.smith_g1(reference.F64, c, np.asarray(kappa))[0])})
    return rows


# ------------------------------------------------------------------------------------------ model vs truth


def model_exits(p, wo, order: int, n: int = 20000, seed: int = 0):
    """Exit directions and weights f cos / pdf of the model's order-``order`` reflection lobe, drawn from the lobe
    itself: what ``warping.sample_moments`` compares with the ground truth's exits (both cut by the horizon
    alike)."""
    lobe = next(lb for lb in reference.lobes_at(p, wo) if lb.order == order and lb.kind != "transmission")
    x, w = reference.lobe_samples(p, lobe, wo, n, np.random.default_rng(seed))
    keep = w.sum(axis=1) > 0
    return x[keep], w[keep]


def truth_rows(paths: int = GT_PATHS, seed: int = 11, grid=None) -> list[dict]:
    """Per configuration (default: the issue's grid), view and bounce order k = 1..bounces: the lobe's energy
    (analytic ∫ f_k cos against the energy the ground truth's order-k paths carry out), its width (moment-matched
    κ of exit directions, the model's lobe sampled the same way) and its peak f_k at the mirror direction (the
    ground truth's next-event estimate, with its standard error)."""
    rows = []
    for p in grid or _grid_params():
        for theta in VIEWS:
            wo = _view(theta)
            mirror = wo * np.array([-1.0, -1.0, 1.0])
            energy = reference.directional_albedo(p, wo, n=4096, orders=True)[:, 0].mean(axis=1)
            peak = reference.eval_orders(p, mirror, wo)[:, 0].mean(axis=1)
            gt = truth.ground_truth_albedo(p, wo[0], n_paths=paths, seed=seed)
            f_gt, f_se = truth.ground_truth(p, mirror, wo[0], n_paths=paths, seed=seed + 1)
            for k in range(1, p.bounces + 1):
                dirs, weights = gt["exits"]["reflection"][k]
                enough = len(dirs) > 50
                rows.append({"k1": p.kappa_top, "k2": p.kappa_bottom, "eta": p.eta, "sigma": p.sigma_a[0],
                             "theta": theta, "order": k,
                             "energy": float(energy[k]), "energy_gt": float(gt["reflection"][k].mean()),
                             "energy_se": float(gt["stderr"]["reflection"][k].mean()),
                             "kappa": warping.sample_moments(*model_exits(p, wo, k))[1] if enough else float("nan"),
                             "kappa_gt": warping.sample_moments(dirs, weights)[1] if enough else float("nan"),
                             "peak": float(peak[k]), "peak_gt": float(f_gt[k, 0].mean()),
                             "peak_se": float(f_se[k, 0].mean())})
    return rows


def _rel(a, b):
    return abs(a / b - 1.0) if b > 0 else float("nan")


def _summary(rows, key_model, key_truth, min_truth=1e-6, se=None):
    """Median and worst relative error over ``rows`` where the truth is above ``min_truth`` (and, with ``se``,
    known to 10 %: next-event estimates through a near-mirror interface are too noisy to judge)."""
    errs = [_rel(r[key_model], r[key_truth]) for r in rows
            if r[key_truth] > min_truth and (se is None or r[se] < 0.1 * r[key_truth])]
    errs = [e for e in errs if np.isfinite(e)]
    if not errs:
        return "n/a", "n/a", 0
    return pct(float(np.median(errs))), pct(float(np.max(errs))), len(errs)


def reciprocity_rows(n: int = 20000, seed: int = 5) -> list[dict]:
    """Σ |f(i, o) − f(o, i)| / Σ (f(i, o) + f(o, i)) / 2 over uniform pairs of the upper hemisphere, per preset:
    the whole BSDF and the subsurface orders alone (the top surface term is reciprocal)."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v /= np.linalg.norm(v, axis=2, keepdims=True)
    v[..., 2] = np.abs(v[..., 2])
    a, b = v
    rows = []
    for name in presets.names(MODEL):
        p = model.params_from_dict(presets.load(MODEL, name))
        fab, fba = reference.eval_orders(p, a, b), reference.eval_orders(p, b, a)

        def asym(x, y):
            return float(np.abs(x - y).sum() / max(0.5 * (x + y).sum(), 1e-300))
        rows.append({"preset": name, "all": asym(fab.sum(0), fba.sum(0)), "sub": asym(fab[1:].sum(0), fba[1:].sum(0))})
    return rows


# ------------------------------------------------------------------------------------------ markdown


def accuracy(sizes) -> str:
    """The thin coat sections of docs/accuracy.md (``bench.Sizes``)."""
    return accuracy_markdown(sizes.resolution)


def speed(sizes) -> str:
    """The thin coat sections of docs/benchmarks.md (``bench.Sizes``)."""
    return speed_markdown(sizes.timing_samples, sizes.timing_resolution)


def accuracy_markdown(resolution: int) -> str:
    kit = vmf_kit_rows()
    lines = ["", "# Thin transparent coat (ENDF)", "",
             "## vMF kit (research notes §2)", "",
             f"A3 and 1 − A3 through their inverses (`vmf.kappa_from_a3`, `kappa_from_complement`), κ ∈ [1e-3, 1e6], "
             f"400 log-spaced points: worst relative round-trip error **{kit['round_trip']:.1e}**. Moment-matched "
             f"convolution (Eq. 18) against {kit['samples']:,} Monte Carlo rotations of a lobe around a lobe "
             "(the κ matching the samples' mean cosine; noise ~0.1-0.3 %):", "",
             "| κ1 | κ2 | `vmf.convolve` | Monte Carlo | difference |", "|---|---|---|---|---|"]
    for r in kit["convolution"]:
        lines.append(f"| {r['k1']:g} | {r['k2']:g} | {r['convolve']:.3f} | {r['mc']:.3f} | "
                     f"{pct(r['convolve'] / r['mc'] - 1.0)} |")
    lines += ["", "## Joint spherical warping against the exact Eqs. 16 / 20 (Figs. 6-7)", "",
              "`warping.joint_warp_error`: quadrature of the exact distribution around the approximating lobe; "
              "angle between the mean directions, κ's error against the exact distribution's moment-matched κ, "
              "L1 distance between the densities (0 identical, 2 disjoint). η = 1.5.", "",
              "| example (µo·µm, κo, κm) | D(r) angle | D(r) κ | D(r) L1 | D(t) angle | D(t) κ | D(t) L1 |",
              "|---|---|---|---|---|---|---|"]
    for ex in warping.FIGURE_EXAMPLES:
        r, t = warping.joint_warp_error("r", *ex), warping.joint_warp_error("t", *ex)
        lines.append(f"| {ex[0]:.3f}, {ex[1]:g}, {ex[2]:g} | {r['angle']:.2f}° | {pct(r['kappa_error'])} | "
                     f"{r['l1']:.3f} | {t['angle']:.2f}° | {pct(t['kappa_error'])} | {t['l1']:.3f} |")
    lines += ["", "At oblique incidence the exact reflected distribution is anisotropic (twice as wide in the plane "
              "of incidence as across it, times cos θ), which an isotropic lobe cannot follow: the paper's "
              "\"visually identical\" holds for the peak, not in L1.", "",
              "## Masking: Eq. 8 against the exact projected area", "",
              "∫⟨v, m⟩M(m) dm by Eq. 8, a cos(b arccos(v·n)), against the exact integral "
              "(`thin_coat_truth.projected_area_exact`, 1D quadrature with the azimuth in closed form), and the "
              "Smith G1 (Eq. 7) each gives.", "",
              "| κ | θ | exact | Eq. 8 | rel. error | G1 exact | G1 Eq. 8 |", "|---|---|---|---|---|---|---|"]
    for r in masking_rows():
        lines.append(f"| {r['kappa']:g} | {r['theta']:g}° | {r['exact']:.4f} | {r['eq8']:.4f} | "
                     f"{pct(r['eq8'] / r['exact'] - 1.0)} | {r['g1_exact']:.4f} | {r['g1_eq8']:.4f} |")
    lines += _truth_section()
    lines += ["", "## Reciprocity", "",
              "The model is built from the view (the paper does not claim reciprocity). Σ|f(i, o) − f(o, i)| ÷ "
              "Σ(f(i, o) + f(o, i))/2 over 20 000 uniform pairs of directions above the surface, for the whole "
              "BSDF and for the subsurface orders alone (the top surface term is reciprocal, tested).", "",
              "| preset | whole BSDF | subsurface orders |", "|---|---|---|"]
    for r in reciprocity_rows():
        lines.append(f"| {r['preset']} | {pct(r['all'])} | {pct(r['sub'])} |")
    lines += _mapping_section(resolution)
    return "\n".join(lines) + "\n"


def _truth_section() -> list[str]:
    rows = truth_rows()
    lines = ["", "## Analytic model against the Monte Carlo ground truth, per bounce order", "",
             "Grid of the issue: κ1, κ2 ∈ {10, 1e3, 1e6}, η ∈ {1.2, 1.5, 2}, σa d ∈ {0, 0.5}, views at "
             f"{', '.join(f'{v:g}°' for v in VIEWS)}; ground truth `thin_coat_truth` ({GT_PATHS:,} paths: "
             "recursive sampling of the visible vMF normals at each interface with the exact Smith masking, "
             "Fresnel, absorption; the point values by next-event estimation through the last interface). "
             "Energy: ∫ f_k cos θi against the energy the ground truth's order-k paths carry out. Width: the lobe's "
             "exit-direction κ against the moment-matched κ of the ground truth's exit directions. Peak: f_k at the "
             "mirror direction. Relative errors, median and worst over the grid points where the ground truth "
             "carries more than 1e-6 (worst cases are listed below).", "",
             "| order | absorption | energy median | energy worst | width median | width worst | peak median | "
             "peak worst | points |", "|---|---|---|---|---|---|---|---|---|"]
    for k in range(1, 5):
        for sigma in ABSORPTION:
            sel = [r for r in rows if r["order"] == k and r["sigma"] == sigma]
            e, w, pk = (_summary(sel, "energy", "energy_gt"), _summary(sel, "kappa", "kappa_gt", 0.0),
                        _summary(sel, "peak", "peak_gt", se="peak_se"))
            lines.append(f"| {k} | {'yes' if sigma else 'no'} | {e[0]} | {e[1]} | {w[0]} | {w[1]} | {pk[0]} | "
                         f"{pk[1]} | {e[2]} |")
    lines += ["", "The same by the bottom's concentration κ2 (both absorptions): the mean path takes the internal "
              "reflection under the top at the mean direction (Fresnel ≈ F(θo)), while a rough bottom scatters "
              "light beyond the critical angle, where the top reflects it totally; those paths feed the higher "
              "orders, which the model then underestimates (Sec. 5.2 assumes they carry little energy).", "",
              "| order | κ2 | energy median | energy worst | width median | peak median | points |",
              "|---|---|---|---|---|---|---|"]
    for k in range(1, 5):
        for k2 in KAPPAS:
            sel = [r for r in rows if r["order"] == k and r["k2"] == k2]
            e, w, pk = (_summary(sel, "energy", "energy_gt"), _summary(sel, "kappa", "kappa_gt", 0.0),
                        _summary(sel, "peak", "peak_gt", se="peak_se"))
            lines.append(f"| {k} | {k2:g} | {e[0]} | {e[1]} | {w[0]} | {pk[0]} | {e[2]} |")
    first = sorted((r for r in rows if r["order"] == 1 and r["energy_gt"] > 1e-6),
                   key=lambda r: -_rel(r["energy"], r["energy_gt"]))
    lines += ["", "First order, the worst ten grid points by energy:", "",
              "| κ1 | κ2 | η | σa d | θo | energy | g.t. ± s.e. | κ | g.t. κ | peak | g.t. peak ± s.e. |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in first[:10]:
        lines.append(f"| {r['k1']:g} | {r['k2']:g} | {r['eta']:g} | {r['sigma']:g} | {r['theta']:g}° | "
                     f"{r['energy']:.4g} | {r['energy_gt']:.4g} ± {r['energy_se']:.1g} | {r['kappa']:.4g} | "
                     f"{r['kappa_gt']:.4g} | {r['peak']:.4g} | {r['peak_gt']:.4g} ± {r['peak_se']:.1g} |")
    return lines


def _mapping_section(resolution: int) -> list[str]:
    from ..nodes import thin_coat as mapping

    lines = ["", "## Named approximations of the Cycles mapping", "",
             "Relative RMSE of the form's numpy prediction against the reference on a configuration chosen to feature "
             "each approximation (as in the other models' sections). The Beckmann shape of the subsurface lobes "
             "(endf-as-beckmann) is present in every configuration with subsurface orders, so an approximation of "
             "the node group alone (kappa-without-newton) shows as the difference between the two columns; the "
             "fitted mapping (OSL) rescales the closures per view and may add some (`nodes.fitted`).",
             "", *approximation_header(MODEL)]
    return (lines + approximation_rows(model, mapping.APPROXIMATIONS, resolution) + preset_rows(model, resolution)
            + mapping_section(model, resolution) + driven_section(model, DRIVEN_CASES, resolution))


# ------------------------------------------------------------------------------------------ speed


def cost_per_sample(bounces: int, n: int = 20000, repeats: int = 3) -> dict:
    """Seconds per sample: the model's ``sample`` (every lobe evaluated, one draw) against one ground-truth path
    (recursive sampling through both interfaces up to ``bounces`` bottom reflections), varnished_metal."""
    p = model.params_from_dict({**presets.load(MODEL, "varnished_metal"), "bounces": bounces})
    wo = _view(30.0)
    ws = np.repeat(wo, n, axis=0)
    u = np.random.default_rng(0).random((n, 3))
    ours = min(timed(lambda: reference.sample(p, ws, u)) for _ in range(repeats)) / n
    gt = min(timed(lambda: truth.ground_truth_albedo(p, wo[0], n_paths=n, seed=1)) for _ in range(repeats)) / n
    return {"bounces": bounces, "ours": ours, "gt": gt}


def render_times(samples: int, resolution: int, repeats: int = 3) -> list[dict]:
    """Cycles render time of the varnished_metal preset with 0..4 bounces, both forms."""
    from ..nodes import material as lamina_material

    def materials(bounces):
        p = model.params_from_dict({**presets.load(MODEL, "varnished_metal"), "bounces": bounces})
        return {form: lamina_material.new_material(MODEL, p, form) for form in ("nodes", "osl")}

    return fastest_renders(range(model.MAX_BOUNCES + 1), materials, samples, resolution, repeats)


def speed_markdown(samples: int, resolution: int) -> str:
    rate = reference_throughput(model.params_from_dict(presets.load(MODEL, "varnished_metal")), MODEL)
    lines = ["", "## Thin transparent coat (ENDF)", "",
             f"Reference `thin_coat.eval`, varnished_metal (2 bounces), float64: **{rate / 1e6:.2f} M evals/s**.", "",
             "### Cost per sample against the bounce count (the paper's Table 2, in kind)", "",
             "One sample of the model (`thin_coat.sample`: all lobes evaluated, one direction drawn) against one "
             "ground-truth path (`thin_coat_truth`: recursive sampling through both rough interfaces), "
             "varnished_metal at 30°, 20 000 samples, fastest of 3. The paper's Table 2 renders 1.66-4.28× faster "
             "with 1-4 bounces.", "",
             "| bounces | model µs/sample | ground truth µs/path | speedup |", "|---|---|---|---|"]
    for k in range(1, model.MAX_BOUNCES + 1):
        r = cost_per_sample(k)
        lines.append(f"| {k} | {1e6 * r['ours']:.2f} | {1e6 * r['gt']:.2f} | {r['gt'] / r['ours']:.2f} |")
    rows = render_times(samples, resolution)
    one = {form: next(r[form] for r in rows if r["preset"] == 1) for form in ("nodes", "osl")}
    lines += ["", "### Cycles render time against the bounce count", "",
              f"Sphere scene, {resolution}×{resolution} px, {samples} samples, fastest of 3, varnished_metal with "
              "0-4 subsurface bounces; ratio to 1 bounce (the goal: 4 bounces ≤ 1.2× of 1).", "",
              "| bounces | node group s | OSL s | node group : 1 bounce | OSL : 1 bounce |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['preset']} | {r['nodes']:.2f} | {r['osl']:.2f} | {r['nodes'] / one['nodes']:.2f} | "
                     f"{r['osl'] / one['osl']:.2f} |")
    lines += ["", "### Node group : OSL : Principled coat", "",
              "Same scene and settings, each preset (default 2 bounces) against Blender's Principled BSDF with a "
              "coat of the same roughness and IOR.", "",
              "| preset | node group s | OSL s | Principled coat s | node group : Principled | OSL : Principled |",
              "|---|---|---|---|---|---|"]
    for r in preset_render_times(MODEL, samples, resolution):
        lines.append(f"| {r['preset']} | {r['nodes']:.2f} | {r['osl']:.2f} | {r['principled']:.2f} | "
                     f"{r['nodes'] / r['principled']:.2f} | {r['osl'] / r['principled']:.2f} |")
    lines += fitted_speed_section(MODEL, samples, resolution)
    return "\n".join(lines) + "\n"
