"""Comparison scenes and their numpy reference renderer (float64, no bpy).

A ``Scene`` describes something that Cycles renders (``addon.operators.cycles_render``) and that this
module renders exactly, with direct lighting only and no interreflection. Both sides use the same
pixel -> (surface point, normal, tangent, wo) mapping, so a BSDF that is implemented twice (a bpy
material and a numpy ``bsdf_eval``) can be compared pixel by pixel.

Conventions (all of them checked against Cycles by ``tests/blender/test_cycles_harness.py``):

* Images are H x W x 3 float64 linear radiance, row 0 = TOP of the picture, column 0 = left.
* World frame: z up. Directions point AWAY from the surface (``wi`` toward the light, ``wo`` toward
  the camera), as in the reference API.
* ``bsdf_eval(wi, wo) -> (N, 3)`` takes (N, 3) unit vectors in the local shading frame (x = tangent,
  y = bitangent = n x t, z = shading normal) and returns f without the cosine, reflection and
  transmission. A pixel's value is ``f(wi, wo) |cos theta_i| E`` summed over the suns, plus, for a
  uniform environment of radiance ``L``, ``L * integral f |cos theta_i| d omega_i`` (the directional
  albedo).

Scene kinds
-----------
``sphere``  A unit sphere at the origin seen by an orthographic camera on +z looking down -z
            (camera up = +y, so column -> +x, row -> -y; the view spans ``ortho_scale`` = 2 along
            the larger image side). Pixel centre (x, y) with x^2 + y^2 < 1 hits (x, y, sqrt(1-x^2-y^2));
            n = that point (analytic normal), wo = +z. Tangent: t = normalize(z x n) = normalize(-y, x, 0),
            the direction of increasing longitude around the sphere's pole axis (+z). This is what Cycles
            uses by default for anisotropic closures (an unconnected Tangent socket gets the Geometry
            node's Tangent = the "radial Z" tangent built from Generated coordinates, which on a sphere
            centred in its bounding box is exactly this), and it is also dPdu of the UV map the Cycles
            side gives the mesh (u = longitude / 2 pi). At the pole pixel (x = y = 0) t = +x.
            OSL shaders see this tangent only through an input linked from the Geometry node's Tangent
            (or a Tangent node, Radial Z); ``normalize(dPdu)`` in OSL is the per-triangle barycentric
            derivative on meshes and does not match (tests/blender/test_cycles_harness.py).
            The sphere is closed, so light from below the surface is blocked by the sphere itself:
            the reference drops wi with wi.n < 0 (only the reflection lobe shows).
            Cycles renders a smooth-shaded UV sphere mesh (``sphere_segments`` x ``sphere_rings``);
            the mask keeps only pixels whose whole square lies inside the mesh's silhouette (the
            inscribed polygon of the equator), so silhouette pixels never enter the metrics.
``plane``, ``backlit``, ``furnace``
            A flat, one-sided plane z = 0 (normal +z) seen by a panoramic (equirectangular) camera at
            height 1 above its centre: every pixel sees the plane from a different direction, so the
            image is a (theta_o, phi_o) chart of the lobe for a fixed light.
            Row r <-> theta_o = (r + 0.5) / H * theta_max (theta_max = 90 deg by default: top row looks
            straight down, bottom row grazes), column c <-> phi_o = (c + 0.5) / W * 360 deg, measured from
            +x toward +y; wo = (sin t cos p, sin t sin p, cos t), the camera ray is -wo. Local frame = world
            frame (t = +x, b = +y, n = +z; the Cycles side pins its Generated texture space far off
            along +y so that the default tangent is +x: textures driven by Generated coordinates are
            therefore meaningless on this plane). The plane is large enough that every pixel hits it,
            and nothing occludes either hemisphere.
            ``plane``: a sun above (reflection); ``backlit``: a sun below the plane (transmission lobe;
            camera above); ``furnace``: no sun, a uniform white environment (radiance 1), so each pixel
            is the directional albedo a(wo) = integral over the whole sphere of f |cos theta_i| (reflection
            plus transmission). Cycles renders it with world colour 1 / strength 1 and max_bounces 0: the
            camera ray hits the plane and the world is sampled as a light (MIS with the BSDF).
``views``   Not rendered by Cycles: the points of an object that a camera sees (``frames``: per point the
            world normal, tangent, bitangent and wo), one pixel each in a 1-row image, lit as the panoramas
            are (nothing occludes either hemisphere). ``view_scenes`` makes a key-lit and a furnace-lit pair
            of them (Fit to budget's measure on the active camera's view of the object).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

__all__ = [
    "Sun", "Scene", "KINDS", "NOTES", "sun_direction", "sphere_scene", "plane_scene", "backlit_scene",
    "furnace_scene", "default_scenes", "pixel_geometry", "scene_mask", "reference_image",
    "directional_albedo", "lobe_view", "uv_sphere_mesh", "plane_half_size", "to_local", "VIEWS", "view_scenes",
]

KINDS = ("sphere", "plane", "backlit", "furnace")  # the kinds Cycles renders
VIEWS = "views"  # the kind of ``view_scenes``: the numpy reference and predictions only
# What each kind of scene shows, in one sentence for people reading a comparison (the demo's report).
NOTES = {
    "sphere": "A sphere under one sun 45° up, seen from straight above: the material as it looks on an object, "
              "every angle between light, view and surface at once.",
    "plane": "A flat sample under a sun 45° up, photographed in every direction at once (rows: the view from "
             "overhead at the top to grazing at the bottom, columns: the view's azimuth): the reflection lobe.",
    "backlit": "The same panorama with the sun 45° below the sample: the light the material lets through "
               "(its transmission lobe).",
    "furnace": "The same panorama in a uniform white sky, no sun: each pixel is the share of light the material "
               "reflects or lets through towards that view (its directional albedo: 1 loses nothing).",
}
PANORAMA_KINDS = ("plane", "backlit", "furnace")

BsdfEval = Callable[[np.ndarray, np.ndarray], np.ndarray]


def sun_direction(elevation_deg: float, azimuth_deg: float) -> tuple[float, float, float]:
    """Unit vector toward a sun at ``elevation`` above the xy plane (negative: below) and ``azimuth`` from +x toward +y."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))


