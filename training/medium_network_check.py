"""What the bake's tables cost, apart from the boundary: the shipped networks' tables (and double scattering by
quadrature, which the bake uses instead of the double network) against the Monte Carlo tables of
``training.medium_dataset`` (the paper's energy ratio and the power they put in the wrong cells and directions), and
in a render, the gather (``addon.reference.neural_medium.gather``, boundary images on) with the bake's tables
(``addon.bake.neural_medium.channel_tables``) against the same gather with Monte Carlo tables of the medium itself,
per preset and shape. What it prints goes into docs/training.md ("Networks").

    python -m training.medium_network_check          # about five minutes here, after make medium-dataset
    python -m training.medium_network_check --weights /tmp/w     # networks trained elsewhere, before shipping them
"""
from __future__ import annotations

import argparse
import json
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from addon import presets
from addon.bake import neural_medium as nb
from addon.models import neural_medium as model
from addon.reference import neural_medium as nm
from addon.reference import neural_medium_truth as truth
from addon.reference import scenes as S
from training import medium_tracer as mt
from training.medium_dataset import DEFAULT_CACHE
from training.medium_gather_check import SHAPES

# (preset, scale, shape); the green channel, the comparison scene's sun.
CASES = (("cloud", 0.5, "sphere"), ("milk", 0.25, "sphere"), ("milk", 0.25, "box"), ("candle", 0.25, "sphere"),
         ("dragon", 0.25, "sphere"))
RESOLUTION, PHOTONS, DOUBLE_PHOTONS, CELLS, STEPS = 16, 40_000, 400_000, 32, 12


METHODS = (("double", "network"), ("double", "quadrature"), ("multiple", "network"))


def table_errors(path: Path, kind: str, method: str = "network", weights: Path = nm.WEIGHTS) -> tuple[float, float]:
    """(energy ratio, misplaced power) of the ``kind`` table for one dataset file by ``method`` (the shipped network,
    or for double scattering ``nm.double_table``, what the bake uses) against the Monte Carlo table: its power over
    the Monte Carlo table's minus 1, and sum |Phi - Phi_MC| V dOmega over the Monte Carlo table's power (0: exact,
    2: disjoint)."""
    mc = nm.dataset_tables(path)[kind]
    with np.load(path) as f:
        meta = json.loads(str(f["meta"]))
    grid = (mc.rho_edges, mc.z_edges, mc.theta, mc.phi)
    if method == "quadrature":
        predicted = meta["alpha"] ** 2 * _double_shape(meta["g"], *(tuple(np.asarray(v).tolist()) for v in grid))
    else:
        predicted = nm.table(nm.network(kind, weights), meta["alpha"], meta["g"], *grid)
    power = nm.table_energy(mc.values, *grid[:2])
    return (nm.table_energy(predicted, *grid[:2]) / power - 1.0,
            nm.table_energy(np.abs(predicted - mc.values), *grid[:2]) / power)


@lru_cache(maxsize=8)
def _double_shape(g: float, *grid) -> np.ndarray:
    """``nm.double_table`` at albedo 1 (albedo^2 scales it), once per g and grid."""
    return nm.double_table(1.0, g, *(np.asarray(v) for v in grid))


def quadrature_seconds() -> float:
    """Time of ``nm.double_table`` for one g on the tracer's default grid (what a bake spends per material)."""
    grid = mt.default_grid()
    start = time.perf_counter()
    nm.double_table(1.0, 0.3, grid.rho_edges, grid.z_edges, grid.theta_centres(), grid.phi_centres())
    return time.perf_counter() - start


