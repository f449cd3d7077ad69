"""Whether a lobe network can learn what per-configuration fits reach: fit, then distil.

Session 45 read the gap between the networks and the lobe form fitted to each configuration on its own
(``training.lobe_bound``) as underfitting. If the per-configuration optima were a smooth function of the layer
parameters, a network regressed on them would learn them, on configurations held back from it too. It does not
(docs/training.md, session 48): the fits bend to the directions they are fitted at.

    python -m training.distill fit --layers 2 --count 4096 --out <folder>      # resumable, chunk by chunk
    python -m training.distill fit ... --part 1/2                               # a second process beside the first
    python -m training.distill train --layers 2 --fits <folder> --minutes 20 --out <weights folder>
    python -m training.distill score --layers 2 --fits <folder> addon/bake/weights <weights folder> ...

``fit`` optimises the network outputs of ``--count`` of the split's training configurations, each on its own
(``lobe_bound.best_outputs``, started from the shipped network's prediction), on the score alone plus ``--scaled``
times the score of the lobes scaled to the Monte Carlo's energy (the shape the energy scale renders), and stores
them in chunks. ``train`` regresses a network on them, warm-started from the shipped network (``regress``: on the
fits' lobes, or on their raw outputs), and exports it as ``training.train`` does (manifest, split and held-out
scores), so that ``training.compare`` scores it beside the shipped one. ``score`` scores the fits and the networks
in the given weights folders on the fitted configurations, as training scores them (the prediction from above for
every wo), alone and scaled to the Monte Carlo's energy per wi and channel.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from addon.bake import mlp, validation
from addon.bake.exr import atomic_path
from addon.bake import spongecake as ms
from training import dataset, lobe_bound, train

CHUNK = 256  # configurations fitted together (one stored file each)
FIT_STEPS = 1000
FIT_RATE = 0.02


def fitted_configurations(n_data: int, count: int) -> np.ndarray:
    """The first ``count`` of the configurations ``train.split`` trains on, in its (random) order."""
    return train.split(n_data)[1][:count]


def chunk_path(folder: Path, n_layers: int, first: int) -> Path:
    return folder / f"layers{n_layers}-{first:06d}.npz"


def fit(data: dict, n_layers: int, count: int, folder: Path, part: tuple = (0, 1), steps: int = FIT_STEPS,
        scaled: float = 1.0, log=print) -> None:
    """Fit and store, chunk by chunk, the outputs of ``fitted_configurations``; chunks already stored are kept
    (a run resumes), and chunk i is this process's when i % part[1] == part[0]."""
    index = fitted_configurations(len(data["rows"]), count)
    net = ms.network(n_layers)
    folder.mkdir(parents=True, exist_ok=True)
    for i, first in enumerate(range(0, len(index), CHUNK)):
        path = chunk_path(folder, n_layers, first)
        if i % part[1] != part[0] or path.exists():
            continue
        started = time.time()
        picked = index[first:first + CHUNK]
        batch = {k: data[k][picked] for k in ("rows", "wi", "wo", "ms")}
        start = net(ms.features(batch["rows"].astype(np.float64)))
        raw = lobe_bound.best_outputs(batch, start, steps, FIT_RATE, scaled=scaled).cpu().numpy()
        with atomic_path(path) as temporary, open(temporary, "wb") as f:
            np.savez(f, index=picked, raw=raw, start=start, steps=steps, scaled=scaled)
        log(f"  fitted {len(picked)} configurations from {first} in {time.time() - started:.0f} s", flush=True)


def load_fits(folder: Path, n_layers: int) -> tuple[np.ndarray, np.ndarray]:
    """The stored fits' configurations (into the dataset) and raw outputs."""
    chunks = [np.load(p) for p in sorted(folder.glob(f"layers{n_layers}-*.npz"))]
    if not chunks:
        raise FileNotFoundError(f"no {n_layers}-layer fits in {folder}")
    return np.concatenate([c["index"] for c in chunks]), np.concatenate([c["raw"] for c in chunks])


TARGETS = ("outputs", "lobes")  # what ``regress`` compares with the fits'


