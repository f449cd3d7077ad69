"""Tables of double and multiple scattering in infinite homogeneous media (Ge et al., Sec. 3.4), one file per
material, for the neural_medium networks.

For each (albedo, g) of the material grid, ``training.medium_tracer.simulate`` traces photons from a
point-directional source and tabulates Phi_2 (``double``) and Sum_{k>=3} Phi_k (``multiple``) over
(rho, z, theta, phi) (definitions, grid and estimator in that module's docstring), with standard errors from
independent batches. Each material is a seeded, self-contained .npz written atomically (temporary file + rename)
into the cache folder outside the repository; a file already there with the same configuration hash is skipped,
so an interrupted run resumes, and a changed configuration (photons, grid, seed, ...) recomputes only what it
changes. ``manifest.json`` lists what the folder holds.

    python -m training.medium_dataset                                   # the documented default (about an hour)
    python -m training.medium_dataset --albedos 0.9 --gs 0.5 --quick --out /tmp/m   # seconds, for tests

File arrays: ``double``, ``multiple`` and their ``*_se`` (float32, (n_rho, n_z, n_theta, n_phi), radiance per unit
volume per unit source power, lengths in mfp); ``density_double``, ``density_multiple`` and ``*_se`` (weighted
collision densities, (n_rho, n_z)); ``rho_edges``, ``z_edges``, ``theta``, ``phi`` (bin centres, radians);
``order_weight`` (mean weight per photon at order k, index k - 1; sums to 1 / (1 - alpha) up to far photons);
``captured`` (share of orders 1, 2, >= 3 inside the table); ``meta`` (JSON: configuration, its hash, photon
counts, seconds).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from dataclasses import asdict
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from addon.bake.exr import atomic_path
from training import medium_tracer as mt

VERSION = 1
DEFAULT_CACHE = Path(os.environ.get("LAMINA_CACHE", Path.home() / ".cache" / "lamina")) / "neural-medium"

# 7 x 8 = 56 materials. Albedo is spaced in log(1 - alpha) (what multiple scattering depends on) from oil's low
# albedos (0.03-0.45 in the paper's Table 1) up to milk's 0.999; g from -0.9 to 0.95 with the isotropic media of
# Table 1 (Lucy, cloud: g = 0) on the grid and denser where real media are (milk, wax, dragon: 0.5-0.9). g = 0.3 and
# 0.7 were added after the 42-material grid's multiple network missed milk (0.999, 0.7) by 16 % in a render.
ALBEDOS = (0.05, 0.3, 0.7, 0.9, 0.97, 0.99, 0.999)
GS = (-0.9, -0.3, 0.0, 0.3, 0.5, 0.7, 0.8, 0.95)

COLLISIONS = 4e8  # full walks per material: photons = COLLISIONS / (expected collisions + 1)
DOUBLE_PHOTONS = 40_000_000  # walks cut after collision 2 (the double table)
BATCHES = 8

QUICK_GRID = mt.Grid(rho_edges=(0.0, 0.5, 1.0, 2.0, 4.0), z_edges=(-4.0, -2.0, -1.0, 0.0, 1.0, 2.0, 4.0, 8.0),
                     n_theta=6, n_phi=6)


def material_name(alpha: float, g: float) -> str:
    return f"a{alpha:.4f}_g{g:+.3f}"


def auto_photons(alpha: float, collisions: float, batches: int) -> int:
    """Full-walk photons that cost about ``collisions`` collisions (the same time for every albedo)."""
    n = int(collisions / (mt.expected_collisions(alpha) + 1.0))
    return max(batches * 100, n - n % batches)


def config(alpha: float, g: float, grid: mt.Grid, settings: mt.Settings, seed: int) -> dict:
    return {"version": VERSION, "alpha": alpha, "g": g, "grid": grid.to_json(), "settings": asdict(settings),
            "roulette_used": mt.default_roulette(alpha) if settings.roulette is None else settings.roulette,
            "far_used": mt.default_far(grid) if settings.far is None else settings.far, "seed": seed}


def config_hash(cfg: dict) -> str:
    return hashlib.sha256(json.dumps(cfg, sort_keys=True).encode()).hexdigest()[:16]


def material_seed(seed: int, alpha: float, g: float) -> list:
    """Seed of one material, independent of which other materials are in the run."""
    return [seed, int(round(alpha * 1e6)), int(round((g + 1.0) * 1e6))]


def stored_hash(path: Path) -> str | None:
    try:
        with np.load(path) as f:
            return json.loads(str(f["meta"])).get("config_hash")
    except Exception:  # a foreign or damaged file is recomputed
        return None


def make_material(job) -> str:
    out, alpha, g, grid, settings, seed = job
    cfg = config(alpha, g, grid, settings, seed)
    h = config_hash(cfg)
    path = out / f"{material_name(alpha, g)}.npz"
    if path.exists() and stored_hash(path) == h:
        return f"{path.name} (cached)"
    r = mt.simulate(alpha, g, grid, settings, seed=material_seed(seed, alpha, g))
    meta = {**cfg, "config_hash": h, "photons": settings.photons, "double_photons": settings.double_photons,
            "seconds": round(r["seconds"], 2), "grid_shape": list(grid.shape), "dropped": int(r["dropped"]),
            "dropped_weight": float(r["dropped_weight"]), "captured": [float(c) for c in r["captured"]],
            "created": time.strftime("%Y-%m-%dT%H:%M:%S")}
    arrays = {k: r[k].astype(np.float32) for k in ("double", "double_se", "multiple", "multiple_se", "density_double",
                                                     "density_double_se", "density_multiple",
                                                     "density_multiple_se")}
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays, rho_edges=np.asarray(grid.rho_edges), z_edges=np.asarray(grid.z_edges),
                                theta=grid.theta_centres(), phi=grid.phi_centres(), order_weight=r["order_weight"],
                                captured=r["captured"], meta=np.array(json.dumps(meta)))
    return f"{path.name} {r['seconds']:.0f} s"


def write_manifest(out: Path) -> dict:
    """manifest.json: every material file in ``out`` with its configuration summary (rebuilt from the files)."""
    materials = []
    for path in sorted(out.glob("a*_g*.npz")):
        try:
            with np.load(path) as f:
                meta = json.loads(str(f["meta"]))
        except Exception:
            continue
        materials.append({"file": path.name, "alpha": meta["alpha"], "g": meta["g"], "config_hash": meta["config_hash"],
                          "photons": meta["photons"], "double_photons": meta["double_photons"],
                          "seconds": meta["seconds"], "captured": meta["captured"], "seed": meta["seed"],
                          "bytes": path.stat().st_size})
    manifest = {"version": VERSION, "materials": materials,
                "seconds": round(sum(m["seconds"] for m in materials), 1),
                "megabytes": round(sum(m["bytes"] for m in materials) / 1e6, 1),
                "definition": "double = Phi_2, multiple = Sum_{k>=3} Phi_k: radiance emitted per unit volume per unit "
                              "source power (see training/medium_tracer.py)"}
    with atomic_path(out / "manifest.json") as tmp:
        Path(tmp).write_text(json.dumps(manifest, indent=1))
    return manifest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.medium_dataset", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_CACHE, help=f"cache folder (default {DEFAULT_CACHE})")
    ap.add_argument("--albedos", type=float, nargs="+", default=list(ALBEDOS))
    ap.add_argument("--gs", type=float, nargs="+", default=list(GS))
    ap.add_argument("--photons", type=int, default=None,
                    help="full-walk photons per material (default: --collisions / expected collisions per photon)")
    ap.add_argument("--collisions", type=float, default=COLLISIONS, help="collision budget of the full walks")
    ap.add_argument("--double-photons", type=int, default=DOUBLE_PHOTONS)
    ap.add_argument("--batches", type=int, default=BATCHES, help="independent batches (standard errors)")
    ap.add_argument("--extent", type=float, default=256.0, help="table half-width in mfp")
    ap.add_argument("--n-rho", type=int, default=40)
    ap.add_argument("--n-z", type=int, default=80)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--quick", action="store_true", help="a tiny grid and photon count, for tests (seconds)")
    a = ap.parse_args(argv)
    for alpha in a.albedos:
        if not 0.0 <= alpha < 1.0:
            raise SystemExit(f"albedo {alpha}: the dataset needs 0 <= albedo < 1 (albedo 1 never ends its walks)")
    for g in a.gs:
        if not -1.0 < g < 1.0:
            raise SystemExit(f"g {g}: must be in (-1, 1)")
    if a.quick:
        grid = QUICK_GRID
        base = mt.Settings(photons=400, double_photons=4000, batches=2, sub=4)
    else:
        grid = mt.default_grid(a.extent, a.n_rho, a.n_z)
        base = None
    jobs = []
    for alpha in a.albedos:
        for g in a.gs:
            if base is None:
                photons = a.photons or auto_photons(alpha, a.collisions, a.batches)
                settings = mt.Settings(photons=photons, double_photons=a.double_photons, batches=a.batches)
            else:
                settings = base
            jobs.append((a.out, float(alpha), float(g), grid, settings, a.seed))
    a.out.mkdir(parents=True, exist_ok=True)
    start = time.time()
    workers = max(1, min(a.workers, len(jobs)))
    if workers == 1:
        results = map(make_material, jobs)
    else:
        pool = Pool(workers)
        results = pool.imap_unordered(make_material, jobs)
    try:
        for done, name in enumerate(results, 1):
            write_manifest(a.out)
            print(f"[{done}/{len(jobs)}] {name}  {time.time() - start:.0f} s", flush=True)
    finally:
        if workers > 1:
            pool.close()
            pool.join()
    manifest = write_manifest(a.out)
    print(f"{len(manifest['materials'])} materials in {a.out} ({manifest['seconds']:.0f} s of simulation in all, "
          f"{manifest['megabytes']:.0f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
