"""Headless entry points: ``blender -b -c lamina <command> ...`` and ``python -m addon.cli <command> ...``.

One code path for both (``main(argv)``). Exit codes: 0 success, 1 the work failed, 2 bad arguments;
a failure prints one line ``lamina: error: <reason>`` on stderr.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys

from . import paths, presets
from .asset_catalogs import PREVIEW_SAMPLES, PREVIEW_SIZE
from .models import MODELS, REGISTRY
from .models.params import ParamError
from .nodes import FORMS, MAPPING_KINDS, fittable, principled_models
from .nodes.budget import DEFAULT_BUDGET, BudgetError, checked_budget
from .reference import truth_models
from .reference.neural_medium_truth import COMPARE_SHAPES
from .reference.scenes import KINDS

SCENES = KINDS


class CliError(Exception):
    """A refusal with a one-line reason (exit code 2)."""


class Parser(argparse.ArgumentParser):
    """argparse with a one-line refusal (``lamina: error: ...``, exit 2) instead of usage text and a reason, and
    no abbreviations (``--form`` is not ``--forms``)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, allow_abbrev=False, **kwargs)

    def error(self, message):
        command = self.prog.split(" ", 1)[1] if " " in self.prog else ""
        raise CliError(f"{command}: {message}" if command else message)


