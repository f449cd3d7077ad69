"""``make bench``, Fit to budget (``nodes.budget``): its cost model against Cycles render times, and the configuration
it chooses for every preset at budgets of 1, 2, 5 and 10% (docs/benchmarks.md, "Fit to budget").

Every preset of every BSDF model, and the SpongeCake presets of ``MS_ON`` with multiple scattering on, is measured
in each configuration Fit to budget chooses among (both forms, each cheaper variant, both mappings where the model
has a fitted one: ``budget.candidates``), then rendered on the timing sphere (the fastest of ``repeats`` renders).
From those times come the cost model's coefficients (least squares per form; ``python -m addon.bench.budget``
prints them, ``nodes.budget.COST`` ships them) and how well the shipped ones predict: Spearman's rank correlation
and the worst ratio of predicted to measured time, either way.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
from dataclasses import replace

import numpy as np

from .. import presets
from ..models import MODELS
from ..nodes import FORM_LABELS, FORMS, budget
from .common import fastest_renders, pct

SECTION = "budget"  # its marked section of docs/benchmarks.md
BUDGETS = (0.01, 0.02, 0.05, 0.1)
MS_ON = ("fabric", "window_shade")  # SpongeCake presets also measured with multiple scattering on
REPEATS = 2  # renders per configuration (the fastest counts)


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


def measured(entries, progress=print) -> dict:
    """{name: (model id, params, candidates)} of ``entries`` (``materials``), in both forms."""
    out = {}
    for model_id, name, p in entries:
        out[name] = (model_id, p, budget.candidates(model_id, p, FORMS))
        progress(f"lamina: measured the configurations of {name}")
    return out


def render_seconds(cands: dict, samples: int, resolution: int, repeats: int) -> dict:
    """{(name, i): seconds} of the i-th candidate of each material of ``cands`` (``measured``) as Cycles renders
    it, and {(name, "principled"): seconds} of its Principled BSDF of about the same lobe count (the OSL shading
    system on for every render, as the timing sphere of the presets' tables)."""
    from ..nodes import material as lamina_material

    def materials_of(name):
        model_id, p, cs = cands[name]
        return {**{i: configured(model_id, c) for i, c in enumerate(cs)},
                "principled": lamina_material.principled_material(model_id, p)}

    rows = fastest_renders(list(cands), materials_of, samples, resolution, repeats)
    return {(row["preset"], label): seconds for row in rows for label, seconds in row.items() if label != "preset"}


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


def markdown(cands: dict, seconds: dict, samples: int, resolution: int, repeats: int) -> str:
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
             "of this run beside them.", "",
             "| form | configurations | shipped | least squares here | Spearman ρ | worst predicted : measured |",
             "|---|---|---|---|---|---|"]
    for form in FORMS:
        n, rho, worst = agreement(cands, seconds, (form,))
        lines.append(f"| {FORM_LABELS[form]} | {n} | {_coefficients(budget.COST[form])} | "
                     f"{_coefficients(fitted[form])} | {rho:.2f} | {worst:.2f} |")
    n, rho, worst = agreement(cands, seconds)
    lines += [f"| both | {n} | | | {rho:.2f} | {worst:.2f} |", "",
              "### The configuration chosen per budget", "",
              "Predicted error: mean relative RMSE on the comparison scenes against the reference of the material as "
              "set (numpy prediction, no noise); the budget is added to the most accurate configuration's error. "
              "Time ×: measured render time against the most accurate configuration's.", "",
              "| material | most accurate (error) | budget | chosen | predicted error | predicted cost × | "
              "time × |", "|---|---|---|---|---|---|---|"]
    for name, (_, _, cs) in cands.items():
        best = min(range(len(cs)), key=lambda i: cs[i].error)
        for b in BUDGETS:
            i = cs.index(budget.pick(cs, b))
            lines.append(f"| {name} | {cs[best].describe()} ({pct(cs[best].error)}) | {100 * b:g}% | "
                         f"{cs[i].describe()} | {pct(cs[i].error)} | {cs[i].seconds / cs[best].seconds:.2f} | "
                         f"{seconds[(name, i)] / seconds[(name, best)]:.2f} |")
    return "\n".join(lines + goals_table(cands, seconds)) + "\n"


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
            why = f"not met: no configuration within the budget renders within {goal:g}× here"
        lines.append(f"| {name} | ≤ {goal:g}× {against} | {seconds[(name, best)] / base:.2f}× | "
                     f"{cs[i].describe()}: {ratio:.2f}× | {why} |")
    return lines


def speed(sizes, repeats: int = REPEATS, progress=print) -> str:
    """The Fit-to-budget section of docs/benchmarks.md (``bench.Sizes``)."""
    cands = measured(materials(), progress)
    seconds = render_seconds(cands, sizes.timing_samples, sizes.timing_resolution, repeats)
    return markdown(cands, seconds, sizes.timing_samples, sizes.timing_resolution, repeats)


def save(path: str, cands: dict, seconds: dict) -> None:
    """The measurements (``measured``, ``render_seconds``) as JSON."""
    from ..operators.compare_run import write_text_atomic

    data = {name: {"model": model_id, "candidates": [c.to_json() for c in cs],
                   "seconds": [seconds[(name, i)] for i in range(len(cs))],
                   "principled": seconds[(name, "principled")]}
            for name, (model_id, _, cs) in cands.items()}
    write_text_atomic(path, json.dumps(data))


def load(path: str) -> tuple[dict, dict]:
    """``save``'s measurements, the candidates priced by the cost model as it is now."""
    with open(path, encoding="utf-8") as f:
        data = json.load(f)
    cands, seconds = {}, {}
    for name, entry in data.items():
        cs = [budget.Candidate.from_json(entry["model"], c) for c in entry["candidates"]]
        seconds.update(((name, i), s) for i, s in enumerate(entry["seconds"]))
        seconds[(name, "principled")] = entry["principled"]
        cands[name] = (entry["model"], cs[0].params, cs)
    return cands, seconds


def main(argv=None) -> int:
    """Measure this section alone and splice it into ``--out``/benchmarks.md; print the least-squares coefficients.
    With ``--measurements FILE``: the measurements are saved there, or read from there when it exists (the
    section priced again by the cost model as it is now, without measuring)."""
    from . import Sizes, splice
    from ..operators.compare_run import write_text_atomic

    ap = argparse.ArgumentParser(prog="python -m addon.bench.budget", description=main.__doc__)
    ap.add_argument("--out", default="docs")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--resolution", type=int, default=48)
    ap.add_argument("--repeats", type=int, default=REPEATS)
    ap.add_argument("--measurements", help="a JSON file of the measurements: written, or read when it exists")
    args = ap.parse_args(argv)
    sizes = Sizes(samples=args.samples, resolution=args.resolution)
    if args.measurements and os.path.exists(args.measurements):
        cands, seconds = load(args.measurements)
    else:
        cands = measured(materials())
        seconds = render_seconds(cands, sizes.timing_samples, sizes.timing_resolution, args.repeats)
        if args.measurements:
            save(args.measurements, cands, seconds)
    for form, m in least_squares(cands, seconds).items():
        print(f"lamina: {form}: {m}")
    path = os.path.join(args.out, "benchmarks.md")
    with open(path, encoding="utf-8") as f:
        text = f.read()
    note = (f"*This section was measured again alone (`python -m addon.bench.budget`, "
            f"{datetime.date.today().isoformat()}); the rest of the page is from the run above.*")
    write_text_atomic(path, splice(text, SECTION, markdown(cands, seconds, sizes.timing_samples,
                                                           sizes.timing_resolution, args.repeats), note))
    print(f"lamina: wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