@dataclass(frozen=True)
class Sun:
    """A sun lamp with angle 0: ``direction`` (unit, world) points from the scene TOWARD the light;
    ``irradiance`` E is the irradiance on a surface facing it (= Blender's sun Strength)."""

    direction: tuple[float, float, float]
    irradiance: float = 1.0

    def __post_init__(self):
        d = np.asarray(self.direction, dtype=np.float64)
        n = float(np.linalg.norm(d))
        if d.shape != (3,) or not np.isfinite(n) or n == 0.0:
            raise ValueError(f"Sun direction must be a non-zero 3-vector, got {self.direction!r}")
        if not math.isfinite(self.irradiance) or self.irradiance < 0:
            raise ValueError(f"Sun irradiance must be finite and >= 0, got {self.irradiance!r}")
        object.__setattr__(self, "direction", tuple(float(v) for v in d / n))


@dataclass(frozen=True)
class Scene:
    """A comparison scene. ``resolution`` is (width, height) in pixels.

    ``camera`` is derived from ``kind``: "orthographic" for ``sphere``, "panorama" for the plane kinds.
    ``environment`` is the radiance of a uniform world (0: black; ``furnace``: 1).
    ``theta_max_deg`` is the theta_o range of the panorama rows; ``ortho_scale`` the orthographic view
    width (along the larger image side); ``sphere_segments`` / ``sphere_rings`` the Cycles mesh.
    """

    name: str
    kind: str
    resolution: tuple[int, int] = (64, 64)
    suns: tuple[Sun, ...] = ()
    environment: float = 0.0
    ortho_scale: float = 2.0
    theta_max_deg: float = 90.0
    sphere_segments: int = 256
    sphere_rings: int = 128
    frames: tuple[tuple[float, ...], ...] = ()  # ``views``: per pixel (n, t, b, wo), 12 floats, world

    def __post_init__(self):
        if self.kind not in KINDS + (VIEWS,):
            raise ValueError(f"Scene {self.name!r}: unknown kind {self.kind!r}; expected one of {', '.join(KINDS)}")
        if (self.kind == VIEWS) != bool(self.frames) or (self.frames and self.resolution != (len(self.frames), 1)):
            raise ValueError(f"Scene {self.name!r}: frames go with the kind {VIEWS!r}, one per pixel of one row")
        w, h = (int(v) for v in self.resolution)
        if w < 1 or h < 1 or w > 8192 or h > 8192:
            raise ValueError(f"Scene {self.name!r}: resolution {self.resolution!r} out of range")
        object.__setattr__(self, "resolution", (w, h))
        object.__setattr__(self, "suns", tuple(self.suns))
        if not (0.0 < self.theta_max_deg <= 90.0):
            raise ValueError(f"Scene {self.name!r}: theta_max_deg must be in (0, 90]")
        if self.sphere_segments % 4 or self.sphere_segments < 8 or self.sphere_rings % 2 or self.sphere_rings < 4:
            raise ValueError("sphere_segments must be a multiple of 4 (>= 8) and sphere_rings even (>= 4)")
        if not math.isfinite(self.environment) or self.environment < 0:
            raise ValueError(f"Scene {self.name!r}: environment must be finite and >= 0")

    @property
    def camera(self) -> str:
        return "orthographic" if self.kind == "sphere" else "panorama"

    @property
    def width(self) -> int:
        return self.resolution[0]

    @property
    def height(self) -> int:
        return self.resolution[1]

    def with_resolution(self, width: int, height: int | None = None) -> "Scene":
        return replace(self, resolution=(width, width if height is None else height))