def build_parser() -> argparse.ArgumentParser:
    ap = Parser(prog="lamina", description="Lamina layered materials for Cycles")
    sub = ap.add_subparsers(dest="command", required=True)

    lp = sub.add_parser("list-presets", help="list the presets of a model")
    lp.add_argument("--model", default="spongecake", choices=sorted(REGISTRY))

    mm = sub.add_parser("make-material", help="write a .blend with a Lamina material on a sphere")
    _material_args(mm)
    mm.add_argument("--form", default="nodes", choices=FORMS)
    _mapping_arg(mm)
    mm.add_argument("--out", required=True, help="the .blend to write (refused if it exists, see --overwrite)")
    mm.add_argument("--overwrite", action="store_true", help="replace an existing file")

    cp = sub.add_parser("compare", help="render Cycles vs the Python reference; write images and report.json")
    _material_args(cp)
    _compare_args(cp)
    cp.add_argument("--out", required=True, help="the results folder (created; refused if it has files, see "
                                                 "--overwrite)")
    cp.add_argument("--overwrite", action="store_true", help="replace the results in an existing --out")
    _mapping_arg(cp)
    cp.add_argument("--ms", action="store_true",
                    help="multiple scattering: compare SS only, SS + MS (network) and SS + MS (Monte Carlo)")
    cp.add_argument("--ms-paths", type=int, default=2000,
                    help="with --ms: random-walk paths per light direction (each sphere pixel has its own)")
    cp.add_argument("--ms-albedo-paths", type=int, default=4000, help="with --ms: furnace paths per pixel")
    cp.add_argument("--ms-stride", type=int, default=2,
                    help="with --ms: Monte Carlo at every n-th row and column (errors use those pixels)")
    cp.add_argument("--blends", action="store_true",
                    help="micrograin: also render the reference with the linear mix by the filling factor (Fig. 14) "
                         "and d'Eon et al.'s weighting (Eq. 26), side by side with ours")
    cp.add_argument("--principled", action="store_true",
                    help=f"{', '.join(principled_models())}: also render Blender's Principled BSDF set up from the "
                         "same parameters and report its error against the reference beside Lamina's")
    cp.add_argument("--truth", action="store_true",
                    help=f"{', '.join(truth_models())}: also measure the reference and Cycles against a Monte Carlo "
                         "simulation of the material's light paths at sampled pixels")
    cp.add_argument("--truth-paths", type=int, default=2000, help="with --truth: paths per sampled pixel")
    cp.add_argument("--truth-stride", type=int, default=4,
                    help="with --truth: Monte Carlo at every n-th row and column (errors use those pixels)")

    dm = sub.add_parser("demo", help="compare the presets of every model and write index.html")
    dm.add_argument("--model", choices=list(MODELS), help="only this model (default: every model)")
    dm.add_argument("--all-presets", action="store_true",
                    help="every preset of each model (default: a representative set)")
    _compare_args(dm)
    dm.add_argument("--out", default="out", help="the results folder (created; refused if it has files, see "
                                                 "--overwrite)")
    dm.add_argument("--overwrite", action="store_true", help="replace the results in an existing --out")

    bn = sub.add_parser("bench", help="benchmarks and accuracy tables (docs/benchmarks.md, docs/accuracy.md)")
    bn.add_argument("--out", default="docs")
    bn.add_argument("--model", action="append", choices=list(REGISTRY),
                    help="measure only this model again (repeatable) and replace its sections in the existing pages "
                         "(a model without a section there gets one at the end)")
    bn.add_argument("--part", choices=("accuracy", "speed"),
                    help="with --model: measure only this page (accuracy.md or benchmarks.md); default both")
    bn.add_argument("--samples", type=int, default=64)
    bn.add_argument("--resolution", type=int, default=64)
    bn.add_argument("--no-ms", action="store_true", help="leave out the multiple-scattering sections")
    bn.add_argument("--ms-paths", type=int, default=4000,
                    help="Monte Carlo paths per light direction of the rendered multiple-scattering comparison")
    bn.add_argument("--ms-stride", type=int, default=3, help="its Monte Carlo runs at every n-th row and column")
    bn.add_argument("--ms-furnace-configs", type=int, default=6, help="random white-furnace stacks per layer count")
    bn.add_argument("--ms-failure-paths", type=int, default=4000, help="paths per wi for the low-roughness fibers")
    bn.add_argument("--ms-repeats", type=int, default=5, help="renders per timing (the fastest counts)")
    bn.add_argument("--ms-bake-size", type=int, default=512, help="texture side for the bake timing")
    bk = sub.add_parser("bake", help="bake a Lamina material's multiple scattering (per texel where Image Textures "
                                     "drive its layers) and save the .blend")
    bk.add_argument("--blend", required=True, help="the .blend to open")
    bk.add_argument("--material", required=True, help="the Lamina material to bake")
    _blend_output_args(bk)

    op = sub.add_parser("optimize", help="rebuild Lamina materials of a .blend in the cheapest configuration within "
                                         "an error budget (Fit to budget) and save the .blend")
    op.add_argument("--blend", required=True, help="the .blend to open")
    g = op.add_mutually_exclusive_group(required=True)
    g.add_argument("--material", action="append", help="a Lamina material to fit (repeatable)")
    g.add_argument("--all", action="store_true", help="every Lamina material of the file")
    op.add_argument("--budget", type=float, default=DEFAULT_BUDGET,
                    help="relative RMSE allowed above the most accurate configuration (default %(default)g); OSL "
                         "forms are candidates only where every scene of the file renders OSL")
    op.add_argument("--view", default="scenes", choices=("scenes", "camera"),
                    help="measure on the comparison scenes, or on the points of each material's objects that the "
                         "scene's active camera sees (a material it does not see: on the comparison scenes)")
    _blend_output_args(op)

    ad = sub.add_parser("add-porous", help="add a micrograin porous layer (dust, rust, ...) over a material of a "
                                           ".blend: a new material, assigned wherever the original was used")
    ad.add_argument("--blend", required=True, help="the .blend to open")
    ad.add_argument("--material", required=True, help="the material to cover (it is kept, with a fake user)")
    g = ad.add_mutually_exclusive_group(required=True)
    g.add_argument("--preset", help="a micrograin preset (list-presets --model micrograin); its bulk is ignored")
    g.add_argument("--json", help="a JSON file with a micrograin dict (its bulk is ignored)")
    ad.add_argument("--form", default="nodes", choices=FORMS)
    _blend_output_args(ad)

    bm = sub.add_parser("bake-medium", help="fill a closed mesh of a .blend with a neural medium (or keep the medium "
                                            "material it has), bake its double and multiple scattering from the "
                                            "scene's lamps and save the .blend")
    bm.add_argument("--blend", required=True, help="the .blend to open")
    bm.add_argument("--object", required=True, help="the mesh object the medium fills")
    g = bm.add_mutually_exclusive_group()
    g.add_argument("--preset", help="a neural_medium preset (list-presets --model neural_medium): a new material")
    g.add_argument("--json", help="a JSON file with a neural_medium dict: a new material")
    bm.add_argument("--scale", type=float, help="with --preset or --json: scene units per unit length")
    bm.add_argument("--cells", type=int, default=16, help="beams per lamp side (cells x cells per lamp)")
    bm.add_argument("--steps", type=int, default=12, help="quadrature points along each gathering ray")
    bm.add_argument("--spacing", type=float, default=0.5, help="surface points closer than this many mean free "
                                                               "paths share one gather (0: every vertex gathers)")
    bm.add_argument("--grid-angle", type=float, default=0.0,
                    help="gather a cube of beams through one representative beam where it is seen under less than "
                         "this angle in radians (the paper's VRL grid; 0: every beam)")
    bm.add_argument("--grid-cube", type=float, default=1.0, help="the VRL grid's cube side in mean free paths")
    bm.add_argument("--segments", action="store_true",
                    help="gather with the paper's accumulated camera segments (faster for many points)")
    _blend_output_args(bm)

    cm = sub.add_parser("compare-medium", help="render a neural medium on the comparison sphere: Cycles single "
                                               "scattering, + Lamina's bake, full path tracing, random-walk "
                                               "subsurface scattering, against a numpy ground truth; write "
                                               "comparison.png and report.json")
    g = cm.add_mutually_exclusive_group(required=True)
    g.add_argument("--preset", help="a neural_medium preset (list-presets --model neural_medium)")
    g.add_argument("--json", help="a JSON file with a neural_medium dict")
    cm.add_argument("--scale", type=float, help="scene units per unit length (the sphere has radius 1)")
    cm.add_argument("--shape", default="sphere", choices=COMPARE_SHAPES,
                    help="what the medium fills: the comparison sphere, a 1.6 x 1.6 x 0.5 box, a torus or "
                         "Suzanne (these two have no numpy truth: measured against Cycles' full path tracing)")
    cm.add_argument("--samples", type=int, default=64, help="Cycles samples per pixel")
    cm.add_argument("--resolution", type=int, default=48, help="image width and height in pixels")
    cm.add_argument("--truth-paths", type=int, default=1024, help="ground-truth paths per pixel")
    cm.add_argument("--bounces", type=int, default=1024, help="volume bounces of Cycles' full path tracing")
    cm.add_argument("--out", required=True, help="the results folder (created; refused if it has files, see "
                                                 "--overwrite)")
    cm.add_argument("--overwrite", action="store_true", help="replace the results in an existing --out")
    am = sub.add_parser("assets", help="write the asset library: every preset of every BSDF model as a material "
                                       "asset with a rendered preview (lamina_library.blend and its catalogs)")
    am.add_argument("--out", required=True, help="the library folder (created; refused if it has files, see "
                                                 "--overwrite)")
    am.add_argument("--overwrite", action="store_true", help="replace the contents of an existing --out")
    _mapping_arg(am)
    am.add_argument("--size", type=int, default=PREVIEW_SIZE, help="preview width and height in pixels (8 to 512)")
    am.add_argument("--samples", type=int, default=PREVIEW_SAMPLES, help="Cycles samples per preview pixel")
    return ap


