"""Train the neural_medium networks (Ge et al., Secs. 3.3-3.6) on the tables of ``training.medium_dataset`` and
export them for ``addon.reference.neural_medium``.

One network per table (``double``: order 2, ``multiple``: orders >= 3), as the paper: an MLP 6-50-50-1 with tanh,
inputs (rho, z, theta, phi, albedo, g) in [0, 1] through ``neural_medium.encode`` (each cell paired with its centre
in the encoded coordinates, each direction bin with its centre), target log(1 + Phi / (PHI_0 albedo^k))
(``neural_medium.target``: the paper's log(1 + Phi) with Phi in units of PHI_0 = 1e-12 and of the lowest order's power
of the albedo, k = 2 or 3), L2 loss weighted per sample (``--power-share``), Adam (learning rate
0.01 for multiple and 0.001 for double scattering, the paper's, with cosine decay over the time budget), mini-
batches of 30 000 samples reshuffled every epoch. 10 % of the samples are held out (the checkpoint with the lowest
held-out loss is kept); whole materials can be held out too (``--hold-out``), for the off-grid check. Float32
throughout, as the shipped weights (11.8 KB per network).

The export (``addon.bake.mlp.save``) carries a manifest: activation, encoding, the materials and sample count,
seed, minutes, losses, and per material the energy ratio (power of the reconstructed table over the tabulated
one, minus 1: the paper's measure of its ~5 % error), for the training materials and the held-out ones apart.

    python -m training.medium_train --data ~/.cache/lamina/neural-medium --minutes 20 --out addon/bake/weights \
        --off-grid ~/.cache/lamina/neural-medium-off-grid
    python -m training.medium_train --data /tmp/m --quick --out /tmp/w              # seconds, for tests
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from addon.bake import mlp
from addon.reference import neural_medium as nm
from training.medium_dataset import DEFAULT_CACHE
from training.train import code_version

HIDDEN = (50, 50)
LEARNING_RATE = {"double": 1e-3, "multiple": 1e-2}
BATCH = 30_000
VALIDATION_SHARE = 0.1


def load_material(path: Path, kind: str) -> dict:
    """One dataset file: its albedo, g, grid and ``kind`` table."""
    with np.load(path) as f:
        meta = json.loads(str(f["meta"]))
        return {"name": path.stem, "kind": kind, "alpha": float(meta["alpha"]), "g": float(meta["g"]),
                "table": f[kind].astype(np.float64), "rho_edges": f["rho_edges"], "z_edges": f["z_edges"],
                "theta": f["theta"], "phi": f["phi"]}


def samples(material: dict, power_share: float = 0.0, power_range: float = math.inf
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inputs (N, 6), targets ``nm.target`` (N,), loss weights (N,)) of every cell and direction bin of a
    material's table. The weights average 1 over the material: a share ``power_share`` of them goes to the samples
    in proportion to the power they emit (cell volume x bin solid angle x Phi, what the energy ratio integrates)
    times exp(-r / ``power_range``) at the cell centre's distance r (mfp) from the source (what a render of an object
    a few ``power_range`` across sees: its surface lies within that reach of the beams), the rest uniformly."""
    rho_c, z_c = nm.cell_centres(material["rho_edges"], material["z_edges"])
    grid = np.meshgrid(rho_c, z_c, material["theta"], material["phi"], indexing="ij")
    x = nm.encode(*grid, material["alpha"], material["g"])
    reach = np.exp(-np.hypot(grid[0], grid[1]) / power_range)
    power = (nm.cell_powers(material["table"], material["rho_edges"], material["z_edges"]) * reach).ravel()
    weights = (1.0 - power_share) + power_share * power * (power.size / max(power.sum(), 1e-300))
    y = nm.target(material["table"], albedo=material["alpha"], albedo_power=nm.ALBEDO_POWER[material["kind"]])
    return (x.astype(np.float32), y.ravel().astype(np.float32),
            weights.astype(np.float32))


def make_network(seed: int) -> torch.nn.Sequential:
    torch.manual_seed(seed)
    sizes = (6, *HIDDEN, 1)
    modules = []
    for i in range(len(sizes) - 1):
        modules.append(torch.nn.Linear(sizes[i], sizes[i + 1]))
        if i + 2 < len(sizes):
            modules.append(torch.nn.Tanh())
    return torch.nn.Sequential(*modules)


