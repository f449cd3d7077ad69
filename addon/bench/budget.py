"""``make bench``, Fit to budget (``nodes.budget``): its cost model against Cycles render times, and the configuration
it chooses for every preset at budgets of 1, 2, 5 and 10% (docs/benchmarks.md, "Fit to budget").

Every preset of every BSDF model, and the SpongeCake presets of ``MS_ON`` with multiple scattering on, is measured
in each configuration Fit to budget chooses among (both forms, each cheaper variant, both mappings where the model
has a fitted one: ``budget.candidates``), then rendered on the timing sphere (the fastest of ``repeats`` renders).
From those times come the cost model's coefficients (least squares per form; ``python -m addon.bench.budget``
prints them, ``nodes.budget.COST`` ships them) and how well the shipped ones predict: Spearman's rank correlation
and the worst ratio of predicted to measured time, either way. The configurations chosen, and the most accurate one,
are rendered on the comparison scenes too (``rendered_errors``): their error as Cycles renders it, beside the
prediction's, with the renders' own noise.

The measurements are kept per material (``measurements``), so that an interrupted run resumes where it stopped and a
run with a new cost model renders only the configurations it newly chooses.
"""
from __future__ import annotations

import argparse
import json
import os
from dataclasses import replace

import numpy as np

from .. import presets
from ..models import MODELS
from ..nodes import FORM_LABELS, FORMS, budget, choice
from .common import fastest_renders, pct

SECTION = "budget"  # its marked section of docs/benchmarks.md
BUDGETS = (0.01, 0.02, 0.05, 0.1)
MS_ON = ("fabric", "window_shade")  # SpongeCake presets also measured with multiple scattering on
REPEATS = 2  # renders per configuration (the fastest counts)
RENDER_SAMPLES = 128  # samples per pixel of the rendered errors (two seeds: their difference gives the noise)


FOUR_BOUNCES = "varnished_metal, 4 bounces"
# Issue 16's render-cost goals: (material, the most its configuration at the default budget may cost, against what).
# "principled": a Principled BSDF of about the same lobe count (``principled_material``); else a candidate's variant.
GOALS = (("leaf", 1.2, "principled"), ("window_shade", 1.2, "principled"), (FOUR_BOUNCES, 1.2, "1 bounce"),
         *((name, 1.3, "principled") for name in presets.names("micrograin")))


def _preset(model_id: str, name: str):
    return MODELS[model_id].params_from_dict(presets.load(model_id, name))


def materials() -> list[tuple[str, str, object]]:
    """(model id, name, params) of every preset, then the ``MS_ON`` presets with multiple scattering and varnished
    metal with 4 bounces (``GOALS``)."""
    out = [(model_id, name, _preset(model_id, name)) for model_id in MODELS for name in presets.names(model_id)]
    return out + [("spongecake", f"{name} + MS", replace(_preset("spongecake", name), multiple_scattering=True))
                  for name in MS_ON] + [("thin_coat", FOUR_BOUNCES,
                                         replace(_preset("thin_coat", "varnished_metal"), bounces=4))]


def measure(model_id: str, name: str, p, sizes, repeats: int) -> dict:
    """One material's entry of ``measurements``: its configurations in both forms (``budget.candidates``), the
    render time of each and of its Principled BSDF of about the same lobe count (``render_seconds``)."""
    cs = budget.candidates(model_id, p, FORMS)
    seconds = render_seconds({name: (model_id, p, cs)}, sizes.timing_samples, sizes.timing_resolution, repeats)
    return {"model": model_id, "candidates": [c.to_json() for c in cs],
            "seconds": [seconds[(name, i)] for i in range(len(cs))], "principled": seconds[(name, "principled")],
            "rendered": {}}


def render_seconds(cands: dict, samples: int, resolution: int, repeats: int) -> dict:
    """{(name, i): seconds} of the i-th candidate of each material of ``cands`` ({name: (model id, params,
    candidates)}) as Cycles renders it, and {(name, "principled"): seconds} of its Principled BSDF of about the same
    lobe count (the OSL shading system on for every render, as the timing sphere of the presets' tables)."""
    from ..nodes import material as lamina_material

    def materials_of(name):
        model_id, p, cs = cands[name]
        return {**{i: configured(model_id, c) for i, c in enumerate(cs)},
                "principled": lamina_material.principled_material(model_id, p)}

    rows = fastest_renders(list(cands), materials_of, samples, resolution, repeats)
    return {(row["preset"], label): seconds for row in rows for label, seconds in row.items() if label != "preset"}


