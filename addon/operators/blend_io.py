"""Write a self-contained .blend with a Lamina material on a lit sphere (no add-on needed to render it)."""
from __future__ import annotations

import bpy  # noqa: I001 - bpy must be imported before bmesh in the bpy module
import bmesh

from ..bake.exr import atomic_path
from ..nodes import material as lamina_material


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


def write_material_blend(model_id: str, p, form: str, name: str, path: str) -> None:
    """Build the material and its preview scene, write only them to ``path`` atomically, then remove them."""
    before = snapshot()
    mat = lamina_material.new_material(model_id, p, form, name=f"Lamina {name}")
    scene = preview_scene(mat, name)
    try:
        with atomic_path(path) as tmp:
            bpy.data.libraries.write(tmp, {scene}, fake_user=True)
    finally:
        remove_new_data(before)


COLLECTIONS = ("scenes", "objects", "meshes", "materials", "node_groups", "texts", "lights", "cameras",
               "worlds", "images")


def snapshot() -> dict:
    return {c: set(getattr(bpy.data, c)) for c in COLLECTIONS}


def remove_new_data(before: dict) -> None:
    """Remove every datablock created since ``before`` (objects first, so nothing is left dangling)."""
    for c in COLLECTIONS:
        for block in set(getattr(bpy.data, c)) - before[c]:
            getattr(bpy.data, c).remove(block)
