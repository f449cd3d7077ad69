"""The Lamina asset library: every preset of every BSDF model as a material asset in ``lamina_library.blend``, with a
Cycles-rendered preview and a catalog per model (``asset_catalogs``), and a user asset-library entry pointing at it,
so presets drag from the Asset Browser onto objects. Media are left out: their light is baked per object.

The library is built by the running Blender (a file saved by 5.0 does not open in 4.2) into the extension's user
folder, or a given one; one preset per step (``build_steps``), the catalogs and then the file written at the end
(nothing before every preset is done), and everything built is removed from the open file again. Its materials are ordinary node groups: they
render without Lamina.
"""
from __future__ import annotations

import os
import tempfile

import bpy

from .. import presets
from ..asset_catalogs import (CATALOG_FILE, LIBRARY_FILE, LIBRARY_NAME, PREVIEW_SAMPLES, PREVIEW_SIZE, catalog_id,
                              catalog_text, preview_pixels)
from ..bake.exr import atomic_path
from ..console import blender_quiet
from ..models import MODELS
from ..nodes import fittable
from ..nodes import material as lamina_material
from ..reference import scenes as S
from . import blend_io
from .cycles_render import render_cycles
from .material_ops import MAPPING_ITEMS, label
from .progress import begin_modal, end_modal


def library_folder(create: bool = True) -> str:
    """The extension's user folder ``assets``, or Blender's user data folder ``lamina/assets`` when Lamina runs from a
    source tree (created unless ``create`` is false: the panel only looks)."""
    return (blend_io.extension_folder("assets", create)
            or bpy.utils.user_resource("DATAFILES", path="lamina/assets", create=create))


def jobs() -> list[tuple[str, str]]:
    """(model id, preset name) of every asset, in registry order."""
    return [(model_id, name) for model_id in MODELS for name in presets.names(model_id)]


def build_steps(folder: str, mapping: str = "auto", size: int = PREVIEW_SIZE, samples: int = PREVIEW_SAMPLES):
    """A generator: one preset's asset per step, yielding the fraction done; then the library and its catalogs are
    written into ``folder``. Closing it early (a cancel) or a failure writes nothing; either way what its steps built
    (and only that: the user may go on working between steps) is removed from the open file. Its return value
    (``StopIteration.value``) is the library's path."""
    built = {}
    try:
        made, todo = [], jobs()
        for done, (model_id, name) in enumerate(todo, 1):
            before = blend_io.snapshot()
            try:
                made.append(_asset(model_id, name, mapping, size, samples))
            finally:
                for c, blocks in blend_io.new_since(before).items():
                    built.setdefault(c, set()).update(blocks)
            yield done / len(todo)
        return _write(folder, made)
    finally:
        blend_io.remove_blocks(built)


def build(folder: str, mapping: str = "auto", size: int = PREVIEW_SIZE, samples: int = PREVIEW_SAMPLES) -> str:
    """``build_steps`` at once; the library's path."""
    steps = build_steps(folder, mapping, size, samples)
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def _asset(model_id: str, name: str, mapping: str, size: int, samples: int):
    model = MODELS[model_id]
    p = model.params_from_dict(presets.load(model_id, name))
    mat = lamina_material.new_material(model_id, p, "nodes", name=f"Lamina {model.LABEL} {label(name)}",
                                       mapping=mapping if fittable(model_id) else "analytic")
    mat.asset_mark()
    mat.asset_data.catalog_id = catalog_id(model_id)
    mat.asset_data.description = presets.description(model_id, name)
    spec = S.sphere_scene(resolution=size)
    with tempfile.TemporaryDirectory() as tmp:
        image, _ = render_cycles(mat, spec, samples, 0, os.path.join(tmp, "preview.exr"))
    preview = mat.preview_ensure()
    preview.image_size = (size, size)
    preview.image_pixels_float.foreach_set(preview_pixels(image, S.scene_mask(spec)))
    return mat


def _write(folder: str, materials: list) -> str:
    os.makedirs(folder, exist_ok=True)
    with atomic_path(os.path.join(folder, CATALOG_FILE)) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(catalog_text({m: MODELS[m].LABEL for m in MODELS}))
    path = os.path.join(folder, LIBRARY_FILE)
    with atomic_path(path) as tmp, blender_quiet():
        bpy.data.libraries.write(tmp, set(materials), fake_user=True)
    return path


def library_entry(folder: str):
    """The user asset-library entry pointing at ``folder``, or None."""
    target = os.path.realpath(folder)
    return next((lib for lib in bpy.context.preferences.filepaths.asset_libraries
                 if os.path.realpath(bpy.path.abspath(lib.path)) == target), None)


class LAMINA_OT_build_asset_library(bpy.types.Operator):
    """Write every Lamina preset as a material asset, with a rendered preview, into the Lamina asset library
    (Esc cancels; nothing is written until every preset is done)"""

    bl_idname = "lamina.build_asset_library"
    bl_label = "Build Lamina Asset Library"

    mapping: bpy.props.EnumProperty(name="Mapping", items=MAPPING_ITEMS, default="auto")
    folder: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH",
                                     description="Where to write it (default: the extension's user folder)")

    _timer = None
    _steps = None

    def _start(self):
        self._steps = build_steps(self.folder or library_folder(), self.mapping)

    def execute(self, context):
        self._start()
        return self._finish()

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        self._start()
        self._timer = begin_modal(self, context, 0.05, 100)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self._steps.close()
            end_modal(context, self._timer)
            self.report({"WARNING"}, "Asset library not built: nothing was written")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            fraction = next(self._steps)
        except StopIteration as done:
            end_modal(context, self._timer)
            return self._done(done.value)
        except Exception as e:  # noqa: BLE001 - report; nothing was written
            end_modal(context, self._timer)
            self.report({"ERROR"}, f"Could not build the asset library: {e}")
            return {"CANCELLED"}
        context.window_manager.progress_update(int(100 * fraction))
        if context.workspace is not None:
            context.workspace.status_text_set(f"Lamina: building the asset library {fraction:.0%} (Esc cancels)")
        return {"RUNNING_MODAL"}

    def _finish(self):
        try:
            while True:
                next(self._steps)
        except StopIteration as done:
            return self._done(done.value)
        except Exception as e:  # noqa: BLE001 - report; nothing was written
            self.report({"ERROR"}, f"Could not build the asset library: {e}")
            return {"CANCELLED"}

    def _done(self, path: str):
        self.report({"INFO"}, f"Wrote {len(jobs())} Lamina assets to {path}")
        return {"FINISHED"}


class LAMINA_OT_add_asset_library(bpy.types.Operator):
    """Add the Lamina asset library to the Asset Browser (a user asset-library entry in the Preferences), building it
    first if it is not there yet"""

    bl_idname = "lamina.add_asset_library"
    bl_label = "Add Lamina Asset Library"

    folder: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE"})

    def execute(self, context):
        folder = self.folder or library_folder()
        if library_entry(folder) is None:
            context.preferences.filepaths.asset_libraries.new(name=LIBRARY_NAME, directory=folder)
            self.report({"INFO"}, f"Added the asset library {LIBRARY_NAME!r} ({folder})")
        if not os.path.isfile(os.path.join(folder, LIBRARY_FILE)):
            bpy.ops.lamina.build_asset_library("EXEC_DEFAULT" if bpy.app.background else "INVOKE_DEFAULT",
                                               folder=folder)
        return {"FINISHED"}


classes = (LAMINA_OT_build_asset_library, LAMINA_OT_add_asset_library)
