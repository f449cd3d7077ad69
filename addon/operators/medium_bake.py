"""Baking a neural medium into an object (bpy side of ``bake/neural_medium.py``), shared by the Bake operator and
``lamina bake-medium``.

Where the bake lives. The coefficients are point attributes of the object's mesh (``nodes.neural_medium``), so a
material shared by several objects works (each mesh carries its own light) and so does a mesh without UVs; the
object's ``lamina_medium_bake`` property records what the bake was made for (``bake_key``), which the panel
compares with the scene as it is now to say "stale". Linked duplicates share one mesh and so one bake: the panel
says so. The mesh is taken before modifiers, in world space.

Lamps. Suns (strength = irradiance), point and spot lamps (power P watts: radiant intensity P / (4 pi) W/sr, a spot
masked by its cone, its blend ignored), area lamps (square, rectangle, disk, ellipse: one-sided Lambertian, total
power P, ``reference.neural_medium.area_beams``; a spread below 180 degrees is baked as 180, and the operator says
so), each lamp's colour per channel (both conventions tested against Cycles); the world is not baked (the operator
says so). A beam whose way to its lamp is blocked by another object is dropped (``scene.ray_cast``):
other objects shadow the light; the object's own other parts do not (its medium attenuates the beam's light as the
tables assume).
"""
from __future__ import annotations

import dataclasses
import json
import math
import time

import bpy  # noqa: I001 - the bpy module must be imported before bmesh
import bmesh
import numpy as np
from mathutils import Vector
from mathutils.bvhtree import BVHTree

from ..bake import neural_medium as nb
from ..nodes import neural_medium as medium_nodes
from ..reference import neural_medium as nm
from ..reference.scenes import Sun

PROPERTY = "lamina_medium_bake"
CHUNK = 256  # surface points per step of the modal bake
BAKED_LAMPS = ("SUN", "POINT", "SPOT", "AREA")


class BakeError(ValueError):
    """Why an object cannot be baked, in one line for the user."""


def mesh_problem(obj) -> str | None:
    """Why ``obj`` cannot hold a baked medium, or None."""
    if obj is None or obj.type != "MESH":
        return "select a mesh object (the medium fills a closed mesh)"
    mesh = obj.data
    if len(mesh.polygons) == 0:
        return f"{obj.name}: the mesh has no faces"
    bm = bmesh.new()
    try:
        bm.from_mesh(mesh)
        open_edges = sum(1 for e in bm.edges if len(e.link_faces) != 2)
    finally:
        bm.free()
    if open_edges:
        return (f"{obj.name}: the mesh is not closed ({open_edges} open or non-manifold edges); a medium needs a "
                f"closed surface")
    return None


class MeshShape:
    """A closed mesh in world space for the gather: ``interval`` of rays with it through a BVH, and a bounding
    sphere."""

    def __init__(self, obj):
        mesh = obj.data
        m = obj.matrix_world
        self.vertices = [m @ v.co for v in mesh.vertices]
        self.bvh = BVHTree.FromPolygons(self.vertices, [tuple(p.vertices) for p in mesh.polygons])
        co = np.array([tuple(v) for v in self.vertices])
        centre = 0.5 * (co.min(axis=0) + co.max(axis=0))
        self.bounding_sphere = (centre, max(float(np.linalg.norm(co - centre, axis=1).max()), 1e-9))
        self.epsilon = 1e-6 * (1.0 + float(np.abs(co).max()))

    def normal(self, points):
        """Unit outward normals of the faces nearest to the points."""
        out = np.zeros((len(points), 3))
        for i, x in enumerate(np.atleast_2d(points)):
            _, normal, _, _ = self.bvh.find_nearest(Vector(x))
            out[i] = tuple(normal)
        return out

    def interval(self, origins, directions):
        """(t0, t1) of each ray's first entry into the mesh and the exit after it (inf, -inf on a miss)."""
        origins, directions = np.atleast_2d(origins), np.atleast_2d(directions)
        t0, t1 = np.full(len(origins), np.inf), np.full(len(origins), -np.inf)
        for i, (o, d) in enumerate(zip(origins, directions)):
            o, d = Vector(o), Vector(d)
            hit, _, _, enter = self.bvh.ray_cast(o, d)
            if hit is None:
                continue
            out, _, _, leave = self.bvh.ray_cast(hit + self.epsilon * d, d)
            if out is not None:
                t0[i], t1[i] = enter, enter + self.epsilon + leave
        return t0, t1


def surface_points(obj) -> tuple[np.ndarray, np.ndarray]:
    """World-space vertex positions and unit vertex normals of the mesh."""
    mesh = obj.data
    n = len(mesh.vertices)
    co, normals = np.empty(n * 3), np.empty(n * 3)
    mesh.vertices.foreach_get("co", co)
    mesh.vertex_normals.foreach_get("vector", normals)
    normals = normals.reshape(n, 3)
    m = np.array(obj.matrix_world)
    points = co.reshape(n, 3) @ m[:3, :3].T + m[:3, 3]
    normals = normals @ np.linalg.inv(m[:3, :3])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    return points, normals


