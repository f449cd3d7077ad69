"""Train the SpongeCake multiple-scattering energy networks (issue 15, part 1) and export them.

For a stack without a substrate and light arriving along ω, multiple scattering returns a share q(ω) of what single
scattering and the Dirac leave, left(ω) = 1 − A_ss(ω) − T_δ(ω): q = 1 for a white stack without Fresnel flakes,
less where the layers absorb. One MLP per layer count predicts q per channel (the channels are independent
random-walk experiments over the same paths) from the layers (``addon.bake.spongecake.energy_inputs``: the lobe
network's features of the channel's rows and two more, then ω, then what ω meets in each layer):
``energy_input_count(L, True)`` inputs, three hidden layers of 128 SiLU units, one output, q = sigmoid(output). The
add-on scales the lobe network's lobes to q × left per view (``addon.bake.spongecake.fraction_limit``).

Data: its own, not the lobe dataset's. The lobe dataset's energies are sums over 128 uniform directions, which miss
or over-weight the narrow multiply scattered peaks of low-roughness flakes (up to 4x the true energy on some stacks);
here the reference's random walk tallies the throughput leaving the stack by order (``ground_truth_albedo``: the
unscattered light, order 1, orders ≥ 2), exact in expectation whatever the lobe's shape, and far cheaper than next-event
estimation towards every wo. Stacks and wi come from the lobe dataset's distribution (``dataset.sample_layers``,
jittered-stratified wi over the upper hemisphere); chunks of ``CHUNK`` stacks, seeded by (seed, layer count, chunk),
are written atomically beside the lobe dataset, so a run resumes. Target: q = E_ms / (1 − T_δ − E_1) from the same
paths. Loss: |q − q_target| left / (the stack's mean E_ms + ``ENERGY_FLOOR``); Adam, learning rate ``LEARNING_RATE``
with cosine decay over the time budget; mini-batches of ``BATCH`` samples rotated and mirrored about the normal (an
exact symmetry); 10% of the stacks held out, the checkpoint with the best split-validation energy error kept. A
held-out set with an independent seed and four times the paths (``--validation-set``, shipped in tests/data) is
scored at export, against left from the reference as the add-on computes it.

    python -m training.energy_train --data ~/.cache/lamina/spongecake-ms-energy --layers 1 2 3 4 --out addon/bake/weights
    python -m training.energy_train --layers 1 2 3 4 --validation-set tests/data/spongecake_ms_energy_validation.npz
    python -m training.energy_train --layers 1 2 --ensemble <run 1> <run 2> --out addon/bake/weights
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from multiprocessing import Pool
from pathlib import Path

import numpy as np
import torch

from addon.bake import layer_rows, mlp, validation
from addon.bake import spongecake as ms
from addon.bake.exr import atomic_path
from addon.reference import spongecake as reference
from training import dataset
from training.train import code_version, cosine_step, ensemble, silu_mlp, to_mlp

VERSION = 1
DEFAULT_CACHE = dataset.DEFAULT_CACHE.parent / "spongecake-ms-energy"
VALIDATION_SET = Path(__file__).resolve().parents[1] / "tests" / "data" / "spongecake_ms_energy_validation.npz"
HIDDEN = (128, 128, 128)
LEARNING_RATE = 3e-3
BATCH = 4096  # (stack, wi, channel) samples per step
ENERGY_FLOOR = 1e-3  # in albedo units: stacks with less multiple scattering count by this much
ORIENTATION_COLUMNS = slice(11, 14)  # within each layer's ENERGY_FEATURES inputs (``addon.bake.spongecake.features``)


@dataclass(frozen=True)
class Size:
    configs: int
    chunk: int = 50
    n_wi: int = 16  # a square number
    paths: int = 4000  # per wi
    max_depth: int = 64


QUICK = Size(configs=8, chunk=4, n_wi=4, paths=200)
VALIDATION = Size(configs=32, chunk=32, n_wi=16, paths=16000)
VALIDATION_SEED = 1001
TALLIES = ("unscattered", "single", "multiple")  # the walk's: ``validation.ENERGY_ARRAYS`` after rows and wi
CONFIGS = {1: 12000, 2: 11200, 3: 15000, 4: 15000}  # stacks per layer count (what the shipped networks saw)


# ------------------------------------------------------------------------------------------------ data

def walk(rows: np.ndarray, wi: np.ndarray, size: Size, seeds) -> dict:
    """The walk's tallies (C, n_wi, 3) for light from each wi: ``unscattered``, ``single`` (order 1) and
    ``multiple`` (orders ≥ 2) (``reference.spongecake.ground_truth_albedo``)."""
    out = {k: np.empty(wi.shape[:2] + (3,)) for k in TALLIES}
    for c, stack in enumerate(rows):
        params = layer_rows.params_from_rows(stack)
        tallies = reference.ground_truth_albedo(params, wi[c], n_paths=size.paths, seed=int(seeds[c]),
                                                max_depth=size.max_depth)
        for key, tally in zip(TALLIES, tallies):
            out[key][c] = tally
    return out


def chunk_inputs(n_layers: int, index: int, size: Size, base_seed: int):
    """The seeded stacks, light directions and walk seeds of one chunk."""
    rng = np.random.default_rng(np.random.SeedSequence([base_seed, n_layers, index]))
    rows = dataset.sample_layers(rng, size.chunk, n_layers)
    wi = np.stack([dataset.stratified_hemisphere(rng, size.n_wi) for _ in range(size.chunk)])
    return rows, wi, rng.integers(0, 2**31, size.chunk)


def chunk_path(out: Path, n_layers: int, index: int) -> Path:
    return Path(out) / f"layers{n_layers}" / f"chunk{index:04d}.npz"


def make_chunk(job) -> str:
    out, n_layers, index, size, base_seed = job

    def make():
        rows, wi, seeds = chunk_inputs(n_layers, index, size, base_seed)
        return ({"rows": rows, "wi": wi, **walk(rows, wi, size, seeds)},
                {"version": VERSION, "seed": base_seed, "layers": n_layers, "chunk": size.chunk, "n_wi": size.n_wi,
                 "paths": size.paths, "max_depth": size.max_depth})

    return dataset.write_once(chunk_path(out, n_layers, index), make)


def generate(out: Path, layer_counts, configs, size: Size, seed: int = 1, workers: int = 2, log=print) -> None:
    """Make the chunks of ``configs[i]`` stacks of ``layer_counts[i]`` layers that are not there yet, interleaved."""
    counts = {n: -(-c // size.chunk) for n, c in zip(layer_counts, configs)}
    jobs = [(out, n, i, size, seed) for i in range(max(counts.values())) for n in layer_counts if i < counts[n]]
    start = time.time()
    with Pool(max(1, workers)) as pool:
        for k, line in enumerate(pool.imap(make_chunk, jobs)):
            if not line.endswith("(cached)"):
                log(f"  [{k + 1}/{len(jobs)}] {line}  {time.time() - start:.0f} s", flush=True)


def load(out: Path, n_layers: int) -> dict:
    """All chunks of one layer count concatenated: ``rows``, ``wi``, the three tallies and ``meta`` (one per chunk)."""
    files = sorted((Path(out) / f"layers{n_layers}").glob("chunk*.npz"))
    if not files:
        raise FileNotFoundError(f"no {n_layers}-layer energy chunks in {out}")
    parts = [dict(np.load(f)) for f in files]
    data = {k: np.concatenate([p[k] for p in parts]) for k in validation.ENERGY_ARRAYS}
    data["meta"] = [json.loads(str(p["meta"])) for p in parts]
    return data


def write_validation_set(path: Path, layer_counts=(1, 2), size: Size = VALIDATION, workers: int = 2) -> None:
    """The held-out set: ``size.configs`` stacks per layer count, an independent seed, in one small file; the other
    layer counts of a file already there are kept (its sizes must be ``size``'s)."""
    arrays, meta = {}, {"version": VERSION, "seed": VALIDATION_SEED, "configs": size.configs, "n_wi": size.n_wi,
                        "paths": size.paths, "max_depth": size.max_depth}
    if Path(path).exists():
        with np.load(path) as f:
            if json.loads(str(f["meta"])) != meta:
                raise ValueError(f"{path} was made with other sizes: {str(f['meta'])}")
            arrays = {k: f[k] for k in f.files if k != "meta"}
    with Pool(max(1, workers)) as pool:
        for n_layers in layer_counts:
            rows, wi, seeds = chunk_inputs(n_layers, 0, size, VALIDATION_SEED)
            parts = pool.starmap(walk, [(rows[k:k + 1], wi[k:k + 1], size, seeds[k:k + 1]) for k in range(len(rows))])
            arrays.update({f"layers{n_layers}_rows": rows, f"layers{n_layers}_wi": wi})
            for key in TALLIES:
                arrays[f"layers{n_layers}_{key}"] = np.concatenate([p[key] for p in parts])
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, meta=np.array(json.dumps(meta)), **arrays)


