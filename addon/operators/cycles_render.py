"""Render a comparison scene (``addon.reference.scenes.Scene``) with Cycles on the CPU, in a temporary
scene that is removed afterwards. Functions only; the UI operators live elsewhere.

Nothing of the user's is changed: a new ``bpy.data`` scene gets its own camera, lamp(s), world and
mesh; the user's material is only assigned to that mesh (never edited); everything created, including a
"Render Result" image that did not exist before, is removed in a ``finally`` block, so the counts of
every ``bpy.data`` collection, the active scene and its render settings are the same afterwards.

Cycles set-up (research notes section 6): CPU, fixed seed, ``max_bounces`` = 0 (and every other bounce
limit 0, so only the surface the camera sees is shaded with direct light), pixel filter width 0.01 px,
no denoising, no adaptive sampling, no clamping, no light threshold, Standard view transform (EXR
written linear), 32-bit float EXR written with ``write_still`` to a temporary file and renamed.
The EXR is read back with OpenEXR, whose first scanline is the TOP row, so the returned image has
row 0 at the top like ``reference_image`` (checked by the tests: a flipped or mirrored image fails).

Geometry accuracy (bpy 5.0.1, Lambert on the 64 x 64 sphere scene, sun 45 deg up): the analytic
normals of the reference differ from Cycles' interpolated normals of a smooth UV sphere by a relative
RMSE of 0.9% (32 or 64 segments), 0.08-0.5% (128 x 64) and 0.02-0.03% (256 x 128, the default). The
mesh gets exact radial custom normals (makes no measurable difference at 256 segments).
Cycles quirk: with filter_width 0.01 px most samples land at the pixel centre, but a few (about 1 in
200 with 64 spp) land up to ~0.5 px away; sun-lit scenes are otherwise noise-free, so 16 spp suffice
there (GGX alpha 0.3: 0.05-0.1% relative RMSE). The furnace is Monte Carlo (world/BSDF MIS):
GGX alpha 0.3 gives 5% at 16 spp, 0.34% at 256, 0.07% at 1024; a Lambertian is exact at any count.
Limitation: the render goes through ``bpy.ops.render.render``, so an existing "Render Result"
image shows the comparison render afterwards (it is not removed; one created by us is).
"""
from __future__ import annotations

import math
import os
import time

import bpy
import numpy as np

from ..bake.exr import atomic_path, read_exr
from ..console import blender_quiet
from ..reference import scenes as _scenes

__all__ = ["render_cycles", "material_uses_osl", "build_scene"]

_PREFIX = "Lamina Compare"
_CAMERA_HEIGHT = 1.0  # panorama camera above the plane


def material_uses_osl(material) -> bool:
    """True if ``material`` (or a node group inside it, at any depth) has an OSL Script node."""
    seen = set()

    def walk(tree):
        if tree is None or tree.name_full in seen:
            return False
        seen.add(tree.name_full)
        for node in tree.nodes:
            if node.bl_idname == "ShaderNodeScript":
                return True
            if getattr(node, "node_tree", None) is not None and walk(node.node_tree):
                return True
        return False

    return material is not None and walk(getattr(material, "node_tree", None))


def _look_at_rotation(direction):
    """Euler rotation that turns an object's local +Z onto ``direction``. A sun lamp shines along its
    local -Z, so with ``direction`` = the unit vector toward the light the light travels along -direction."""
    from mathutils import Vector

    return Vector(direction).to_track_quat("Z", "Y").to_euler()


def _configure(scene, spec, samples, seed, osl, bounces=0):
    w, h = spec.resolution
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.use_border = False
    r.film_transparent = False
    r.use_compositing = False
    r.use_sequencer = False
    r.use_persistent_data = False
    r.dither_intensity = 0.0
    r.threads_mode = "AUTO"
    r.use_file_extension = False
    r.use_motion_blur = False
    img = r.image_settings
    if hasattr(img, "media_type"):
        img.media_type = "IMAGE"
    img.file_format = "OPEN_EXR"
    img.color_mode = "RGBA"
    img.color_depth = "32"
    img.exr_codec = "ZIP"
    v = scene.view_settings
    v.view_transform = "Standard"
    v.look = "None"
    v.exposure = 0.0
    v.gamma = 1.0
    v.use_curve_mapping = False
    c = scene.cycles
    c.device = "CPU"
    c.shading_system = bool(osl)
    c.samples = int(samples)
    c.seed = int(seed)
    c.use_animated_seed = False
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.time_limit = 0.0
    c.max_bounces = c.volume_bounces = int(bounces)  # 0: direct light only (a volume's single scattering)
    c.diffuse_bounces = 0
    c.glossy_bounces = 0
    c.transmission_bounces = 0
    c.transparent_max_bounces = max(8, int(bounces))  # lets the furnace see delta transmission (transparent closures)
    c.min_light_bounces = 0
    c.min_transparent_bounces = 0
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.blur_glossy = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.filter_width = 0.01
    c.pixel_filter_type = "BLACKMAN_HARRIS"
    c.film_exposure = 1.0
    c.use_auto_tile = False