def regress(data: dict, index: np.ndarray, raw: np.ndarray, init: mlp.MLP, minutes: float, target: str = "lobes",
            seed: int = 0, batch: int = 32, learning_rate: float = 3e-4, log=print):
    """``init`` trained for ``minutes`` towards the fits ``raw`` of ``index``'s configurations: on the mean squared
    error of its raw outputs (``target`` "outputs"), or on the relative L1 distance of its lobes to the fits' lobes
    ("lobes": outputs the lobes do not depend on are left free); returns the network at its best loss on a tenth of
    them held back, and what happened (``train.export``'s record; its split is ``train.split``'s, none of which is
    fitted)."""
    if len(index) < 10:
        raise ValueError(f"{len(index)} fits are too few to hold a tenth of them back")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    n_layers = data["rows"].shape[1]
    net = train.make_network(n_layers, raw.shape[1] > train.outputs(n_layers), init.hidden)
    train.warm_start(net, init)
    fitted = {k: data[k][index] for k in ("rows", "wi", "wo", "ms")}
    x = torch.as_tensor(ms.features(fitted["rows"].astype(np.float64)), dtype=train.PRECISION)
    y = torch.as_tensor(raw, dtype=train.PRECISION)
    if target == "lobes":
        goal = torch.cat([fit_lobes(fitted, y, part) for part in np.array_split(np.arange(len(index)),
                                                                                 max(1, len(index) // CHUNK))])
        total = train.target(fitted).sum(dim=(1, 2, 3)).clamp_min(1e-12)

        def distance(rows):
            lobes = train.predicted_lobe(net, *train.tensors({k: v[rows] for k, v in fitted.items()}))
            return ((lobes - goal[rows]).abs().sum(dim=(1, 2, 3)) / total[rows]).mean()
    else:
        def distance(rows):
            return ((net(x[rows]) - y[rows]) ** 2).mean()
    held_back = np.arange(len(index)) % 10 == 0
    run = train.optimise(net, np.flatnonzero(~held_back), distance,
                         lambda: distance(np.flatnonzero(held_back)).item(), minutes, batch, learning_rate, rng,
                         lambda text: log(f"  {text}", flush=True))
    val, _ = train.split(len(data["rows"]))
    return net, {"seed": seed, **run, "batch": batch, "device": str(train.DEVICE), "wi_per_step": None,
                 "energy_floor": None, "energy_weight": None, "scaled_loss": False, "learning_rate": learning_rate,
                 "precision": str(train.PRECISION).removeprefix("torch."), "train_configs": int(len(index)),
                 "distilled_from": target, "split_validation_configs": int(len(val)), "val_index": val}


def fit_lobes(fitted: dict, raw: torch.Tensor, part: np.ndarray) -> torch.Tensor:
    """The lobes (f |cos wo|) of the fits ``raw`` for the configurations ``part`` of ``fitted``."""
    with torch.no_grad():
        return train.predicted_lobe(lambda _: raw[part], *train.tensors({k: v[part] for k, v in fitted.items()}))


def scores(data: dict, index: np.ndarray, outputs: list) -> list[dict]:
    """Mean lobe errors on the fitted configurations ``index`` of each of ``outputs`` (raw network outputs for
    them, (len(index), width)), as training scores them: alone, and scaled to the Monte Carlo's energy
    (``train.scaled_to``)."""
    fitted = {k: data[k][index] for k in validation.ARRAYS if k in data}
    truth = train.target(fitted)
    out = []
    for raw in outputs:
        with torch.no_grad():
            lobes = train.predicted_lobe(lambda _: torch.as_tensor(raw, dtype=train.PRECISION),
                                         *train.tensors(fitted))
            scaled = train.scaled_to(lobes, truth)
        alone, shaped = (validation.lobe_errors(fitted, v.double().cpu().numpy()) for v in (lobes, scaled))
        out.append({"configurations": len(index), "alone": alone["mean_relative_lobe_error"],
                    "alone_energy": alone["mean_relative_energy_error"], "scaled": shaped["mean_relative_lobe_error"]})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.distill", description=__doc__.split("\n\n")[0])
    ap.add_argument("action", choices=["fit", "train", "score"])
    ap.add_argument("folders", type=Path, nargs="*", help="score: weights folders to score beside the fits")
    ap.add_argument("--layers", type=int, default=2, choices=[1, 2])
    ap.add_argument("--data", type=Path, default=dataset.DEFAULT_CACHE)
    ap.add_argument("--out", type=Path, help="fit: the fits' folder; train: the weights' folder")
    ap.add_argument("--count", type=int, default=2048, help="fit: how many training configurations")
    ap.add_argument("--part", default="0/1", help="fit: this process's share of the chunks, k/n")
    ap.add_argument("--steps", type=int, default=FIT_STEPS, help="fit: optimiser steps per chunk")
    ap.add_argument("--scaled", type=float, default=1.0, help="fit: weight of the scaled lobes' score")
    ap.add_argument("--fits", type=Path, help="train: the fits' folder")
    ap.add_argument("--target", choices=TARGETS, default="lobes",
                    help="train: regress the raw outputs (mean squared error) or the lobes (relative L1) on the fits'")
    ap.add_argument("--init", type=Path, default=ms.WEIGHTS, help="train: the weights folder to start from")
    ap.add_argument("--minutes", type=float, default=20.0)
    ap.add_argument("--learning-rate", type=float, default=3e-4)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_intermixed_args(argv)
    torch.set_num_threads(a.threads)
    train.PRECISION = torch.float32
    if a.out is None and a.action != "score":
        print(f"{a.action} needs --out", file=sys.stderr)
        return 2
    data = dataset.load(a.data, a.layers)
    if a.action == "fit":
        k, n = (int(v) for v in a.part.split("/"))
        fit(data, a.layers, a.count, a.out, (k, n), a.steps, a.scaled)
        return 0
    if a.fits is None:
        print(f"{a.action} needs --fits", file=sys.stderr)
        return 2
    index, raw = load_fits(a.fits, a.layers)
    if a.action == "score":
        x = ms.features(data["rows"][index].astype(np.float64))
        outputs = [raw] + [mlp.load(folder / ms.weights_path(a.layers).name)(x) for folder in a.folders]
        for name, record in zip(["fits"] + [str(f) for f in a.folders], scores(data, index, outputs)):
            print(json.dumps({"lobes": name, **record}), flush=True)
        return 0
    init = mlp.load(a.init / ms.weights_path(a.layers).name)
    net, info = regress(data, index, raw, init, a.minutes, a.target, learning_rate=a.learning_rate)
    info["init"] = {k: init.manifest.get(k) for k in ("training_configs", "steps", "date", "code_version")}
    train.export(net, info, data, a.layers, a.out, train.VALIDATION_SET)
    return 0


if __name__ == "__main__":
    sys.exit(main())
