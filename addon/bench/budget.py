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


def materials() -> list[tuple[str, str, object]]:
    """(model id, name, params) of every preset, then the ``MS_ON`` presets with multiple scattering."""
    out = [(model_id, name, MODELS[model_id].params_from_dict(presets.load(model_id, name)))
           for model_id in MODELS for name in presets.names(model_id)]
    sponge = MODELS["spongecake"]
    return out + [("spongecake", f"{name} + MS",
                   replace(sponge.params_from_dict(presets.load("spongecake", name)), multiple_scattering=True))
                  for name in MS_ON]


def measured(entries, progress=print) -> dict:
    """{name: (model id, params, candidates)} of ``entries`` (``materials``), in both forms."""
    out = {}
    for model_id, name, p in entries:
        out[name] = (model_id, p, budget.candidates(model_id, p, FORMS))
        progress(f"lamina: measured the configurations of {name}")
    return out


def render_seconds(cands: dict, samples: int, resolution: int, repeats: int) -> dict:
    """{(name, i): seconds} of the i-th candidate of each material of ``cands`` (``measured``) as Cycles renders
    it (the OSL shading system on for every render, as the timing sphere of the presets' tables)."""

    def materials_of(name):
        model_id, _, cs = cands[name]
        return {i: configured(model_id, c) for i, c in enumerate(cs)}

    rows = fastest_renders(list(cands), materials_of, samples, resolution, repeats)
    return {(row["preset"], i): row[i] for row in rows for i in range(len(cands[row["preset"]][2]))}


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


def _short(c: budget.Candidate) -> str:
    return f"{FORM_LABELS[c.form]}, {c.mapping}, {c.variant}"


def markdown(cands: dict, seconds: dict, samples: int, resolution: int, repeats: int) -> str:
    fitted = least_squares(cands, seconds)
    lines = ["", "## Fit to budget", "",
             f"Every preset of every BSDF model (and {', '.join(MS_ON)} with multiple scattering) in each "
             "configuration Fit to budget chooses among: both forms, each cheaper variant (thin-coat bounces, "
             "multiple scattering off, GGX's geometric term), both mappings where the model has a fitted one. Cycles "
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
            lines.append(f"| {name} | {_short(cs[best])} ({pct(cs[best].error)}) | {100 * b:g}% | {_short(cs[i])} | "
                         f"{pct(cs[i].error)} | {cs[i].seconds / cs[best].seconds:.2f} | "
                         f"{seconds[(name, i)] / seconds[(name, best)]:.2f} |")
    return "\n".join(lines) + "\n"


def speed(sizes, repeats: int = REPEATS, progress=print) -> str:
    """The Fit-to-budget section of docs/benchmarks.md (``bench.Sizes``)."""
    cands = measured(materials(), progress)
    seconds = render_seconds(cands, sizes.timing_samples, sizes.timing_resolution, repeats)
    return markdown(cands, seconds, sizes.timing_samples, sizes.timing_resolution, repeats)


def save(path: str, cands: dict, seconds: dict) -> None:
    """The measurements (``measured``, ``render_seconds``) as JSON."""
    from ..operators.compare_run import write_text_atomic

    data = {name: {"model": model_id, "candidates": [c.to_json() for c in cs],
                   "seconds": [seconds[(name, i)] for i in range(len(cs))]}
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
