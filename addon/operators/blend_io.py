""".blend files for the headless commands: a self-contained .blend with a Lamina material on a lit sphere (no
add-on needed to render it), and opening a user's file, finding a material in it and saving a copy, with
Blender's own console lines hidden (``console.blender_quiet``)."""
from __future__ import annotations

import os

import bpy  # noqa: I001 - bpy must be imported before bmesh in the bpy module
import bmesh

from ..bake.exr import atomic_path
from ..console import blender_quiet
from ..nodes import material as lamina_material


class BlendArgumentError(ValueError):
    """The .blend or the material a command was given cannot be used (a bad argument: nothing was changed)."""


class SaveError(RuntimeError):
    """Blender could not save the result (the work failed; the destination is unchanged)."""


def open_blend(path: str) -> None:
    """Open ``path`` as the current file; BlendArgumentError when Blender cannot read it."""
    try:
        with blender_quiet():
            bpy.ops.wm.open_mainfile(filepath=path)
    except RuntimeError as e:
        reason = str(e).strip().splitlines()[-1] if str(e).strip() else "unreadable"
        raise BlendArgumentError(f"--blend {path!r}: Blender cannot read it ({reason.split(': ')[-1]})") from None


def find_material(name: str, path: str):
    """The material ``name`` of the open file ``path``; BlendArgumentError naming the ones it has."""
    mat = bpy.data.materials.get(name)
    if mat is None:
        names = ", ".join(sorted(m.name for m in bpy.data.materials)) or "none"
        raise BlendArgumentError(f"--material {name!r}: no such material in {path} (it has: {names})")
    return mat


def save_copy(path: str) -> None:
    """Save the open file as ``path`` atomically (no .blend1 backup); SaveError when Blender cannot."""
    with atomic_path(path) as tmp:
        os.remove(tmp)  # Blender would keep a .blend1 backup of the file it saves over
        with blender_quiet():
            saved = "FINISHED" in bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True)
        if not saved:
            raise SaveError(f"Blender could not save {path}")


def extension_folder(sub: str, create: bool = True) -> str | None:
    """The extension's user folder ``sub`` (created unless ``create`` is false), or None when Lamina runs from a
    source tree (tests)."""
    extension = ".".join(__package__.split(".")[:3])  # bl_ext.<repository>.<id>
    try:
        return bpy.utils.extension_path_user(extension, path=sub, create=create)
    except ValueError:
        return None


def preview_scene(mat, name: str) -> bpy.types.Scene:
    """A new scene (the user's scenes are untouched) with a smooth UV sphere using ``mat``, a sun and a camera."""
    scene = bpy.data.scenes.new(f"Lamina {name}")
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.shading_system = lamina_material.form_of(mat) == "osl"
    scene.cycles.samples = 64
    scene.render.resolution_x = scene.render.resolution_y = 256
    world = bpy.data.worlds.new(f"Lamina {name}")
    world.color = (0.05, 0.05, 0.05)
    scene.world = world

    mesh = bpy.data.meshes.new(f"Lamina {name}")
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=64, v_segments=32, radius=1.0, calc_uvs=True)
    bm.to_mesh(mesh)
    bm.free()
    mesh.shade_smooth()
    mesh.materials.append(mat)
    sphere = bpy.data.objects.new(f"Lamina {name}", mesh)

    sun_data = bpy.data.lights.new(f"Lamina {name} sun", "SUN")
    sun_data.energy = 3.0
    sun = bpy.data.objects.new(f"Lamina {name} sun", sun_data)
    sun.rotation_euler = (0.7, 0.2, 0.5)

    cam_data = bpy.data.cameras.new(f"Lamina {name} camera")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = 2.4
    cam = bpy.data.objects.new(f"Lamina {name} camera", cam_data)
    cam.location = (0.0, 0.0, 5.0)
    scene.camera = cam
    for obj in (sphere, sun, cam):
        scene.collection.objects.link(obj)
    return scene


def write_material_blend(model_id: str, p, form: str, name: str, path: str, mapping: str = "analytic"):
    """Build the material and its preview scene, write only them to ``path`` atomically, then remove them. Returns
    the material's mapping record (``nodes.material.fit_record``; None for the analytic mapping)."""
    before = snapshot()
    mat = lamina_material.new_material(model_id, p, form, name=f"Lamina {name}", mapping=mapping)
    record = lamina_material.fit_record(mat)
    scene = preview_scene(mat, name)
    try:
        with atomic_path(path) as tmp, blender_quiet():
            bpy.data.libraries.write(tmp, {scene}, fake_user=True)
    finally:
        remove_new_data(before)
    return record


COLLECTIONS = ("scenes", "objects", "meshes", "materials", "node_groups", "texts", "lights", "cameras",
               "worlds", "images")


def snapshot() -> dict:
    return {c: set(getattr(bpy.data, c)) for c in COLLECTIONS}


def new_since(before: dict) -> dict:
    """The datablocks created since the ``snapshot`` ``before``, per collection."""
    return {c: set(getattr(bpy.data, c)) - before[c] for c in COLLECTIONS}


def remove_blocks(blocks: dict) -> None:
    """Remove these datablocks ({collection: set}, as ``new_since`` gives; objects first, so nothing is left
    dangling); those already gone (an undo) are skipped."""
    for c in COLLECTIONS:
        for block in blocks.get(c, ()):
            try:
                getattr(bpy.data, c).remove(block)
            except ReferenceError:
                pass


def remove_new_data(before: dict) -> None:
    """Remove every datablock created since ``before``."""
    remove_blocks(new_since(before))
