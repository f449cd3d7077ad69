"""The Lamina asset library (issue 16): every preset of every BSDF model as a material asset with a rendered preview
and its model's catalog, built by the running Blender; every asset loads and renders in a fresh Blender without
Lamina; the open file is left as it was; the Asset Browser entry (the headless command's refusals:
tests/unit/test_cli_contract.py)."""
import os
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from addon import asset_catalogs  # noqa: E402
from addon.bake.exr import read_exr  # noqa: E402
from addon.models import MODELS  # noqa: E402
from addon.operators import asset_library  # noqa: E402
from addon.operators.material_ops import label  # noqa: E402
from ui_helpers import panel_text  # noqa: E402

pytestmark = pytest.mark.blender
SIZE = 24

# In a fresh Blender without Lamina: append every material of the library, put each on a sphere of a grid under a
# sun, render once; prints the assets' names in grid order.
RENDER_ALL = """
import sys, math, bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
with bpy.data.libraries.load(sys.argv[1], assets_only=True) as (src, dst):
    dst.materials = sorted(src.materials)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device, scene.cycles.samples = "CPU", 1
side = math.ceil(math.sqrt(len(dst.materials)))
scene.render.resolution_x = scene.render.resolution_y = 8 * side
for i, mat in enumerate(dst.materials):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=(i % side - side / 2 + 0.5, side / 2 - 0.5 - i // side, 0))
    bpy.context.object.data.materials.append(mat)
sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
sun.rotation_euler = (0.5, 0.3, 0.0)
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
cam.data.type, cam.data.ortho_scale, cam.location = "ORTHO", side, (0, 0, 10)
for obj in (sun, cam):
    scene.collection.objects.link(obj)
scene.camera = cam
scene.render.image_settings.file_format = "OPEN_EXR"
scene.render.filepath = sys.argv[2]
bpy.ops.render.render(write_still=True)
print("LAMINA_MODULES", [m for m in sys.modules if m == "addon" or m.startswith("addon.")])
print("ASSETS", "|".join(m.name for m in dst.materials))
"""


@pytest.fixture(scope="module")
def jobs_built():
    """Every preset under Blender 5.0; under 4.2 the first preset of each model only: the same asset, preview, catalog,
    library-writing and appending calls on 4.2's API, without building every preset's node group again (the
    anisotropic stacks' take minutes; what the presets build does not depend on the Blender version)."""
    if bpy.app.version >= (5, 0, 0):
        yield
        return
    first = {}
    for model_id, name in asset_library.jobs():
        first.setdefault(model_id, (model_id, name))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(asset_library, "jobs", lambda: list(first.values()))
        yield


@pytest.fixture(scope="module")
def library(jobs_built, tmp_path_factory):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    user = bpy.data.materials.new("the user's material")
    before = {c: sorted(x.name for x in getattr(bpy.data, c)) for c in ("materials", "node_groups", "scenes", "texts")}
    folder = tmp_path_factory.mktemp("assets")
    path = asset_library.build(str(folder), mapping="analytic", size=SIZE, samples=2)
    after = {c: sorted(x.name for x in getattr(bpy.data, c)) for c in before}
    assert after == before and user.name in after["materials"]  # the open file is left as it was
    return folder, path


def test_every_preset_is_an_asset_with_a_preview_in_its_models_catalog(library):
    folder, path = library
    catalogs = {}
    for line in (folder / asset_catalogs.CATALOG_FILE).read_text().splitlines():
        if line and not line.startswith(("#", "VERSION")):
            uid, catalog, _ = line.split(":")
            catalogs[uid] = catalog
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with bpy.data.libraries.load(path, assets_only=True) as (src, dst):
        dst.materials = list(src.materials)
    expected = {f"Lamina {MODELS[m].LABEL} {label(n)}": m for m, n in asset_library.jobs()}
    assert sorted(m.name for m in dst.materials) == sorted(expected)
    for mat in dst.materials:
        assert mat.asset_data is not None and mat.asset_data.description
        assert catalogs[mat.asset_data.catalog_id] == f"Lamina/{MODELS[expected[mat.name]].LABEL}"
        assert tuple(mat.preview.image_size) == (SIZE, SIZE)
        pixels = np.empty(SIZE * SIZE * 4, dtype=np.float32)
        mat.preview.image_pixels_float.foreach_get(pixels)
        rgba = pixels.reshape(SIZE, SIZE, 4)
        assert rgba[..., 3].max() == 1.0 and rgba[0, 0, 3] == 0.0  # the sphere, transparent around it
        assert rgba[..., :3][rgba[..., 3] > 0].max() > 0.0, mat.name


def test_every_asset_renders_in_a_blender_without_lamina(library, tmp_path):
    _, path = library
    out = tmp_path / "all.exr"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run([sys.executable, "-c", RENDER_ALL, path, str(out)], capture_output=True, text=True,
                       cwd=str(tmp_path), timeout=600, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "LAMINA_MODULES []" in r.stdout
    names = next(line for line in r.stdout.splitlines() if line.startswith("ASSETS ")).split(" ", 1)[1].split("|")
    image = read_exr(out, "RGB")
    side = image.shape[0] // 8
    assert np.isfinite(image).all() and image.min() >= 0.0
    for i, name in enumerate(names):  # each sphere's 8 x 8 cell shows light
        row, col = divmod(i, side)
        assert image[8 * row:8 * row + 8, 8 * col:8 * col + 8].max() > 0.0, name


def test_the_asset_browser_entry_is_added_once_and_builds_a_missing_library(registered, tmp_path, monkeypatch):
    def quick(folder, mapping):  # the build itself is tested above; here: that a missing library gets built
        yield 1.0
        (tmp_path / asset_catalogs.LIBRARY_FILE).write_bytes(b"")
        return str(tmp_path / asset_catalogs.LIBRARY_FILE)

    monkeypatch.setattr(asset_library, "build_steps", quick)
    monkeypatch.setattr(asset_library, "library_folder", lambda create=True: str(tmp_path))
    libraries = bpy.context.preferences.filepaths.asset_libraries
    count = len(libraries)
    assert "lamina.add_asset_library" in panel_text(None)
    try:
        assert bpy.ops.lamina.add_asset_library() == {"FINISHED"}
        assert asset_library.library_entry(str(tmp_path)) is not None and len(libraries) == count + 1
        assert (tmp_path / asset_catalogs.LIBRARY_FILE).is_file()  # built, as it was missing (background: at once)
        assert bpy.ops.lamina.add_asset_library() == {"FINISHED"}
        assert len(libraries) == count + 1
        drawn = panel_text(None)
        assert "lamina.build_asset_library" in drawn and "lamina.add_asset_library" not in drawn
    finally:
        entry = asset_library.library_entry(str(tmp_path))
        if entry is not None:
            libraries.remove(entry)