def sphere_scene(elevation_deg=45.0, azimuth_deg=30.0, irradiance=1.0, resolution=64, name="sphere", **kw) -> Scene:
    res = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
    return Scene(name, "sphere", res, (Sun(sun_direction(elevation_deg, azimuth_deg), irradiance),), **kw)


def plane_scene(elevation_deg=45.0, azimuth_deg=0.0, irradiance=1.0, resolution=(64, 32), name="plane", **kw) -> Scene:
    """Panorama over a plane lit from above. Default sun azimuth 0: the mirror direction is at
    phi_o = 180 deg, the middle column."""
    res = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
    return Scene(name, "plane", res, (Sun(sun_direction(elevation_deg, azimuth_deg), irradiance),), **kw)


def backlit_scene(elevation_deg=-45.0, azimuth_deg=0.0, irradiance=1.0, resolution=(64, 32), name="backlit", **kw) -> Scene:
    """Panorama over a plane lit from BELOW (elevation < 0): shows the transmission lobe. Default sun
    azimuth 0: the straight-through direction -wi is at phi_o = 180 deg, the middle column."""
    if elevation_deg >= 0:
        raise ValueError("backlit_scene: the sun must be below the plane (elevation < 0)")
    res = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
    return Scene(name, "backlit", res, (Sun(sun_direction(elevation_deg, azimuth_deg), irradiance),), **kw)


def furnace_scene(resolution=(64, 32), environment=1.0, name="furnace", **kw) -> Scene:
    res = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
    return Scene(name, "furnace", res, (), environment=environment, **kw)