def recounted(model_id: str, c: budget.Candidate) -> budget.Candidate:
    """``c`` with its size counted and priced as ``budget`` counts and prices now."""
    fit = c.pruned if c.mapping == "analytic" else choice.choose(model_id, c.params, c.form, "fitted").fit
    operations, closures = budget.shader_size(model_id, c.params, c.form, fit)
    return replace(c, operations=operations, closures=closures,
                   seconds=budget.COST[c.form].seconds(operations, closures))


def shown(cs: list) -> set[int]:
    """The candidates the tables show: the most accurate, and the one chosen at each of ``BUDGETS``."""
    return {min(range(len(cs)), key=lambda i: cs[i].error)} | {cs.index(budget.pick(cs, b)) for b in BUDGETS}


def rendered_errors(model_id: str, p, cs: list, indices, samples: int = RENDER_SAMPLES) -> dict:
    """{i: {"error", "noise"}} of the candidates ``indices`` of ``cs`` as Cycles renders them on the comparison
    scenes (``choice``'s): the mean relative RMSE against the reference of ``p`` over the scenes that count
    (``choice.counted``), and the renders' noise, from two seeds (their relative RMSE against each other / √2)."""
    import bpy

    from ..operators import blend_io
    from ..operators.cycles_render import render_cycles
    from ..reference import metrics
    from ..reference import scenes as ref_scenes

    specs = ref_scenes.comparison_scenes(choice.CHOICE_RESOLUTION, choice.CHOICE_FURNACE_WIDTH)
    refs = {spec.name: choice.reference_image(model_id, p, spec, choice.SCENE_ALBEDO_SAMPLES) for spec in specs}
    masks = {spec.name: ref_scenes.scene_mask(spec) for spec in specs}
    means = {name: float(refs[name][masks[name]].mean()) for name in refs}
    path = os.path.join(bpy.app.tempdir, "bench_error.exr")
    out = {}
    for i in sorted(indices):
        before = blend_io.snapshot()
        try:
            mat = configured(model_id, cs[i])
            images = {(spec.name, seed): render_cycles(mat, spec, samples, seed, path)[0]
                      for spec in specs for seed in (0, 1)}
        finally:
            blend_io.remove_new_data(before)
        error = {n: metrics.rel_rmse(images[(n, 0)], refs[n], masks[n]) for n in refs}
        noise = {n: metrics.rel_rmse(images[(n, 0)], images[(n, 1)], masks[n]) / np.sqrt(2.0) for n in refs}
        out[i] = {"error": choice.counted(error, means), "noise": choice.counted(noise, means)}
    return out


def measurements(entries, path: str | None, sizes, repeats: int = REPEATS, progress=print) -> dict:
    """{name: entry} of ``entries`` (``materials``): ``measure``'s (every material's render times first, while
    nothing else runs), the candidates ``recounted``, and the ``rendered_errors`` of those ``shown``. With ``path``,
    what is there already is kept and each material is saved there as soon as it is measured."""
    data = _read(path) if path and os.path.exists(path) else {}

    def measured(name):
        if path:
            _write(path, data)
        progress(f"lamina: measured {name}")

    for model_id, name, p in entries:
        if name not in data:
            data[name] = measure(model_id, name, p, sizes, repeats)
            measured(f"the configurations of {name}")
    for model_id, name, p in entries:
        entry = data[name]
        cs = [recounted(model_id, budget.Candidate.from_json(model_id, c)) for c in entry["candidates"]]
        entry["candidates"] = [c.to_json() for c in cs]
        missing = shown(cs) - {int(i) for i in entry["rendered"]}
        if missing:
            entry["rendered"].update(rendered_errors(model_id, p, cs, missing))
            measured(f"the rendered errors of {name}")
    return data


def configured(model_id: str, c: budget.Candidate):
    """A new material in the configuration of candidate ``c``."""
    from ..nodes import material as lamina_material

    mat = lamina_material.new_material(model_id, c.params, c.form)
    lamina_material.apply_decision(mat, budget.Decision(1.0, c.params, c, [c]))
    return mat


def least_squares(cands: dict, seconds: dict) -> dict:
    """{form: budget.CostModel} fitted to the measured ``seconds``."""
    out = {}
    for form in FORMS:
        keys = [(name, i) for name, (_, _, cs) in cands.items() for i, c in enumerate(cs) if c.form == form]
        a = np.array([[1.0, cands[n][2][i].operations, cands[n][2][i].closures] for n, i in keys])
        y = np.array([seconds[k] for k in keys])
        out[form] = budget.CostModel(*(float(v) for v in np.linalg.lstsq(a, y, rcond=None)[0]))
    return out


def spearman(a, b) -> float:
    """Spearman's rank correlation of two sequences (average ranks for ties)."""
    def ranks(x):
        x = np.asarray(x, dtype=float)
        order = np.argsort(x, kind="stable")
        r = np.empty(len(x))
        r[order] = np.arange(len(x), dtype=float)
        for v in np.unique(x):
            r[x == v] = r[x == v].mean()
        return r
    return float(np.corrcoef(ranks(a), ranks(b))[0, 1])