def table_lines(folders: list[Path], weights: Path) -> list[str]:
    lines = ["| table | by | materials | energy ratio: mean, worst | misplaced power: mean, worst | worst material |",
             "|---|---|---|---|---|---|"]
    for kind, method in METHODS:
        for folder in folders:
            files = sorted(folder.glob("a*_g*.npz"))
            if not files:
                raise SystemExit(f"no dataset files in {folder}: run make medium-dataset first")
            errors = np.array([table_errors(p, kind, method, weights) for p in files])
            worst = files[int(np.argmax(errors[:, 1]))].stem
            lines.append(f"| {kind} | {method} | {folder.name} ({len(files)}) | {np.mean(np.abs(errors[:, 0])):.1%}, "
                         f"{np.max(np.abs(errors[:, 0])):.1%} | {np.mean(errors[:, 1]):.1%}, "
                         f"{np.max(errors[:, 1]):.1%} | {worst} |")
    return lines


def render_errors(name: str, scale: float, shape_name: str, weights: Path, channel: int = 1) -> dict:
    """Mean and relative RMSE over the object's pixels of the gather with the bake's tables against the gather
    with Monte Carlo tables, for double, multiple and both."""
    p = model.params_from_dict({**presets.load(model.ID, name), "scale": scale})
    albedo, g = p.albedo[channel], p.g
    grid = mt.default_grid()
    r = mt.simulate(albedo, g, grid, mt.Settings(photons=PHOTONS, double_photons=DOUBLE_PHOTONS, batches=2), seed=[7])
    edges = (np.asarray(grid.rho_edges), np.asarray(grid.z_edges), grid.theta_centres(), grid.phi_centres())
    scene, shape = S.sphere_scene(resolution=RESOLUTION), SHAPES[shape_name]
    rays = truth.camera_rays(scene, shape)
    beams = nm.Beams.join(nm.sun_beams(shape, sun, CELLS) for sun in scene.suns)

    def gather(tables):
        return nm.gather(tables, p.mean_free_path[channel], shape, beams, *rays, steps=STEPS,
                         images=nm.boundary(albedo, g))

    reference = gather({kind: nm.Table(r[kind], *edges) for kind in nm.KINDS})
    networks = gather(nb.channel_tables(p, weights)[channel])
    out = {"albedo": albedo, "g": g, "mfp": 2.0 / p.mean_free_path[channel]}
    for label, kinds in (("double", ("double",)), ("multiple", ("multiple",)), ("both", nm.KINDS)):
        want, got = (sum(x[k] for k in kinds) for x in (reference, networks))
        lit = want > 0.0
        out[label] = (got[lit].mean() / want[lit].mean() - 1.0,
                      float(np.sqrt(np.mean((got[lit] - want[lit]) ** 2)) / want[lit].mean()))
    return out


def render_lines(weights: Path) -> list[str]:
    lines = ["| preset | scale | shape | mfp per 2 units | albedo, g | double: mean, rel. RMSE | multiple | both |",
             "|---|---|---|---|---|---|---|---|"]
    for name, scale, shape_name in CASES:
        e = render_errors(name, scale, shape_name, weights)
        lines.append(f"| {name} | {scale:g} | {shape_name} | {e['mfp']:.1f} | {e['albedo']:.3f}, {e['g']:g} | "
                     + " | ".join(f"{e[k][0]:+.1%}, {e[k][1]:.1%}" for k in ("double", "multiple", "both")) + " |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.medium_network_check", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_CACHE, help=f"dataset folder (default {DEFAULT_CACHE})")
    ap.add_argument("--weights", type=Path, default=nm.WEIGHTS, help="folder of the networks (default: the shipped)")
    a = ap.parse_args(argv)
    start = time.perf_counter()
    folders = [a.data, a.data.with_name(a.data.name + "-off-grid")]
    print("\n".join(table_lines([f for f in folders if f.exists()], a.weights)), "\n", flush=True)
    print(f"double scattering by quadrature: {quadrature_seconds():.1f} s per g on the dataset's grid\n", flush=True)
    print("\n".join(render_lines(a.weights)))
    print(f"({time.perf_counter() - start:.0f} s; {RESOLUTION} px, Monte Carlo tables of {PHOTONS:,} photons and "
          f"{DOUBLE_PHOTONS:,} double walks, {CELLS} x {CELLS} beams, {STEPS} steps, the green channel)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
