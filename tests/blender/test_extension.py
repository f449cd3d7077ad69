"""Packaging and registration: the zip built by Blender's own extension tool installs and enables; register and
unregister leave nothing behind."""
import glob
import os
import subprocess
import sys
import textwrap

import pytest

bpy = pytest.importorskip("bpy")

import addon  # noqa: E402

pytestmark = pytest.mark.blender
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _ext_tool():
    scripts = bpy.utils.resource_path("LOCAL")  # the bpy module's own copy of Blender's scripts
    (tool,) = glob.glob(os.path.join(scripts, "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py"))
    return tool


def _state():
    return ({name for name in dir(bpy.types) if "LAMINA" in name.upper()},
            hasattr(bpy.types.WindowManager, "lamina_compare"),
            hasattr(bpy.ops.lamina, "add_spongecake") and "add_spongecake" in dir(bpy.ops.lamina))


def test_register_then_unregister_leaves_nothing_behind():
    before = _state()
    addon.register()
    try:
        registered = _state()
        assert "LAMINA_OT_add_spongecake" in registered[0] and registered[1]
    finally:
        addon.unregister()
    assert _state() == before


def test_register_twice_in_a_row_works():
    for _ in range(2):
        addon.register()
        addon.unregister()


def test_manifest_validates_and_zip_installs_and_enables(tmp_path):
    tool = _ext_tool()
    subprocess.run([sys.executable, tool, "validate", ROOT], check=True, capture_output=True)
    dist = tmp_path / "dist"
    dist.mkdir()
    subprocess.run([sys.executable, tool, "build", "--source-dir", ROOT, "--output-dir", str(dist)],
                   check=True, capture_output=True)
    (zip_path,) = dist.glob("lamina-*.zip")
    import zipfile

    names = zipfile.ZipFile(zip_path).namelist()
    assert "blender_manifest.toml" in names and "addon/nodes/material.py" in names
    assert not [n for n in names if n.startswith(("tests/", "training/", "docs/", ".venv/"))]
    script = textwrap.dedent(f"""
        import bpy, sys
        bpy.ops.extensions.package_install_files(filepath={str(zip_path)!r}, repo="user_default",
                                                 enable_on_install=True)
        ok = hasattr(bpy.ops.lamina, "add_spongecake") and "add_spongecake" in dir(bpy.ops.lamina)
        print("LAMINA_ENABLED", ok)
        sys.exit(0 if ok else 1)
    """)
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, cwd=tmp_path,
                       timeout=300)
    assert "LAMINA_ENABLED True" in r.stdout, r.stdout[-2000:] + r.stderr[-2000:]