def scene_lamps(scene) -> tuple[list[dict], list[str]]:
    """The lamps the bake uses (type, position or direction, strength, colour, spot cone) and notes on the ones it
    leaves out."""
    lamps, notes = [], []
    for ob in scene.objects:
        if ob.type != "LIGHT" or ob.hide_render:
            continue
        light = ob.data
        if light.type not in BAKED_LAMPS:
            notes.append(f"{ob.name}: {light.type.lower()} lamps are not baked")
            continue
        m = ob.matrix_world
        lamp = {"name": ob.name, "type": light.type, "color": [float(c) for c in light.color],
                "energy": float(light.energy), "position": [float(v) for v in m.translation],
                "direction": [float(v) for v in (-(m.to_3x3() @ Vector((0.0, 0.0, 1.0)))).normalized()]}
        if light.type == "SPOT":
            lamp["spot_size"] = float(light.spot_size)
        if light.type == "AREA":
            lamp.update(_area_extent(light, m))
            if getattr(light, "spread", math.pi) < math.pi - 1e-6:
                notes.append(f"{ob.name}: the area lamp's spread is baked as 180 degrees")
        lamps.append(lamp)
    if world_lights(scene.world):
        notes.append(f"the world ({scene.world.name}) lights the object and is not baked")
    return lamps, notes