def samples_of(data: dict, view: bool = True) -> dict:
    """Flat (stack, wi, channel) training samples: the network's inputs ``x`` (with the view features, or without:
    ``addon.bake.spongecake.energy_inputs``) and ``validation.energy_samples``."""
    n_wi = data["wi"].shape[1]
    x = ms.energy_inputs(np.repeat(data["rows"], n_wi, axis=0), data["wi"].reshape(-1, 3), view)
    return {"x": x.reshape(-1, x.shape[-1]), **validation.energy_samples(data)}


# ------------------------------------------------------------------------------------------------ network

def best_constant_share(samples: dict, norm: np.ndarray) -> float:
    """The constant q that minimises the training loss Σ |q left − E_ms| / norm: the median of E_ms / left weighted
    by left / norm (clipped to [0.01, 0.99])."""
    left = np.maximum(samples["left"], 1e-12)
    ratio, weight = samples["energy"] / left, left / norm
    order = np.argsort(ratio)
    cumulative = np.cumsum(weight[order])
    return float(np.clip(ratio[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])], 0.01, 0.99))


def make_network(n_inputs: int, start: float = 0.5) -> torch.nn.Sequential:
    """The MLP, its output starting at q = ``start`` everywhere (its last layer's weights start at 0;
    ``best_constant_share``): a start far from the loss's best constant pushes the sigmoid into saturation at 0,
    where training stalls (the 3-layer network started at the data's mean share scored 3.5 times the split's energy
    error of q = 0 and stalled at q = 0 for 446 of its 720 seconds)."""
    net = silu_mlp((n_inputs, *HIDDEN, 1))
    with torch.no_grad():
        net[-1].weight.zero_()
        net[-1].bias.fill_(math.log(start / (1.0 - start)))
    return net


