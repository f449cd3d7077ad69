"""Compare multiple-scattering lobe networks on a set large enough to resolve their differences.

The shipped held-out set has 64 stacks per layer count, so a network's mean lobe error there is known to about
±3 to ±5 points, while the runs compared in docs/training.md differ by 1 or 2. The training data's split (the 10%
that ``train.split`` holds out, the same for every run on a dataset of that size: 1183 scored two-layer
configurations of the 12000) resolves them: each network is scored on it as the add-on runs it without the energy
scale (``validation.lobe_errors``), with the standard error of its mean, the paired difference to the first
network with the standard error of that difference (the same configurations, so most of their spread cancels), and
its mean error in each quarter of the configurations sorted by how much multiple scattering they have (and the
Monte Carlo's own noise there, ``validation.monte_carlo_noise``).

``--energy-scale`` scores each network as the add-on would render a stack without a substrate were that network
shipped: with the energy scale (``reference.spongecake.energy_tables``), computed with the shipped energy-fraction
networks beside it. Its tables take about 11 s per configuration and network on one core, so it suits the held-out
set (``--held-out``: 64 stacks, about 12 minutes a network) better than the split (hours).

    python -m training.compare --layers 2 addon/bake/weights ~/.cache/lamina/experiments/2layer-4x256
    python -m training.compare --layers 1 --held-out addon/bake/weights <folder>   # the shipped held-out set
    python -m training.compare --layers 2 --trained-on addon/bake/weights   # as many configurations it trained on

A network whose manifest says it trained on another number of configurations than the split leaves may have seen
part of the split: its line says ``"split_unseen": false`` (with ``--trained-on``, true says that it trained on the
configurations scored).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from addon.bake import mlp, validation
from addon.bake import spongecake as ms
from training import dataset, train

QUARTERS = 4


def split_configurations(data: dict, trained_on: bool = False) -> dict:
    """The configurations ``train.split`` holds out of ``data``, in their stored order; with ``trained_on``, as many
    of those it trains on (the first in stored order), to set a network's error where it trained beside the split's."""
    val, trained = train.split(len(data["rows"]))
    picked = np.sort(trained)[:len(val)] if trained_on else np.sort(val)
    return {k: data[k][picked] for k in validation.ARRAYS if k in data}  # a training pack has no ms_half_diff, ss


def by_multiple_scattering(data: dict, per_config: np.ndarray, parts: int = QUARTERS) -> list:
    """The mean of ``per_config`` (NaN where unscored) in each of ``parts`` equal-count groups of the scored
    configurations, sorted by the mean of their Monte Carlo lobe f_ms |cos wo|: the least multiple scattering first."""
    truth, _, keep = validation.scored_lobes(data)
    order = np.argsort(truth.mean(axis=(1, 2, 3))[keep])
    scored = per_config[keep][order]
    return [float(scored[group].mean()) for group in np.array_split(np.arange(len(scored)), parts)]


def paired_difference(errors: np.ndarray, baseline: np.ndarray) -> dict:
    """Mean of ``errors - baseline`` over the configurations both score, and that mean's standard error."""
    diff = (errors - baseline)[np.isfinite(errors) & np.isfinite(baseline)]
    return {"mean": float(diff.mean()), "standard_error": validation.standard_error(diff)}


def split_unseen(net: mlp.MLP, n_data: int) -> bool:
    """Whether ``net`` trained on exactly the configurations ``train.split`` leaves of ``n_data``: then none of the
    split's (a manifest without the count, or with another, may have seen some)."""
    return net.manifest.get("training_configs") == len(train.split(n_data)[1])


@contextmanager
def shipped_in_place(net: mlp.MLP, n_layers: int):
    """While in the block, the add-on's weights folder (``bake.spongecake.WEIGHTS``) is a temporary one of the
    shipped networks with ``net`` in place of the ``n_layers`` lobe network."""
    shipped, replaced = ms.WEIGHTS, ms.weights_path(n_layers).name
    with tempfile.TemporaryDirectory(prefix="lamina-compare-") as folder:
        for path in shipped.glob("spongecake_ms_*.npz"):
            if path.name != replaced:
                (Path(folder) / path.name).symlink_to(path)
        mlp.save(Path(folder) / replaced, net.weights, net.biases, net.manifest)
        ms.WEIGHTS = Path(folder)
        try:
            yield
        finally:
            ms.WEIGHTS = shipped
            ms.forget_networks()


def predicted_lobes(data: dict, net: mlp.MLP, energy_scale: bool) -> np.ndarray:
    """``net``'s lobes at ``data``'s pairs as the add-on runs it: alone, or (``energy_scale``) as if shipped."""
    if not energy_scale:
        return validation.predicted_lobes(data, net)
    with shipped_in_place(net, len(data["rows"][0])):
        return validation.predicted_lobes(data)


def compare(data: dict, nets: list, n_data: int | None = None, energy_scale: bool = False) -> Iterator[dict]:
    """One record per network of ``nets`` (``mlp.MLP``) on ``data``, yielded as each is scored:
    ``validation.lobe_errors``' summary, the mean error (and noise) by quarter of multiple scattering, the paired
    difference to the first network, and (given the size of the dataset the split came from, ``n_data``) whether the
    split is unseen by it; with ``energy_scale``, each network's lobes with the energy scale (``predicted_lobes``)."""
    baseline = None
    for net in nets:
        scores = validation.lobe_errors(data, predicted_lobes(data, net, energy_scale))
        per_config = np.asarray(scores.pop("per_config"), dtype=float)
        record = {**scores, "by_multiple_scattering": by_multiple_scattering(data, per_config)}
        if "ms_half_diff" in data:
            record["noise_by_multiple_scattering"] = by_multiple_scattering(data, validation.monte_carlo_noise(data))
        if baseline is not None:
            record["minus_first"] = paired_difference(per_config, baseline)
        if n_data is not None:
            record["split_unseen"] = split_unseen(net, n_data)
        baseline = per_config if baseline is None else baseline
        yield record


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.compare", description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", type=Path, nargs="+", help="weights folders; the first is the baseline")
    ap.add_argument("--layers", type=int, default=2, choices=[1, 2])
    ap.add_argument("--data", type=Path, default=dataset.DEFAULT_CACHE, help="the training dataset (its split)")
    which_set = ap.add_mutually_exclusive_group()
    which_set.add_argument("--held-out", action="store_true",
                           help="score on the shipped held-out set instead of the split")
    which_set.add_argument("--trained-on", action="store_true",
                           help="score on as many configurations the split trains on (the first, in stored order)")
    ap.add_argument("--energy-scale", action="store_true",
                    help="score with the energy scale, as the add-on renders stacks without a substrate (slow)")
    a = ap.parse_args(argv)
    paths = [folder / ms.weights_path(a.layers).name for folder in a.folders]
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        print(f"no {a.layers}-layer network in: {', '.join(missing)}", file=sys.stderr)
        return 2
    if a.held_out:
        data, n_data = validation.load_shards(train.VALIDATION_SET, a.layers), None
    else:
        full = dataset.load(a.data, a.layers)
        data, n_data = split_configurations(full, a.trained_on), len(full["rows"])
    where = "held out" if a.held_out else "trained on" if a.trained_on else "split"
    for path, record in zip(paths, compare(data, [mlp.load(p) for p in paths], n_data, a.energy_scale)):
        print(json.dumps({"network": str(path), "set": where,
                          "energy_scale": a.energy_scale, **record}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
