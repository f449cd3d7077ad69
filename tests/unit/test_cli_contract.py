"""The CLI's contract on bad input, one table for every command (later models add their rows here).

Each row runs ``python -m addon.cli`` (the code ``blender -c lamina`` runs) as a subprocess in a working folder
of its own that holds a valid .blend, a corrupt one, JSON files, a text file, a results folder and an empty
folder. A refusal must exit with 2, print nothing on stdout and exactly one line on stderr (``lamina: warning:``
lines may precede it) that names what was wrong, no traceback, and leave every file of the working folder as it
was, with nothing new in it.
"""
import hashlib
import json
import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MATERIAL = "Lamina plastic"  # the material of in.blend (make-material --preset plastic)


def lamina(*args, cwd):
    return subprocess.run([sys.executable, "-m", "addon.cli", *args], capture_output=True, text=True, cwd=cwd,
                          env=dict(os.environ, PYTHONPATH=ROOT), timeout=300)


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory):
    """The working folder every row starts from (copied per row)."""
    folder = tmp_path_factory.mktemp("cli-contract")
    r = lamina("make-material", "--preset", "plastic", "--out", "in.blend", cwd=folder)
    assert r.returncode == 0, r.stderr
    (folder / "corrupt.blend").write_bytes(b"BLENDER-v500" + b"\0" * 64)  # a .blend's header, nothing after
    (folder / "text.txt").write_text("not a .blend, not JSON\n")
    (folder / "list.json").write_text(json.dumps([0.1, 0.2]))
    (folder / "velvet.json").write_text(json.dumps({"layers": [{"type": "velvet"}]}))
    (folder / "broken.json").write_text('{"layers": [')
    (folder / "coat.json").write_text(json.dumps({"bounces": 1.5}))
    (folder / "grains.json").write_text(json.dumps({"filling_factor": 0.3, "grain": {"type": "velvet"}}))
    (folder / "zero_medium.json").write_text(json.dumps({"sigma_s": [0.0, 0.0, 0.0], "sigma_a": [0.0, 0.0, 0.0]}))
    for name, data in ANISO_BAD.items():
        (folder / f"{name}.json").write_text(json.dumps(data))
    plain = ("import bpy; bpy.ops.wm.read_factory_settings(use_empty=True); "
             "bpy.data.materials.new('Plain').use_fake_user = True; bpy.ops.wm.save_as_mainfile(filepath='plain.blend')")
    subprocess.run([sys.executable, "-c", plain], cwd=folder, check=True, capture_output=True, timeout=120)
    (folder / "results").mkdir()
    (folder / "results" / "report.json").write_text("{}")  # earlier results
    (folder / "empty").mkdir()
    return folder


# Anisotropic stacks the declaration refuses (addon/models/aniso_stack.py).
DIELECTRIC, CONDUCTOR = {"type": "dielectric", "ior": 1.5}, {"type": "conductor"}
ANISO_BAD = {
    "aniso_conductor_first": {"interfaces": [CONDUCTOR, DIELECTRIC]},
    "aniso_five": {"interfaces": [DIELECTRIC] * 5},
    "aniso_ior_zero": {"interfaces": [{"type": "dielectric", "ior": 0.0}]},
    "aniso_negative_k": {"interfaces": [{"type": "conductor", "k": [-1.0, 0.0, 0.0]}]},
    "aniso_media_count": {"interfaces": [DIELECTRIC, CONDUCTOR], "media": [{}, {}]},
    "aniso_unknown_key": {"layers": []},
}

MAKE = ("make-material", "--preset", "plastic")
OPTIMIZE = ("optimize", "--blend", "in.blend", "--material", MATERIAL)
COMPARE = ("compare", "--preset", "plastic", "--forms", "nodes", "--scenes", "sphere")
COAT = ("--model", "thin_coat", "--preset", "amber_lacquer")
BAKE = ("bake", "--blend", "in.blend", "--material", MATERIAL)
MEDIUM = ("bake-medium", "--blend", "in.blend", "--object", "Lamina plastic")  # in.blend's sphere
POROUS = ("add-porous", "--blend", "in.blend", "--material", MATERIAL, "--preset", "dust_on_wood")