def default_scenes(resolution=64) -> list[Scene]:
    """The standard set: sphere (sun 45 deg up, azimuth 30), plane, backlit, furnace (panoramas W x W/2)."""
    pano = (resolution, max(1, resolution // 2))
    return [sphere_scene(resolution=resolution), plane_scene(resolution=pano),
            backlit_scene(resolution=pano), furnace_scene(resolution=pano)]


# ------------------------------------------------------------------------------------------ geometry

# The scenes on which every mapping's error is measured (``make bench``, the mapping choice, ``compare``).
ACCURACY_SCENES = ("sphere", "plane", "backlit", "furnace")


def view_scenes(frames, key_light) -> list[Scene]:
    """The ``views`` scenes of the points ``frames`` (N x 12: world n, t, b, wo each) that a camera sees: under one
    sun from ``key_light`` (a world direction), and in a uniform white environment (their directional albedo)."""
    frames = tuple(tuple(float(v) for v in f) for f in np.asarray(frames, dtype=np.float64).reshape(-1, 12))
    size = (len(frames), 1)
    return [Scene("camera, key light", VIEWS, size, suns=(Sun(tuple(key_light)),), frames=frames),
            Scene("camera, furnace", VIEWS, size, environment=1.0, frames=frames)]


def comparison_scenes(resolution: int, furnace_width: int | None = None) -> list[Scene]:
    """The comparison scenes; the furnace ``furnace_width`` wide (default half the resolution: its reference costs
    an albedo per pixel)."""
    scenes = [s for s in default_scenes(resolution) if s.name in ACCURACY_SCENES]
    width = furnace_width or resolution // 2
    return [s.with_resolution(width, width // 2) if s.kind == "furnace" else s for s in scenes]


def _pixel_centres(n: int) -> np.ndarray:
    return (np.arange(n, dtype=np.float64) + 0.5) / n


def ortho_extent(scene: Scene) -> tuple[float, float]:
    """Half-width and half-height of the orthographic view (Blender: ortho_scale spans the larger side)."""
    w, h = scene.resolution
    s = scene.ortho_scale
    return (0.5 * s, 0.5 * s * h / w) if w >= h else (0.5 * s * w / h, 0.5 * s)


def plane_half_size(scene: Scene, height: float = 1.0) -> float:
    """Half-size of the Cycles plane for a panorama scene: the hit point of a ray a quarter pixel
    beyond the last row's centre, times 4, so that jittered samples never miss it."""
    h = scene.height
    theta = math.radians(scene.theta_max_deg) * min(1.0, (h - 0.25) / h)
    return 4.0 * height * math.tan(min(theta, math.radians(89.99))) + 4.0 * height


def sphere_mask_radius(scene: Scene) -> float:
    """Pixel centres closer than this to the image centre have their whole pixel square inside the
    silhouette of the Cycles UV sphere (inscribed radius of the equator polygon)."""
    hx, hy = ortho_extent(scene)
    px = 2.0 * hx / scene.width
    py = 2.0 * hy / scene.height
    return math.cos(math.pi / scene.sphere_segments) - 0.5 * math.hypot(px, py)


def pixel_geometry(scene: Scene) -> dict:
    """Per-pixel shading frame of ``scene`` (all H x W arrays, row 0 = top).

    Returns ``mask`` (bool: pixel shows the object and enters the metrics), ``n``, ``t``, ``b`` (unit
    normal, tangent, bitangent, H x W x 3, world), ``wo`` (unit, world, toward the camera) and, for
    panoramas, ``theta_o`` / ``phi_o`` (radians, H x W). Outside the mask the frame is the world frame.
    """
    w, h = scene.resolution
    if scene.kind == VIEWS:
        n, t, b, wo = np.asarray(scene.frames, dtype=np.float64).reshape(1, w, 4, 3).transpose(2, 0, 1, 3)
        every = np.ones((1, w), dtype=bool)
        return {"mask": every, "hit": every, "n": n, "t": t, "b": b, "wo": wo}
    if scene.kind == "sphere":
        hx, hy = ortho_extent(scene)
        x = (2.0 * _pixel_centres(w) - 1.0) * hx
        y = (1.0 - 2.0 * _pixel_centres(h)) * hy  # row 0 = top = +y
        X, Y = np.meshgrid(x, y)
        r2 = X * X + Y * Y
        hit = r2 < 1.0
        Z = np.sqrt(np.clip(1.0 - r2, 0.0, None))
        n = np.stack([X, Y, Z], axis=-1)
        n = np.where(hit[..., None], n, np.array([0.0, 0.0, 1.0]))
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        t = np.stack([-n[..., 1], n[..., 0], np.zeros_like(Z)], axis=-1)
        tl = np.linalg.norm(t, axis=-1, keepdims=True)
        t = np.where(tl > 1e-12, t / np.maximum(tl, 1e-300), np.array([1.0, 0.0, 0.0]))
        b = np.cross(n, t)
        wo = np.broadcast_to(np.array([0.0, 0.0, 1.0]), n.shape).copy()
        mask = np.sqrt(r2) < sphere_mask_radius(scene)
        return {"mask": mask, "hit": hit, "n": n, "t": t, "b": b, "wo": wo}
    theta = _pixel_centres(h) * math.radians(scene.theta_max_deg)
    phi = _pixel_centres(w) * 2.0 * math.pi
    PHI, THETA = np.meshgrid(phi, theta)
    st = np.sin(THETA)
    wo = np.stack([st * np.cos(PHI), st * np.sin(PHI), np.cos(THETA)], axis=-1)
    shape = (h, w, 3)
    return {
        "mask": np.ones((h, w), dtype=bool), "hit": np.ones((h, w), dtype=bool),
        "n": np.broadcast_to(np.array([0.0, 0.0, 1.0]), shape).copy(),
        "t": np.broadcast_to(np.array([1.0, 0.0, 0.0]), shape).copy(),
        "b": np.broadcast_to(np.array([0.0, 1.0, 0.0]), shape).copy(),
        "wo": wo, "theta_o": THETA, "phi_o": PHI,
    }


def scene_mask(scene: Scene) -> np.ndarray:
    """H x W bool: pixels that show the object with a trustworthy geometry (the metrics' mask)."""
    return pixel_geometry(scene)["mask"]


def to_local(v: np.ndarray, t: np.ndarray, b: np.ndarray, n: np.ndarray) -> np.ndarray:
    """World vectors (..., 3) into the frame (t, b, n) (..., 3)."""
    return np.stack([np.sum(v * t, -1), np.sum(v * b, -1), np.sum(v * n, -1)], axis=-1)


def _eval_rgb(bsdf_eval: BsdfEval, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    f = np.asarray(bsdf_eval(wi, wo), dtype=np.float64)
    if f.ndim == 1:
        f = f[:, None]
    if f.shape[0] != wi.shape[0] or f.shape[1] not in (1, 3):
        raise ValueError(f"bsdf_eval returned shape {f.shape}; expected ({wi.shape[0]}, 3)")
    return np.broadcast_to(f, (wi.shape[0], 3))


PHI_CLUSTER = 0.95


def _albedo_nodes(n_mu: int, n_phi: int):
    """Quadrature over the sphere, relative to the plane of incidence of wo.

    cos(theta): Gauss-Legendre on [0, 1] and on [-1, 0] separately (the integrand may have a kink at
    the horizon). phi = phi_mirror + psi with psi(s) = s - (k/2) sin(2 s), s on a uniform midpoint grid
    of [0, 2 pi): a smooth periodic change of variables (so the midpoint rule stays spectrally accurate)
    that packs the nodes (k = 0.95: 39 times denser) around the plane of incidence, where specular,
    transmitted and retro-reflected lobes all peak. Returns (mu, w_mu, psi, w_psi)."""
    x, wgt = np.polynomial.legendre.leggauss(int(n_mu))
    mu = np.concatenate([0.5 * (x + 1.0), -0.5 * (x + 1.0)])
    wmu = np.concatenate([0.5 * wgt, 0.5 * wgt])
    s = (np.arange(int(n_phi)) + 0.5) * (2.0 * math.pi / n_phi)
    psi = s - 0.5 * PHI_CLUSTER * np.sin(2.0 * s)
    wpsi = (1.0 - PHI_CLUSTER * np.cos(2.0 * s)) * (2.0 * math.pi / n_phi)
    return mu, wmu, psi, wpsi


def directional_albedo(bsdf_eval: BsdfEval, wo: np.ndarray, quadrature=(64, 128), chunk=1 << 20,
                       by_row: bool = False) -> np.ndarray:
    """a(wo) = integral over the sphere of f(wi, wo) |cos theta_i| d wi, for local wo (N, 3) -> (N, 3).
    With ``by_row``, ``bsdf_eval(wi, rows)`` gets the index into ``wo`` of each wi's view instead of the view (a
    BSDF whose parameters were computed once per view).

    Deterministic product quadrature (``quadrature`` = (Gauss-Legendre nodes per hemisphere in
    cos theta, nodes in phi), the phi nodes packed around wo's plane of incidence, see ``_albedo_nodes``).
    Measured against a 1024 x 2048 uniform rule for GGX (specular and retro-reflective) lobes at
    theta_o up to 89.3 deg: error < 1e-5 for alpha >= 0.3, < 4e-4 for alpha = 0.1, < 1% for
    alpha = 0.05. Raise the node counts for narrower lobes, or pass an analytic or Monte Carlo
    ``bsdf_albedo`` to ``reference_image`` instead.
    """
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    mu, wmu, psi, wpsi = _albedo_nodes(*quadrature)
    nq = mu.size * psi.size
    sin_t = np.sqrt(np.clip(1.0 - mu * mu, 0.0, None))
    wts = (wmu * np.abs(mu))[:, None] * wpsi[None, :]  # (n_mu2, n_phi), includes |cos theta_i|
    out = np.zeros((wo.shape[0], 3))
    per = max(1, chunk // nq)
    for s0 in range(0, wo.shape[0], per):
        wo_c = wo[s0:s0 + per]
        m = wo_c.shape[0]
        phi = (np.arctan2(wo_c[:, 1], wo_c[:, 0]) + math.pi)[:, None] + psi[None, :]  # (m, n_phi)
        cp, sp = np.cos(phi), np.sin(phi)
        wi_all = np.stack([
            sin_t[None, :, None] * cp[:, None, :],
            sin_t[None, :, None] * sp[:, None, :],
            np.broadcast_to(mu[None, :, None], (m, mu.size, psi.size)),
        ], axis=-1).reshape(-1, 3)
        if by_row:
            views = np.repeat(np.arange(s0, s0 + m), nq)
        else:
            views = np.ascontiguousarray(np.broadcast_to(wo_c[:, None, :], (m, nq, 3)).reshape(-1, 3))
        f = _eval_rgb(bsdf_eval, wi_all, views).reshape(m, nq, 3)
        out[s0:s0 + m] = np.einsum("mqc,q->mc", f, wts.reshape(-1))
    return out


def reference_image(scene: Scene, bsdf_eval: BsdfEval, bsdf_albedo: Callable | None = None,
                    quadrature=(64, 128)) -> np.ndarray:
    """Render ``scene`` with the BSDF ``bsdf_eval`` exactly (direct light only): H x W x 3 float64,
    row 0 = top, 0 outside the object. See the module docstring for the pixel -> (wi, wo) mapping.

    For the environment term ``bsdf_albedo(wo_local (N,3)) -> (N,3)`` is used when given, otherwise
    ``directional_albedo(bsdf_eval, ..., quadrature)``.
    """
    g = pixel_geometry(scene)
    h, w = scene.height, scene.width
    img = np.zeros((h, w, 3))
    hit = g["hit"]
    if not hit.any():
        return img
    t, b, n, wo = g["t"][hit], g["b"][hit], g["n"][hit], g["wo"][hit]
    wo_l = to_local(wo, t, b, n)
    acc = np.zeros((wo_l.shape[0], 3))
    for sun in scene.suns:
        d = np.broadcast_to(np.asarray(sun.direction), wo_l.shape)
        wi_l = to_local(d, t, b, n)
        f = _eval_rgb(bsdf_eval, np.ascontiguousarray(wi_l), wo_l)
        cos_i = np.abs(wi_l[:, 2])
        if scene.kind == "sphere":  # closed surface: light from below is blocked by the sphere itself
            cos_i = np.where(wi_l[:, 2] > 0.0, cos_i, 0.0)
        acc += f * (cos_i * sun.irradiance)[:, None]
    if scene.environment > 0.0:
        if scene.kind == "sphere":
            # closed sphere: only the upper hemisphere is unoccluded
            def upper(wi, wo, _f=bsdf_eval):
                return _eval_rgb(_f, wi, wo) * (wi[:, 2] > 0.0)[:, None]
            alb = directional_albedo(upper, wo_l, quadrature)
        elif bsdf_albedo is not None:
            alb = np.broadcast_to(np.asarray(bsdf_albedo(wo_l), dtype=np.float64).reshape(wo_l.shape[0], -1),
                                  wo_l.shape)
        else:
            alb = directional_albedo(bsdf_eval, wo_l, quadrature)
        acc += scene.environment * alb
    img[hit] = acc
    return img


def lobe_view(bsdf_eval: BsdfEval, n_theta: int = 90, n_phi: int = 360, cosine: str = "in") -> np.ndarray:
    """Paper-style BSDF slice, reference only: n_theta x n_phi x 3 float64.

    Row r: incident direction wi = (sin ti, 0, cos ti) with ti = (r + 0.5) / n_theta * 90 deg (light in
    the xz plane at phi_i = 0). Column c: outgoing direction on the great circle of the plane of
    incidence, wo = (sin p, 0, cos p) with p = -180 deg + (c + 0.5) / n_phi * 360 deg: p = 0 is the
    normal, p = -ti the mirror direction, |p| > 90 deg transmission (p = 180 - ti straight through).
    Value: f(wi, wo) times |cos ti| (``cosine="in"``, radiance per unit irradiance, as in the scenes),
    |cos to| (``"out"``) or 1 (``"none"``).
    """
    ti = _pixel_centres(n_theta) * (0.5 * math.pi)
    p = -math.pi + _pixel_centres(n_phi) * 2.0 * math.pi
    TI, P = np.meshgrid(ti, p, indexing="ij")
    zeros = np.zeros_like(TI)
    wi = np.stack([np.sin(TI), zeros, np.cos(TI)], -1).reshape(-1, 3)
    wo = np.stack([np.sin(P), zeros, np.cos(P)], -1).reshape(-1, 3)
    f = _eval_rgb(bsdf_eval, wi, wo)
    if cosine == "in":
        f = f * np.abs(wi[:, 2:3])
    elif cosine == "out":
        f = f * np.abs(wo[:, 2:3])
    elif cosine != "none":
        raise ValueError("cosine must be 'in', 'out' or 'none'")
    return f.reshape(n_theta, n_phi, 3)


# ------------------------------------------------------------------------------- meshes for Cycles

def uv_sphere_mesh(segments: int = 256, rings: int = 128):
    """A unit UV sphere with poles on +-z: (verts (V,3), faces list of tuples, loop_uvs (L,2) in face order).

    Vertex k of ring j (j = 1 .. rings-1 from the top) is at colatitude pi j / rings and longitude
    2 pi k / segments (from +x toward +y). Faces wind counter-clockwise seen from outside (normals out).
    UV: u = longitude / 2 pi (1.0 on the seam side of the last column), v = 1 - colatitude / pi, so
    dP/du is the direction of increasing longitude (= z x n).
    """
    seg, rg = int(segments), int(rings)
    th = np.pi * np.arange(1, rg) / rg
    ph = 2.0 * np.pi * np.arange(seg) / seg
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    ring_verts = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1).reshape(-1, 3)
    verts = np.concatenate([[[0.0, 0.0, 1.0]], ring_verts, [[0.0, 0.0, -1.0]]])
    top, bottom = 0, verts.shape[0] - 1

    def vid(j, k):  # ring j in 1..rg-1, column k (wraps)
        return 1 + (j - 1) * seg + (k % seg)

    faces, uvs = [], []
    for k in range(seg):
        u0, u1 = k / seg, (k + 1) / seg
        # top cap: pole, ring 1 at k, ring 1 at k+1 (counter-clockwise from outside)
        faces.append((top, vid(1, k), vid(1, k + 1)))
        uvs += [((u0 + u1) / 2, 1.0), (u0, 1 - 1 / rg), (u1, 1 - 1 / rg)]
    for j in range(1, rg - 1):
        v0, v1 = 1 - j / rg, 1 - (j + 1) / rg
        for k in range(seg):
            u0, u1 = k / seg, (k + 1) / seg
            faces.append((vid(j, k), vid(j + 1, k), vid(j + 1, k + 1), vid(j, k + 1)))
            uvs += [(u0, v0), (u0, v1), (u1, v1), (u1, v0)]
    for k in range(seg):
        u0, u1 = k / seg, (k + 1) / seg
        faces.append((vid(rg - 1, k), bottom, vid(rg - 1, k + 1)))
        uvs += [(u0, 1 / rg), ((u0 + u1) / 2, 0.0), (u1, 1 / rg)]
    return verts, faces, np.asarray(uvs, dtype=np.float64)