def _blend_output_args(p) -> None:
    """--out and --overwrite of a command that saves the .blend it opened (``_blend_paths``)."""
    p.add_argument("--out", help="the .blend to write (refused if it exists, see --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --out; without --out, save over --blend")


def _material_args(p) -> None:
    p.add_argument("--model", default="spongecake", choices=sorted(MODELS))
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--preset", help="a preset name (see list-presets)")
    g.add_argument("--json", "--params", dest="params", help="a JSON file with the model's parameter dict")


def _mapping_arg(p) -> None:
    p.add_argument("--mapping", default="auto", choices=MAPPING_KINDS,
                   help=f"how the closures are found ({', '.join(m for m in MODELS if fittable(m))}; the other models "
                        "are analytic): the mapping's formulas, tables fitted to the reference, or whichever of the "
                        "two is closer on the comparison scenes (a fit takes seconds, cached)")


def _compare_args(p) -> None:
    p.add_argument("--forms", default=",".join(FORMS), help=f"comma-separated: {', '.join(FORMS)}")
    p.add_argument("--scenes", help=f"comma-separated: {', '.join(SCENES)} (default: all of them; backlit only "
                                    "for materials that transmit light)")
    p.add_argument("--samples", type=int, default=128, help="Cycles samples per pixel")
    p.add_argument("--resolution", type=int, default=96, help="image width and height in pixels")
    p.add_argument("--seed", type=int, default=0)