def agreement(cands: dict, seconds: dict, forms=FORMS) -> tuple[int, float, float]:
    """(configurations, Spearman ρ, worst ratio of predicted to measured either way) of the shipped cost model over
    the candidates in ``forms``."""
    keys = [(n, i) for n, (_, _, cs) in cands.items() for i, c in enumerate(cs) if c.form in forms]
    predicted = np.array([cands[n][2][i].seconds for n, i in keys])
    measured_s = np.array([seconds[k] for k in keys])
    ratio = predicted / measured_s
    return len(keys), spearman(predicted, measured_s), float(max(ratio.max(), 1.0 / ratio.min()))


def _coefficients(m: budget.CostModel) -> str:
    return f"{m.base:.2f} s + {1000 * m.per_operation:.2f} ms/op + {m.per_closure:.2f} s/closure"


def markdown(cands: dict, seconds: dict, rendered: dict, samples: int, resolution: int, repeats: int) -> str:
    """The section from ``tables``' measurements."""
    fitted = least_squares(cands, seconds)
    lines = ["", "## Fit to budget", "",
             f"Every preset of every BSDF model (and {', '.join(MS_ON)} with multiple scattering, {FOUR_BOUNCES}) in "
             "each configuration Fit to budget chooses among: both forms, each cheaper variant (thin-coat bounces, "
             "multiple scattering off, GGX's geometric term), the weakest closures left out (analytic mapping), both "
             "mappings where the model has a fitted one. Cycles "
             f"CPU render of the sphere scene, {resolution}×{resolution} px, {samples} samples, fastest of "
             f"{repeats}, the OSL shading system on.", "",
             "### Cost model", "",
             "Predicted render time = base + per operation × the shader's arithmetic operations + per closure × its "
             "closures (`nodes.budget.COST`, shipped), against the measured times; the least-squares coefficients "
             "of this run beside them. The operations are those of the form's own shader that feed a closure "
             "(`nodes.budget.shader_size`).", "",
             "| form | configurations | shipped | least squares here | Spearman ρ | worst predicted : measured |",
             "|---|---|---|---|---|---|"]
    for form in FORMS:
        n, rho, worst = agreement(cands, seconds, (form,))
        lines.append(f"| {FORM_LABELS[form]} | {n} | {_coefficients(budget.COST[form])} | "
                     f"{_coefficients(fitted[form])} | {rho:.2f} | {worst:.2f} |")
    n, rho, worst = agreement(cands, seconds)
    return "\n".join(lines + [f"| both | {n} | | | {rho:.2f} | {worst:.2f} |"] + choice_table(cands, seconds, rendered)
                     + goals_table(cands, seconds)) + "\n"


def _rendered(r: dict) -> str:
    return f"{pct(r['error'])} ± {pct(r['noise'])}"


def choice_table(cands: dict, seconds: dict, rendered: dict) -> list[str]:
    """The configuration chosen per material and budget: its predicted and rendered errors, its predicted cost and
    measured time against the most accurate configuration's; then how many rendered within their budget."""
    lines = ["", "### The configuration chosen per budget", "",
             "Predicted error: mean relative RMSE on the comparison scenes against the reference of the material as "
             "set (numpy prediction, no noise); the budget is added to the most accurate configuration's error. "
             f"Rendered error: the same measure of the Cycles render ({choice.CHOICE_RESOLUTION} px, "
             f"{RENDER_SAMPLES} samples) ± its noise (two seeds). Time ×: measured render time against the most "
             "accurate configuration's.", "",
             "| material | most accurate: predicted, rendered error | budget | chosen | predicted error | "
             "rendered error | predicted cost × | time × |", "|---|---|---|---|---|---|---|---|"]
    within, total = 0, 0
    for name, (_, _, cs) in cands.items():
        best = min(range(len(cs)), key=lambda i: cs[i].error)
        for b in BUDGETS:
            i = cs.index(budget.pick(cs, b))
            r, rb = rendered[(name, i)], rendered[(name, best)]
            total += 1
            within += r["error"] <= rb["error"] + b + 2.0 * (r["noise"] + rb["noise"])
            lines.append(f"| {name} | {cs[best].describe()}: {pct(cs[best].error)}, {_rendered(rb)} | "
                         f"{100 * b:g}% | {cs[i].describe()} | {pct(cs[i].error)} | {_rendered(r)} | "
                         f"{cs[i].seconds / cs[best].seconds:.2f} | {seconds[(name, i)] / seconds[(name, best)]:.2f} |")
    return lines + ["", f"Rendered within the budget of the most accurate configuration's rendered error (plus twice "
                        f"both renders' noise): {within} of {total}."]


