"""How far the infinite-medium tables are from a finite object: the gather (``addon.reference.neural_medium.gather``)
with Monte Carlo tables of the medium itself (no network) against the independent path tracer
(``addon.reference.neural_medium_truth``) on the comparison sphere, per preset and size. What it prints goes into
docs/training.md ("What the infinite-medium tables miss").

    python -m training.medium_gather_check            # about five minutes here
    python -m training.medium_gather_check --offsets 0 1 2 4   # the camera image's offset, each on every sphere
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

# (preset, scale); the green channel
CASES = (("cloud", 0.5), ("cloud", 0.1), ("lucy", 0.2), ("milk", 0.25), ("milk", 0.05))
RESOLUTION, PATHS, PHOTONS, DOUBLE_PHOTONS = 16, 1024, 60_000, 600_000


def setting(name: str, scale: float, channel: int = 1) -> dict:
    """Everything a measurement of one sphere needs: the medium, its Monte Carlo tables, the camera rays, the sun's
    beams and the truth."""
    p = model.params_from_dict({**presets.load(model.ID, name), "scale": scale})
    grid = mt.default_grid()
    r = mt.simulate(p.albedo[channel], p.g, grid, mt.Settings(photons=PHOTONS, double_photons=DOUBLE_PHOTONS,
                                                              batches=4), seed=[7])
    edges = (np.asarray(grid.rho_edges), np.asarray(grid.z_edges), grid.theta_centres(), grid.phi_centres())
    scene = S.sphere_scene(resolution=RESOLUTION)
    t = truth.render(p, truth.Sphere(), scene, PATHS, seed=3)
    return {"name": name, "scale": scale, "channel": channel, "p": p,
            "tables": {kind: nm.Table(r[kind], *edges) for kind in nm.KINDS},
            "rays": truth.camera_rays(scene, truth.Sphere()),
            "beams": nm.Beams.join(nm.sun_beams(truth.Sphere(), sun, 48) for sun in scene.suns),
            "truth": t, "mask": (S.scene_mask(scene) & t["mask"]).ravel()}


def _error(s: dict, order: str, got) -> tuple[float, float]:
    ref = s["truth"][order][..., s["channel"]].ravel()[s["mask"]]
    got = got[s["mask"]]
    return got.mean() / ref.mean() - 1.0, float(np.sqrt(np.mean((got - ref) ** 2)) / ref.mean())


def images_error(s: dict) -> tuple[float, float]:
    """Multiple scattering with the boundary images (``nm.IMAGE_OFFSET`` as it is now) against the truth."""
    p, c = s["p"], s["channel"]
    imaged = nm.gather(s["tables"], p.mean_free_path[c], truth.Sphere(), s["beams"], *s["rays"], kinds=("multiple",),
                       images=nm.extrapolation_distance(p.albedo[c], p.g))
    return _error(s, "multiple", imaged["multiple"])


def measure(name: str, scale: float, channel: int = 1) -> dict:
    s = setting(name, scale, channel)
    p, t = s["p"], s["truth"]
    gathered = nm.gather(s["tables"], p.mean_free_path[channel], truth.Sphere(), s["beams"], *s["rays"])
    out = {"preset": name, "scale": scale, "across": float(truth.optical_depth(p, 2.0)[channel]),
           "albedo": p.albedo[channel], "g": p.g, "double": _error(s, "order2", gathered["double"]),
           "multiple": _error(s, "multiple", gathered["multiple"]), "images": images_error(s)}
    total = sum(t[o][..., channel].ravel()[s["mask"]].mean() for o in truth.GROUPS)
    out["multiple_share"] = t["multiple"][..., channel].ravel()[s["mask"]].mean() / total
    return out


def offsets(values) -> None:
    """Mean error of multiple scattering with the boundary images for each camera-image offset (in z_b) of
    ``nm.IMAGE_OFFSET``, per sphere, and the mean |error| over them."""
    default = nm.IMAGE_OFFSET
    errors = {v: [] for v in values}
    print("| preset | scale | " + " | ".join(f"offset {v:g} z_b" for v in values) + " |")
    print("|---|---|" + "---|" * len(values))
    try:
        for name, scale in CASES:
            s = setting(name, scale)
            row = []
            for v in values:
                nm.IMAGE_OFFSET = v
                e = images_error(s)[0]
                errors[v].append(abs(e))
                row.append(f"{e:+.1%}")
            print(f"| {name} | {scale:g} | " + " | ".join(row) + " |", flush=True)
    finally:
        nm.IMAGE_OFFSET = default
    print("| mean \\|error\\| | | " + " | ".join(f"{np.mean(errors[v]):.1%}" for v in values) + " |")


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m training.medium_gather_check", description=__doc__.split("\n\n")[0])
    ap.add_argument("--offsets", type=float, nargs="+", help="compare these camera-image offsets (z_b) instead")
    a = ap.parse_args(argv)
    if a.offsets:
        offsets(a.offsets)
        return 0
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