def build_scene(material, spec, samples=16, seed=0, bounces=0):
    """Create the temporary Cycles scene for ``spec``; returns (scene, created) where ``created`` lists
    (collection_name, ID) pairs in the order they must be removed. The caller removes them."""
    created = []
    scene = bpy.data.scenes.new(f"{_PREFIX} {spec.name}")
    created.append(("scenes", scene))
    try:
        _configure(scene, spec, samples, seed, material_uses_osl(material), bounces)

        # --- object
        mesh = bpy.data.meshes.new(f"{_PREFIX} {spec.kind}")
        created.insert(0, ("meshes", mesh))
        if spec.kind == "sphere":
            verts, faces, uvs = _scenes.uv_sphere_mesh(spec.sphere_segments, spec.sphere_rings)
            mesh.from_pydata(verts.tolist(), [], faces)
            uv = mesh.uv_layers.new(name="UVMap")
            uv.data.foreach_set("uv", uvs.astype(np.float32).ravel())
            mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), dtype=bool))
            # exact radial vertex normals (the analytic sphere's); Cycles interpolates them per triangle
            mesh.normals_split_custom_set_from_vertices(verts.tolist())
        else:
            s = _scenes.plane_half_size(spec, _CAMERA_HEIGHT)
            mesh.from_pydata([(-s, -s, 0.0), (s, -s, 0.0), (s, s, 0.0), (-s, s, 0.0)], [], [(0, 1, 2, 3)])
            uv = mesh.uv_layers.new(name="UVMap")
            uv.data.foreach_set("uv", np.array([0, 0, 1, 0, 1, 1, 0, 1], dtype=np.float32))
            # Pin the Generated texture space far off along +y so that Cycles' default tangent (the
            # "radial Z" tangent from Generated coordinates, -(gy-.5), gx-.5, 0) is +x everywhere
            # (deviation < 1e-4 rad over the plane).
            mesh.use_auto_texspace = False
            mesh.texspace_location = (0.0, 1.0e4 * s, 0.0)
            mesh.texspace_size = (s, s, s)
        mesh.update()
        if material is not None:
            mesh.materials.append(material)
        obj = bpy.data.objects.new(f"{_PREFIX} {spec.kind}", mesh)
        created.insert(0, ("objects", obj))
        scene.collection.objects.link(obj)

        # --- camera
        cam = bpy.data.cameras.new(f"{_PREFIX} camera")
        created.insert(0, ("cameras", cam))
        cam_obj = bpy.data.objects.new(f"{_PREFIX} camera", cam)
        created.insert(0, ("objects", cam_obj))
        scene.collection.objects.link(cam_obj)
        scene.camera = cam_obj
        cam.clip_start = 1e-3
        cam.clip_end = 1e5
        if spec.kind == "sphere":
            cam.type = "ORTHO"
            cam.ortho_scale = spec.ortho_scale
            cam.sensor_fit = "AUTO"
            cam.shift_x = cam.shift_y = 0.0
            cam_obj.location = (0.0, 0.0, 10.0)
            cam_obj.rotation_euler = (0.0, 0.0, 0.0)  # looks down -z, up = +y
        else:
            cam.type = "PANO"
            cam.panorama_type = "EQUIRECTANGULAR"
            # Camera looks along -y with its up axis on -z: latitude +90 deg = straight down (top row,
            # theta_o = 0), latitude 90 - theta_max at the bottom row; the z rotation of +90 deg puts
            # column c at phi_o = (c + .5) / W * 360 deg (measured: see tests/blender).
            cam.latitude_max = 0.5 * math.pi
            cam.latitude_min = 0.5 * math.pi - math.radians(spec.theta_max_deg)
            cam.longitude_min = -math.pi
            cam.longitude_max = math.pi
            cam_obj.location = (0.0, 0.0, _CAMERA_HEIGHT)
            cam_obj.rotation_euler = (-0.5 * math.pi, 0.0, 0.5 * math.pi)

        # --- suns
        for i, sun in enumerate(spec.suns):
            ld = bpy.data.lights.new(f"{_PREFIX} sun {i}", type="SUN")
            created.insert(0, ("lights", ld))
            ld.energy = float(sun.irradiance)
            ld.angle = 0.0
            ld.color = (1.0, 1.0, 1.0)
            if hasattr(ld, "exposure"):
                ld.exposure = 0.0
            lo = bpy.data.objects.new(f"{_PREFIX} sun {i}", ld)
            created.insert(0, ("objects", lo))
            scene.collection.objects.link(lo)
            lo.rotation_euler = _look_at_rotation(sun.direction)  # local +z toward the light

        # --- world
        world = bpy.data.worlds.new(f"{_PREFIX} world")
        created.insert(0, ("worlds", world))
        env = float(spec.environment)
        world.color = (env, env, env)
        tree = getattr(world, "node_tree", None)
        if tree is None and hasattr(world, "use_nodes"):
            world.use_nodes = True
            tree = world.node_tree
        if tree is not None:
            bg = next((n for n in tree.nodes if n.bl_idname == "ShaderNodeBackground"), None)
            if bg is None:
                bg = tree.nodes.new("ShaderNodeBackground")
                out = next((n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld"), None) \
                    or tree.nodes.new("ShaderNodeOutputWorld")
                tree.links.new(bg.outputs[0], out.inputs["Surface"])
            bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
            bg.inputs["Strength"].default_value = env
        scene.world = world
        return scene, created
    except BaseException:
        _remove(created)
        raise


def _remove(created):
    for coll_name, idb in created:
        coll = getattr(bpy.data, coll_name)
        try:
            if idb.name_full in coll and coll[idb.name_full] == idb:
                coll.remove(idb, do_unlink=True)
        except ReferenceError:  # already freed together with something else
            pass


def render_cycles(material, scene_spec, samples, seed, out_exr_path, bounces=0, prepare=None):
    """Render ``scene_spec`` with ``material`` in Cycles (CPU).

    Writes a 32-bit float RGBA EXR to ``out_exr_path`` (atomically: rendered to a temporary file in the
    same folder, then renamed) and returns ``(image, seconds)``: ``image`` H x W x 3 float64 linear
    radiance with row 0 at the TOP (like ``reference_image``), ``seconds`` the wall time of the render
    call (scene sync, kernel set-up and sampling). The user's scenes, settings and data are unchanged.
    ``bounces``: light bounces after the first interaction (0, the default: direct light only, which for a volume
    is its single scattering; volumes need many for their multiple scattering). ``prepare(scene, obj)`` runs on the
    temporary scene and its object before the render (e.g. a medium's bake into the object's mesh).
    """
    if samples < 1:
        raise ValueError("samples must be >= 1")
    images_before = {im.name_full for im in bpy.data.images}
    created = []
    try:
        scene, created = build_scene(material, scene_spec, samples, seed, bounces)
        if prepare is not None:
            prepare(scene, next(o for o in scene.objects if o.type == "MESH"))
        with atomic_path(out_exr_path) as tmp:
            scene.render.filepath = tmp
            t0 = time.perf_counter()
            with blender_quiet():
                result = bpy.ops.render.render(write_still=True, scene=scene.name)
            seconds = time.perf_counter() - t0
            if "FINISHED" not in result or not os.path.exists(tmp) or os.path.getsize(tmp) == 0:
                raise RuntimeError(f"Cycles render of {scene_spec.name!r} failed ({result})")
            image = read_exr(tmp, "RGBA")[:, :, :3]
        return np.ascontiguousarray(image, dtype=np.float64), seconds
    finally:
        _remove(created)
        for im in list(bpy.data.images):
            if im.name_full not in images_before and im.type == "RENDER_RESULT":
                bpy.data.images.remove(im)