def world_lights(world) -> bool:
    """Whether ``world`` may light the scene: anything but none, a black colour, or a Background node whose unlinked
    Color or Strength is 0."""
    if world is None:
        return False
    tree = world.node_tree if bpy.app.version >= (5, 0, 0) or world.use_nodes else None  # 5.0: always nodes
    if tree is None:
        return max(world.color) > 0.0
    out = next((n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld" and n.is_active_output), None)
    if out is None or not out.inputs["Surface"].is_linked:
        return False
    node = out.inputs["Surface"].links[0].from_node
    if node.bl_idname != "ShaderNodeBackground" or any(i.is_linked for i in node.inputs):
        return True
    return node.inputs["Strength"].default_value > 0.0 and max(node.inputs["Color"].default_value[:3]) > 0.0


def _area_extent(light, m) -> dict:
    """An area lamp's half extents in world space (its object's scale included) and whether it is round."""
    size_y = light.size_y if light.shape in ("RECTANGLE", "ELLIPSE") else light.size
    axes = m.to_3x3()
    return {"half_u": [float(v) for v in axes @ Vector((0.5 * light.size, 0.0, 0.0))],
            "half_v": [float(v) for v in axes @ Vector((0.0, 0.5 * size_y, 0.0))],
            "round": light.shape in ("DISK", "ELLIPSE")}


def lamp_beams(lamp: dict, shape, cells: int) -> nm.Beams:
    """A lamp's beams into ``shape`` (unit colour; ``channel_beams`` applies it)."""
    if lamp["type"] == "SUN":
        return nm.sun_beams(shape, Sun(tuple(-v for v in lamp["direction"]), lamp["energy"]), cells)
    try:
        if lamp["type"] == "AREA":  # it emits along its local -z: the frame (half_v, half_u) has that normal
            return nm.area_beams(shape, lamp["position"], lamp["half_v"], lamp["half_u"], lamp["energy"], cells,
                                 lamp["round"])
        beams = nm.point_beams(shape, lamp["position"], lamp["energy"] / (4.0 * math.pi), cells)
    except ValueError:
        raise BakeError(f"the lamp {lamp['name']} is inside the object's bounds: move it outside") from None
    if lamp["type"] == "SPOT":
        inside = beams.directions @ np.asarray(lamp["direction"]) >= math.cos(0.5 * lamp["spot_size"])
        beams = nm.Beams(beams.entries[inside], beams.directions[inside], beams.powers[inside])
    return beams


def unshadowed(beams: nm.Beams, lamp: dict, scene, depsgraph, obj) -> nm.Beams:
    """The beams whose way back to the lamp no other object blocks."""
    keep = np.ones(len(beams), dtype=bool)
    for i, (entry, d) in enumerate(zip(beams.entries, beams.directions)):
        origin = Vector(entry) - 1e-5 * Vector(d)
        if lamp["type"] == "SUN":
            distance = 1e9
        else:
            distance = float(np.linalg.norm(np.asarray(lamp["position"]) - entry))
        hit, location, _, _, other, _ = scene.ray_cast(depsgraph, origin, -Vector(d), distance=distance)
        while hit and other is not None and other.original == obj.original:
            origin = location - 1e-5 * Vector(d)
            distance -= (Vector(entry) - location).length
            hit, location, _, _, other, _ = scene.ray_cast(depsgraph, origin, -Vector(d),
                                                           distance=max(distance, 0.0))
        keep[i] = not hit
    return nm.Beams(beams.entries[keep], beams.directions[keep], beams.powers[keep])


def channel_beams(lamps: list[dict], shape, scene, depsgraph, obj, cells: int) -> list[nm.Beams]:
    """Per RGB channel, every lamp's unshadowed beams with its colour."""
    parts = [(unshadowed(lamp_beams(lamp, shape, cells), lamp, scene, depsgraph, obj), lamp["color"])
             for lamp in lamps]
    return [nm.Beams.join(nm.Beams(b.entries, b.directions, b.powers * color[c]) for b, color in parts)
            for c in range(3)]


def medium_material(obj):
    """The object's first material that is a Lamina medium, or None."""
    for slot in getattr(obj, "material_slots", ()):
        if medium_nodes.is_medium(slot.material):
            return slot.material
    return None


def weights_version() -> str:
    """The shipped networks' content hash ("none" without them: a bake from other tables, in tests)."""
    files = [nm.weights_path(k) for k in nm.KINDS]
    if not all(f.exists() for f in files):
        return "none"
    return nb.array_digest(*(np.frombuffer(f.read_bytes(), dtype=np.uint8) for f in files))


def current_key(obj, scene, p, settings: nb.Settings) -> str:
    """The key a bake of ``obj`` made now would carry (``bake_key``)."""
    points, normals = surface_points(obj)
    lamps, _ = scene_lamps(scene)
    return nb.bake_key(p.to_dict(), nb.array_digest(points, normals), lamps, settings, weights_version())


def bake_state(obj, scene) -> tuple[str, str]:
    """("none" | "baked" | "stale" | "unknown", a line for the panel) of the object's bake."""
    mat = medium_material(obj)
    record = obj.get(PROPERTY) if obj is not None else None
    if record is None or not medium_nodes.has_bake(obj.data):
        return "none", "Not baked: the medium shows single scattering only"
    info = json.loads(record)
    try:
        p = medium_nodes.current_params(mat)
        key = current_key(obj, scene, p, nb.Settings(**info["settings"]))
    except Exception as e:  # noqa: BLE001 - a hand-edited material or missing weights: say so
        return "unknown", f"Cannot check the bake: {e}"
    if key != info["key"]:
        return "stale", "Stale: a lamp, the mesh or the medium changed since the bake"
    gathered = info.get("gathered", info["points"])
    return "baked", (f"Baked {info['points']} points ({gathered} gathered) from {info['beams']} beams in "
                     f"{info['seconds']:.1f} s")


def bake_steps(obj, scene, depsgraph, p, settings: nb.Settings, tables=None):
    """The bake as a generator of (fraction done, message); its return value (StopIteration.value) is the result
    dict for ``apply``. Raises BakeError on bad input before any work."""
    problem = mesh_problem(obj)
    if problem:
        raise BakeError(problem)
    lamps, notes = scene_lamps(scene)
    if not lamps:
        raise BakeError("no lamp lights the object: nothing to bake"
                        + (f" ({'; '.join(notes)})" if notes else ""))
    start = time.perf_counter()
    shape = MeshShape(obj)
    beams = channel_beams(lamps, shape, scene, depsgraph, obj, settings.cells)
    yield 0.0, "Reconstructing the medium's tables from the networks"
    tables = tables if tables is not None else nb.channel_tables(p)
    points, normals = surface_points(obj)
    spacing = nb.gathering_spacing(p, settings)
    chosen = nb.gathering_points(points, normals, spacing)
    gathered = np.zeros((len(chosen), 4, 3))
    for begin in range(0, len(chosen), CHUNK):
        end = min(begin + CHUNK, len(chosen))
        at = chosen[begin:end]
        gathered[begin:end] = nb.bake_points(p, tables, shape, beams, points[at], normals[at], settings)
        yield end / max(len(chosen), 1), f"Gathered {end} of {len(chosen)} points ({len(points)} vertices)"
    out = nb.spread(gathered, points[chosen], normals[chosen], points, normals, spacing)
    key = nb.bake_key(p.to_dict(), nb.array_digest(points, normals), lamps, settings, weights_version())
    return {"coefficients": out, "notes": notes,
            "record": {"key": key, "points": len(points), "gathered": len(chosen),
                       "beams": int(sum(len(b) for b in beams) // 3),
                       "seconds": round(time.perf_counter() - start, 2), "version": nb.VERSION,
                       "settings": dataclasses.asdict(settings)}}


def apply(obj, result: dict) -> None:
    """Store a finished bake: the mesh's attributes and the object's record, together."""
    medium_nodes.store(obj.data, result["coefficients"])
    obj[PROPERTY] = json.dumps(result["record"])


def run(obj, scene, depsgraph, p, settings: nb.Settings, progress=None, tables=None) -> dict:
    """The whole bake at once (headless); ``progress(fraction, message)``. Applies it and returns the result."""
    steps = bake_steps(obj, scene, depsgraph, p, settings, tables)
    while True:
        try:
            fraction, message = next(steps)
        except StopIteration as done:
            result = done.value
            break
        if progress is not None:
            progress(fraction, message)
    apply(obj, result)
    return result
