"""Compare a neural medium (bpy): Cycles single scattering, single scattering + Lamina's bake, Cycles' full
volumetric path tracing, and Cycles' random-walk subsurface scattering of the same medium (a Principled BSDF,
``nodes/subsurface_np.py``: what an artist would use instead of a volume), each with its render time and its error against Cycles' full path tracing (the external
truth) and, for the shapes it renders (sphere, box), the numpy ground truth (``reference/neural_medium_truth.py``,
all orders). Shapes: the comparison sphere, a box (a thick tile: thin parts at its edges), a torus (closed, not
convex) and Suzanne (her head, eye sockets closed: thin ears, a mesh as an artist has one). Shared by ``lamina
compare-medium`` (pictures and report.json) and the bench. The user's scene is untouched: everything renders in ``cycles_render``'s temporary scene (its mesh replaced for the other shapes),
whose sun the bake uses.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import bpy  # noqa: I001 - the bpy module must be imported before bmesh
import bmesh
import numpy as np

from ..bake import neural_medium as nb
from ..bake.exr import atomic_path, write_png
from ..nodes import neural_medium as medium_nodes
from ..reference import metrics
from ..reference import neural_medium_truth as truth
from ..reference import scenes as S
from . import blend_io, medium_bake
from .compare_run import comparison_picture, write_text_atomic
from .cycles_render import render_cycles

CACHE = Path(os.environ.get("LAMINA_CACHE", Path.home() / ".cache" / "lamina")) / "neural-medium-truth"
SINGLE, BAKED, FULL = "single scattering", "single + Lamina bake", "Cycles full path tracing"
SUBSURFACE = "Cycles random-walk SSS"


@dataclass(frozen=True)
class Sizes:
    samples: int = 64
    resolution: int = 48
    truth_paths: int = 1024
    full_bounces: int = 1024
    bake: nb.Settings = nb.Settings()
    equal_error_samples: int = 0  # > 0: also find the samples Cycles' full path tracing needs for the bake's error


SHAPES = truth.COMPARE_SHAPES
BOX = truth.Box((-0.8, -0.8, -0.25), (0.8, 0.8, 0.25))
TORUS = (0.65, 0.3)  # major and minor radius


def scene(resolution: int) -> S.Scene:
    return S.sphere_scene(resolution=resolution, sphere_segments=64, sphere_rings=32)


def _numpy_shape(shape: str):
    return {"sphere": truth.Sphere(), "box": BOX}.get(shape)


def _box_mesh(cuts: int = 15):
    """The box with every face cut into a grid (the bake lives at vertices: large faces would interpolate it)."""
    bm = bmesh.new()
    try:
        bmesh.ops.create_cube(bm, size=2.0)
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)
        half = [0.5 * (b - a) for a, b in zip(BOX.lo, BOX.hi)]
        centre = [0.5 * (a + b) for a, b in zip(BOX.lo, BOX.hi)]
        verts = [tuple(c + h * x for c, h, x in zip(centre, half, v.co)) for v in bm.verts]
        faces = [tuple(v.index for v in f.verts) for f in bm.faces]
    finally:
        bm.free()
    return verts, faces


def _torus_mesh(segments: int = 48, sides: int = 16):
    major, minor = TORUS
    verts, faces = [], []
    for i in range(segments):
        u = 2.0 * math.pi * i / segments
        for j in range(sides):
            v = 2.0 * math.pi * j / sides
            r = major + minor * math.cos(v)
            verts.append((r * math.cos(u), r * math.sin(u), minor * math.sin(v)))
    for i in range(segments):
        for j in range(sides):
            a, b = i * sides + j, ((i + 1) % segments) * sides + j
            faces.append((a, b, ((i + 1) % segments) * sides + (j + 1) % sides, i * sides + (j + 1) % sides))
    return verts, faces


SUZANNE_SCALE = 0.7  # her head (2.7 units wide as Blender makes it) about 2 units across, as the comparison sphere


def _suzanne_mesh():
    """Suzanne's head without her eyes (separate parts inside it), the sockets filled to close it, subdivided once
    (the bake lives at vertices), turned to face the comparison camera."""
    bm = bmesh.new()
    try:
        bmesh.ops.create_monkey(bm)
        head = max(_islands(bm), key=len)
        bmesh.ops.delete(bm, geom=[v for v in bm.verts if v not in head], context="VERTS")
        bmesh.ops.holes_fill(bm, edges=bm.edges[:], sides=0)
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=1, use_grid_fill=True)
        verts = [tuple(SUZANNE_SCALE * x for x in (v.co.x, v.co.z, -v.co.y)) for v in bm.verts]
        faces = [tuple(v.index for v in f.verts) for f in bm.faces]
    finally:
        bm.free()
    return verts, faces


def _islands(bm) -> list[set]:
    """The connected parts of a bmesh, as sets of vertices."""
    seen, parts = set(), []
    for start in bm.verts:
        if start in seen:
            continue
        part, stack = set(), [start]
        while stack:
            v = stack.pop()
            if v not in part:
                part.add(v)
                stack.extend(e.other_vert(v) for e in v.link_edges)
        seen |= part
        parts.append(part)
    return parts


MESHES = {"box": _box_mesh, "torus": _torus_mesh, "suzanne": _suzanne_mesh}


def _reshape(obj, shape: str) -> None:
    """Give the temporary scene's object the ``shape``'s mesh (the sphere stays as cycles_render made it)."""
    if shape == "sphere":
        return
    verts, faces = MESHES[shape]()
    mesh = obj.data
    mesh.clear_geometry()
    mesh.from_pydata(verts, [], faces)
    mesh.update()


def cached_truth(p, spec: S.Scene, paths: int, shape=truth.Sphere(), shape_name: str = "sphere") -> dict:
    """The numpy truth of ``p`` filling ``shape`` under ``spec`` (all orders, its standard error, single
    scattering), cached by content hash outside the repository (a second run reuses it)."""
    key = hashlib.sha256(json.dumps([p.to_dict(), spec.name, spec.width, spec.height, paths, shape_name, repr(shape),
                                     1], sort_keys=True).encode()).hexdigest()[:16]
    path = CACHE / f"{key}.npz"
    if path.exists():
        with np.load(path) as f:
            return {k: f[k] for k in f.files}
    t = truth.render(p, shape, spec, paths, seed=1)
    out = {"total": t["total"], "order1": t["order1"], "mask": t["mask"],
           "noise": np.sqrt(sum(t["noise"][g] ** 2 for g in truth.GROUPS)), "seconds": np.array(t["seconds"])}
    CACHE.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **out)
    return out


def _psnr(img, ref, mask) -> float:
    mse = float(np.mean((img[mask] - ref[mask]) ** 2))
    peak = float(ref[mask].max())
    return 20.0 * math.log10(peak / math.sqrt(mse)) if mse > 0 and peak > 0 else math.inf


def _full_at_error(mat, spec, sizes: Sizes, path: str, prepare, ref, mask, target: float) -> dict:
    """Cycles' full path tracing at twice, four times, ... ``sizes.samples`` (up to ``equal_error_samples``) until
    its relative RMSE against the truth is at most ``target`` (the bake's): the samples, the time and the error of
    the first that is (``reached`` False if none up to the cap)."""
    samples = sizes.samples
    while True:
        samples *= 2
        img, seconds = render_cycles(mat, spec, samples, 0, path, bounces=sizes.full_bounces, prepare=prepare)
        error = float(metrics.rel_rmse(img, ref, mask))
        if error <= target or 2 * samples > sizes.equal_error_samples:
            return {"samples": samples, "seconds": seconds, "rel_rmse": error, "target": target,
                    "reached": error <= target}


def compare_medium(p, sizes: Sizes = Sizes(), out_dir: str | None = None, label: str = "custom",
                   shape: str = "sphere") -> dict:
    """The report (module docstring); with ``out_dir``, also ``comparison.png`` (the four Cycles images and the
    truth, then each one's error map against the truth) and ``report.json`` there."""
    if shape not in SHAPES:
        raise ValueError(f"unknown shape {shape!r}; expected one of {', '.join(SHAPES)}")
    spec = scene(sizes.resolution)
    numpy_shape = _numpy_shape(shape)
    t = cached_truth(p, spec, sizes.truth_paths, numpy_shape, shape) if numpy_shape is not None else None
    bake_info: dict = {}

    def plain(scene_, obj):
        _reshape(obj, shape)

    def bake(scene_, obj):
        _reshape(obj, shape)
        scene_.view_layers[0].update()  # the temporary sun's matrix
        start = time.perf_counter()
        tables = nb.channel_tables(p)
        bake_info["tables_seconds"] = time.perf_counter() - start
        result = medium_bake.run(obj, scene_, scene_.view_layers[0].depsgraph, p, sizes.bake, tables=tables)
        bake_info.update(result["record"])
        bake_info["bake_seconds"] = time.perf_counter() - start - bake_info["tables_seconds"]

    path = os.path.join(bpy.app.tempdir, "lamina_medium.exr")
    before = blend_io.snapshot()
    equal_error = None
    try:
        mat, sss = medium_nodes.new_material(p), medium_nodes.subsurface_material(p)
        subsurface_notes = json.loads(sss["lamina_notes"])
        images = {SINGLE: render_cycles(mat, spec, sizes.samples, 0, path, prepare=plain),
                  BAKED: render_cycles(mat, spec, sizes.samples, 0, path, prepare=bake),
                  FULL: render_cycles(mat, spec, sizes.samples, 0, path, bounces=sizes.full_bounces,
                                      prepare=plain),
                  SUBSURFACE: render_cycles(sss, spec, sizes.samples, 0, path, prepare=plain)}
        full = images[FULL][0]
        if t is not None:
            ref, mask = t["total"], t["mask"].astype(bool) & (S.scene_mask(spec) if shape == "sphere" else True)
            truth_report = {"paths": sizes.truth_paths,
                            "relative_noise": float(np.sqrt(np.mean(t["noise"][mask] ** 2)) / ref[mask].mean())}
            if sizes.equal_error_samples:
                target = float(metrics.rel_rmse(images[BAKED][0], ref, mask))
                equal_error = _full_at_error(mat, spec, sizes, path, plain, ref, mask, target)
        else:  # no numpy truth for this shape: Cycles' full path tracing is the truth
            ref, mask = full, np.max(images[SINGLE][0], axis=-1) > 0.0
            truth_report = None
    finally:
        blend_io.remove_new_data(before)
    report = {"label": label, "shape": shape, "params": p.to_dict(), "resolution": sizes.resolution,
              "samples": sizes.samples, "mean_free_paths_across": float(truth.optical_depth(p, 2.0).mean()),
              "truth": truth_report, "bake": bake_info, "subsurface_notes": subsurface_notes,
              "full_at_bake_error": equal_error, "forms": {}}
    for name, (img, seconds) in images.items():
        report["forms"][name] = {"seconds": seconds, "energy_error": float(img[mask].mean() / ref[mask].mean() - 1.0),
                                 "rel_rmse": float(metrics.rel_rmse(img, ref, mask)), "psnr": _psnr(img, ref, mask),
                                 "energy_vs_full": float(img[mask].mean() / full[mask].mean() - 1.0),
                                 "rel_rmse_vs_full": float(metrics.rel_rmse(img, full, mask)),
                                 "finite": bool(np.isfinite(img).all()), "min": float(img.min())}
    if out_dir is not None:
        shown = [img for img, _ in images.values()] + ([ref] if t is not None else [])
        picture = comparison_picture(shown, ref, mask)
        write_png(os.path.join(out_dir, "comparison.png"), picture)
        write_text_atomic(os.path.join(out_dir, "report.json"), json.dumps(report, indent=1))
    return report


def summary_lines(report: dict) -> str:
    noise = (f"numpy truth noise {report['truth']['relative_noise']:.1%}" if report["truth"]
             else "no numpy truth: errors against Cycles' full path tracing")
    lines = [f"{report['label']} ({report['shape']}): {report['mean_free_paths_across']:.1f} mean free paths per 2 "
             f"units, {noise}"]
    for name, f in report["forms"].items():
        lines.append(f"  {name:28s} {f['seconds']:7.2f} s  energy {f['energy_error']:+.1%}  rel. RMSE "
                     f"{f['rel_rmse']:.1%}  vs full path tracing {f['rel_rmse_vs_full']:.1%}")
    b = report["bake"]
    lines += [f"  {SUBSURFACE}: {note}" for note in report["subsurface_notes"]]
    equal = report.get("full_at_bake_error")
    if equal is not None:
        lines.append(f"  full path tracing at {equal['samples']} samples: rel. RMSE {equal['rel_rmse']:.1%} "
                     f"(the bake's {equal['target']:.1%}) in {equal['seconds']:.2f} s")
    lines.append(f"  bake: {b['points']} points, {b['beams']} beams, {b['bake_seconds']:.1f} s (tables "
                 f"{b['tables_seconds']:.1f} s)")
    return "\n".join(lines)
