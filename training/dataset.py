"""Monte Carlo dataset of SpongeCake multiple scattering (Wang et al. 2022, Sec. 5 "Dataset").

For random stacks of 1 and 2 layers (the training data; 3 and 4 for the held-out check of the grouped
prediction; no substrate), the reference's independent random walk (``addon.reference.spongecake.ground_truth``)
estimates the order >= 2 part of f(wi, wo) on jittered
stratified directions: ``wi`` over the upper hemisphere, ``wo`` over the whole sphere (reflection and
transmission), both uniform in solid angle so grazing angles are covered (as in the paper). Light from below is
the flipped stack (``addon.bake.layer_rows.flipped``), so it needs no data of its own.

Each shard is a seeded, self-contained .npz written atomically into the cache folder (outside the repository);
re-running skips the shards already there, so an interrupted run resumes. Every configuration is simulated as
two independent halves, which gives its Monte Carlo noise for free: the standard error of the stored mean is
|a - b| / 2 per pair (``noise`` below).

    python -m training.dataset --layers 1 2 --configs 5075 12000           # the default: what the shipped networks saw
    python -m training.dataset --quick --out /tmp/lamina-quick             # seconds, for tests
    python -m training.dataset --throughput                                # paths per second (one process)
    python -m training.dataset --pack /tmp/ms-pack.npz                     # one compact file to train elsewhere

Shard arrays: ``rows`` (C, L, 12) layer rows, ``wi`` (C, n_wi, 3), ``wo`` (C, n_wo, 3), ``ms`` (C, n_wi, n_wo, 3)
the order >= 2 estimate of f (no cosine), ``ms_half_diff`` the same for a - b, ``ss`` the walk's order 1.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict, dataclass
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from addon.bake import layer_rows
from addon.bake.exr import atomic_path
from addon.bake.validation import load_shards
from addon.reference import spongecake as reference
from addon.reference.frames import spherical

VERSION = 1
DEFAULT_CACHE = Path(os.environ.get("LAMINA_CACHE", Path.home() / ".cache" / "lamina")) / "spongecake-ms"

# Parameter ranges of the training data (what the network has seen; inputs outside are clamped to them).
ROUGHNESS_RANGE = (0.01, 1.0)  # flake alpha, log-uniform
G_RANGE = (-0.95, 0.95)  # hg mean cosine, uniform
THICKNESS_RANGE = (0.01, 10.0)  # optical thickness T rho, log-uniform
TYPE_SHARES = (0.4, 0.4, 0.2)  # surface, fiber, hg


@dataclass(frozen=True)
class Size:
    configs: int
    shard: int = 25
    n_wi: int = 16  # a square number: cos-theta x azimuth strata
    n_wo: int = 128  # twice a square number: per hemisphere
    paths: int = 4000  # per wi, both halves together
    max_depth: int = 64


QUICK = Size(configs=8, shard=4, n_wi=4, n_wo=32, paths=200)
PACK_MANTISSA_BITS = 6  # float16 keeps 10; with 6 (0.8% at most) the default dataset packs into 51 MB


# ------------------------------------------------------------------------------------------ parameters

def sample_layers(rng: np.random.Generator, n: int, n_layers: int) -> np.ndarray:
    """(n, n_layers, ROW) random layer rows from the training distribution."""
    rows = np.zeros((n, n_layers, layer_rows.ROW))
    for k in range(n_layers):
        rows[:, k] = _sample_layer(rng, n)
    return rows


def _sample_layer(rng, n) -> np.ndarray:
    row = np.zeros((n, layer_rows.ROW))
    kind = rng.choice(3, size=n, p=TYPE_SHARES)
    row[:, layer_rows.TYPE] = kind
    log_lo, log_hi = np.log(ROUGHNESS_RANGE)
    alpha = np.exp(rng.uniform(log_lo, log_hi, n))
    row[:, layer_rows.ROUGHNESS] = np.where(kind == 2, rng.uniform(*G_RANGE, n), alpha)
    # half the channels uniform, half pushed towards 1 where multiple scattering matters most
    uniform = rng.random((n, 3))
    bright = 1.0 - rng.random((n, 3)) ** 2
    row[:, layer_rows.ALBEDO] = np.where(rng.random((n, 1)) < 0.5, uniform, bright)
    row[:, layer_rows.THICKNESS] = np.exp(rng.uniform(*np.log(THICKNESS_RANGE), n))
    grey = rng.uniform(0.02, 1.0, (n, 1)) * np.ones(3)
    f0 = np.select([rng.random((n, 1)) < 0.6, rng.random((n, 1)) < 0.75], [np.ones(3), grey],
                   rng.uniform(0.02, 1.0, (n, 3)))
    row[:, layer_rows.F0] = f0
    row[:, layer_rows.ORIENTATION] = _sample_orientation(rng, kind)
    return row


def _sample_orientation(rng, kind) -> np.ndarray:
    """Surface flakes: half along the normal, half tilted; fibers: in-plane, along the normal or tilted.
    Upper hemisphere only (the SGGX matrix of -w is that of w)."""
    n = len(kind)
    tilted = spherical(rng.random(n), 2.0 * np.pi * rng.random(n))
    in_plane = spherical(np.zeros(n), 2.0 * np.pi * rng.random(n))
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    u = rng.random((n, 1))
    surface = np.where(u < 0.5, normal, tilted)
    fiber = np.where(u < 0.4, in_plane, np.where(u < 0.6, normal, tilted))
    return np.where((kind == 1)[:, None], fiber, surface)


# ------------------------------------------------------------------------------------------ directions

def stratified_hemisphere(rng, n: int) -> np.ndarray:
    """n (a square) jittered directions uniform in solid angle over the upper hemisphere."""
    side = int(round(np.sqrt(n)))
    if side * side != n:
        raise ValueError(f"direction counts must be square numbers per hemisphere, got {n}")
    i, j = np.divmod(np.arange(side * side), side)
    cos_theta = 1.0 - (i + rng.random(side * side)) / side
    phi = 2.0 * np.pi * (j + rng.random(side * side)) / side
    return spherical(np.maximum(cos_theta, 1e-3), phi)


def stratified_sphere(rng, n: int) -> np.ndarray:
    upper = stratified_hemisphere(rng, n // 2)
    lower = stratified_hemisphere(rng, n // 2) * np.array([1.0, 1.0, -1.0])
    return np.concatenate([upper, lower])


# ------------------------------------------------------------------------------------------ simulation

def simulate(rows: np.ndarray, wi: np.ndarray, wo: np.ndarray, size: Size, seed: int):
    """(ms, ms_half_diff, ss) of one stack, each (n_wi, n_wo, 3), from two independent halves of the paths."""
    params = layer_rows.params_from_rows(rows)
    big_wi = np.repeat(wi, len(wo), axis=0)
    big_wo = np.tile(wo, (len(wi), 1))
    halves = [reference.ground_truth(params, big_wi, big_wo, n_paths=size.paths // 2, seed=seed + h,
                                     max_depth=size.max_depth) for h in (0, 1)]
    shape = (len(wi), len(wo), 3)
    ss = 0.5 * (halves[0][0] + halves[1][0])
    ms = 0.5 * (halves[0][1] + halves[1][1])
    return ms.reshape(shape), (0.5 * (halves[0][1] - halves[1][1])).reshape(shape), ss.reshape(shape)


def shard_path(out: Path, n_layers: int, index: int) -> Path:
    return out / f"layers{n_layers}" / f"shard{index:04d}.npz"


def shard_inputs(n_layers: int, index: int, size: Size, base_seed: int):
    """The seeded stacks, directions and walk seeds of one shard: (rows, wi, wo, walk seeds)."""
    rng = np.random.default_rng(np.random.SeedSequence([base_seed, n_layers, index]))
    rows = sample_layers(rng, size.shard, n_layers)
    wi = np.stack([stratified_hemisphere(rng, size.n_wi) for _ in range(size.shard)])
    wo = np.stack([stratified_sphere(rng, size.n_wo) for _ in range(size.shard)])
    return rows, wi, wo, rng.integers(0, 2**31, size.shard)


def write_once(path: Path, make) -> str:
    """Write the arrays of ``make()`` (arrays dict, meta dict) to ``path`` atomically unless it is there; the meta gets
    the seconds it took. Returns the file's name, with "(cached)" where it was there."""
    if path.exists():
        return f"{path.name} (cached)"
    start = time.perf_counter()
    arrays, meta = make()
    meta["seconds"] = round(time.perf_counter() - start, 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, meta=np.array(json.dumps(meta)), **arrays)
    return path.name


