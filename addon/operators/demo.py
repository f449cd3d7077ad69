"""The demo (``lamina demo``, ``make demo``): every model's presets compared with their reference, written as one
report page a person can read (bpy: Cycles renders; the page itself is written by ``addon.demo_page``).

Layout of ``out_dir``: ``<model>/<preset>/`` holds each comparison (``compare_run.compare_params``: pictures, EXRs,
``report.json``), ``overview.png`` the sphere strips of every preset, ``index.html`` the page.
"""
from __future__ import annotations

import datetime
import os
import time
from pathlib import Path

import numpy as np

from .. import demo_page, presets
from ..bake.exr import read_png, write_png
from ..models import MODELS
from ..nodes import approximations
from ..nodes import material as lamina_material
from . import blend_io, compare_run

ACCURACY = Path(__file__).resolve().parents[2] / "docs" / "accuracy.md"


def run(models, forms, scenes, samples: int, resolution: int, seed: int, out_dir: str,
        all_presets: bool = False) -> list[dict]:
    """Compare the presets of each model of ``models`` (ids, in that order) in ``forms`` and write the report.
    ``all_presets`` False: each model's demo selection (``presets.demo_names``), True: every preset. ``scenes``
    (names) None: each preset's applicable scenes (``compare_run.default_scene_names``); scenes that do not apply
    to a preset (``compare_run.inapplicable_scenes``) are never rendered, the report says why. Prints one progress
    line per preset, then a summary. Returns the reports (``demo_page``'s module docstring)."""
    jobs = [(m, name) for m in models for name in (presets.names(m) if all_presets else presets.demo_names(m))]
    if not jobs:
        raise ValueError(f"no presets to show for {', '.join(models) or 'no model'}")
    t0 = time.perf_counter()
    reports = []
    for model_id, name in jobs:
        reports.append(run_preset(model_id, name, forms, scenes, samples, resolution, seed, out_dir))
        left = demo_page.time_left(reports, [m for m, _ in jobs[len(reports):]])
        print(demo_page.progress_line(len(reports), len(jobs), reports[-1], time.perf_counter() - t0, left),
              flush=True)
    picture = overview(reports, out_dir)
    write_png(os.path.join(out_dir, demo_page.OVERVIEW), picture)
    page = demo_page.index_html(reports, accuracy_href(out_dir), datetime.date.today().isoformat(), picture.shape[1])
    compare_run.write_text_atomic(os.path.join(out_dir, "index.html"), page)
    print("\n".join(demo_page.summary_lines(reports)), flush=True)
    return reports


def run_preset(model_id: str, name: str, forms, scenes, samples: int, resolution: int, seed: int,
               out_dir: str) -> dict:
    """One preset compared into ``<out_dir>/<model>/<name>``: ``compare_params``' report plus the demo's keys."""
    t0 = time.perf_counter()
    p = MODELS[model_id].params_from_dict(presets.load(model_id, name))
    skipped = compare_run.inapplicable_scenes(p)
    asked = list(compare_run.SCENES) if scenes is None else list(scenes)
    folder = os.path.join(out_dir, model_id, name)
    report = compare_run.compare_params(model_id, p, forms, [s for s in asked if s not in skipped], samples,
                                        resolution, seed, folder, label=name,
                                        principled=compare_run.has_principled(model_id))
    report.update({
        "dir": f"{model_id}/{name}",
        "description": presets.description(model_id, name),
        "not_applicable": {s: why for s, why in skipped.items() if s in asked},
        "approximations": [list(a) for a in approximations(model_id, p)],
        "principled_seconds": principled_seconds(model_id, p, report, resolution, folder),
    })
    report["seconds"] = time.perf_counter() - t0
    return report


def principled_seconds(model_id: str, p, report: dict, resolution: int, folder: str) -> float | None:
    """The Cycles time of the model's Principled BSDF (``principled_settings``) on ``demo_page.TIMED_SCENE`` with
    the report's samples and seed (None when that scene was not rendered). A comparison with the mapping's
    Principled counterpart (``compare_run.has_principled``) rendered it already."""
    entry = next(iter(report["forms"].values()), {}).get(demo_page.TIMED_SCENE)
    if entry is None:
        return None
    if "principled" in entry:
        return entry["principled"]["cycles_seconds"]
    from .cycles_render import render_cycles

    spec = compare_run.scene_specs([demo_page.TIMED_SCENE], resolution)[0]
    before = blend_io.snapshot()
    try:
        mat = lamina_material.principled_material(model_id, p, name="Lamina demo Principled")
        path = os.path.join(folder, f"{demo_page.TIMED_SCENE}_principled.exr")
        return render_cycles(mat, spec, report["samples"], report["seed"], path)[1]
    finally:
        blend_io.remove_new_data(before)


def accuracy_href(out_dir: str) -> str:
    """docs/accuracy.md relative to the page in ``out_dir`` (a file URI where no relative path exists)."""
    try:
        return Path(os.path.relpath(ACCURACY, out_dir)).as_posix()
    except ValueError:  # another drive
        return ACCURACY.as_uri()


def overview(reports, out_dir: str, gap: int = demo_page.OVERVIEW_GAP,
             column_gap: int = demo_page.OVERVIEW_COLUMN_GAP) -> np.ndarray:
    """The picture of pictures: one column per model, the side-by-side strip of each of its presets top to bottom
    (the sphere scene, or the first one rendered, in ``demo_page.overview_form``)."""
    form = demo_page.overview_form(reports)
    columns = []
    for model_id in demo_page.models_of(reports):
        strips = [read_png(os.path.join(out_dir, r["dir"], r["forms"][form][scene]["files"]["side_by_side"]))[..., :3]
                  for r in reports if r["model"] == model_id
                  for scene in [demo_page.overview_scene(r, form)] if scene is not None]
        if strips:
            columns.append(stacked(strips, 0, gap))
    return stacked(columns, 1, column_gap)


def stacked(pictures, axis: int, gap: int) -> np.ndarray:
    """uint8 ``pictures`` one after the other along ``axis`` (0: top to bottom, 1: left to right), ``gap`` black
    pixels between them, the smaller ones padded with black at their end."""
    across = 1 - axis
    size = max(x.shape[across] for x in pictures)
    padded = [np.pad(x, [(0, size - x.shape[across]) if a == across else (0, 0) for a in range(2)] + [(0, 0)])
              for x in pictures]
    space = np.zeros((gap, size, 3) if axis == 0 else (size, gap, 3), dtype=np.uint8)
    return np.concatenate([x for picture in padded for x in (picture, space)][:-1], axis=axis)
