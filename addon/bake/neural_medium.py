"""Baking a neural medium's double and multiple scattering onto an object's surface (issue 13), bpy-free.

What is baked. Cycles renders the medium's single scattering itself (a Volume Scatter + Absorption at
``volume_bounces = 0``); what it leaves out is the light of orders >= 2. At a surface point x with outward normal
n, that light leaves the object towards w (w . n > 0) with radiance

    L(x, w) = Integral over the first segment of the ray entering at x against w of exp(-s / l) Phi(x - s w, w) ds

where Phi is the medium's in-scattered radiance of orders >= 2 (``reference.neural_medium.gather``: for the
channel's albedo and the medium's g, double scattering's table by quadrature and multiple scattering's from the
network, from every beam of every lamp). The bake evaluates L in
``DIRECTIONS`` directions of x's outward hemisphere and stores the least-squares linear fit (L1 spherical
harmonics, per channel)

    L(x, w) ~ c0 + cx wx + cy wy + cz wz      (world-space w, the direction towards the viewer)

which the material evaluates as max(c0 + c . w, 0) on front faces. Named approximations (measured in
docs/accuracy.md): the infinite-medium tables (they count light that would have left the object, Sec. 3.2), the
index-matched boundary (no refraction, no Fresnel: what Cycles' volume renders too), the linear fit in w, and
the first segment only of a ray that leaves and re-enters a non-convex object. The boundary's image sources
(``Settings.boundary``, on by default) take away most of what the infinite-medium tables add.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from functools import lru_cache

import numpy as np

from ..reference import neural_medium as nm

VERSION = 3  # of what a bake stores; bump when its meaning changes (older bakes read as stale). 2: exit images,
# 3: double scattering by quadrature
DIRECTIONS = 7  # the normal and six directions at 60 degrees around it
COEFFICIENTS = ("c0", "cx", "cy", "cz")


@dataclasses.dataclass(frozen=True)
class Settings:
    """Bake resolution: beams per lamp side (``cells`` x ``cells`` beams), quadrature points along each ray;
    ``boundary``: multiple scattering with the boundary's image sources (``reference.neural_medium.gather``'s
    ``images``), or the paper's infinite medium; ``spacing``: how close (in the medium's smallest mean free path)
    surface points may be and share one gather (``gathering_points``, ``spread``; 0: every point gathers);
    ``grid_angle``, ``grid_cube``: the paper's grid of representative beams (``reference.neural_medium.beam_grid``,
    cubes of ``grid_cube`` mean free paths taken whole where seen under less than ``grid_angle`` radians; 0: every
    beam); ``segments``: the paper's accumulated camera segments (``reference.neural_medium.segment_table``: one
    lookup per ray instead of ``steps``, after a few seconds building them per channel)."""

    cells: int = 16
    steps: int = 12
    boundary: bool = True
    spacing: float = 0.5
    grid_angle: float = 0.0
    grid_cube: float = 1.0
    segments: bool = False

    def __post_init__(self):
        if not (1 <= self.cells <= 256 and 1 <= self.steps <= 256 and 0.0 <= self.spacing <= 16.0
                and 0.0 <= self.grid_angle <= math.pi and 0.01 <= self.grid_cube <= 64.0):
            raise ValueError(f"bake settings out of range: cells {self.cells} (1-256), steps {self.steps} (1-256), "
                             f"spacing {self.spacing} (0-16 mean free paths), grid angle {self.grid_angle} (0-pi), "
                             f"grid cube {self.grid_cube} (0.01-64 mean free paths)")

    def key(self) -> tuple:
        """What of the settings a bake depends on: the grid's and the segments' only where they are on (a bake
        without them keeps the key it had before they existed)."""
        key = (self.cells, self.steps, self.boundary, self.spacing)
        if self.grid_angle > 0.0:
            key += (self.grid_angle, self.grid_cube)
        return key + ("segments",) if self.segments else key


def reconstruction_grid(net) -> tuple:
    """(rho_edges, z_edges, theta, phi) the network's tables are reconstructed on: its training grid, from the
    weights' manifest."""
    g = net.manifest["grid"]
    return tuple(np.asarray(g[k], dtype=np.float64) for k in ("rho_edges", "z_edges", "theta", "phi"))


def channel_tables(p, folder=nm.WEIGHTS) -> list[dict]:
    """Per RGB channel, {kind: Table} for the channel's albedo and the medium's g: double scattering by quadrature
    (``nm.double_table``, exact up to the grid: its shape depends on g alone, albedo^2 scales it), multiple scattering
    reconstructed from the shipped network (Sec. 3.7); channels with the same albedo share their tables, and the
    last few materials are kept (a re-bake does not reconstruct them again)."""
    return [_material_tables(float(albedo), float(p.g), str(folder)) for albedo in p.albedo]


