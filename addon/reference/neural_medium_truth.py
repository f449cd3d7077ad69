"""Monte Carlo ground truth of a homogeneous medium (the ``neural_medium`` model; issue 13, part 3): a numpy float64
volumetric path tracer for a sphere, a slab and a box of the medium, scattering orders 1, 2 and >= 3 separated.

What it renders. What Cycles renders for a Principled Volume (or Volume Scatter + Absorption) of the same medium
inside an object whose surface is fully transparent (an index-matched boundary: rays cross it unbent, shadow rays
too), under the scene's suns (angle 0, irradiance E on a surface facing them), world black. Conventions of
``reference/scenes.py``: an orthographic camera on +z looking down -z, pixel centres only, ``ortho_extent``,
row 0 = top; only the orthographic (``sphere``-kind) scenes, whose unit sphere is ``Sphere()``. A slab or box is
rendered under the same camera instead of the sphere.

Units. Shapes are in scene units; the coefficients are ``p.per_scene_unit()`` (sigma / p.scale). A Table 1 preset
at scale 1 has a mean free path of about 1 scene unit, so the unit sphere is 2 mean free paths across; to make it
``n`` mean free paths across, set ``scale`` = 2 sigma_t / n (sigma_t per unit length of the coefficients;
``optical_depth(p, 2.0)`` gives that diameter in mean free paths per channel). The cloud preset at scale 0.5 is
4.4 mean free paths across the unit sphere, milk at scale 0.25 about 10.

Radiance. Along a camera ray x(s) = x0 + s d (d = -z for the camera), with sigma_t, sigma_s and albedo alpha of one
channel, L = Sum_k L_k, the k-th scattering order. A scattering vertex x_k seen through vertices x_1 .. x_{k-1}
adds next-event estimation to each sun l (unit, towards the sun):

    alpha p(l . d_k) exp(-sigma_t t_sun(x_k, l)) E

where d_k is the direction of the path's flight that reached x_k (the light leaves x_k along -d_k and arrives
along -l, so the cosine between the propagation directions is l . d_k: HG with g > 0 scatters forward,
``reference.hg``) and t_sun is the distance from x_k to the boundary towards the sun (analytic: the shapes are
convex, so nothing else is crossed).

Estimator, per channel. Each RGB channel is traced on its own with its own extinction (no hero channel: the
channels' free flights differ, and identical channels are traced once and copied). A path starts where the camera
ray enters the medium. Free flights are forced collisions: the distance to the next vertex is drawn from
sigma_t exp(-sigma_t t) truncated to the segment [0, t_exit] up to the boundary, and the weight takes the
probability 1 - exp(-sigma_t t_exit) of colliding before the boundary. This has the expectation of the analog walk
in which a path that leaves the medium ends there (index-matched boundary, black world), with far less noise in
thin media; ``forced=False`` runs that analog walk instead (a cross-check). At vertex k the weight w (the path's
throughput before the vertex) gives the next-event term above times w, credited to order k; then w *= alpha and
the path continues in a direction drawn from HG about d_k (the phase function over its pdf is 1). Every path
reaches vertex 2 (a weight-0 path aside), so each gives one sample of orders 1 and 2 however thin the medium;
after vertex k >= 2 it continues with probability q = min(1, w / ROULETTE) at weight w / q (Russian roulette,
unbiased whatever q is). ``max_order`` stops the paths after that vertex (the orders above it are then missing, not
approximated). With albedo 1 only the boundary ends a walk (through the factors 1 - T, then roulette); walks
longer than MAX_VERTICES raise (an optically huge albedo-1 medium needs ``max_order``).

Cost (measured, 2 shared cores): a 32 px sphere of the cloud preset at scale 0.5, 1024 paths per pixel, 1.4 s,
relative noise (RMS standard error over the mean) 1.5 % order 1, 2.0 % order 2, 2.7 % orders >= 3; milk at scale
0.25 (g 0.7, three different channels), 1024 paths, 6.9 s, 1.8 %, 12 %, 6 %: forward scattering sends the second
vertex deep, where few paths see the sun.

Noise. ``paths`` per pixel (per ray) are split into independent seeded batches (``montecarlo.batches``); each
image's standard error is the spread of the batch means. ``total`` is summed per batch, so its noise is right too.

``slab_albedo`` traces photons from the light side instead: a collimated beam entering the top of a slab, analog
free flights, tallies of the weight leaving through the top (reflectance) and the bottom (transmittance) by the
number of scatterings (0: the direct beam) and of the weight absorbed; R + T + absorbed = 1 in expectation.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from . import hg
from . import scenes as ref_scenes
from .montecarlo import batches as mc_batches
from .montecarlo import mean_stderr

__all__ = ["Sphere", "Slab", "Box", "GROUPS", "optical_depth", "camera_rays", "radiance", "render", "slab_albedo"]

GROUPS = ("order1", "order2", "multiple")  # orders 1, 2, >= 3
COMPARE_SHAPES = ("sphere", "box", "torus", "suzanne")  # what ``compare-medium`` fills (truth: sphere and box)
ROULETTE = 0.1  # weight below which Russian roulette starts (survival w / ROULETTE, weight ROULETTE after)
MAX_VERTICES = 100_000  # a walk longer than this raises (albedo 1 in an optically huge medium: pass max_order)
CHUNK = 1 << 17  # paths per vectorised block
N_BATCHES = 8


def _rows(v):
    return np.atleast_2d(np.asarray(v, dtype=np.float64))


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


# ------------------------------------------------------------------------------------------ shapes

@dataclass(frozen=True)
class Sphere:
    """A ball of ``radius`` (scene units) about ``centre``; ``Sphere()`` is the comparison scenes' unit sphere."""
    radius: float = 1.0
    centre: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        c = tuple(float(v) for v in self.centre)
        if not (math.isfinite(self.radius) and self.radius > 0.0) or len(c) != 3 or not all(map(math.isfinite, c)):
            raise ValueError(f"Sphere needs a finite radius > 0 and a finite centre, got {self.radius}, {self.centre}")
        object.__setattr__(self, "centre", c)

    @property
    def top(self) -> float:
        return self.centre[2] + self.radius

    def interval(self, o, d):
        """Parameters (t0, t1) where the lines o + t d (unit d) enter and leave the ball; t0 = inf, t1 = -inf on a
        miss. Roots without cancellation: q = -(b + sign(b) sqrt(b^2 - c)), roots q and c / q."""
        oc = _rows(o) - np.asarray(self.centre)
        d = _rows(d)
        b = _dot(oc, d)
        c = _dot(oc, oc) - self.radius * self.radius
        disc = b * b - c
        hit = disc >= 0.0
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -(b + np.where(b >= 0.0, sq, -sq))
        r2 = np.divide(c, q, out=np.zeros_like(q), where=q != 0.0)
        return np.where(hit, np.minimum(q, r2), np.inf), np.where(hit, np.maximum(q, r2), -np.inf)

    def exit_distance(self, x, d):
        """Distance from the points x (inside) along the unit d to the boundary (>= 0)."""
        return np.maximum(self.interval(x, d)[1], 0.0)

    def normal(self, x):
        """Unit outward normals of the boundary at (or nearest to) the points x."""
        v = _rows(x) - np.asarray(self.centre)
        return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)


