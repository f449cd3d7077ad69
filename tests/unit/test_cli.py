"""The headless CLI: exit codes and one-line reasons (``python -m addon.cli``, the same code as ``blender -c``)."""
import json
import os
import subprocess
import sys


ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def lamina(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "addon.cli", *args], capture_output=True, text=True, cwd=cwd,
                          env=dict(os.environ, PYTHONPATH=ROOT), timeout=300)


def test_list_presets_prints_every_preset():
    r = lamina("list-presets")
    assert r.returncode == 0
    assert {line.split()[0] for line in r.stdout.splitlines()} >= {"fabric", "window_shade", "leaf"}


def test_micrograin_presets_are_listed_and_make_a_material(tmp_path):
    r = lamina("list-presets", "--model", "micrograin")
    assert r.returncode == 0
    assert {line.split()[0] for line in r.stdout.splitlines()} >= {"rust_on_metal", "dust_on_wood", "soot_on_clay"}
    out = tmp_path / "rust.blend"
    r = lamina("make-material", "--model", "micrograin", "--preset", "rust_on_metal", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:7] == b"BLENDER"


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