@lru_cache(maxsize=6)
def _material_tables(albedo: float, g: float, folder: str) -> dict:
    net = nm.network("multiple", folder)
    grid = reconstruction_grid(net)
    a = min(max(albedo, 0.0), 1.0)
    return {"double": nm.Table(a * a * _double_shape(g, folder), *grid),
            "multiple": nm.Table(nm.table(net, albedo, g, *grid), *grid)}


@lru_cache(maxsize=2)
def _double_shape(g: float, folder: str) -> np.ndarray:
    """``nm.double_table`` at albedo 1 on the multiple network's grid."""
    return nm.double_table(1.0, g, *reconstruction_grid(nm.network("multiple", folder)))


def hemisphere_directions(normals: np.ndarray) -> np.ndarray:
    """(N, DIRECTIONS, 3) unit directions about each unit normal: the normal and six at 60 degrees around it."""
    n = np.asarray(normals, dtype=np.float64)
    helper = np.where(np.abs(n[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    a = np.cross(n, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(n, a)
    phi = 2.0 * math.pi * np.arange(DIRECTIONS - 1) / (DIRECTIONS - 1)
    ring = (0.5 * n[:, None, :] + math.sqrt(0.75) * (np.cos(phi)[None, :, None] * a[:, None, :]
                                                     + np.sin(phi)[None, :, None] * b[:, None, :]))
    return np.concatenate([n[:, None, :], ring], axis=1)


def fit_linear(directions: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(N, 4) least-squares (c0, cx, cy, cz) of values (N, K) ~ c0 + c . w over the directions (N, K, 3)."""
    design = np.concatenate([np.ones(directions.shape[:2] + (1,)), directions], axis=2)  # (N, K, 4)
    return np.linalg.solve(np.einsum("nki,nkj->nij", design, design), np.einsum("nki,nk->ni", design, values))


def evaluate(coefficients: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """What the material renders: max(c0 + c . w, 0) per channel; coefficients (N, 4, 3), directions (N, 3)."""
    c = np.asarray(coefficients, dtype=np.float64)
    return np.maximum(c[:, 0] + np.einsum("nk,nkc->nc", directions, c[:, 1:]), 0.0)


def bake_points(p, tables: list[dict], shape, beams: list, points, normals, settings: Settings = Settings(),
                progress=None, epsilon: float = 1e-4) -> np.ndarray:
    """(N, 4, 3) coefficients (c0, cx, cy, cz per RGB channel) of the radiance of orders >= 2 leaving the surface
    points (world space, unit outward normals) of the medium ``p`` filling ``shape`` (``interval(origins,
    directions)`` and ``bounding_sphere`` or a truth shape), lit by ``beams`` (per channel: each lamp's beams with its
    colour). ``progress(fraction)`` is called as
    the work advances; it may raise to cancel."""
    points, normals = np.asarray(points, dtype=np.float64), np.asarray(normals, dtype=np.float64)
    directions = hemisphere_directions(normals)
    scale = 1.0 + float(np.max(np.abs(points))) if len(points) else 1.0
    origins = (points[:, None, :] + epsilon * scale * directions).reshape(-1, 3)
    inward = -directions.reshape(-1, 3)
    out = np.zeros((len(points), 4, 3))
    for c in range(3):
        same = next((k for k in range(c) if _same_channel(p, beams, k, c)), None)
        if same is not None:  # a grey medium under white lamps: computed once
            out[:, :, c] = out[:, :, same]
            continue

        def report(done, total, c=c):
            if progress is not None:
                progress((c + done / max(total, 1)) / 3.0)

        images = nm.boundary(p.albedo[c], p.g) if settings.boundary else None
        grid = (nm.beam_grid(beams[c], settings.grid_cube * p.mean_free_path[c], settings.grid_angle)
                if settings.grid_angle > 0.0 and len(beams[c]) else None)
        channel = ({kind: nm.segment_table(table) for kind, table in tables[c].items()} if settings.segments
                   else tables[c])
        radiance = nm.gather(channel, p.mean_free_path[c], shape, beams[c], origins, inward, steps=settings.steps,
                             progress=report, images=images, grid=grid)
        values = sum(radiance[kind] for kind in nm.KINDS).reshape(len(points), DIRECTIONS)
        out[:, :, c] = fit_linear(directions, values)
    return out


def gathering_spacing(p, settings: Settings) -> float:
    """``settings.spacing`` in scene units: that many of the medium's smallest mean free paths."""
    return settings.spacing * min(p.mean_free_path)


def gathering_points(points, normals, spacing: float) -> np.ndarray:
    """Indices of the points the bake gathers at when neighbours closer than ``spacing`` (scene units) may share
    their light: one point per cell of a grid of that spacing and per side it faces (the axis and sign of the
    largest component of its normal, so the two sides of a thin part never share), the one nearest the cell's
    points' centroid. ``spacing`` <= 0: every point."""
    points, normals = np.asarray(points, dtype=np.float64), np.asarray(normals, dtype=np.float64)
    if spacing <= 0.0 or len(points) == 0:
        return np.arange(len(points))
    axis = np.argmax(np.abs(normals), axis=1)
    side = 2 * axis + (normals[np.arange(len(normals)), axis] > 0.0)
    keys = np.concatenate([np.floor(points / spacing).astype(np.int64), side[:, None]], axis=1)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.ravel()
    counts = np.bincount(group)
    centroids = np.stack([np.bincount(group, points[:, k]) for k in range(3)], axis=1) / counts[:, None]
    distance = np.linalg.norm(points - centroids[group], axis=1)
    order = np.lexsort((distance, group))  # by group, nearest first
    first = np.ones(len(order), dtype=bool)
    first[1:] = group[order][1:] != group[order][:-1]
    return np.sort(order[first])


def spread(coefficients, sources, source_normals, points, normals, spacing: float, neighbours: int = 4,
           chunk: int = 2048) -> np.ndarray:
    """Coefficients at every point from those gathered at ``sources``: the inverse-square-distance blend (softened
    by a tenth of ``spacing``) of the ``neighbours`` nearest sources that face the same way (normals within 60
    degrees; the nearest source if none does). A source point gets its own value back."""
    sources, source_normals = np.asarray(sources, dtype=np.float64), np.asarray(source_normals, dtype=np.float64)
    points, normals = np.asarray(points, dtype=np.float64), np.asarray(normals, dtype=np.float64)
    k = min(neighbours, len(sources))
    out = np.zeros((len(points),) + coefficients.shape[1:])
    for start in range(0, len(points), chunk):
        x, n = points[start:start + chunk], normals[start:start + chunk]
        d2 = np.einsum("ik,ik->i", x, x)[:, None] - 2.0 * x @ sources.T + np.einsum("jk,jk->j", sources, sources)
        d2 = np.maximum(d2, 0.0)
        near = np.argpartition(d2, k - 1, axis=1)[:, :k] if k < len(sources) else np.tile(np.arange(k), (len(x), 1))
        d2 = np.sum((x[:, None, :] - sources[near]) ** 2, axis=2)  # exact (0 for a source itself)
        facing = np.einsum("ik,ijk->ij", n, source_normals[near]) > 0.5
        nearest = d2 == d2.min(axis=1, keepdims=True)
        use = np.where(facing.any(axis=1, keepdims=True), facing, nearest)
        exact = d2 == 0.0
        with np.errstate(divide="ignore"):
            w = np.where(exact.any(axis=1, keepdims=True), exact, use / (d2 + (0.1 * spacing) ** 2))
        w /= w.sum(axis=1, keepdims=True)
        out[start:start + chunk] = np.einsum("ij,ij...->i...", w, coefficients[near])
    return out


def _same_channel(p, beams: list, a: int, b: int) -> bool:
    return (p.albedo[a] == p.albedo[b] and p.mean_free_path[a] == p.mean_free_path[b]
            and np.array_equal(beams[a].powers, beams[b].powers))


def bake_key(params: dict, mesh_digest: str, lamps: list, settings: Settings, weights: str) -> str:
    """What a bake depends on, hashed: the medium, the mesh in world space, the lamps, the settings and the
    networks' version, numbers to 5 significant digits (a value read back from a float32 socket is the same value).
    A changed key means the stored bake is stale."""
    key = json.dumps({"version": VERSION, "params": _rounded(params), "mesh": mesh_digest, "lamps": _rounded(lamps),
                      "settings": settings.key(), "weights": weights},
                     sort_keys=True)
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def _rounded(value):
    if isinstance(value, float):
        return float(f"{value:.5g}")
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_rounded(v) for v in value]
    return value


def array_digest(*arrays) -> str:
    """A short content hash of float arrays (rounded to float32, so a re-read mesh hashes the same)."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(np.asarray(a, dtype=np.float32)).tobytes())
    return h.hexdigest()[:16]
