"""What the energy scale does to the held-out configurations, in energy and in lobe shape.

The held-out lobe set (``validation.lobe_errors``) sums f_ms |cos wo| over a few stored direction pairs per
configuration, so its "energy error" is that sum's, not the light multiple scattering returns. For each held-out
configuration of the given layer counts this prints the light returned at the configuration's own stored views
(``validation.returned_light``: an independent random walk against the network's lobes' albedo with the energy
scale and without it) beside the lobe set's lobe and pair-sum energy errors with and without the scale. A
configuration whose returned light the scale brings closer while its lobe error grows has lobes of the right total
in the wrong directions.

    python -m training.held_out_albedo              # one and two layers, about 15 minutes
    python -m training.held_out_albedo --layers 1 --paths 4000
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from addon.bake import validation
from training import train


def config_rows(data: dict, paths: int) -> list[dict]:
    """One row per scored configuration, each pair (without the scale, with it): the lobe set's lobe error and
    pair-sum energy error, and the returned light's error; and the walk's own noise in that error's measure."""
    predicted = [validation.predicted_lobes(data, energy=e) for e in (False, True)]
    lobe_errors = [validation.lobe_errors(data, p)["per_config"] for p in predicted]
    _, total, _ = validation.scored_lobes(data)
    light = validation.returned_light(data, paths)
    light_errors = [validation.returned_light_errors(light, energy=e) for e in (False, True)]
    return [{"config": r["config"],
             "lobe_error": [e[r["config"]] for e in lobe_errors],
             "pair_sum_energy_error": [float(p[r["config"]].sum() / total[r["config"]] - 1.0) for p in predicted],
             "albedo_error": [float(e[i]) for e in light_errors],
             "walk_albedo_mean": float(r["walk"].mean()), "walk_noise": r["walk_noise"]} for i, r in enumerate(light)]


def summary(rows: list[dict]) -> dict:
    """Means over the configurations (without the scale, with it), and how many the scale moves each way."""
    lobe, albedo = (np.array([r[key] for r in rows]) for key in ("lobe_error", "albedo_error"))
    pair_sum = np.abs([r["pair_sum_energy_error"] for r in rows])
    return {"configs": len(rows), "mean_lobe_error": lobe.mean(axis=0).tolist(),
            "mean_abs_pair_sum_energy_error": pair_sum.mean(axis=0).tolist(),
            "mean_albedo_error": albedo.mean(axis=0).tolist(),
            "mean_walk_noise": float(np.mean([r["walk_noise"] for r in rows])),
            "scale_lowers_albedo_error": int((albedo[:, 1] < albedo[:, 0]).sum()),
            "scale_raises_lobe_error": int((lobe[:, 1] > lobe[:, 0]).sum()),
            "both": int(((albedo[:, 1] < albedo[:, 0]) & (lobe[:, 1] > lobe[:, 0])).sum())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.held_out_albedo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--validation", default=str(train.VALIDATION_SET))
    ap.add_argument("--layers", type=int, nargs="+", default=[1, 2], choices=[1, 2, 3, 4])
    ap.add_argument("--paths", type=int, default=validation.ALBEDO_PATHS, help="random-walk paths per view")
    a = ap.parse_args(argv)
    if a.paths < 1:
        ap.error("--paths must be at least 1")
    for n_layers in a.layers:
        rows = config_rows(validation.load_shards(a.validation, n_layers), a.paths)
        for r in rows:
            print(json.dumps({"layers": n_layers, **r}), flush=True)
        print(json.dumps({"layers": n_layers, "paths": a.paths, "summary": summary(rows)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