def rotated(x: torch.Tensor, n_layers: int, generator: torch.Generator) -> torch.Tensor:
    """Inputs with every orientation and the direction turned by one random angle about the normal and mirrored at
    random (SpongeCake does not change; the orientation's z, which ``features`` keeps ≥ 0, is left alone; the view
    features after the direction do not change either)."""
    n = len(x)
    angle = torch.rand(n, generator=generator) * (2.0 * math.pi)
    mirror = torch.where(torch.rand(n, generator=generator) < 0.5, -1.0, 1.0)
    c, s = torch.cos(angle), torch.sin(angle)
    out = x.clone()
    columns = [k * ms.ENERGY_FEATURES + ORIENTATION_COLUMNS.start for k in range(n_layers)]
    columns.append(n_layers * ms.ENERGY_FEATURES)
    for j in columns:
        a, b = x[:, j], x[:, j + 1] * mirror
        out[:, j], out[:, j + 1] = c * a - s * b, s * a + c * b
    return out


def train(samples: dict, n_layers: int, minutes: float, seed: int = 0, log=print):
    """Train for ``minutes``; returns the network at its best split-validation energy error and what happened."""
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    n_configs = samples["config"].max() + 1
    val_configs = rng.permutation(n_configs)[:max(1, n_configs // 10)]
    is_val = np.isin(samples["config"], val_configs)
    x = torch.as_tensor(samples["x"], dtype=torch.float32)
    left = torch.as_tensor(samples["left"], dtype=torch.float32)
    energy = torch.as_tensor(samples["energy"], dtype=torch.float32)
    per_config = np.bincount(samples["config"], weights=samples["energy"]) / np.bincount(samples["config"])
    norm_of_sample = per_config[samples["config"]] + ENERGY_FLOOR
    norm = torch.as_tensor(norm_of_sample, dtype=torch.float32)
    train_idx = torch.as_tensor(np.flatnonzero(~is_val))
    val_samples = {k: samples[k][is_val] for k in ("left", "energy", "config")}
    net = make_network(x.shape[1], best_constant_share(samples, norm_of_sample))
    opt = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE)
    start, step, last_check = time.time(), 0, -math.inf
    best = (math.inf, None, 0)
    budget = minutes * 60.0
    while time.time() - start < budget:
        idx = train_idx[torch.randint(len(train_idx), (BATCH,), generator=generator)]
        q = torch.sigmoid(net(rotated(x[idx], n_layers, generator))[:, 0])
        loss = ((q * left[idx] - energy[idx]).abs() / norm[idx]).mean()
        cosine_step(opt, loss, LEARNING_RATE, (time.time() - start) / budget)
        step += 1
        if time.time() - last_check > min(5.0, budget / 20):
            last_check = time.time()
            with torch.no_grad():
                q_val = torch.sigmoid(net(x[torch.as_tensor(is_val)])[:, 0]).numpy().astype(np.float64)
            error = float(np.nanmean(validation.fraction_errors(q_val, val_samples)))
            if error < best[0]:
                best = (error, {k: v.clone() for k, v in net.state_dict().items()}, step)
                log(f"  {n_layers} layer(s) step {step}: loss {loss.item():.4f}, split validation energy error "
                    f"{error:.4f}  ({time.time() - start:.0f} s)", flush=True)
    net.load_state_dict(best[1])
    return net, {"steps": step, "best_step": best[2], "seconds": round(time.time() - start, 1),
                 "train_configs": int(n_configs - len(val_configs)), "is_val": is_val}


def export(net, info: dict, samples: dict, data: dict, n_layers: int, out: Path, held_out: Path | None,
           log=print) -> dict:
    with torch.no_grad():
        q = torch.sigmoid(net(torch.as_tensor(samples["x"][info["is_val"]], dtype=torch.float32))[:, 0]).numpy()
    held_in = {k: samples[k][info["is_val"]] for k in ("left", "energy", "config")}
    split = validation.error_summary(validation.fraction_errors(q.astype(np.float64), held_in))
    meta = data["meta"][0]
    manifest = {
        "model": "spongecake multiple-scattering energy fraction", "layers": n_layers,
        "inputs": int(samples["x"].shape[1]),
        "view_features": samples["x"].shape[1] == ms.energy_input_count(n_layers, True), "hidden": list(HIDDEN), "activation": "silu", "outputs": 1,
        "output": "sigmoid: the share of left = 1 - A_ss - T_delta that multiple scattering returns",
        "training_configs": info["train_configs"], "wi_per_config": meta["n_wi"], "paths_per_wi": meta["paths"],
        "max_depth": meta["max_depth"], "dataset_seed": meta["seed"], "dataset_version": meta["version"],
        "dataset_worker_seconds": round(sum(m["seconds"] for m in data["meta"])), "steps": info["steps"],
        "best_step": info["best_step"], "batch": BATCH, "training_seconds": info["seconds"],
        "split_validation": split, "date": datetime.date.today().isoformat(), "code_version": code_version(),
    }
    path = Path(out) / ms.energy_weights_path(n_layers).name
    exported = to_mlp(net, manifest)
    if held_out is not None and Path(held_out).exists():
        scores = validation.energy_errors(held_out, n_layers, exported)
        manifest["held_out_validation"] = {k: v for k, v in scores.items() if k != "per_config"}
        manifest["held_out_per_config"] = scores["per_config"]
    mlp.save(path, exported.weights, exported.biases, manifest)
    mlp.load.cache_clear()
    log(f"wrote {path}: " + json.dumps({k: manifest.get(k) for k in
                                         ("training_configs", "steps", "split_validation", "held_out_validation")}))
    return manifest


MEMBER_KEYS = ("steps", "best_step", "training_seconds", "split_validation", "held_out_validation", "date",
               "code_version")  # what differs between an ensemble's members: listed per member in its manifest


def export_ensemble(folders: list, n_layers: int, out: Path, held_out: Path | None, log=print) -> dict:
    """The mean of the energy networks for ``n_layers`` in ``folders`` (trained with different ``--seed``s on the
    same data: their errors differ from run to run more than the held-out set resolves, and their mean varies
    less), as one network (``train.averaged``) in ``out``, scored on the held-out set."""
    name = ms.energy_weights_path(n_layers).name
    weights, biases, manifest = ensemble([mlp.load(Path(f) / name) for f in folders], MEMBER_KEYS)
    if held_out is not None and Path(held_out).exists():
        scores = validation.energy_errors(held_out, n_layers, mlp.MLP(tuple(weights), tuple(biases), manifest))
        manifest["held_out_validation"] = {k: v for k, v in scores.items() if k != "per_config"}
        manifest["held_out_per_config"] = scores["per_config"]
    path = Path(out) / name
    mlp.save(path, weights, biases, manifest)
    mlp.load.cache_clear()
    log(f"wrote {path}: the mean of {len(folders)} networks: " + json.dumps(manifest.get("held_out_validation")))
    return manifest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.energy_train", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_CACHE, help=f"cache folder (default {DEFAULT_CACHE})")
    ap.add_argument("--layers", type=int, nargs="+", default=sorted(CONFIGS), choices=sorted(CONFIGS),
                    help="layer counts (a network each; all four ship, docs/training.md)")
    ap.add_argument("--configs", type=int, nargs="+",
                    help=f"stacks per layer count, in --layers' order (default {CONFIGS})")
    ap.add_argument("--minutes", type=float, default=10.0, help="training time per network")
    ap.add_argument("--out", type=Path, help="folder for the .npz weights (addon/bake/weights ships)")
    ap.add_argument("--validation", type=Path, default=VALIDATION_SET)
    ap.add_argument("--validation-set", type=Path, metavar="FILE", help="write the held-out set to FILE and stop")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="a tiny dataset and a few seconds of training (tests)")
    ap.add_argument("--no-view-features", dest="view", action="store_false",
                    help="the first input format, without what the view meets in each layer (to compare)")
    ap.add_argument("--ensemble", type=Path, nargs="+", metavar="FOLDER",
                    help="write to --out the mean of the networks in these folders (``averaged``) and stop")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    if a.ensemble:
        if a.out is None:
            ap.error("--out is needed for --ensemble")
        for n_layers in a.layers:
            export_ensemble(a.ensemble, n_layers, a.out, a.validation)
        return 0
    if a.validation_set:
        size = QUICK if a.quick else VALIDATION
        write_validation_set(a.validation_set, a.layers, size, a.workers)
        print(f"wrote {a.validation_set}: {size.configs} stacks per layer count, {size.paths} paths per wi")
        return 0
    if a.out is None:
        ap.error("--out is needed to train")
    size = QUICK if a.quick else Size(configs=0)
    configs = a.configs or [QUICK.configs if a.quick else CONFIGS[n] for n in a.layers]
    if len(configs) != len(a.layers):
        ap.error(f"--configs gives {len(configs)} counts for {len(a.layers)} layer counts")
    generate(a.data, a.layers, configs, size, workers=a.workers)
    for n_layers in a.layers:
        data = load(a.data, n_layers)
        samples = samples_of(data, a.view)
        minutes = 0.05 if a.quick else a.minutes
        print(f"training the {n_layers}-layer energy network on {len(data['rows'])} stacks for {minutes} min",
              flush=True)
        net, info = train(samples, n_layers, minutes, seed=a.seed)
        export(net, info, samples, data, n_layers, a.out, a.validation)
    return 0


if __name__ == "__main__":
    sys.exit(main())