def load_params(args):
    data = _read_dict(args.model, args.preset, args.params, "--json")
    return _validated(MODELS[args.model], data).params


def _read_dict(model_id: str, preset: str | None, path: str | None, option: str):
    """A model dict from a JSON file (``option`` names it in messages) or, without one, from a preset."""
    if path is not None:
        try:
            with open(_checked(paths.input_file, option, path)) as f:
                return json.load(f)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise CliError(f"{option} {path!r}: not a JSON file ({e})") from None
    try:
        return presets.load(model_id, preset)
    except KeyError as e:
        raise CliError(f"--preset: {e.args[0]}") from None


def _checked(check, option: str, value, *extra):
    """``check(option, value, *extra)`` from ``paths``, its refusal as a CliError."""
    try:
        return check(option, value, *extra)
    except paths.PathError as e:
        raise CliError(str(e)) from None


def _validated(model, data: dict):
    """The model's validation of ``data``; its clamping messages printed, a refusal as a CliError."""
    try:
        validated = model.validate(data)
    except ParamError as e:
        raise CliError(str(e)) from None
    _warn(validated.warnings)
    return validated


def _warn(warnings, already=()) -> None:
    for w in warnings:
        if w not in already:
            print(f"lamina: warning: {w}", file=sys.stderr)


