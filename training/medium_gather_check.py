"""How far the infinite-medium tables are from a finite object: the gather (``addon.reference.neural_medium.gather``)
with Monte Carlo tables of the medium itself (no network) against the independent path tracer
(``addon.reference.neural_medium_truth``) on the comparison sphere and a thin box, per preset and size. What it
prints goes into docs/training.md ("What the infinite-medium tables miss").

    python -m training.medium_gather_check            # about five minutes here
    python -m training.medium_gather_check --offsets 0 1 2 4   # the camera image's offset, each on every shape
    python -m training.medium_gather_check --exits 0 1 1-g "(1-g)^2" 0.5   # the exit planes' images' weight
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

# (preset, scale, shape); the green channel. The box is compare-medium's tile, 1.6 x 1.6 x 0.5 units.
CASES = (("cloud", 0.5, "sphere"), ("cloud", 0.1, "sphere"), ("lucy", 0.2, "sphere"), ("milk", 0.25, "sphere"),
         ("milk", 0.05, "sphere"), ("cloud", 0.5, "box"), ("milk", 0.25, "box"))
SHAPES = {"sphere": truth.Sphere(), "box": truth.Box((-0.8, -0.8, -0.25), (0.8, 0.8, 0.25))}
RESOLUTION, PATHS, PHOTONS, DOUBLE_PHOTONS = 16, 1024, 60_000, 600_000
EXIT_WEIGHTS = {"0": lambda g: 0.0, "1": lambda g: 1.0, "0.5": lambda g: 0.5, "1-g": lambda g: min(1.0, 1.0 - g),
                "(1-g)^2": lambda g: min(1.0, 1.0 - g) ** 2}


def setting(name: str, scale: float, shape_name: str, channel: int = 1) -> dict:
    """Everything a measurement of one shape needs: the medium, its Monte Carlo tables, the camera rays, the sun's
    beams and the truth."""
    p = model.params_from_dict({**presets.load(model.ID, name), "scale": scale})
    grid = mt.default_grid()
    r = mt.simulate(p.albedo[channel], p.g, grid, mt.Settings(photons=PHOTONS, double_photons=DOUBLE_PHOTONS,
                                                              batches=4), seed=[7])
    edges = (np.asarray(grid.rho_edges), np.asarray(grid.z_edges), grid.theta_centres(), grid.phi_centres())
    scene, shape = S.sphere_scene(resolution=RESOLUTION), SHAPES[shape_name]
    t = truth.render(p, shape, scene, PATHS, seed=3)
    inside = S.scene_mask(scene) if shape_name == "sphere" else True
    return {"name": name, "scale": scale, "shape_name": shape_name, "shape": shape, "channel": channel, "p": p,
            "tables": {kind: nm.Table(r[kind], *edges) for kind in nm.KINDS},
            "rays": truth.camera_rays(scene, shape),
            "beams": nm.Beams.join(nm.sun_beams(shape, sun, 48) for sun in scene.suns),
            "truth": t, "mask": (inside & t["mask"]).ravel()}


def _error(s: dict, order: str, got) -> tuple[float, float]:
    ref = s["truth"][order][..., s["channel"]].ravel()[s["mask"]]
    got = got[s["mask"]]
    return got.mean() / ref.mean() - 1.0, float(np.sqrt(np.mean((got - ref) ** 2)) / ref.mean())


def images_error(s: dict, exits=None) -> tuple[float, float]:
    """Multiple scattering with the boundary images (``nm.IMAGE_OFFSET`` as it is now; the exit planes' images
    weighted ``exits``, by default ``nm.boundary``'s) against the truth."""
    p, c = s["p"], s["channel"]
    images = nm.boundary(p.albedo[c], p.g)
    if exits is not None:
        images = nm.Boundary(images.zb, exits)
    imaged = nm.gather(s["tables"], p.mean_free_path[c], s["shape"], s["beams"], *s["rays"], kinds=("multiple",),
                       images=images)
    return _error(s, "multiple", imaged["multiple"])


def measure(name: str, scale: float, shape_name: str, channel: int = 1) -> dict:
    s = setting(name, scale, shape_name, channel)
    p, t = s["p"], s["truth"]
    gathered = nm.gather(s["tables"], p.mean_free_path[channel], s["shape"], s["beams"], *s["rays"])
    out = {"preset": name, "scale": scale, "shape": shape_name, "across": float(truth.optical_depth(p, 2.0)[channel]),
           "albedo": p.albedo[channel], "g": p.g, "double": _error(s, "order2", gathered["double"]),
           "multiple": _error(s, "multiple", gathered["multiple"]), "entry_images": images_error(s, 0.0),
           "images": images_error(s)}
    total = sum(t[o][..., channel].ravel()[s["mask"]].mean() for o in truth.GROUPS)
    out["multiple_share"] = t["multiple"][..., channel].ravel()[s["mask"]].mean() / total
    return out


def offsets(values) -> None:
    """Mean error of multiple scattering with the boundary images for each camera-image offset (in z_b) of
    ``nm.IMAGE_OFFSET``, per shape, and the mean |error| over them."""
    default = nm.IMAGE_OFFSET

    def error(s, v):
        nm.IMAGE_OFFSET = v
        return images_error(s)[0]

    try:
        _compare([f"offset {v:g} z_b" for v in values], [lambda s, v=v: error(s, v) for v in values])
    finally:
        nm.IMAGE_OFFSET = default


def exit_weights(names) -> None:
    """Mean error of multiple scattering with the exit planes' images weighted each of ``names`` (EXIT_WEIGHTS),
    per shape, and the mean |error| over them."""
    _compare([f"exits {n}" for n in names],
             [lambda s, n=n: images_error(s, EXIT_WEIGHTS[n](s["p"].g))[0] for n in names])


def _compare(labels, errors) -> None:
    table = {label: [] for label in labels}
    print("| preset | scale | shape | " + " | ".join(labels) + " |")
    print("|---|---|---|" + "---|" * len(labels))
    for name, scale, shape_name in CASES:
        s = setting(name, scale, shape_name)
        row = []
        for label, error in zip(labels, errors):
            e = error(s)
            table[label].append(abs(e))
            row.append(f"{e:+.1%}")
        print(f"| {name} | {scale:g} | {shape_name} | " + " | ".join(row) + " |", flush=True)
    print("| mean \\|error\\| | | | " + " | ".join(f"{np.mean(table[label]):.1%}" for label in labels) + " |")


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m training.medium_gather_check", description=__doc__.split("\n\n")[0])
    ap.add_argument("--offsets", type=float, nargs="+", help="compare these camera-image offsets (z_b) instead")
    ap.add_argument("--exits", nargs="+", choices=list(EXIT_WEIGHTS), help="compare these weights of the exit "
                                                                            "planes' images instead")
    a = ap.parse_args(argv)
    if a.offsets:
        offsets(a.offsets)
        return 0
    if a.exits:
        exit_weights(a.exits)
        return 0
    start = time.time()
    print("| preset | scale | shape | mfp across | albedo, g | double: mean, rel. RMSE | multiple: mean, rel. RMSE | "
          "multiple, entry planes' images | multiple, all images (the bake's) | orders >= 3 of all light |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, scale, shape_name in CASES:
        m = measure(name, scale, shape_name)
        print(f"| {name} | {scale:g} | {shape_name} | {m['across']:.1f} | {m['albedo']:.3f}, {m['g']:g} | "
              f"{m['double'][0]:+.1%}, {m['double'][1]:.1%} | {m['multiple'][0]:+.1%}, {m['multiple'][1]:.1%} | "
              f"{m['entry_images'][0]:+.1%}, {m['entry_images'][1]:.1%} | {m['images'][0]:+.1%}, "
              f"{m['images'][1]:.1%} | {m['multiple_share']:.0%} |", flush=True)
    print(f"({time.time() - start:.0f} s; {RESOLUTION} px, {PATHS} truth paths per pixel, tables of "
          f"{PHOTONS:,} photons and {DOUBLE_PHOTONS:,} double walks, green channel)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