def _baseline(cands: dict, seconds: dict, name: str, against: str) -> float:
    if against == "principled":
        return seconds[(name, "principled")]
    cs = cands[name][2]
    return seconds[(name, next(i for i, c in enumerate(cs) if c.variant == against and c.form == "nodes"
                               and c.mapping == "analytic" and c.pruned is None))]


def goals_table(cands: dict, seconds: dict) -> list[str]:
    """Issue 16's render-cost goals (``GOALS``): the most accurate configuration's time and the one chosen at the
    default budget, against the goal's baseline measured in the same run."""
    lines = ["", f"### Render-cost goals at the default budget ({100 * budget.DEFAULT_BUDGET:g}%)", "",
             "Measured render time against the goal's baseline from the same run: a Principled BSDF of about the "
             "same lobe count, or the same coat with 1 bounce (node group, analytic).", "",
             "| material | goal | most accurate | chosen at the default budget | met |", "|---|---|---|---|---|"]
    for name, goal, against in GOALS:
        cs = cands[name][2]
        base = _baseline(cands, seconds, name, against)
        best = min(range(len(cs)), key=lambda i: cs[i].error)
        i = cs.index(budget.pick(cs, budget.DEFAULT_BUDGET))
        ratio = seconds[(name, i)] / base
        within = [j for j, c in enumerate(cs) if c.error <= cs[best].error + budget.DEFAULT_BUDGET
                  and c.change <= budget.DEFAULT_BUDGET]
        fastest = min(within, key=lambda j: seconds[(name, j)])
        fastest_ratio = seconds[(name, fastest)] / base
        if ratio <= goal:
            why = "met"
        elif fastest_ratio <= goal:
            why = f"not met: the cost model ranked this above {cs[fastest].describe()} ({fastest_ratio:.2f}×)"
        else:
            why = (f"not met: the fastest configuration within the budget, {cs[fastest].describe()} "
                   f"({cs[fastest].closures} closures), renders at {fastest_ratio:.2f}×")
        lines.append(f"| {name} | ≤ {goal:g}× {against} | {seconds[(name, best)] / base:.2f}× | "
                     f"{cs[i].describe()}: {ratio:.2f}× | {why} |")
    return lines


def speed(sizes, repeats: int = REPEATS, progress=print) -> str:
    """The Fit-to-budget section of docs/benchmarks.md (``bench.Sizes``)."""
    data = measurements(materials(), None, sizes, repeats, progress)
    return markdown(*tables(data), sizes.timing_samples, sizes.timing_resolution, repeats)


def _write(path: str, data: dict) -> None:
    from ..operators.compare_run import write_text_atomic

    write_text_atomic(path, json.dumps(data))


def _read(path: str) -> dict:
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def tables(data: dict) -> tuple[dict, dict, dict]:
    """(cands, seconds, rendered) of ``measurements``' data: {name: (model id, params as set, candidates)},
    {(name, i or "principled"): seconds}, {(name, i): {"error", "noise"}}."""
    cands, seconds, rendered = {}, {}, {}
    for name, entry in data.items():
        cs = [budget.Candidate.from_json(entry["model"], c) for c in entry["candidates"]]
        seconds.update(((name, i), s) for i, s in enumerate(entry["seconds"]))
        seconds[(name, "principled")] = entry["principled"]
        rendered.update(((name, int(i)), r) for i, r in entry["rendered"].items())
        cands[name] = (entry["model"], cs[0].params, cs)
    return cands, seconds, rendered


def main(argv=None) -> int:
    """Measure this section alone and splice it into ``--out``/benchmarks.md; print the least-squares coefficients.
    With ``--measurements FILE``, each material's measurements are saved there as they are made and kept from an
    earlier run: an interrupted run resumes, and a run after the cost model changed renders only what it newly
    chooses."""
    from . import Sizes, splice_alone

    ap = argparse.ArgumentParser(prog="python -m addon.bench.budget", description=main.__doc__)
    ap.add_argument("--out", default="docs")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--resolution", type=int, default=48)
    ap.add_argument("--repeats", type=int, default=REPEATS)
    ap.add_argument("--measurements", help="a JSON file of the measurements, kept between runs")
    args = ap.parse_args(argv)
    sizes = Sizes(samples=args.samples, resolution=args.resolution)
    cands, seconds, rendered = tables(measurements(materials(), args.measurements, sizes, args.repeats))
    for form, m in least_squares(cands, seconds).items():
        print(f"lamina: {form}: {m}")
    section = markdown(cands, seconds, rendered, sizes.timing_samples, sizes.timing_resolution, args.repeats)
    splice_alone(args.out, "benchmarks.md", SECTION, section, "python -m addon.bench.budget")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