def make_shard(job) -> str:
    out, n_layers, index, size, base_seed = job

    def make():
        rows, wi, wo, walk_seeds = shard_inputs(n_layers, index, size, base_seed)
        results = [simulate(rows[c], wi[c], wo[c], size, int(walk_seeds[c])) for c in range(size.shard)]
        ms, diff, ss = (np.stack([r[i] for r in results]).astype(np.float32) for i in range(3))
        return ({"rows": rows, "wi": wi, "wo": wo, "ms": ms, "ms_half_diff": diff, "ss": ss},
                {"version": VERSION, "seed": base_seed, "layers": n_layers, "shard": index, **asdict(size)})

    return write_once(shard_path(out, n_layers, index), make)


def load(out: Path, n_layers: int) -> dict:
    """All shards of one layer count concatenated (arrays as in the module docstring, plus ``meta``), from the
    shard folder or from a ``pack`` file (which has no ``ms_half_diff`` and ``ss``, and brings its ``noise``)."""
    return unpack(out, n_layers) if Path(out).is_file() else load_shards(out, n_layers)


def pack(folder: Path, path: Path, layer_counts, mantissa_bits: int = PACK_MANTISSA_BITS) -> dict:
    """One compressed file of what training reads, small enough to carry to another machine (a lent GPU): per layer
    count ``rows``, ``wi``, ``wo`` (float32) and ``ms`` as float16 relative to each configuration's largest value,
    rounded to ``mantissa_bits`` bits (relative error at most 2^-(bits + 1), far below a pair's Monte Carlo noise),
    with the shards' ``meta`` and the ``noise`` of the full-precision data (it needs the arrays left out)."""
    arrays = {}
    for n_layers in layer_counts:
        data = load_shards(folder, n_layers)
        scale = data["ms"].reshape(len(data["ms"]), -1).max(axis=1).astype(np.float64)
        relative = data["ms"] / np.maximum(scale, 1e-30)[:, None, None, None]
        arrays.update({f"layers{n_layers}_ms": round_mantissa(relative.astype(np.float16), mantissa_bits),
                       f"layers{n_layers}_scale": scale, f"layers{n_layers}_rows": data["rows"],
                       f"layers{n_layers}_wi": data["wi"].astype(np.float32),
                       f"layers{n_layers}_wo": data["wo"].astype(np.float32),
                       f"layers{n_layers}_meta": np.array(json.dumps({"meta": data["meta"], "noise": noise(data),
                                                                      "mantissa_bits": mantissa_bits}))})
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    return {"path": str(path), "megabytes": round(Path(path).stat().st_size / 1e6, 1), "layers": list(layer_counts)}