# (arguments, text the one line must contain)
REFUSALS = [
    # the command line itself
    ((), "the following arguments are required: command"),
    (("paint",), "invalid choice: 'paint'"),
    (("list-presets", "--model", "velvet"), "invalid choice: 'velvet'"),
    # make-material
    (("make-material", "--preset", "velvet", "--out", "x.blend"), "unknown spongecake preset 'velvet'; available:"),
    (("make-material", "--model", "thin_coat", "--preset", "velvet", "--out", "x.blend"),
     "unknown thin_coat preset 'velvet'; available: amber_lacquer"),
    (("make-material", "--out", "x.blend"), "one of the arguments --preset --json"),
    (("make-material", "--preset", "plastic", "--json", "velvet.json", "--out", "x.blend"), "not allowed with"),
    (("make-material", "--json", "missing.json", "--out", "x.blend"), "--json 'missing.json' does not exist"),
    (("make-material", "--json", "empty", "--out", "x.blend"), "--json 'empty' is a folder; expected a file"),
    (("make-material", "--json", "text.txt", "--out", "x.blend"), "--json 'text.txt': not a JSON file"),
    (("make-material", "--json", "broken.json", "--out", "x.blend"), "--json 'broken.json': not a JSON file"),
    (("make-material", "--json", "list.json", "--out", "x.blend"), "expected a dict"),
    (("make-material", "--json", "velvet.json", "--out", "x.blend"), "unknown value 'velvet'"),
    (("make-material", "--model", "thin_coat", "--json", "coat.json", "--out", "x.blend"),
     "bounces: expected a whole number, got 1.5"),
    (MAKE + ("--form", "glsl", "--out", "x.blend"), "argument --form: invalid choice: 'glsl'"),
    (MAKE + ("--out", ""), "--out is empty"),
    (MAKE + ("--out", "in.blend"), "--out 'in.blend' exists; pass --overwrite to replace it"),
    (MAKE + ("--out", "empty"), "--out 'empty' is a folder; expected a .blend file"),
    (MAKE + ("--out", "new/"), "--out 'new/' is a folder; expected a .blend file"),
    (MAKE + ("--out", "missing/x.blend"), "the folder"),
    (MAKE + ("--out", "text.txt/x.blend"), "is a file, not a folder"),
    (MAKE + ("--out", "/proc/x.blend"), "cannot write in /proc"),
    (MAKE + ("--out", "x.txt"), "--out 'x.txt': expected a file name ending in .blend"),
    (("make-material", "--model", "aniso_stack", "--json", "aniso_conductor_first.json", "--out", "x.blend"),
     "interface 1 is a conductor: a conductor ends the stack"),
    (("make-material", "--model", "aniso_stack", "--json", "aniso_five.json", "--out", "x.blend"),
     "expected a list of 1 to 4 interfaces, got 5"),
    (("make-material", "--model", "aniso_stack", "--json", "aniso_ior_zero.json", "--out", "x.blend"),
     "interface 1: ior: 0.0 must be > 0"),
    (("make-material", "--model", "aniso_stack", "--json", "aniso_negative_k.json", "--out", "x.blend"),
     "interface 1: k: [-1.0, 0.0, 0.0] must be ≥ 0"),
    (("make-material", "--model", "aniso_stack", "--json", "aniso_media_count.json", "--out", "x.blend"),
     "media: expected 1"),
    (("compare", "--model", "aniso_stack", "--json", "aniso_unknown_key.json", "--out", "x"), "unknown key(s) layers"),
    (("compare", "--model", "aniso_stack", "--preset", "velvet", "--out", "x"), "unknown aniso_stack preset 'velvet'"),
    # compare
    (COMPARE + ("--out", ""), "--out is empty"),
    (COMPARE + ("--out", "text.txt"), "--out 'text.txt' is a file; expected a folder"),
    (COMPARE + ("--out", "results"), "--out 'results' exists and is not empty; pass --overwrite"),
    (COMPARE + ("--out", "missing/deeper"), "the folder"),
    (COMPARE + ("--out", "/proc/x"), "cannot write in /proc"),
    (COMPARE + ("--samples", "0", "--out", "x"), "--samples must be ≥ 1, got 0"),
    (COMPARE + ("--resolution", "4", "--out", "x"), "--resolution must be ≥ 8, got 4"),
    (COMPARE + ("--seed", "-1", "--out", "x"), "--seed must be ≥ 0, got -1"),
    (COMPARE + ("--samples", "many", "--out", "x"), "argument --samples: invalid int value: 'many'"),
    (("compare", "--preset", "plastic", "--scenes", "moon", "--out", "x"), "unknown scene moon"),
    (("compare", "--preset", "plastic", "--forms", "glsl", "--out", "x"), "unknown form glsl"),
    (("compare", "--preset", "plastic", "--forms", ",", "--out", "x"), "unknown form (none)"),
    (("compare", "--preset", "plastic", "--form", "nodes", "--out", "x"), "unrecognized arguments: --form"),
    (("compare", "--preset", "velvet", "--out", "x"), "unknown spongecake preset 'velvet'"),
    (("compare", "--model", "thin_coat", "--json", "coat.json", "--out", "x"), "bounces: expected a whole number"),
    (("compare",) + COAT + ("--ms", "--out", "x"), "--ms: model thin_coat has no multiple scattering"),
    (("compare",) + COAT + ("--blends", "--out", "x"), "--blends: model thin_coat has a single blending weight"),
    (COMPARE + ("--principled", "--out", "x"), "--principled: model spongecake has no Principled BSDF counterpart"),
    (COMPARE + ("--truth", "--out", "x"), "--truth: spongecake has no Monte Carlo ground truth"),
    (("compare",) + COAT + ("--truth", "--truth-paths", "3", "--out", "x"), "paths must be ≥ 16"),
    (COMPARE + ("--ms", "--ms-paths", "1", "--out", "x"), "--ms-paths must be ≥"),
    (("compare", "--preset", "leaf", "--ms", "--ms-stride", "0", "--out", "x"), "--ms-stride must be ≥ 1, got 0"),
    # demo
    (("demo", "--forms", "glsl"), "unknown form glsl"),
    (("demo", "--model", "velvet"), "argument --model: invalid choice: 'velvet'"),
    (("demo", "--resolution", "2"), "--resolution must be ≥ 8, got 2"),
    (("demo", "--out", "text.txt"), "--out 'text.txt' is a file; expected a folder"),
    (("demo", "--out", "results"), "--out 'results' exists and is not empty; pass --overwrite"),
    # bench
    (("bench", "--out", "text.txt"), "--out 'text.txt' is a file; expected a folder"),
    (("bench", "--out", "x", "--samples", "0"), "--samples must be ≥ 1, got 0"),
    (("bench", "--out", "x", "--part", "speed"), "bench --part needs --model: a whole run writes both pages"),
    # bake
    (("bake", "--blend", "missing.blend", "--material", MATERIAL, "--out", "x.blend"),
     "--blend 'missing.blend' does not exist"),
    (("bake", "--blend", "empty", "--material", MATERIAL, "--out", "x.blend"), "--blend 'empty' is a folder"),
    (("bake", "--blend", "text.txt", "--material", MATERIAL, "--out", "x.blend"),
     "--blend 'text.txt' is not a .blend file"),
    (("bake", "--blend", "corrupt.blend", "--material", MATERIAL, "--out", "x.blend"), "Blender cannot read it"),
    (("bake", "--blend", "in.blend", "--material", "Nope", "--out", "x.blend"),
     "--material 'Nope': no such material in"),
    (BAKE + ("--out", "x.blend"), "multiple scattering off: turn it on in Blender's Lamina panel, or write"),
    (BAKE, "pass --out FILE, or --overwrite to save over --blend"),
    (BAKE + ("--out", "in.blend"), "--out 'in.blend' exists; pass --overwrite"),
    (BAKE + ("--out", "empty"), "--out 'empty' is a folder"),
    (("bake", "--material", MATERIAL, "--out", "x.blend"), "the following arguments are required: --blend"),
    # optimize
    (OPTIMIZE + ("--budget", "0", "--out", "x.blend"), "--budget 0.0: expected a number > 0"),
    (OPTIMIZE + ("--budget", "nan", "--out", "x.blend"), "--budget nan: expected a number > 0"),
    (OPTIMIZE + ("--budget", "-0.1", "--out", "x.blend"), "--budget -0.1: expected a number > 0"),
    (OPTIMIZE, "pass --out FILE, or --overwrite to save over --blend"),
    (("optimize", "--blend", "in.blend", "--material", "Nope", "--out", "x.blend"),
     "--material 'Nope': no such material in"),
    (("optimize", "--blend", "plain.blend", "--material", "Plain", "--out", "x.blend"),
     "--material 'Plain': not a Lamina material"),
    (("optimize", "--blend", "plain.blend", "--all", "--out", "x.blend"), "plain.blend has no Lamina material to fit"),
    (OPTIMIZE + ("--all", "--out", "x.blend"), "argument --all: not allowed with argument --material"),
    (("optimize", "--blend", "corrupt.blend", "--all", "--out", "x.blend"), "Blender cannot read it"),
    (("optimize", "--blend", "plain.blend", "--all", "--view", "camera", "--out", "x.blend"),
     "plain.blend has no active camera"),
    (OPTIMIZE + ("--view", "top", "--out", "x.blend"), "argument --view: invalid choice: 'top'"),
    # bake-medium
    (MEDIUM + ("--preset", "fluff", "--out", "x.blend"), "unknown neural_medium preset 'fluff'; available:"),
    (MEDIUM + ("--json", "zero_medium.json", "--out", "x.blend"), "zero density"),
    (MEDIUM + ("--scale", "2", "--out", "x.blend"), "--scale needs --preset or --json"),
    (MEDIUM + ("--preset", "milk", "--cells", "0", "--out", "x.blend"), "bake settings out of range"),
    (MEDIUM + ("--preset", "milk", "--spacing", "-1", "--out", "x.blend"), "spacing -1.0 (0-16 mean free paths)"),
    (MEDIUM + ("--preset", "milk", "--spacing", "nan", "--out", "x.blend"), "spacing nan (0-16 mean free paths)"),
    (MEDIUM + ("--preset", "milk", "--grid-angle", "4", "--out", "x.blend"), "grid angle 4.0 (0-pi)"),
    (MEDIUM + ("--preset", "milk", "--grid-cube", "0", "--out", "x.blend"), "grid cube 0.0 (0.01-64 mean free paths)"),
    (MEDIUM + ("--out", "x.blend"), "has no Lamina medium material: pass --preset or --json"),
    (MEDIUM + ("--preset", "milk"), "pass --out FILE, or --overwrite"),
    (("bake-medium", "--blend", "in.blend", "--object", "Nope", "--preset", "milk", "--out", "x.blend"),
     "--object 'Nope': no such object"),
    (("bake-medium", "--blend", "in.blend", "--object", "Lamina plastic camera", "--preset", "milk", "--out",
      "x.blend"), "select a mesh object"),
    (("bake-medium", "--blend", "corrupt.blend", "--object", "x", "--preset", "milk", "--out", "x.blend"),
     "Blender cannot read it"),
    # compare-medium
    (("compare-medium", "--preset", "fluff", "--out", "new"), "unknown neural_medium preset 'fluff'"),
    (("compare-medium", "--preset", "milk", "--samples", "0", "--out", "new"), "--samples must be ≥ 1, got 0"),
    (("compare-medium", "--json", "zero_medium.json", "--out", "new"), "zero density"),
    (("compare-medium", "--preset", "milk", "--out", "results"), "results"),
    (("compare-medium", "--out", "new"), "one of the arguments --preset --json is required"),
    # add-porous
    (("add-porous", "--blend", "in.blend", "--material", "Nope", "--preset", "dust_on_wood", "--out", "x.blend"),
     "--material 'Nope': no such material in"),
    (("add-porous", "--blend", "in.blend", "--material", MATERIAL, "--preset", "fluff", "--out", "x.blend"),
     "unknown micrograin preset 'fluff'"),
    (("add-porous", "--blend", "in.blend", "--material", MATERIAL, "--json", "grains.json", "--out", "x.blend"),
     "velvet"),
    (("add-porous", "--blend", "in.blend", "--material", MATERIAL, "--json", "list.json", "--out", "x.blend"),
     "expected a JSON object"),
    (("add-porous", "--blend", "corrupt.blend", "--material", MATERIAL, "--preset", "dust_on_wood", "--out",
      "x.blend"), "Blender cannot read it"),
    (POROUS + ("--form", "glsl", "--out", "x.blend"), "argument --form: invalid choice"),
    (POROUS + ("--out", "text.txt/x.blend"), "is a file, not a folder"),
    (POROUS, "pass --out FILE, or --overwrite"),
    # assets
    (("assets",), "the following arguments are required: --out"),
    (("assets", "--out", "results"), "--out 'results' exists and is not empty; pass --overwrite"),
    (("assets", "--out", "text.txt"), "is a file; expected a folder"),
    (("assets", "--out", "new", "--size", "4"), "--size 4: expected 8 to 512 pixels"),
    (("assets", "--out", "new", "--samples", "0"), "--samples 0: expected at least 1"),
    (("assets", "--out", "new", "--mapping", "exact"), "argument --mapping: invalid choice: 'exact'"),
]