def to_mlp(net: torch.nn.Sequential, manifest: dict) -> mlp.MLP:
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    return mlp.MLP(tuple(m.weight.detach().numpy().T.astype(np.float64) for m in linears),
                   tuple(m.bias.detach().numpy().astype(np.float64) for m in linears), manifest)


@torch.no_grad()
def weighted_l2(net, x, y, w, chunk: int = 10 * BATCH) -> float:
    """The weighted loss over a whole set, in chunks (all activations at once would not fit in memory)."""
    return sum(float(torch.sum(w[s:s + chunk] * (net(x[s:s + chunk])[:, 0] - y[s:s + chunk]) ** 2))
               for s in range(0, len(x), chunk)) / len(x)


def fit(x: np.ndarray, y: np.ndarray, w: np.ndarray, kind: str, minutes: float, seed: int, log=print) -> tuple:
    """Train on (x, y) with loss weights w for about ``minutes``; returns (network with the best held-out loss,
    info)."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(x))
    n_val = max(1, int(VALIDATION_SHARE * len(x)))
    val, train = order[:n_val], order[n_val:]
    xt, yt, wt = torch.from_numpy(x[train]), torch.from_numpy(y[train]), torch.from_numpy(w[train])
    xv, yv, wv = torch.from_numpy(x[val]), torch.from_numpy(y[val]), torch.from_numpy(w[val])
    net = make_network(seed)
    opt = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE[kind])
    budget, start = 60.0 * minutes, time.perf_counter()
    best = (math.inf, None)
    epoch = 0
    generator = torch.Generator().manual_seed(seed)
    while True:
        perm = torch.randperm(len(xt), generator=generator)
        for s in range(0, len(xt), BATCH):
            frac = min((time.perf_counter() - start) / budget, 1.0)
            for group in opt.param_groups:
                group["lr"] = LEARNING_RATE[kind] * 0.5 * (1.0 + math.cos(math.pi * frac))
            idx = perm[s:s + BATCH]
            loss = torch.mean(wt[idx] * (net(xt[idx])[:, 0] - yt[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
        epoch += 1
        val_loss = weighted_l2(net, xv, yv, wv)
        if val_loss < best[0]:
            best = (val_loss, {k: v.clone() for k, v in net.state_dict().items()})
        log(f"{kind}: epoch {epoch}, held-out weighted L2 {val_loss:.3e} ({time.perf_counter() - start:.0f} s)")
        if time.perf_counter() - start >= budget:
            break
    net.load_state_dict(best[1])
    train_loss = weighted_l2(net, xt, yt, wt)
    return net, {"epochs": epoch, "train_l2": train_loss, "held_out_l2": best[0],
                 "seconds": round(time.perf_counter() - start, 1)}


def energy_ratios(net: mlp.MLP, materials: list[dict]) -> dict:
    """Per material: power of the reconstructed table over the tabulated one, minus 1."""
    out = {}
    for m in materials:
        predicted = nm.table(net, m["alpha"], m["g"], m["rho_edges"], m["z_edges"], m["theta"], m["phi"])
        tabulated = nm.table_energy(m["table"], m["rho_edges"], m["z_edges"])
        out[m["name"]] = nm.table_energy(predicted, m["rho_edges"], m["z_edges"]) / tabulated - 1.0
    return out


def summary(ratios: dict) -> dict:
    values = np.abs(list(ratios.values())) if ratios else np.array([np.nan])
    return {"mean_abs": float(np.mean(values)), "worst_abs": float(np.max(values)),
            "per_material": {k: round(v, 5) for k, v in ratios.items()}}


def train_kind(kind: str, files: list[Path], held_out: set[str], minutes: float, seed: int, out: Path,
               log=print, off_grid: list[Path] = (), power_share: float = 0.0, power_range: float = math.inf) -> dict:
    """Train, evaluate and export the ``kind`` network; returns its manifest."""
    materials = [load_material(p, kind) for p in files]
    training = [m for m in materials if m["name"] not in held_out]
    if not training:
        raise SystemExit("no training materials left after --hold-out")
    x, y, w = (np.concatenate(parts) for parts in zip(*(samples(m, power_share, power_range) for m in training)))
    net, info = fit(x, y, w, kind, minutes, seed, log)
    manifest = {"network": f"neural_medium {kind}", "activation": "tanh", "encoding": nm.ENCODING,
                "target": "log(1 + Phi / (phi_0 albedo^albedo_power))", "phi_0": nm.PHI_0,
                "albedo_power": nm.ALBEDO_POWER[kind], "layers": [6, *HIDDEN, 1],
                "data": {"materials": [m["name"] for m in training], "samples": int(len(x))},
                "seed": seed, "minutes": minutes, "power_share": power_share,
                "power_range": power_range if math.isfinite(power_range) else None, **info,
                "date": datetime.date.today().isoformat(), "code_version": code_version()}
    model = to_mlp(net, manifest)
    manifest["grid"] = {k: np.asarray(training[0][k]).tolist() for k in ("rho_edges", "z_edges", "theta", "phi")}
    manifest["energy_ratio"] = {"training": summary(energy_ratios(model, training)),
                                "held_out": summary(energy_ratios(model, [m for m in materials
                                                                         if m["name"] in held_out])),
                                "off_grid": summary(energy_ratios(model, [load_material(p, kind) for p in off_grid]))}
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    mlp.save(nm.weights_path(kind, out), [m.weight.detach().numpy().T for m in linears],
             [m.bias.detach().numpy() for m in linears], manifest)
    e = manifest["energy_ratio"]
    log(f"{kind}: energy ratio |mean| {e['training']['mean_abs']:.2%}, worst {e['training']['worst_abs']:.2%} "
        f"(held out: {e['held_out']['mean_abs']:.2%} / {e['held_out']['worst_abs']:.2%}; off the grid: "
        f"{e['off_grid']['mean_abs']:.2%} / {e['off_grid']['worst_abs']:.2%}); wrote "
        f"{nm.weights_path(kind, out)}")
    return manifest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.medium_train", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_CACHE, help=f"dataset folder (default {DEFAULT_CACHE})")
    ap.add_argument("--out", type=Path, required=True, help="where the weights go (addon/bake/weights to ship)")
    ap.add_argument("--kinds", nargs="+", choices=nm.KINDS, default=list(nm.KINDS))
    ap.add_argument("--minutes", type=float, default=20.0, help="training time per network")
    ap.add_argument("--hold-out", nargs="*", default=[], help="material names (a<albedo>_g<g>) kept out of training")
    ap.add_argument("--off-grid", type=Path, help="a dataset folder of materials between the grid's (albedo, g), "
                                                  "only evaluated (the manifest's off_grid energy ratios)")
    ap.add_argument("--power-share", type=float, default=0.0,
                    help="share of each material's loss weight given in proportion to the power a sample emits "
                         "(0: every cell and direction alike, the paper's)")
    ap.add_argument("--power-range", type=float, default=math.inf,
                    help="the power weights fall as exp(-r / RANGE) with the distance r (mfp) from the source "
                         "(default: no fall-off)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="a few seconds per network, for tests")
    a = ap.parse_args(argv)
    files = sorted(a.data.glob("a*_g*.npz"))
    if not files:
        raise SystemExit(f"no dataset files in {a.data}: run python -m training.medium_dataset first")
    unknown = set(a.hold_out) - {p.stem for p in files}
    if unknown:
        raise SystemExit(f"--hold-out: no such material(s) {', '.join(sorted(unknown))} in {a.data}")
    a.out.mkdir(parents=True, exist_ok=True)
    off_grid = sorted(a.off_grid.glob("a*_g*.npz")) if a.off_grid else []
    if a.off_grid and not off_grid:
        raise SystemExit(f"--off-grid: no dataset files in {a.off_grid}")
    for kind in a.kinds:
        train_kind(kind, files, set(a.hold_out), 0.05 if a.quick else a.minutes, a.seed, a.out, off_grid=off_grid,
                   power_share=a.power_share, power_range=a.power_range)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