def round_mantissa(x: np.ndarray, bits: int) -> np.ndarray:
    """float16 ``x`` rounded to the nearest value with ``bits`` mantissa bits (the rest zero: they compress)."""
    drop = 10 - bits
    u = x.view(np.uint16).astype(np.uint32)
    return (((u + ((1 << drop) >> 1)) >> drop) << drop).astype(np.uint16).view(np.float16)


def unpack(path: Path, n_layers: int) -> dict:
    with np.load(path) as f:
        if f"layers{n_layers}_ms" not in f.files:
            raise FileNotFoundError(f"no {n_layers}-layer data in the pack {path}")
        info = json.loads(str(f[f"layers{n_layers}_meta"]))
        ms = f[f"layers{n_layers}_ms"].astype(np.float32) * f[f"layers{n_layers}_scale"][:, None, None, None]
        return {"rows": f[f"layers{n_layers}_rows"], "wi": f[f"layers{n_layers}_wi"].astype(np.float64),
                "wo": f[f"layers{n_layers}_wo"].astype(np.float64), "ms": ms.astype(np.float32),
                "meta": info["meta"], "noise": info["noise"]}


def noise(data: dict) -> dict:
    """Monte Carlo noise of the stored estimates: relative standard error of the mean of f |cos wo| per pair
    (RMS over pairs with signal, relative to the mean signal), and the walk's order 1 against the closed form
    (a pack's data bring it, computed when it was packed)."""
    if "noise" in data:
        return data["noise"]
    cos_o = np.abs(data["wo"][:, None, :, 2:3])
    signal = np.mean(data["ms"] * cos_o)
    se = np.sqrt(np.mean((data["ms_half_diff"] * cos_o) ** 2))
    ss_err = []
    for c in range(min(len(data["rows"]), 64)):
        params = layer_rows.params_from_rows(data["rows"][c])
        wi, wo = data["wi"][c].astype(float), data["wo"][c].astype(float)
        exact = reference.eval(params, np.repeat(wi, len(wo), 0), np.tile(wo, (len(wi), 1))).reshape(data["ss"][c].shape)
        ss_err.append(np.mean(np.abs(data["ss"][c] - exact) * cos_o[c]) / max(np.mean(exact * cos_o[c]), 1e-12))
    return {"configs": int(len(data["rows"])), "ms_mean": float(signal), "ms_relative_se": float(se / signal),
            "order1_relative_mae": float(np.mean(ss_err))}


