"""How far the infinite-medium tables are from a finite object: the gather (``addon.reference.neural_medium.gather``)
with Monte Carlo tables of the medium itself (no network) against the independent path tracer
(``addon.reference.neural_medium_truth``) on the comparison sphere, per preset and size. What it prints goes into
docs/training.md ("What the infinite-medium tables miss").

    python -m training.medium_gather_check            # about two minutes here
"""
from __future__ import annotations

import time

import numpy as np

from addon import presets
from addon.models import neural_medium as model
from addon.reference import neural_medium as nm
from addon.reference import neural_medium_truth as truth
from addon.reference import scenes as S
from training import medium_tracer as mt

CASES = (("cloud", 0.5), ("cloud", 0.1), ("lucy", 0.2), ("milk", 0.25), ("milk", 0.05))  # (preset, scale); green channel
RESOLUTION, PATHS, PHOTONS, DOUBLE_PHOTONS = 16, 1024, 60_000, 600_000


def measure(name: str, scale: float, channel: int = 1) -> dict:
    p = model.params_from_dict({**presets.load(model.ID, name), "scale": scale})
    grid = mt.default_grid()
    r = mt.simulate(p.albedo[channel], p.g, grid, mt.Settings(photons=PHOTONS, double_photons=DOUBLE_PHOTONS,
                                                              batches=4), seed=[7])
    edges = (np.asarray(grid.rho_edges), np.asarray(grid.z_edges), grid.theta_centres(), grid.phi_centres())
    tables = {kind: nm.Table(r[kind], *edges) for kind in nm.KINDS}
    scene = S.sphere_scene(resolution=RESOLUTION)
    origins, directions = truth.camera_rays(scene, truth.Sphere())
    beams = nm.Beams.join(nm.sun_beams(truth.Sphere(), sun, 48) for sun in scene.suns)
    gathered = nm.gather(tables, p.mean_free_path[channel], truth.Sphere(), beams, origins, directions)
    zb = nm.extrapolation_distance(p.albedo[channel], p.g)
    imaged = nm.gather(tables, p.mean_free_path[channel], truth.Sphere(), beams, origins, directions,
                       kinds=("multiple",), images=zb)
    t = truth.render(p, truth.Sphere(), scene, PATHS, seed=3)
    mask = (S.scene_mask(scene) & t["mask"]).ravel()
    out = {"preset": name, "scale": scale, "across": float(truth.optical_depth(p, 2.0)[channel]),
           "albedo": p.albedo[channel], "g": p.g}
    for kind, order, got in (("double", "order2", gathered["double"]), ("multiple", "multiple", gathered["multiple"]),
                             ("images", "multiple", imaged["multiple"])):
        ref = t[order][..., channel].ravel()[mask]
        got = got[mask]
        out[kind] = (got.mean() / ref.mean() - 1.0, float(np.sqrt(np.mean((got - ref) ** 2)) / ref.mean()))
    total = sum(t[o][..., channel].ravel()[mask].mean() for o in truth.GROUPS)
    out["multiple_share"] = t["multiple"][..., channel].ravel()[mask].mean() / total
    return out


def main() -> int:
    start = time.time()
    print("| preset | scale | mfp across | albedo, g | double: mean, rel. RMSE | multiple: mean, rel. RMSE | "
          "multiple with boundary images | orders >= 3 of all light |")
    print("|---|---|---|---|---|---|---|---|")
    for name, scale in CASES:
        m = measure(name, scale)
        print(f"| {name} | {scale:g} | {m['across']:.1f} | {m['albedo']:.3f}, {m['g']:g} | "
              f"{m['double'][0]:+.1%}, {m['double'][1]:.1%} | {m['multiple'][0]:+.1%}, {m['multiple'][1]:.1%} | "
              f"{m['images'][0]:+.1%}, {m['images'][1]:.1%} | "
              f"{m['multiple_share']:.0%} |", flush=True)
    print(f"({time.time() - start:.0f} s; {RESOLUTION} px sphere, {PATHS} truth paths per pixel, tables of "
          f"{PHOTONS:,} photons and {DOUBLE_PHOTONS:,} double walks, green channel)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
