"""``make bench``, what more closures would buy the fitted mapping (docs/accuracy.md, "The fitted mapping's closure
budget"): every preset whose fitted mapping (OSL) misses a goal of issue 14 (``common.GOALS``) is fitted again with
``SPARE`` closures beyond the analytic mapping's count and as many more extra closures (``fitted.fit_variants``'
``spare``; the closest of ``choice.VARIANTS`` on the comparison scenes, as for the Fitted mapping), and once with
every closure of the dictionary at once (``EVERY``). If the error hardly falls, the shapes of the closure dictionary,
not the render-cost budget, hold it up. The fit is a non-negative least squares per view (convex), so the fit error
of ``EVERY`` is the least that any choice of the dictionary's closures reaches with that weighting.

    python -m addon.bench.fit_ceiling --out docs      # this section alone, spliced into docs/accuracy.md
"""
from __future__ import annotations

import argparse

from .. import presets
from ..models import MODELS
from ..nodes import budget, choice, fittable, fitted
from .common import ACCURACY_SCENES, ALBEDO_SAMPLES, GOALS, comparison_errors, pct

SECTION = "fit-ceiling"  # its marked section of docs/accuracy.md
SPARE = (0, 1, 2)
EVERY = "every"  # the row of the whole dictionary (the Toon lobes included) at once
FORM = "osl"


def misses_a_goal(errors: dict, means: dict) -> bool:
    return any(errors[s] > GOALS[s] for s in ACCURACY_SCENES if means[s] >= choice.BACKLIT_MIN_MEAN)


def ceiling_rows(model_id: str, p, resolution: int) -> list[dict]:
    """Per ``SPARE`` count, then ``EVERY``: the closures the fit renders, its error in its own quadrature, and the
    comparison scenes' errors ({scene: rel RMSE}) with the reference's means."""
    problem = choice.fit_problem(model_id, p, FORM)
    variants = [(v.damping, v.toons) for v in choice.VARIANTS]
    dampings = sorted({damping for damping, _ in variants})
    rows = []
    for spare in (*SPARE, EVERY):
        if spare == EVERY:
            fits = fitted.fit_variants(*problem, FORM, [(d, True) for d in dampings],
                                       extras=fitted.extra_dictionary(toons=True))
        else:
            fits = fitted.fit_variants(*problem, FORM, variants, spare=spare)
        errors, means = comparison_errors(model_id, p, {i: (FORM, f) for i, f in enumerate(fits)}, resolution,
                                          ALBEDO_SAMPLES, furnace_width=None)
        best = min(errors, key=lambda i: choice.counted(errors[i], means))
        rows.append({"spare": spare, "closures": budget.shader_size(model_id, p, FORM, fits[best])[1],
                     "fit_error": fits[best].error_fitted, "errors": errors[best], "means": means})
    return rows


def accuracy(sizes) -> str:
    lines = ["## The fitted mapping's closure budget", "",
             "Presets whose fitted mapping (OSL) misses a goal, fitted again with up to "
             f"{max(SPARE)} closures beyond the analytic mapping's count and as many more extra closures (`python -m "
             "addon.bench.fit_ceiling`; 0 spare: the Fitted mapping as it ships), and with every closure of the "
             f"dictionary at once ({EVERY}: its {len(fitted.extra_dictionary(toons=True))} extra closures beside the "
             "material's own). Fit: relative RMSE in the fit's own quadrature; each view's fit is a non-negative least "
             f"squares, so the {EVERY} row's fit error is the least any choice of these closures reaches (per "
             "weighting). The scenes as in *Analytic and fitted mappings*.", "",
             "| model | preset | spare closures | closures | fit | " + " | ".join(ACCURACY_SCENES) + " |",
             "|---|---|---|---|---|" + "---|" * len(ACCURACY_SCENES)]
    for model_id in (m for m in MODELS if fittable(m)):
        model = MODELS[model_id]
        for name in presets.names(model_id):
            p = model.params_from_dict(presets.load(model_id, name))
            shipped = choice.choose(model_id, p, FORM, "fitted")
            if not misses_a_goal(shipped.errors["fitted"], shipped.means):
                continue
            for r in ceiling_rows(model_id, p, sizes.resolution):
                cells = [pct(e) if r["means"][s] >= choice.BACKLIT_MIN_MEAN else "n/a"
                         for s, e in ((s, r["errors"][s]) for s in ACCURACY_SCENES)]
                lines.append(f"| {model_id} | {name} | {r['spare']} | {r['closures']} | {pct(r['fit_error'])} | "
                             + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """Measure this section alone and splice it into ``--out``/accuracy.md."""
    from . import Sizes, splice_alone

    ap = argparse.ArgumentParser(prog="python -m addon.bench.fit_ceiling", description=main.__doc__)
    ap.add_argument("--out", default="docs")
    ap.add_argument("--resolution", type=int, default=48)
    args = ap.parse_args(argv)
    splice_alone(args.out, "accuracy.md", SECTION, accuracy(Sizes(resolution=args.resolution)),
                 "python -m addon.bench.fit_ceiling")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
