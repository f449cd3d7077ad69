"""The headless CLI: exit codes and one-line reasons (``python -m addon.cli``, the same code as ``blender -c``)."""
import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def lamina(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "addon.cli", *args], capture_output=True, text=True, cwd=cwd,
                          env=dict(os.environ, PYTHONPATH=ROOT), timeout=300)


def test_list_presets_prints_every_preset():
    r = lamina("list-presets")
    assert r.returncode == 0
    assert {line.split()[0] for line in r.stdout.splitlines()} >= {"fabric", "window_shade", "leaf"}


@pytest.mark.parametrize("args, reason", [
    (("compare", "--preset", "velvet", "--out", "x"), "unknown spongecake preset 'velvet'"),
    (("compare", "--preset", "fabric", "--scenes", "moon", "--out", "x"), "unknown scene moon"),
    (("compare", "--preset", "fabric", "--forms", "glsl", "--out", "x"), "unknown form glsl"),
    (("compare", "--preset", "fabric", "--samples", "0", "--out", "x"), "--samples"),
    (("bake", "--blend", "missing.blend", "--material", "M", "--out", "x.blend"), "missing.blend does not exist"),
])
def test_bad_arguments_exit_2_with_one_line(args, reason):
    r = lamina(*args)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and reason in r.stderr


def test_micrograin_presets_are_listed_and_make_a_material(tmp_path):
    r = lamina("list-presets", "--model", "micrograin")
    assert r.returncode == 0
    assert {line.split()[0] for line in r.stdout.splitlines()} >= {"rust_on_metal", "dust_on_wood", "soot_on_clay"}
    out = tmp_path / "rust.blend"
    r = lamina("make-material", "--model", "micrograin", "--preset", "rust_on_metal", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:7] == b"BLENDER"


def test_add_porous_bad_arguments_exit_2_before_opening_the_file(tmp_path):
    blend = tmp_path / "in.blend"
    blend.write_bytes(b"not opened: every refusal below comes first")
    layer = tmp_path / "layer.json"
    layer.write_text(json.dumps({"filling_factor": 0.3, "grain": {"type": "velvet"}}))
    base = ("add-porous", "--blend", str(blend), "--material", "Paint")
    for args, reason in [
        (base + ("--preset", "fluff", "--out", str(tmp_path / "o.blend")), "unknown micrograin preset 'fluff'"),
        (base + ("--json", str(layer), "--out", str(tmp_path / "o.blend")), "velvet"),
        (base + ("--json", str(tmp_path / "missing.json"), "--out", str(tmp_path / "o.blend")), "cannot read --json"),
        (base + ("--preset", "dust_on_wood"), "pass --out FILE, or --overwrite"),
        (base + ("--preset", "dust_on_wood", "--out", str(blend)), "--overwrite"),
        (("add-porous", "--blend", str(tmp_path / "missing.blend"), "--material", "Paint", "--preset",
          "dust_on_wood", "--overwrite"), "missing.blend does not exist"),
    ]:
        r = lamina(*args)
        assert r.returncode == 2, (args, r.stderr)
        assert r.stderr.strip().count("\n") == 0 and reason in r.stderr, r.stderr
    assert blend.read_bytes() == b"not opened: every refusal below comes first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.blend", "layer.json"]
    assert lamina("add-porous", "--blend", str(blend), "--material", "Paint", "--out", "x.blend").returncode == 2


def test_missing_subcommand_is_a_usage_error():
    assert lamina().returncode == 2


def test_bad_params_file_is_refused(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"layers": [{"type": "velvet"}]}))
    r = lamina("make-material", "--params", str(bad), "--out", str(tmp_path / "x.blend"))
    assert r.returncode == 2 and "velvet" in r.stderr
    r = lamina("make-material", "--params", str(tmp_path / "missing.json"), "--out", str(tmp_path / "x.blend"))
    assert r.returncode == 2 and "cannot read" in r.stderr


def test_out_of_range_params_warn_but_proceed(tmp_path):
    p = tmp_path / "p.json"
    p.write_text(json.dumps({"layers": [{"roughness": 5.0}]}))
    r = lamina("make-material", "--params", str(p), "--out", str(tmp_path / "x.blend"))
    assert r.returncode == 0, r.stderr
    assert "clamped to 1" in r.stderr


def test_make_material_never_overwrites_without_asking(tmp_path):
    out = tmp_path / "m.blend"
    out.write_bytes(b"user data")
    r = lamina("make-material", "--preset", "plastic", "--out", str(out))
    assert r.returncode == 2 and "--overwrite" in r.stderr
    assert out.read_bytes() == b"user data"
    r = lamina("make-material", "--preset", "plastic", "--out", str(out), "--overwrite")
    assert r.returncode == 0 and out.read_bytes()[:7] == b"BLENDER"
    assert [p.name for p in tmp_path.iterdir()] == ["m.blend"]  # no temporary file left behind
