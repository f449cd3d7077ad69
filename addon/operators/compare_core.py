"""Cycles vs reference on the standard comparison scenes: render, measure, write pictures (bpy).

Model-agnostic: the Cycles side is any ``bpy.types.Material`` (node group, OSL script, built-in
nodes), the reference side any ``bsdf_eval(wi, wo) -> (N, 3)`` in the local shading frame (see
``addon.reference.scenes`` for the scenes and conventions). No operator classes here; the UI operator
calls ``compare`` and drives its progress bar through ``progress(fraction, message)``.
"""
from __future__ import annotations

import os
import re
import time
from typing import Callable, Mapping, Sequence

import numpy as np

from ..bake.exr import write_exr, write_png
from ..reference import metrics as _metrics
from ..reference import scenes as _scenes
from .cycles_render import render_cycles

__all__ = ["compare", "safe_file_stem"]


def safe_file_stem(name: str) -> str:
    """A scene name made safe for file names (letters, digits, '-', '_', '.')."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._")
    return stem or "scene"


def _samples_for(samples, scene) -> int:
    if isinstance(samples, Mapping):
        n = samples.get(scene.name, samples.get(scene.kind, samples.get("default")))
        if n is None:
            raise ValueError(f"no sample count for scene {scene.name!r} in {dict(samples)!r}")
    else:
        n = samples
    n = int(n)
    if n < 1:
        raise ValueError(f"sample count for {scene.name!r} must be >= 1, got {n}")
    return n


def compare(material, bsdf_eval: Callable, scenes: Sequence | None = None, samples=64, seed: int = 0,
            out_dir: str = ".", progress: Callable[[float, str], None] | None = None, *,
            bsdf_albedo: Callable | None = None, quadrature=(64, 128), worst: int = 10,
            exposure: float | None = None, picture_scale: int = 1, reference_cache: dict | None = None) -> dict:
    """Render every scene with Cycles (``material``) and with the reference (``bsdf_eval``).

    ``scenes``: ``Scene`` objects (default ``scenes.default_scenes()``), names must be unique.
    ``samples``: an int, or a mapping from scene name / kind (or "default") to a sample count.
    Writes ``<scene>_cycles.exr``, ``<scene>_reference.exr`` (32-bit float RGB(A), row 0 = top) and
    ``<scene>_side_by_side.png`` (Cycles | reference | error heat map) into ``out_dir``, each atomically.
    ``progress(fraction, message)`` is called before each scene, half-way through it and at the end.
    ``reference_cache`` (scene name → (reference image, seconds it took)), when given, is read and filled, so
    that comparing several materials against the same reference renders it once.

    Returns ``{scene_name: {rmse, rel_rmse, max_abs_error, worst_pixels, cycles_seconds,
    reference_seconds, reference_cached, samples, seed, pixels, exposure, heat_vmax, kind, resolution, files}}``;
    ``worst_pixels`` are (row, col, cycles_rgb, reference_rgb), row 0 = top; ``reference_seconds`` is the time the
    reference took when it was rendered, ``reference_cached`` whether this call took it from ``reference_cache``.
    """
    scenes = list(_scenes.default_scenes() if scenes is None else scenes)
    names = [s.name for s in scenes]
    stems = [safe_file_stem(n) for n in names]
    if len(set(stems)) != len(stems):
        raise ValueError(f"scene names must be unique (as file names): {names}")
    os.makedirs(out_dir, exist_ok=True)
    report = {}
    n = len(scenes)

    def tell(fraction, message):
        if progress is not None:
            progress(float(min(max(fraction, 0.0), 1.0)), message)

    for i, (scene, stem) in enumerate(zip(scenes, stems)):
        spp = _samples_for(samples, scene)
        tell(i / n, f"{scene.name}: Cycles, {spp} samples")
        cyc_path = os.path.join(out_dir, f"{stem}_cycles.exr")
        ref_path = os.path.join(out_dir, f"{stem}_reference.exr")
        png_path = os.path.join(out_dir, f"{stem}_side_by_side.png")
        cyc, cycles_seconds = render_cycles(material, scene, spp, seed, cyc_path)

        tell((i + 0.5) / n, f"{scene.name}: reference")
        cache = {} if reference_cache is None else reference_cache
        reference_cached = scene.name in cache
        if not reference_cached:
            t0 = time.perf_counter()
            image = _scenes.reference_image(scene, bsdf_eval, bsdf_albedo=bsdf_albedo, quadrature=quadrature)
            cache[scene.name] = (image, time.perf_counter() - t0)
        ref, reference_seconds = cache[scene.name]
        write_exr(ref_path, ref)

        mask = _scenes.scene_mask(scene)
        entry = _metrics.summary(cyc, ref, mask, worst)
        pic, pic_info = _metrics.side_by_side(cyc, ref, mask, exposure=exposure, scale=picture_scale)
        write_png(png_path, pic)
        entry.update({
            "cycles_seconds": cycles_seconds,
            "reference_seconds": reference_seconds,
            "reference_cached": reference_cached,
            "samples": spp,
            "seed": int(seed),
            "kind": scene.kind,
            "resolution": tuple(scene.resolution),
            "exposure": pic_info["exposure"],
            "heat_vmax": pic_info["heat_vmax"],
            "files": {"cycles": cyc_path, "reference": ref_path, "side_by_side": png_path},
        })
        if not np.all(np.isfinite(ref[mask])):
            entry["warning"] = "the reference has non-finite pixels (shown black; metrics are NaN)"
        report[scene.name] = entry
    tell(1.0, "done")
    return report