def throughput(configs: int = 6, seed: int = 3, size: Size = Size(configs=6)) -> dict:
    """Random-walk paths per second of ``simulate`` in this process on ``configs`` seeded stacks of each layer
    count (the default dataset's directions and paths), so that speed-ups are measured on the same work."""
    out = {}
    for n_layers in (1, 2):
        rng = np.random.default_rng([seed, n_layers])
        rows = sample_layers(rng, configs, n_layers)
        start = time.perf_counter()
        for c in range(configs):
            simulate(rows[c], stratified_hemisphere(rng, size.n_wi), stratified_sphere(rng, size.n_wo), size, seed + c)
        seconds = time.perf_counter() - start
        out[f"layers{n_layers}"] = {"configs": configs, "seconds": round(seconds, 2),
                                    "paths_per_second": round(configs * size.n_wi * size.paths / seconds)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.dataset", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_CACHE, help=f"cache folder (default {DEFAULT_CACHE})")
    ap.add_argument("--layers", type=int, nargs="+", default=[1, 2], choices=[1, 2, 3, 4])
    ap.add_argument("--configs", type=int, nargs="+", default=[5075, 12000],
                    help="configurations per layer count (the default: what the shipped networks saw)")
    ap.add_argument("--paths", type=int, default=Size.paths, help="random-walk paths per wi")
    ap.add_argument("--n-wi", type=int, default=Size.n_wi)
    ap.add_argument("--n-wo", type=int, default=Size.n_wo)
    ap.add_argument("--shard", type=int, default=Size.shard, help="configurations per shard file")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--quick", action="store_true", help="a tiny dataset for tests (seconds)")
    ap.add_argument("--noise", action="store_true", help="report the Monte Carlo noise of what is in --out")
    ap.add_argument("--throughput", action="store_true", help="time the walk on fixed stacks (paths per second)")
    ap.add_argument("--pack", type=Path, metavar="FILE", help="write what training reads from --out into one "
                    "compact file (to train on another machine: python -m training.train --data FILE)")
    a = ap.parse_args(argv)
    if a.throughput:
        print(json.dumps(throughput()))
        return 0
    if a.pack:
        print(json.dumps(pack(a.out, a.pack, a.layers)))
        return 0
    if a.noise:
        for n_layers in a.layers:
            print(json.dumps({"layers": n_layers, **noise(load(a.out, n_layers))}))
        return 0
    configs = dict(zip(a.layers, a.configs if len(a.configs) == len(a.layers) else a.configs[:1] * len(a.layers)))
    jobs = []
    for n_layers in a.layers:
        size = QUICK if a.quick else Size(configs[n_layers], a.shard, a.n_wi, a.n_wo, a.paths)
        jobs += [(a.out, n_layers, i, size, a.seed) for i in range(-(-size.configs // size.shard))]
    jobs.sort(key=lambda j: (j[2], j[1]))  # interleave layer counts so a partial run has both
    run = {"started": time.strftime("%Y-%m-%dT%H:%M:%S"), "configs": configs, "workers": a.workers, "seed": a.seed,
           "shards": len(jobs), "made": 0, "cached": 0}
    start = time.time()
    try:
        with Pool(max(1, a.workers)) as pool:
            for done, name in enumerate(pool.imap(make_shard, jobs), 1):
                run["cached" if name.endswith("(cached)") else "made"] += 1
                print(f"[{done}/{len(jobs)}] {name}  {time.time() - start:.0f} s", flush=True)
    finally:
        log_run(a.out, {**run, "seconds": round(time.time() - start), "complete": run["made"] + run["cached"] == len(jobs),
                        "megabytes": round(shard_bytes(a.out, a.layers) / 1e6, 1)})
    return 0


def shard_bytes(out: Path, layers) -> int:
    """The size on disk of the shards of these layer counts in ``out``."""
    return sum(f.stat().st_size for n in layers for f in (Path(out) / f"layers{n}").glob("*.npz"))


def log_run(out: Path, run: dict) -> None:
    """One line per run (also an interrupted one) in ``runs.jsonl`` beside the shards: what was asked, what was
    made, how long it took, the shards' size on disk afterwards (``megabytes``)."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "runs.jsonl", "a") as f:
        f.write(json.dumps(run) + "\n")


if __name__ == "__main__":
    sys.exit(main())