@dataclass(frozen=True)
class Slab:
    """The layer z0 <= z <= z1 (scene units), infinite in x and y."""
    z0: float = -0.5
    z1: float = 0.5

    def __post_init__(self):
        if not (math.isfinite(self.z0) and math.isfinite(self.z1) and self.z1 > self.z0):
            raise ValueError(f"Slab needs finite z0 < z1, got {self.z0}, {self.z1}")

    @property
    def thickness(self) -> float:
        return self.z1 - self.z0

    @property
    def top(self) -> float:
        return self.z1

    def interval(self, o, d):
        o, d = _rows(o), _rows(d)
        return _axis_interval(o[:, 2], d[:, 2], self.z0, self.z1)

    def exit_distance(self, x, d):
        return np.maximum(self.interval(x, d)[1], 0.0)

    def normal(self, x):
        """+z nearer the top face, -z nearer the bottom one."""
        z = _rows(x)[:, 2]
        up = np.abs(z - self.z1) <= np.abs(z - self.z0)
        return np.stack([np.zeros_like(z), np.zeros_like(z), np.where(up, 1.0, -1.0)], axis=1)


@dataclass(frozen=True)
class Box:
    """The axis-aligned box lo <= x <= hi (scene units)."""
    lo: tuple = (-1.0, -1.0, -1.0)
    hi: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self):
        lo, hi = tuple(float(v) for v in self.lo), tuple(float(v) for v in self.hi)
        if len(lo) != 3 or len(hi) != 3 or not all(map(math.isfinite, lo + hi)) or any(a >= b for a, b in zip(lo, hi)):
            raise ValueError(f"Box needs finite corners with lo < hi on every axis, got {self.lo}, {self.hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @property
    def top(self) -> float:
        return self.hi[2]

    def interval(self, o, d):
        o, d = _rows(o), _rows(d)
        t0 = np.full(len(o), -np.inf)
        t1 = np.full(len(o), np.inf)
        for axis in range(3):
            a0, a1 = _axis_interval(o[:, axis], d[:, axis], self.lo[axis], self.hi[axis])
            t0, t1 = np.maximum(t0, a0), np.minimum(t1, a1)
        miss = t0 > t1
        return np.where(miss, np.inf, t0), np.where(miss, -np.inf, t1)

    def exit_distance(self, x, d):
        return np.maximum(self.interval(x, d)[1], 0.0)

    def normal(self, x):
        """The outward axis of the face nearest to each point."""
        x = _rows(x)
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        gaps = np.concatenate([x - lo, hi - x], axis=1)  # (N, 6): distances to the -x, -y, -z, +x, +y, +z faces
        face = np.argmin(np.abs(gaps), axis=1)
        n = np.zeros_like(x)
        n[np.arange(len(x)), face % 3] = np.where(face < 3, -1.0, 1.0)
        return n


def _axis_interval(o, d, lo, hi):
    """(t0, t1) of the lines o + t d (one coordinate) inside [lo, hi]; parallel lines: all or nothing."""
    par = d == 0.0
    safe = np.where(par, 1.0, d)
    ta, tb = (lo - o) / safe, (hi - o) / safe
    t0, t1 = np.minimum(ta, tb), np.maximum(ta, tb)
    inside = (o >= lo) & (o <= hi)
    t0 = np.where(par, np.where(inside, -np.inf, np.inf), t0)
    t1 = np.where(par, np.where(inside, np.inf, -np.inf), t1)
    return t0, t1


# ------------------------------------------------------------------------------------------ medium

def _coefficients(p):
    """(sigma_s, sigma_t) per scene unit as (3,) arrays and the groups of identical channels {(s, t): [c, ...]}."""
    ss, sa = (np.asarray(v, dtype=np.float64) for v in p.per_scene_unit())
    st = ss + sa
    if ss.shape != (3,) or not (np.all(np.isfinite(st)) and np.all(st > 0.0) and np.all(ss >= 0.0)):
        raise ValueError(f"neural_medium truth: need sigma_s >= 0 and sigma_s + sigma_a > 0 in every channel, got "
                         f"{tuple(ss)}, {tuple(sa)}")
    groups: dict = {}
    for c in range(3):
        groups.setdefault((float(ss[c]), float(st[c])), []).append(c)
    return ss, st, groups


def optical_depth(p, length: float) -> np.ndarray:
    """Optical depth (mean free paths, per channel) of ``length`` scene units of the medium: sigma_t length / scale."""
    return np.asarray(p.sigma_t, dtype=np.float64) * float(length) / float(p.scale)


def _suns(suns):
    out = []
    for sun in suns:
        if not isinstance(sun, ref_scenes.Sun):
            sun = ref_scenes.Sun(*sun) if isinstance(sun, (tuple, list)) and len(sun) == 2 else ref_scenes.Sun(sun)
        out.append((np.asarray(sun.direction, dtype=np.float64), float(sun.irradiance)))
    return out


def _check_order(max_order):
    if max_order is not None and (int(max_order) != max_order or max_order < 1):
        raise ValueError(f"max_order must be None or an integer >= 1, got {max_order!r}")
    return None if max_order is None else int(max_order)


# ------------------------------------------------------------------------------------------ the path tracer

def _trace_channel(shape, x0, d0, t_exit0, sigma_s, sigma_t, g, suns, size, rng, max_order, forced):
    """(3, n) radiance per ray of one channel and order group, averaged over ``size`` paths per ray."""
    n = len(x0)
    alpha = sigma_s / sigma_t
    out = np.zeros((3, n))
    total = n * size
    for start in range(0, total, CHUNK):
        idx = np.arange(start, min(total, start + CHUNK)) // size  # ray of each path
        x, d, t_exit = x0[idx], d0[idx], t_exit0[idx]
        w = np.ones(len(idx))
        k = 0
        while len(idx):
            k += 1
            if k > MAX_VERTICES:
                raise RuntimeError(f"neural_medium truth: walks longer than {MAX_VERTICES} vertices (albedo "
                                   f"{alpha:.6g} in an optically huge medium); pass max_order")
            u = rng.random(len(idx))
            if forced:
                p_hit = -np.expm1(-sigma_t * t_exit)  # collides before the boundary
                t = np.minimum(-np.log1p(-u * p_hit) / sigma_t, t_exit)
                w = w * p_hit
            else:
                t = -np.log1p(-u) / sigma_t
                inside = t < t_exit  # the others leave the medium: the world is black
                idx, x, d, w, t = idx[inside], x[inside], d[inside], w[inside], t[inside]
                if not len(idx):
                    break
            x = x + t[:, None] * d
            group = min(k, 3) - 1
            if alpha > 0.0:
                for l, irradiance in suns:
                    lb = np.broadcast_to(l, x.shape)
                    t_sun = shape.exit_distance(x, lb)
                    c = w * alpha * hg.eval(g, d @ l) * np.exp(-sigma_t * t_sun) * irradiance
                    out[group] += np.bincount(idx, c, minlength=n)
            if max_order is not None and k >= max_order:
                break
            w = w * alpha
            # orders 1 and 2 at full weight (one sample of each per path, thin media too); roulette from then on
            q = np.minimum(1.0, w / ROULETTE) if k >= 2 else np.ones(len(w))
            live = (rng.random(len(idx)) < q) & (w > 0.0)
            idx, x, d = idx[live], x[live], d[live]
            w = w[live] / q[live]
            if not len(idx):
                break
            d = hg.sample(g, d, rng.random(len(idx)), rng.random(len(idx)))
            t_exit = shape.exit_distance(x, d)
    return out / size


def radiance(p, shape, origins, directions, suns, paths: int, seed: int = 0, max_order: int | None = None,
             batches: int = N_BATCHES, forced: bool = True) -> dict:
    """Radiance arriving at ``origins`` (N, 3) from the medium along the rays ``-directions`` (unit, the directions
    the rays travel; the part of each ray in front of its origin). Returns ``order1``, ``order2``, ``multiple``,
    ``total`` (N, 3), ``noise`` {name: (N, 3) standard error}, ``hit`` (N,) bool and ``seconds``."""
    start = time.perf_counter()
    max_order = _check_order(max_order)
    if paths < 1:
        raise ValueError("paths must be >= 1")
    _, _, groups = _coefficients(p)
    suns = _suns(suns)
    o = _rows(origins)
    d = _rows(directions)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    d = np.broadcast_to(d, o.shape).copy()
    t0, t1 = shape.interval(o, d)
    t0 = np.maximum(t0, 0.0)
    hit = t1 > t0
    rows = np.flatnonzero(hit)
    x0 = o[rows] + t0[rows, None] * d[rows]
    t_exit = t1[rows] - t0[rows]
    per_batch = []
    for size, rng in mc_batches(paths, batches, seed):
        acc = np.zeros((3, len(o), 3))
        for (s, t), channels in groups.items():
            part = _trace_channel(shape, x0, d[rows], t_exit, s, t, p.g, suns, size, rng, max_order, forced)
            for c in channels:
                acc[:, rows, c] = part
        per_batch.append(acc)
    per_batch = np.asarray(per_batch)  # (batches, 3 groups, N, 3)
    mean, se = mean_stderr(per_batch)
    tot_mean, tot_se = mean_stderr(per_batch.sum(axis=1))
    out = {name: mean[i] for i, name in enumerate(GROUPS)}
    out["total"] = tot_mean
    out["noise"] = {**{name: se[i] for i, name in enumerate(GROUPS)}, "total": tot_se}
    out["hit"] = hit
    out["seconds"] = time.perf_counter() - start
    return out


def camera_rays(scene: ref_scenes.Scene, shape):
    """Origins (H W, 3) and directions (H W, 3) of the orthographic camera's rays through the pixel centres
    (row 0 = top = +y, column 0 = left = -x), starting above the shape."""
    if scene.camera != "orthographic":
        raise ValueError(f"neural_medium truth: scene {scene.name!r} has a {scene.camera} camera; only the "
                         f"orthographic (sphere-kind) scenes are rendered")
    w, h = scene.resolution
    hx, hy = ref_scenes.ortho_extent(scene)
    x = (2.0 * (np.arange(w) + 0.5) / w - 1.0) * hx
    y = (1.0 - 2.0 * (np.arange(h) + 0.5) / h) * hy
    X, Y = np.meshgrid(x, y)
    origins = np.stack([X.ravel(), Y.ravel(), np.full(w * h, shape.top + 1.0)], axis=1)
    return origins, np.tile([0.0, 0.0, -1.0], (w * h, 1))


def render(p, shape, scene: ref_scenes.Scene, paths: int, seed: int = 0, max_order: int | None = None,
           batches: int = N_BATCHES, forced: bool = True) -> dict:
    """H x W x 3 images of the medium ``p`` (a neural_medium Params) filling ``shape`` under the scene's suns
    (module docstring): ``order1``, ``order2``, ``multiple`` (orders >= 3), ``total``, ``noise`` {name: standard
    error image}, ``mask`` (pixels whose ray meets the shape), ``seconds``; ``paths`` per pixel."""
    if scene.environment != 0.0:
        raise ValueError("neural_medium truth: only a black world (environment 0) is rendered")
    origins, directions = camera_rays(scene, shape)
    r = radiance(p, shape, origins, directions, scene.suns, paths, seed, max_order, batches, forced)
    w, h = scene.resolution
    image = {name: r[name].reshape(h, w, 3) for name in GROUPS + ("total",)}
    image["noise"] = {name: v.reshape(h, w, 3) for name, v in r["noise"].items()}
    image["mask"] = r["hit"].reshape(h, w)
    image["seconds"] = r["seconds"]
    return image


# ------------------------------------------------------------------------------------------ slab albedo

SLAB_ORDERS = ("direct", "order1", "order2", "multiple")  # scatterings 0, 1, 2, >= 3


def _slab_channel(thickness, mu, sigma_s, sigma_t, g, size, rng, max_order):
    """(R (4,), T (4,), absorbed, left) per photon of one channel: weights leaving through the top and the bottom by
    number of scatterings, absorbed, and still inside after ``max_order`` scatterings."""
    alpha = sigma_s / sigma_t
    R, T = np.zeros(4), np.zeros(4)
    absorbed = left = 0.0
    for start in range(0, size, CHUNK):
        n = min(CHUNK, size - start)
        z = np.full(n, thickness)
        d = np.tile([math.sqrt(max(0.0, 1.0 - mu * mu)), 0.0, -mu], (n, 1))
        w = np.ones(n)
        k = 0  # scatterings so far
        while len(z):
            if k > MAX_VERTICES:
                raise RuntimeError(f"slab_albedo: walks longer than {MAX_VERTICES} scatterings; pass max_order")
            zn = z + (-np.log1p(-rng.random(len(z))) / sigma_t) * d[:, 2]
            up, down = zn >= thickness, zn <= 0.0
            group = min(k, 3)
            R[group] += w[up].sum()
            T[group] += w[down].sum()
            stay = ~(up | down)
            z, d, w = zn[stay], d[stay], w[stay]
            if not len(z):
                break
            k += 1  # a scattering event at z
            absorbed += (w * (1.0 - alpha)).sum()
            w = w * alpha
            if max_order is not None and k >= max_order:
                left += w.sum()
                break
            q = np.minimum(1.0, w / ROULETTE)
            live = (rng.random(len(z)) < q) & (w > 0.0)
            z, d = z[live], d[live]
            w = w[live] / q[live]
            if len(z):
                d = hg.sample(g, d, rng.random(len(z)), rng.random(len(z)))
    return R / size, T / size, absorbed / size, left / size


def slab_albedo(p, thickness: float, cos_in: float, paths: int, seed: int = 0, max_order: int | None = None,
                batches: int = N_BATCHES) -> dict:
    """Total reflectance and transmittance of a slab ``thickness`` scene units thick for a collimated beam entering
    its top at cosine ``cos_in`` to the normal, by photon tracing from the light side (``paths`` photons per
    channel). Returns ``reflectance`` and ``transmittance`` {order: (3,)} with orders ``direct`` (unscattered;
    transmittance only), ``order1``, ``order2``, ``multiple`` and ``total``; ``absorbed`` (3,), ``left`` (3,) (weight
    still inside after ``max_order`` scatterings; 0 without it); ``balance`` (3,) = R + T + absorbed + left, which is 1
    in expectation (exactly per photon without roulette); ``noise`` with the same structure (standard errors, the
    balance's from its own batch sums); ``seconds``."""
    start = time.perf_counter()
    max_order = _check_order(max_order)
    if not (math.isfinite(thickness) and thickness > 0.0) or not (0.0 < cos_in <= 1.0):
        raise ValueError(f"slab_albedo needs thickness > 0 and 0 < cos_in <= 1, got {thickness}, {cos_in}")
    _, _, groups = _coefficients(p)
    per_batch = []  # (batches, 10, 3): R[4], T[4], absorbed, left
    for size, rng in mc_batches(paths, batches, seed):
        acc = np.zeros((10, 3))
        for (s, t), channels in groups.items():
            R, T, a, left = _slab_channel(float(thickness), float(cos_in), s, t, p.g, size, rng, max_order)
            for c in channels:
                acc[:, c] = np.concatenate([R, T, [a, left]])
        per_batch.append(acc)
    per_batch = np.asarray(per_batch)
    mean, se = mean_stderr(per_batch)
    tot_mean, tot_se = mean_stderr(np.stack([per_batch[:, 0:4].sum(1), per_batch[:, 4:8].sum(1),
                                             per_batch.sum(1)], axis=1))

    def table(values, total):
        out = {name: values[i] for i, name in enumerate(SLAB_ORDERS)}
        out["total"] = total
        return out

    return {
        "reflectance": table(mean[0:4], tot_mean[0]), "transmittance": table(mean[4:8], tot_mean[1]),
        "absorbed": mean[8], "left": mean[9], "balance": tot_mean[2],
        "noise": {"reflectance": table(se[0:4], tot_se[0]), "transmittance": table(se[4:8], tot_se[1]),
                  "absorbed": se[8], "left": se[9], "balance": tot_se[2]},
        "seconds": time.perf_counter() - start,
    }