def _split(option: str, value: str, allowed, what: str) -> list[str]:
    items = [v.strip() for v in value.split(",") if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        raise CliError(f"{option} {value!r}: unknown {what} {', '.join(bad) or '(none)'}; expected some of "
                       f"{', '.join(allowed)}")
    return items


def _at_least(args, **least) -> None:
    """Refuse the first option below its least value (``--name must be ≥ N, got M``)."""
    for name, lowest in least.items():
        value = getattr(args, name)
        if value < lowest:
            raise CliError(f"--{name.replace('_', '-')} must be ≥ {lowest}, got {value}")


def _check_compare_args(args) -> tuple[list[str], list[str] | None]:
    """The forms and the scenes (None: the material's default scenes, ``compare_run.default_scene_names``)."""
    _at_least(args, samples=1, resolution=8, seed=0)
    scenes = None if args.scenes is None else _split("--scenes", args.scenes, SCENES, "scene")
    return _split("--forms", args.forms, FORMS, "form"), scenes


class WorkFailed(Exception):
    """The work failed after every argument was accepted (exit code 1); the message is one line."""


def _in_results_folder(out: str, work):
    """Run ``work(folder)`` in a staging folder that becomes ``out`` when it succeeds (``paths.staged_folder``);
    a failure leaves ``out`` as it was and is reported with ``out``'s name, not the staging folder's."""
    stage = None
    try:
        with paths.staged_folder(out) as stage:
            return work(stage)
    except (CliError, KeyboardInterrupt):
        raise
    except Exception as e:  # noqa: BLE001 - reported as one line, exit code 1
        raise WorkFailed(paths.unstaged(one_line(e), stage, out) if stage else one_line(e)) from None


# -------------------------------------------------------------------------------------------- commands


def cmd_list_presets(args) -> int:
    names = presets.names(args.model)
    width = max([16] + [len(n) for n in names])
    for name in names:
        print(f"{name:{width}s} {presets.description(args.model, name)}")
    return 0


def _check_mapping(args) -> None:
    """Refuse ``--mapping fitted`` for a model without a fitted mapping (Auto is its analytic one)."""
    if args.mapping == "fitted" and not fittable(args.model):
        raise CliError(f"--mapping: model {args.model} has only its analytic mapping (models with a fitted one: "
                       f"{', '.join(m for m in MODELS if fittable(m))})")


def cmd_make_material(args) -> int:
    p = load_params(args)
    _check_mapping(args)
    out = _checked(paths.output_file, "--out", args.out, args.overwrite)
    from .operators import blend_io

    name = args.preset or os.path.splitext(os.path.basename(args.params))[0]
    record = blend_io.write_material_blend(args.model, p, args.form, name, out, args.mapping)
    if record is not None:
        from .nodes.choice import describe

        print(f"lamina: {describe(record)}")
    print(f"lamina: wrote {out}")
    return 0


def cmd_compare(args) -> int:
    p = load_params(args)
    forms, scenes = _check_compare_args(args)
    ms = _ms_settings(args, p) if args.ms else None
    from .operators import compare_run

    reason = compare_run.refusal(args.model, p)
    if reason:
        raise CliError(reason)
    if args.blends and not compare_run.has_blends(args.model):
        raise CliError(f"--blends: model {args.model} has a single blending weight")
    _check_mapping(args)
    if args.principled and not compare_run.has_principled(args.model):
        raise CliError(f"--principled: model {args.model} has no Principled BSDF counterpart "
                       f"(models with one: {', '.join(principled_models())})")
    truth = _truth_settings(args) if args.truth else None
    out = _checked(paths.output_folder, "--out", args.out, args.overwrite)
    report = _in_results_folder(out, lambda folder: compare_run.compare_params(
        args.model, p, forms, scenes, args.samples, args.resolution, args.seed, folder,
        label=args.preset or "custom", ms=ms, blends=args.blends, principled=args.principled, truth=truth,
        mapping=args.mapping))
    print(compare_run.summary_lines(report))
    print(f"lamina: wrote {out}")
    return 0


def _truth_settings(args):
    """The Monte Carlo settings of ``compare --truth`` (models with a ground truth of their light paths)."""
    from .operators import compare_run

    if not compare_run.has_truth(args.model):
        raise CliError(f"--truth: {args.model} has no Monte Carlo ground truth of its light paths (models with one: "
                       f"{', '.join(truth_models())}; SpongeCake's Monte Carlo comparison is --ms)")
    try:
        return compare_run.CoatTruth(paths=args.truth_paths, stride=args.truth_stride, seed=args.seed)
    except ValueError as e:
        raise CliError(f"--truth-paths / --truth-stride: {e}") from None


def _ms_settings(args, p):
    """The Monte Carlo settings of ``compare --ms``; refuses stacks the networks do not cover."""
    from .reference.spongecake_truth import TruthSettings

    least = 2 * TruthSettings.batches  # at least 2 paths per batch
    _at_least(args, ms_paths=least, ms_albedo_paths=least, ms_stride=1)
    from .operators import compare_run

    if not compare_run.has_multiple_scattering(args.model):
        raise CliError(f"--ms: model {args.model} has no multiple scattering")
    try:
        MODELS[args.model].validate({**p.to_dict(), "multiple_scattering": True})
    except ParamError as e:
        raise CliError(f"--ms: {e}") from None
    return TruthSettings(paths=args.ms_paths, albedo_paths=args.ms_albedo_paths, stride=args.ms_stride,
                         seed=args.seed)


def cmd_demo(args) -> int:
    forms, scenes = _check_compare_args(args)
    out = _checked(paths.output_folder, "--out", args.out, args.overwrite)
    from .operators import demo

    models = [args.model] if args.model else list(MODELS)
    _in_results_folder(out, lambda folder: demo.run(models, forms, scenes, args.samples, args.resolution, args.seed,
                                                    folder, all_presets=args.all_presets))
    print(f"lamina: open {os.path.join(out, 'index.html')}")
    return 0


def cmd_bench(args) -> int:
    from . import bench

    out = _checked(paths.output_folder, "--out", args.out, True)  # the benchmark pages are rewritten in place
    _at_least(args, samples=1, resolution=8)
    if args.part and not args.model:
        raise CliError("bench --part needs --model: a whole run writes both pages")
    ms = None
    if not args.no_ms:
        from .reference.spongecake_truth import TruthSettings

        least = 2 * TruthSettings.batches  # at least 2 paths per batch
        _at_least(args, ms_paths=least, ms_failure_paths=least, ms_stride=1, ms_furnace_configs=1, ms_repeats=1,
                  ms_bake_size=1)
        ms = bench.MsSizes(truth=TruthSettings(paths=args.ms_paths, albedo_paths=args.ms_paths, stride=args.ms_stride,
                                               seed=bench.MS_DEFAULT.seed),
                           furnace_configs=args.ms_furnace_configs, failure_paths=args.ms_failure_paths,
                           speed_repeats=args.ms_repeats, bake_size=args.ms_bake_size)
    os.makedirs(out, exist_ok=True)
    try:
        bench.run(out, bench.Sizes(samples=args.samples, resolution=args.resolution, ms=ms), models=args.model,
                  parts=(args.part,) if args.part else bench.PARTS)
    except FileNotFoundError as e:  # --model without the pages of a whole run
        raise CliError(f"bench --model: {e.filename} does not exist: run the whole `make bench` first") from None
    return 0


def _blend_paths(args) -> tuple[str, str]:
    """--blend and where to write (--out, or --blend itself with --overwrite), checked before any work."""
    blend = _checked(paths.input_blend, "--blend", args.blend)
    if args.out is None and not args.overwrite:
        raise CliError("pass --out FILE, or --overwrite to save over --blend")
    if args.out is None:
        return blend, _checked(paths.output_file, "--blend", args.blend, True)
    return blend, _checked(paths.output_file, "--out", args.out, args.overwrite)


def cmd_bake(args) -> int:
    blend, out = _blend_paths(args)
    from .operators import bake_ops, blend_io

    try:
        summary, warnings = bake_ops.bake_file(blend, args.material, out)
    except (blend_io.BlendArgumentError, bake_ops.MaterialError) as e:
        raise CliError(str(e)) from None
    _warn(warnings)
    print(f"lamina: {summary}; wrote {out}")
    return 0


def cmd_optimize(args) -> int:
    try:
        value = checked_budget(args.budget)
    except BudgetError as e:
        raise CliError(f"--budget {e}") from None
    blend, out = _blend_paths(args)
    from .operators import blend_io, budget_ops

    try:
        lines = budget_ops.optimize_file(blend, args.material or [], value, out, camera=args.view == "camera")
    except blend_io.BlendArgumentError as e:
        raise CliError(str(e)) from None
    for line in lines:
        print(f"lamina: {line}")
    print(f"lamina: wrote {out}")
    return 0


def _porous_dict(args) -> tuple[dict, list[str]]:
    """The layer's micrograin dict from --preset or --json, checked (warnings printed) before the .blend is
    opened; returns it and the warnings."""
    from .models import micrograin

    data = _read_dict(micrograin.ID, args.preset, args.json, "--json")
    if not isinstance(data, dict):
        raise CliError(f"--json {args.json!r}: expected a JSON object (a micrograin dict)")
    data = {k: v for k, v in data.items() if k != "bulk"}  # the bulk is the material's own shader
    return data, _validated(micrograin, {**data, "bulk": {"type": micrograin.WRAPPED}}).warnings


def cmd_add_porous(args) -> int:
    data, printed = _porous_dict(args)
    blend, out = _blend_paths(args)
    from .operators import blend_io
    from .operators import micrograin as porous

    try:
        summary, warnings = porous.add_porous_file(blend, args.material, data, args.form, out, args.preset)
    except (blend_io.BlendArgumentError, porous.PorousError) as e:  # nothing was written
        raise CliError(str(e)) from None
    _warn(warnings, already=printed)
    print(f"lamina: {summary}; wrote {out}")
    return 0


def _medium_dict(args) -> dict | None:
    """The medium of --preset / --json (with --scale), checked and its warnings printed before the .blend is opened;
    None without either (the object's own medium material is baked)."""
    from .models import neural_medium

    if args.preset is None and args.json is None:
        if args.scale is not None:
            raise CliError("--scale needs --preset or --json")
        return None
    data = _read_dict(neural_medium.ID, args.preset, args.json, "--json")
    if not isinstance(data, dict):
        raise CliError(f"--json {args.json!r}: expected a JSON object (a neural_medium dict)")
    if args.scale is not None:
        data = {**data, "scale": args.scale}
    _validated(neural_medium, data)
    return data


def cmd_bake_medium(args) -> int:
    from .bake import neural_medium as nb

    data = _medium_dict(args)
    try:
        settings = nb.Settings(args.cells, args.steps, spacing=args.spacing, grid_angle=args.grid_angle,
                               grid_cube=args.grid_cube, segments=args.segments)
    except ValueError as e:
        raise CliError(str(e)) from None
    blend, out = _blend_paths(args)
    from .operators import blend_io, medium_bake
    from .operators import neural_medium as medium_ops

    try:
        summary, warnings = medium_ops.bake_medium_file(blend, args.object, data, out, settings)
    except (blend_io.BlendArgumentError, medium_bake.BakeError) as e:  # nothing was written
        raise CliError(str(e)) from None
    _warn(warnings)
    print(f"lamina: {summary}; wrote {out}")
    return 0


def cmd_compare_medium(args) -> int:
    from .models import neural_medium

    p = neural_medium.params_from_dict(_medium_dict(args))  # checked there, its warnings printed
    _at_least(args, samples=1, resolution=8, truth_paths=16, bounces=1)
    out = _checked(paths.output_folder, "--out", args.out, args.overwrite)
    from .operators import medium_compare

    sizes = medium_compare.Sizes(samples=args.samples, resolution=args.resolution, truth_paths=args.truth_paths,
                                 full_bounces=args.bounces)
    report = _in_results_folder(out, lambda folder: medium_compare.compare_medium(
        p, sizes, folder, label=args.preset or "custom", shape=args.shape))
    print(medium_compare.summary_lines(report))
    print(f"lamina: wrote {out}")
    return 0


def cmd_assets(args) -> int:
    if not 8 <= args.size <= 512:
        raise CliError(f"--size {args.size}: expected 8 to 512 pixels")
    if args.samples < 1:
        raise CliError(f"--samples {args.samples}: expected at least 1")
    out = _checked(paths.output_folder, "--out", args.out, args.overwrite)
    from .operators import asset_library

    _in_results_folder(out, lambda folder: asset_library.build(folder, args.mapping, args.size, args.samples))
    print(f"lamina: wrote {len(asset_library.jobs())} assets to {os.path.join(out, 'lamina_library.blend')}")
    return 0


COMMANDS = {"list-presets": cmd_list_presets, "make-material": cmd_make_material, "compare": cmd_compare,
            "demo": cmd_demo, "bench": cmd_bench, "bake": cmd_bake, "optimize": cmd_optimize,
            "add-porous": cmd_add_porous, "bake-medium": cmd_bake_medium, "compare-medium": cmd_compare_medium, "assets": cmd_assets}

# Lamina's temporary names (``bake.exr.atomic_path``'s ".<name>.<random>.tmp.<ext>", ``paths.staged_folder``'s
# ".<name>.<random>.lamina-tmp"): a message shows the final name instead.
_TEMPORARY = re.compile(r"\.([^/\s'\"]+?)\.[A-Za-z0-9_]{8}\.(?:tmp(?:\.[A-Za-z0-9]+)?|lamina-tmp)")


def one_line(e: BaseException) -> str:
    """An exception as one line for a user: the OS's reason and the file, or the message's last line, with
    Lamina's temporary names replaced by the final ones and Blender's "Error: " prefix dropped."""
    if isinstance(e, OSError) and e.strerror:
        text = f"{e.strerror}: {e.filename}" if e.filename else e.strerror
    else:
        lines = [line.strip() for line in str(e).strip().splitlines() if line.strip()]
        text = lines[-1] if lines else type(e).__name__
    text = _TEMPORARY.sub(r"\1", text)
    return text[len("Error: "):] if text.startswith("Error: ") else text


def main(argv=None) -> int:
    command = "lamina"
    try:
        args = build_parser().parse_args(argv)
        command = args.command
        return COMMANDS[args.command](args)
    except CliError as e:
        print(f"lamina: error: {e}", file=sys.stderr)
        return 2
    except SystemExit as e:  # --help printed its text
        return int(e.code or 0)
    except WorkFailed as e:
        print(f"lamina: error: {command} failed: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # noqa: BLE001 - a headless run must end with one line and a status, not a trace
        print(f"lamina: error: {command} failed: {one_line(e)}", file=sys.stderr)
        return 1


def blender_command(argv) -> int:
    """The handler given to ``bpy.utils.register_cli_command`` (``blender -b -c lamina ...``)."""
    return main(list(argv))


_handle = None


def register():
    """``blender -c lamina ...`` (Blender 4.2+; the bpy module has no ``-c``: ``python -m addon.cli``)."""
    global _handle
    import bpy

    if hasattr(bpy.utils, "register_cli_command"):
        _handle = bpy.utils.register_cli_command("lamina", blender_command)


def unregister():
    global _handle
    if _handle is not None:
        import bpy

        bpy.utils.unregister_cli_command(_handle)
        _handle = None


if __name__ == "__main__":
    sys.exit(main())