def checksums(folder) -> dict:
    out = {}
    for path in sorted(folder.rglob("*")):
        rel = str(path.relative_to(folder))
        out[rel] = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "folder"
    return out


@pytest.mark.parametrize("args, reason", REFUSALS, ids=[" ".join(a)[:60] or "(none)" for a, _ in REFUSALS])
def test_a_refusal_exits_2_with_one_line_and_changes_nothing(fixtures, tmp_path, args, reason):
    work = tmp_path / "work"
    shutil.copytree(fixtures, work)
    before = checksums(work)
    r = lamina(*args, cwd=work)
    lines = [line for line in r.stderr.splitlines() if not line.startswith("lamina: warning: ")]
    assert r.returncode == 2, r.stderr
    assert r.stdout == "" and len(lines) == 1 and lines[0].startswith("lamina: error: "), (r.stdout, r.stderr)
    assert reason in lines[0], lines[0]
    assert "Traceback" not in r.stderr and ".tmp" not in r.stderr
    assert checksums(work) == before


def test_the_table_covers_every_command_with_at_least_40_rows():
    from addon.cli import COMMANDS

    assert len(REFUSALS) >= 40
    assert {args[0] for args, _ in REFUSALS if args} >= set(COMMANDS) - {"list-presets"}


def test_compare_replaces_earlier_results_only_with_overwrite_and_writes_nothing_else(fixtures, tmp_path):
    work = tmp_path / "work"
    shutil.copytree(fixtures, work)
    before = checksums(work)
    r = lamina(*COMPARE, "--resolution", "8", "--samples", "1", "--out", "results", "--overwrite", cwd=work)
    assert r.returncode == 0, r.stderr
    after = checksums(work)
    assert {k: v for k, v in after.items() if not k.startswith("results")} == \
        {k: v for k, v in before.items() if not k.startswith("results")}
    report = json.loads((work / "results" / "report.json").read_text())
    assert report["label"] == "plastic" and list(report["forms"]) == ["nodes"]
    assert sorted(p.name for p in (work / "results").iterdir()) == ["nodes", "report.json"]
