"""What the energy scale does to the held-out configurations, in energy and in lobe shape.

The held-out lobe set (``validation.lobe_errors``) sums f_ms |cos wo| over a few stored direction pairs per
configuration, so its "energy error" is that sum's, not the light multiple scattering returns. For each held-out
configuration of the given layer counts this prints, at the configuration's own stored views wi, the multiple-
scattering albedo of an independent random walk (orders >= 2, ``reference.spongecake.ground_truth_albedo``) against
the model's (the network's lobes' albedo, ``lobes_albedo``, times the energy scale there, and without the scale),
beside the lobe set's lobe and pair-sum energy errors with and without the scale. A configuration whose albedo the
scale brings closer while its lobe error grows has lobes of the right total in the wrong directions.

    python -m training.held_out_albedo              # one and two layers, about 5 minutes
    python -m training.held_out_albedo --layers 1 --paths 4000
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from addon.bake import layer_rows, validation
from addon.reference.spongecake import energy_at, energy_tables, ground_truth_albedo, lobes_albedo
from training import train


def albedo_errors(params, wi, paths: int, seed: int) -> dict:
    """Relative L1 errors (summed over the views wi above the stack and the channels) of the model's multiple-
    scattering albedo against the random walk's, with the energy scale and without it, and the walk's albedos."""
    walk = ground_truth_albedo(params, wi, n_paths=paths, seed=seed)[2]
    lobes = lobes_albedo(params, wi)
    scaled = lobes * energy_at(energy_tables(params)[0], wi)
    total = max(float(walk.sum()), 1e-12)
    return {"walk": walk, "scaled": scaled, "lobes": lobes,
            "with_scale": float(np.abs(scaled - walk).sum()) / total,
            "without_scale": float(np.abs(lobes - walk).sum()) / total}


def config_rows(data: dict, paths: int) -> list[dict]:
    """One row per scored configuration: the lobe set's errors with and without the scale and the albedo errors."""
    predicted = [validation.predicted_lobes(data, energy=e) for e in (False, True)]  # without the scale, with it
    lobe_errors = [validation.lobe_errors(data, p)["per_config"] for p in predicted]
    _, total, keep = validation.scored_lobes(data)
    out = []
    for c in np.flatnonzero(keep):
        params = layer_rows.params_from_rows(data["rows"][c])
        wi = data["wi"][c].astype(float)
        wi = wi[wi[:, 2] > 0]
        albedo = albedo_errors(params, wi, paths, seed=c)
        out.append({"config": int(c),
                    "lobe_error": [e[c] for e in lobe_errors],
                    "pair_sum_energy_error": [float(p[c].sum() / total[c] - 1.0) for p in predicted],
                    "albedo_error": [albedo["without_scale"], albedo["with_scale"]],
                    "walk_albedo_mean": float(albedo["walk"].mean())})
    return out


def summary(rows: list[dict]) -> dict:
    """Means over the configurations (without the scale, with it), and how many the scale moves each way."""
    def mean(key, absolute=False):
        values = np.array([r[key] for r in rows])
        return np.abs(values).mean(axis=0).tolist() if absolute else values.mean(axis=0).tolist()

    lobe = np.array([r["lobe_error"] for r in rows])
    albedo = np.array([r["albedo_error"] for r in rows])
    return {"configs": len(rows), "mean_lobe_error": mean("lobe_error"),
            "mean_abs_pair_sum_energy_error": mean("pair_sum_energy_error", absolute=True),
            "mean_albedo_error": mean("albedo_error"),
            "scale_lowers_albedo_error": int((albedo[:, 1] < albedo[:, 0]).sum()),
            "scale_raises_lobe_error": int((lobe[:, 1] > lobe[:, 0]).sum()),
            "both": int(((albedo[:, 1] < albedo[:, 0]) & (lobe[:, 1] > lobe[:, 0])).sum())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.held_out_albedo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--validation", default=str(train.VALIDATION_SET))
    ap.add_argument("--layers", type=int, nargs="+", default=[1, 2], choices=[1, 2, 3, 4])
    ap.add_argument("--paths", type=int, default=20000, help="random-walk paths per view")
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
