"""Neural participating media (Ge et al.; paper: neural_media), bpy-free: the networks' numpy inference and the
per-material table reconstruction (Sec. 3.7).

Two networks, ``double`` and ``multiple``, each an MLP 6-50-50-1 with tanh (Sec. 3.5; ``bake.mlp``), predict
log(1 + Phi / (PHI_0 albedo^k)) of the tables that ``training/medium_tracer.py`` defines: Phi(rho, z, theta, phi;
albedo, g), the radiance emitted per unit volume into direction (theta, phi) at the point (rho, z) by the double (order 2) or
multiple (orders >= 3) scattering of a unit point-directional source along +z in an infinite medium, lengths in
mean free paths (sigma_t = 1), directions in the point's local frame (theta from +z, phi from the radial direction,
folded to [0, pi]). Reconstruction: Phi = max(exp(network) - 1, 0) PHI_0 albedo^k (``target``). Double scattering
also has a closed form as a 1-D integral along the beam (``double_table``), which the bake uses instead of the double
network.

Inputs reach the networks in [0, 1] through ``encode``, whose constants travel in each weights file's manifest
(``encoding``): rho and z through the same sinh map as the training grid (uniform near the source, geometric far
away), theta / pi, phi / pi, the albedo as log(1 - albedo) / log(1 - ALBEDO_MAX) (the dataset's spacing; albedos
above ALBEDO_MAX are taken at ALBEDO_MAX: the networks never saw them) and (g + 1) / 2.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bake import mlp
from . import hg

KINDS = ("double", "multiple")
WEIGHTS = Path(__file__).resolve().parents[1] / "bake" / "weights"
ALBEDO_MAX = 0.999

# Encoding version 1: the sinh map of the training grid (training.medium_tracer.sinh_edges) and its extents.
PHI_0 = 1e-12  # the unit of Phi in the networks' target (``target``)
ALBEDO_POWER = {"double": 2, "multiple": 3}  # the lowest order's power of the albedo, divided out of the target
ENCODING = {"version": 1, "scale": 1.0, "rho_max": 256.0, "z_max": 256.0, "albedo_max": ALBEDO_MAX}


def weights_path(kind: str, folder: Path = WEIGHTS) -> Path:
    return Path(folder) / f"neural_medium_{kind}.npz"


def network(kind: str, folder: Path = WEIGHTS) -> mlp.MLP:
    if kind not in KINDS:
        raise ValueError(f"unknown network {kind!r}; expected one of {', '.join(KINDS)}")
    return mlp.load(weights_path(kind, folder))


def _sinh_unit(x, scale: float, extent: float):
    """asinh(x / scale) / asinh(extent / scale): 0 at 0, ±1 at ±extent (the grid's sinh spacing made uniform)."""
    return np.arcsinh(np.asarray(x, dtype=np.float64) / scale) / math.asinh(extent / scale)


def encode(rho, z, theta, phi, albedo, g, encoding: dict = ENCODING) -> np.ndarray:
    """(N, 6) network inputs in [0, 1] (broadcast arguments; module docstring)."""
    albedo_max = encoding["albedo_max"]
    a = np.clip(np.asarray(albedo, dtype=np.float64), 0.0, albedo_max)
    columns = (_sinh_unit(rho, encoding["scale"], encoding["rho_max"]),
               0.5 + 0.5 * _sinh_unit(z, encoding["scale"], encoding["z_max"]),
               np.asarray(theta, dtype=np.float64) / math.pi, np.asarray(phi, dtype=np.float64) / math.pi,
               np.log1p(-a) / math.log1p(-albedo_max), (np.asarray(g, dtype=np.float64) + 1.0) * 0.5)
    return np.stack([c.ravel() for c in np.broadcast_arrays(*columns)], axis=1)


def target(phi_values, phi_0: float = PHI_0, albedo: float = 1.0, albedo_power: int = 0) -> np.ndarray:
    """What the networks learn: log(1 + Phi / (PHI_0 albedo^k)), k = ``ALBEDO_POWER`` of the table (the paper's
    log(1 + Phi), k = 0, with Phi in units of PHI_0). In Lamina's units (per unit source power, per mfp^3) Phi spans
    1e-16 to 100 and mostly lies far below 1, where log(1 + Phi) would be Phi itself and a network's absolute error a
    huge relative one (the energy of the far cells, whose volumes reach 1e5 mfp^3, would be wrong by orders of
    magnitude). Order n carries albedo^n exactly, so albedo^k takes out the steepest change between the grid's low
    albedos (0.05 and 0.3 lie close in the albedo's encoding, and their multiple scattering differs 200-fold)."""
    scale = phi_0 * float(albedo) ** albedo_power
    return np.log1p(np.maximum(np.asarray(phi_values, dtype=np.float64), 0.0) / scale)


def predict(net: mlp.MLP, rho, z, theta, phi, albedo, g) -> np.ndarray:
    """Phi at the given points, directions and materials (flattened broadcast), non-negative (``target``'s inverse,
    with the PHI_0 and the albedo's power of the network's manifest)."""
    m = net.manifest
    x = encode(rho, z, theta, phi, albedo, g, m.get("encoding", ENCODING))
    a = np.clip(np.broadcast_arrays(rho, z, theta, phi, np.asarray(albedo, dtype=np.float64), g)[4].ravel(), 0.0, 1.0)
    return np.maximum(np.expm1(_in_blocks(net, x)[:, 0]), 0.0) * m.get("phi_0", 1.0) * a ** m.get("albedo_power", 0)


BLOCK = 16384  # rows a network evaluates at once (16384 rows × 50 hidden × 8 B: 6.5 MB of activations)


def _in_blocks(net: mlp.MLP, x: np.ndarray) -> np.ndarray:
    """net(x), BLOCK rows at a time: the same values up to BLAS's rounding of a short last block (rows do not mix),
    faster than one pass over a table's million rows, whose activations stream through memory."""
    return np.concatenate([net(x[i:i + BLOCK]) for i in range(0, max(len(x), 1), BLOCK)])


def cell_centres(rho_edges, z_edges, encoding: dict = ENCODING) -> tuple[np.ndarray, np.ndarray]:
    """The cells' centres in the encoded (sinh) coordinates, mapped back: where a table's cell averages are
    predicted (the training pairs each cell with this point)."""
    s = encoding["scale"]

    def mid(edges, extent):
        u = _sinh_unit(edges, s, extent)
        return s * np.sinh(0.5 * (u[1:] + u[:-1]) * math.asinh(extent / s))

    return mid(rho_edges, encoding["rho_max"]), mid(z_edges, encoding["z_max"])


def table(net: mlp.MLP, albedo: float, g: float, rho_edges, z_edges, theta, phi) -> np.ndarray:
    """The per-material table (n_rho, n_z, n_theta, n_phi) on a grid's cells and direction bin centres (Sec. 3.7)."""
    rho_c, z_c = cell_centres(rho_edges, z_edges, net.manifest.get("encoding", ENCODING))
    grid = np.meshgrid(rho_c, z_c, np.asarray(theta), np.asarray(phi), indexing="ij")
    return predict(net, *grid, albedo, g).reshape(grid[0].shape)


def bin_solid_angles(n_theta: int, n_phi: int) -> np.ndarray:
    """(n_theta, n_phi) solid angle each folded direction bin stands for: both mirror halves, 4 pi in all."""
    t = np.linspace(0.0, math.pi, n_theta + 1)
    return np.outer(np.cos(t[:-1]) - np.cos(t[1:]), np.full(n_phi, 2.0 * math.pi / n_phi))


def cell_powers(phi_table: np.ndarray, rho_edges, z_edges) -> np.ndarray:
    """Power each cell and direction bin of a table emits, per unit source power: Phi x cell volume x bin solid
    angle."""
    r, z = np.asarray(rho_edges, dtype=np.float64), np.asarray(z_edges, dtype=np.float64)
    volumes = np.pi * np.outer(np.diff(r * r), np.diff(z))
    return np.einsum("ijkl,ij,kl->ijkl", phi_table, volumes, bin_solid_angles(*phi_table.shape[2:]))


def table_energy(phi_table: np.ndarray, rho_edges, z_edges) -> float:
    """Power the table emits, per unit source power."""
    return float(cell_powers(phi_table, rho_edges, z_edges).sum())


def double_table(albedo: float, g: float, rho_edges, z_edges, theta, phi, nodes: int = 512, sub: int = 4,
                 near_sub: int = 16) -> np.ndarray:
    """Double scattering's table (n_rho, n_z, n_theta, n_phi) without a network: the 1-D integral over the first
    collision at depth s on the beam, Phi_2(x, w) = albedo^2 Integral exp(-s) p(mu_1) exp(-r) / r^2 p(d . w) ds
    (r = |x - s z|, d its direction, mu_1 = d . z, p Henyey-Greenstein), written in the angle psi of d from the beam
    (z - s = rho cot psi, ds / r^2 = dpsi / rho): albedo^2 / rho Integral_psi0^pi exp(-s - r) p(cos psi) p(d . w)
    dpsi, psi0 = atan2(rho, z); midpoints of ``nodes`` steps of psi over (0, pi), the first cut at psi0, dense
    towards 0 and pi (Chebyshev spacing) where forward lobes and the short intervals behind the source lie. Cell
    averages (the Monte Carlo tables' cells) from ``sub`` x ``sub`` points per cell, ``near_sub`` x ``near_sub``
    within a mean free path of the source, where the density varies fastest; uniform in rho, whose ring area
    rho drho cancels the 1 / rho. Each direction bin holds the average over ``sub`` x ``sub`` directions uniform in
    solid angle within it (``theta`` and ``phi`` are the centres of equal bins over [0, pi]): a lobe narrower than
    a bin keeps its power (the Monte Carlo tables smooth over the arrival bins instead)."""
    for name, centres in (("theta", theta), ("phi", phi)):
        n = len(centres)
        if not np.allclose(centres, (np.arange(n) + 0.5) * math.pi / n):
            raise ValueError(f"double_table: {name} must be the centres of {n} equal bins over [0, pi]")
    a = min(max(float(albedo), 0.0), 1.0)
    edges = 0.5 * math.pi * (1.0 - np.cos(np.linspace(0.0, math.pi, nodes + 1)))  # dense at 0 and pi
    psi = 0.5 * (edges[1:] + edges[:-1])
    arrival = np.stack([np.sin(psi), np.zeros_like(psi), np.cos(psi)], axis=1)  # (nodes, 3) in (e_rho, e_phi, e_z)
    out_dirs = _bin_directions(len(theta), len(phi), sub)  # (n_dir, sub^2, 3)
    second = hg.eval(float(g), np.clip(np.einsum("nk,dsk->nds", arrival, out_dirs), -1.0, 1.0)).mean(axis=2)
    quadrature = (edges, psi, hg.eval(float(g), np.cos(psi)), second)
    r_edges, z_edges = np.asarray(rho_edges, dtype=np.float64), np.asarray(z_edges, dtype=np.float64)
    z0, z1 = z_edges[:-1], z_edges[1:]
    near_z = (z0 < 1.0) & (z1 > -1.0)
    out = np.zeros((len(r_edges) - 1, len(z0), second.shape[1]))
    for i, (r0, r1) in enumerate(zip(r_edges[:-1], r_edges[1:])):
        out[i] = _double_ring(r0, r1, z0, z1, sub, quadrature)
        if r0 < 1.0 and near_z.any():
            out[i, near_z] = _double_ring(r0, r1, z0[near_z], z1[near_z], near_sub, quadrature)
    return (a * a * out).reshape(len(r_edges) - 1, len(z0), len(theta), len(phi))


def _bin_directions(n_theta: int, n_phi: int, sub: int) -> np.ndarray:
    """(n_theta n_phi, sub^2, 3) unit directions in the local frame (e_rho, e_phi, e_z), uniform in solid angle
    within each of the equal (theta, phi) bins over [0, pi] x [0, pi]."""
    frac = (np.arange(sub) + 0.5) / sub
    t = np.linspace(0.0, math.pi, n_theta + 1)
    cos_t = np.cos(t[:-1])[:, None] + frac[None, :] * (np.cos(t[1:]) - np.cos(t[:-1]))[:, None]  # (n_theta, sub)
    p = (np.arange(n_phi)[:, None] + frac[None, :]) * math.pi / n_phi  # (n_phi, sub)
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    c = np.broadcast_to(cos_t[:, None, :, None], (n_theta, n_phi, sub, sub))
    sn = np.broadcast_to(sin_t[:, None, :, None], c.shape)
    ph = np.broadcast_to(p[None, :, None, :], c.shape)
    return np.stack([sn * np.cos(ph), sn * np.sin(ph), c], axis=-1).reshape(n_theta * n_phi, sub * sub, 3)


def _double_ring(r0: float, r1: float, z0, z1, sub: int, quadrature) -> np.ndarray:
    """``double_table``'s cell averages (n_z, n_dir) over one ring rho in [r0, r1] and the z cells [z0, z1], without
    albedo^2. Along psi the integrand factors: exp(-s - r) = exp(-z - rho tan(psi / 2)) (s = z - rho cot psi,
    r = rho csc psi), so the steps wholly beyond psi0 are one suffix sum per rho (``_suffix_sums``) and only the
    step that psi0 cuts is summed per point."""
    edges, psi, first, second = quadrature
    frac = (np.arange(sub) + 0.5) / sub
    rho = r0 + frac * (r1 - r0)  # (sub,) against the points z (n_z, sub)
    z = z0[:, None] + frac[None, :] * (z1 - z0)[:, None]
    half_mid, half_edge = np.tan(0.5 * psi), np.tan(0.5 * edges)
    suffix = _suffix_sums(rho, half_mid, half_edge, (first * np.diff(edges))[:, None] * second)
    R, Z = rho[:, None, None], z[None]
    psi0 = np.arctan2(R, Z)  # (sub, n_z, sub): the first step psi0 cuts, then the steps beyond it
    k = np.clip(np.searchsorted(edges, psi0, side="right") - 1, 0, len(psi) - 1)
    beyond = np.exp(-Z - R * half_edge[k + 1])[..., None] * suffix[np.arange(len(rho))[:, None, None], k + 1]
    cut = psi[k] >= psi0  # the step's midpoint lies beyond psi0 (s >= 0 there)
    part = np.where(cut, np.exp(np.where(cut, -Z - R * half_mid[k], 0.0)) * first[k] * (edges[k + 1] - psi0), 0.0)
    return np.einsum("azbd->zd", beyond + part[..., None] * second[k]) * 2.0 / ((r0 + r1) * sub * sub)


def _suffix_sums(rho, half_mid, half_edge, g) -> np.ndarray:
    """(n_rho, nodes + 1, n_dir): S_m = sum over the steps n >= m of exp(-rho (tan(psi_n / 2) - tan(e_m / 2))) g_n,
    by the backward recursion S_m = exp(-rho (t_m - T_m)) g_m + exp(-rho (T_m+1 - T_m)) S_m+1 (every exponent <= 0)."""
    own = np.exp(-rho[:, None] * (half_mid - half_edge[:-1]))[..., None]  # (n_rho, nodes, 1): every step's factors
    carried = np.exp(-rho[:, None] * (half_edge[1:] - half_edge[:-1]))[..., None]
    out = np.zeros((len(rho), len(half_mid) + 1, g.shape[1]))
    for m in range(len(half_mid) - 1, -1, -1):
        out[:, m] = own[:, m] * g[m] + carried[:, m] * out[:, m + 1]
    return out


# ------------------------------------------------------------------------------------------ tables and the gather

@dataclass(frozen=True)
class Table:
    """Phi of one kind (``double`` or ``multiple``) for one material on a grid: ``values`` (n_rho, n_z, n_theta,
    n_phi) per unit volume (mfp^3) per unit source power, the cells' edges in mfp and the direction bin centres."""

    values: np.ndarray
    rho_edges: np.ndarray
    z_edges: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    segment: float = 0.0  # 0: Phi at a point; > 0: the paper's accumulated table (``segment_table``), this long

    def lookup(self, rho, z, theta, phi) -> np.ndarray:
        """Phi at points (rho, z in mfp) and folded directions: multilinear between the cells' centres in the encoded
        (sinh) coordinates and between the bin centres (clamped at the ends); 0 outside the table."""
        return self.at(self.locate(rho, z, theta, phi))

    def locate(self, rho, z, theta, phi) -> tuple:
        """Where the points fall in the grid (each axis's lower node and weight, and which points are inside): what
        ``at`` needs, shared by the tables of one grid."""
        rho_c, z_c = cell_centres(self.rho_edges, self.z_edges)
        axes = (_linear(_sinh_unit(rho_c, ENCODING["scale"], ENCODING["rho_max"]),
                        _sinh_unit(rho, ENCODING["scale"], ENCODING["rho_max"])),
                _linear(_sinh_unit(z_c, ENCODING["scale"], ENCODING["z_max"]),
                        _sinh_unit(z, ENCODING["scale"], ENCODING["z_max"])),
                _linear(self.theta, theta), _linear(self.phi, phi))
        inside = (rho <= self.rho_edges[-1]) & (z >= self.z_edges[0]) & (z <= self.z_edges[-1])
        return axes, inside

    def at(self, located: tuple) -> np.ndarray:
        """Phi at points ``locate`` found (the axes may broadcast against each other): the 16 corners gathered by
        flat index, lerped along phi, then theta, z and rho."""
        axes, inside = located
        shape = self.values.shape
        strides = (shape[1] * shape[2] * shape[3], shape[2] * shape[3], shape[3], 1)
        step = [stride if n > 1 else 0 for stride, n in zip(strides, shape)]  # a single node: no upper neighbour
        flat = self.values.ravel()
        base = sum(i * stride for (i, _), stride in zip(axes, strides))
        values = {}
        for c in range(8):  # bits: rho, z, theta
            b = base + sum(((c >> a) & 1) * step[a] for a in range(3))
            lower = flat.take(b)
            values[c] = lower + axes[3][1] * (flat.take(b + step[3]) - lower)
        for a in (2, 1, 0):
            w = axes[a][1]
            values = {c: values[c] + w * (values[c | (1 << a)] - values[c]) for c in values if not (c >> a) & 1}
        return np.where(inside, values[0], 0.0)


SEGMENT = 5.0  # mfp: the length of the paper's accumulated camera segment (Sec. 3.7)


def segment_table(table: Table, steps: int = 16, length: float = SEGMENT) -> Table:
    """The paper's segment-to-segment table (Sec. 3.7): at each cell centre x0 and direction bin centre w of
    ``table``, A(x0, w) = Integral_0^length exp(-s) Phi(x0 - s w, w) ds, the light a camera segment of ``length``
    mean free paths starting at x0 and looking against w gathers, by ``steps`` quantiles of the exponential.
    ``gather`` uses it with the paper's weight W (Eq. 5) for shorter segments. The source's axis is +z, so the
    segments' rho, theta and phi do not depend on z: they are found once per row of cells, their z once in all."""
    rho_c, z_c = cell_centres(table.rho_edges, table.z_edges)
    th, ph = (a.ravel() for a in np.meshgrid(table.theta, table.phi, indexing="ij"))
    w = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)  # (D, 3) at (rho, 0, z)
    reach = -math.expm1(-length)
    s = -np.log1p(-(np.arange(steps) + 0.5) / steps * reach)
    source, axis = np.zeros((1, 1, 3)), np.array([[[0.0, 0.0, 1.0]]])
    z = z_c[:, None, None] - s[None, None, :] * w[None, :, None, 2]  # (n_z, D, steps) along every segment of the row
    out = np.zeros((len(rho_c), len(z_c), len(w)))
    for i, rho in enumerate(rho_c):
        x = np.array([rho, 0.0, 0.0]) - s[None, :, None] * w[:, None, :]  # (D, steps, 3): the segments from z = 0
        rho_x, _, theta, phi = (c[..., 0] for c in _coordinates(x, source, axis, w, 1.0))
        out[i] = reach / steps * table.lookup(rho_x, z, theta, phi).sum(axis=-1)
    return Table(out.reshape(table.values.shape), table.rho_edges, table.z_edges, table.theta, table.phi,
                 float(length))


def segment_weight(tau, length: float = SEGMENT):
    """The paper's W (Eq. 5) for camera segments ``tau`` mean free paths long: the share of the accumulated
    segment's attenuation they cover, (1 - exp(-tau)) / (1 - exp(-length)). Eq. 5 as printed sums exp(-i l) over
    i = 1 ... k with k the segment's length over 5 mfp, which is not a count; this is its continuous form."""
    return -np.expm1(-np.asarray(tau, dtype=np.float64)) / -math.expm1(-length)


def _linear(nodes: np.ndarray, x):
    """(lower index, weight of the upper node) of x between sorted ``nodes``, clamped to the first and last."""
    nodes = np.asarray(nodes, dtype=np.float64)
    if len(nodes) == 1:
        return np.zeros(np.shape(x), dtype=int), np.zeros(np.shape(x))
    i = np.clip(np.searchsorted(nodes, x) - 1, 0, len(nodes) - 2)
    return i, np.clip((x - nodes[i]) / (nodes[i + 1] - nodes[i]), 0.0, 1.0)


def dataset_tables(path) -> dict:
    """{"double": Table, "multiple": Table} of one file of ``training.medium_dataset`` (the Monte Carlo tables)."""
    with np.load(path) as f:
        edges = (f["rho_edges"], f["z_edges"], f["theta"], f["phi"])
        return {kind: Table(f[kind].astype(np.float64), *edges) for kind in KINDS}


def bounding_sphere(shape) -> tuple[np.ndarray, float]:
    """(centre, radius) of a sphere holding ``shape``: a Sphere or Box of the truth, or any shape with a
    ``bounding_sphere`` attribute (e.g. the bake's mesh)."""
    if hasattr(shape, "bounding_sphere"):
        centre, radius = shape.bounding_sphere
        return np.asarray(centre, dtype=np.float64), float(radius)
    if hasattr(shape, "radius"):
        return np.asarray(shape.centre, dtype=np.float64), float(shape.radius)
    if hasattr(shape, "lo"):
        lo, hi = np.asarray(shape.lo), np.asarray(shape.hi)
        return 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    raise ValueError(f"the gather needs a bounded shape (a sphere, a box or a mesh), got {type(shape).__name__}")


@dataclass(frozen=True)
class Beams:
    """Virtual ray lights (Sec. 3.8): where each beam of a lamp enters the medium (M, 3), its unit direction (M, 3)
    and its power (M,), each a point-directional source of the tables."""

    entries: np.ndarray
    directions: np.ndarray
    powers: np.ndarray

    def __len__(self) -> int:
        return len(self.powers)

    @staticmethod
    def join(parts) -> "Beams":
        parts = list(parts)
        if not parts:
            return Beams(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
        return Beams(*(np.concatenate([getattr(b, f) for b in parts]) for f in ("entries", "directions", "powers")))


def _orthonormal(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = _perpendicular(d)
    return a, np.cross(d, a)


def _entering(shape, starts, directions, powers) -> Beams:
    """The beams from ``starts`` along ``directions`` that hit ``shape``, moved to where they enter it."""
    t0, t1 = shape.interval(starts, directions)
    hit = np.isfinite(t0) & (t1 > t0)
    return Beams(starts[hit] + np.maximum(t0[hit], 0.0)[:, None] * directions[hit], directions[hit], powers[hit])


def sun_beams(shape, sun, cells: int) -> Beams:
    """A sun's parallel light as a ``cells`` x ``cells`` grid of beams over the shape's bounding disc seen from the
    sun, each of power E x its cell's area."""
    d = -np.asarray(sun.direction, dtype=np.float64)
    d /= np.linalg.norm(d)
    centre, radius = bounding_sphere(shape)
    a, b = _orthonormal(d)
    u = ((np.arange(cells) + 0.5) / cells * 2.0 - 1.0) * radius
    U, V = (x.ravel() for x in np.meshgrid(u, u))
    starts = centre + U[:, None] * a + V[:, None] * b - 2.0 * radius * d
    powers = np.full(len(U), float(sun.irradiance) * (2.0 * radius / cells) ** 2)
    return _entering(shape, starts, np.tile(d, (len(U), 1)), powers)


def point_beams(shape, position, intensity: float, cells: int) -> Beams:
    """A point lamp of radiant ``intensity`` (W/sr) outside the shape: beams through a ``cells`` x ``cells`` grid of
    equal-solid-angle directions over the cone that holds the bounding sphere, each of power intensity x its solid
    angle."""
    position = np.asarray(position, dtype=np.float64)
    centre, radius = bounding_sphere(shape)
    axis = centre - position
    distance = float(np.linalg.norm(axis))
    if distance <= radius:
        raise ValueError("a point light inside the medium's bounding sphere: move it outside the object")
    axis /= distance
    cos_max = math.sqrt(1.0 - (radius / distance) ** 2)
    a, b = _orthonormal(axis)
    u = (np.arange(cells) + 0.5) / cells
    U, V = (x.ravel() for x in np.meshgrid(u, u))
    cos_t = 1.0 - U * (1.0 - cos_max)  # uniform in solid angle over the cone
    sin_t, phi = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0)), 2.0 * math.pi * V
    directions = (cos_t[:, None] * axis + (sin_t * np.cos(phi))[:, None] * a + (sin_t * np.sin(phi))[:, None] * b)
    solid_angle = 2.0 * math.pi * (1.0 - cos_max) / len(U)
    return _entering(shape, np.tile(position, (len(U), 1)), directions, np.full(len(U), intensity * solid_angle))


def area_beams(shape, centre, half_u, half_v, power: float, cells: int, round_: bool = False) -> Beams:
    """An area lamp (Cycles' convention, tested: a one-sided Lambertian emitter of total power ``power`` W, radiance
    P / (pi A)) spanning ``centre`` +- ``half_u`` +- ``half_v``, emitting along half_u x half_v (unnormalised
    vectors; a disc or ellipse with ``round_``): k x k points over it, k = isqrt(cells), each a point lamp of
    intensity P cos / (pi n) over its n points (``point_beams`` with cells // k beams a side), so that a lamp
    costs about as many beams as a point lamp. A point of the lamp inside the bounding sphere raises ValueError."""
    centre, half_u, half_v = (np.asarray(v, dtype=np.float64) for v in (centre, half_u, half_v))
    normal = np.cross(half_u, half_v)
    normal /= np.linalg.norm(normal)
    k = max(1, math.isqrt(cells))
    u = (np.arange(k) + 0.5) / k * 2.0 - 1.0
    U, V = (x.ravel() for x in np.meshgrid(u, u))
    keep = U * U + V * V <= 1.0 if round_ else np.ones(len(U), dtype=bool)
    points = centre + U[keep, None] * half_u + V[keep, None] * half_v
    parts = []
    for point in points:
        b = point_beams(shape, point, power / (math.pi * len(points)), max(1, cells // k))
        emitted = b.powers * np.maximum(b.directions @ normal, 0.0)
        parts.append(Beams(b.entries[emitted > 0.0], b.directions[emitted > 0.0], emitted[emitted > 0.0]))
    return Beams.join(parts)


def extrapolation_distance(albedo: float, g: float) -> float:
    """The diffusion's extrapolated boundary z_b = 2 D in mean free paths, D = 1 / (3 sigma_t') with the reduced
    extinction sigma_t' = 1 - albedo g per mfp, for an index-matched boundary (A = 1; Jensen et al. 2001, Eq. 6)."""
    return 2.0 / (3.0 * max(1.0 - float(albedo) * float(g), 1e-6))


@dataclass(frozen=True)
class Boundary:
    """The boundary's image sources for ``gather``: the extrapolation distance ``zb`` in mfp and the weight
    ``exits`` of the images across the planes where the beam and the camera ray leave the object."""

    zb: float
    exits: float


def boundary(albedo: float, g: float) -> Boundary:
    """The image sources of a medium: z_b = ``extrapolation_distance``, and the exit planes' images weighted
    min(1, 1 - g). The weight is a calibration (``python -m training.medium_gather_check --exits``, docs/training.md):
    with weight 1 the exit images bring an isotropic cloud in a thin box from +79% to +3% but take 40% too much
    from forward-scattering milk, whose mirrored beam points its forward lobe back into the object."""
    return Boundary(extrapolation_distance(albedo, g), min(1.0, 1.0 - float(g)))


def _perpendicular(d: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each unit row of d (..., 3)."""
    helper = np.where(np.abs(d[..., 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    a = np.cross(d, helper)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _mirror(points, directions, plane_points, normals, offset: float):
    """Points and directions mirrored across the planes through ``plane_points`` + ``offset`` x ``normals`` (unit,
    outward): the image sources of the extrapolated boundary."""
    depth = np.sum((points - plane_points) * normals, axis=-1, keepdims=True) - offset
    return (points - 2.0 * depth * normals,
            directions - 2.0 * np.sum(directions * normals, axis=-1, keepdims=True) * normals)


def _coordinates(x, sources, directions, w, ell: float) -> tuple:
    """(rho, z, theta, phi) in the tables' frame, lengths in mfp, of the points x (R, S, 3) from the sources
    (R or 1, M, 3) along their unit directions (same shape), seen along the propagation directions w (R, 3):
    each (R, S, M) but theta, the same at every point of a ray, (R, 1, M)."""
    v = x[:, :, None, :] - sources[:, None, :, :]
    d = directions[:, None, :, :]
    z = np.einsum("rsmk,rsmk->rsm", v, np.broadcast_to(d, v.shape))
    radial = v - z[..., None] * d
    rho = np.sqrt(np.einsum("rsmk,rsmk->rsm", radial, radial))
    e_rho = np.where((rho > 1e-12)[..., None], radial / np.maximum(rho, 1e-12)[..., None], _perpendicular(d))
    wb = np.broadcast_to(w[:, None, None, :], v.shape)
    cos_theta = np.einsum("rmk,rk->rm", np.broadcast_to(directions, (len(w),) + directions.shape[1:]), w)
    theta = np.arccos(np.clip(cos_theta, -1.0, 1.0))[:, None, :]
    phi = np.abs(np.arctan2(np.einsum("rsmk,rsmk->rsm", np.cross(d, e_rho), wb),
                            np.einsum("rsmk,rsmk->rsm", e_rho, wb)))
    return rho / ell, z / ell, theta, phi


IMAGE_OFFSET = 1.0  # z_b; chosen by ``python -m training.medium_gather_check --offsets`` (docs/training.md)


def _distinct_weight(image, earlier: list, zb: float):
    """Weight of an image that may duplicate ``earlier`` ones (each broadcastable to it), from how far it lies from
    the nearest: 0 within IMAGE_OFFSET z_b (the planes nearly coincide: one image, the dipole's), rising linearly to
    1 2 z_b further. The offset is a calibration on the spheres of training/medium_gather_check.py, not a
    derivation."""
    apart = functools.reduce(np.minimum, [np.linalg.norm(image - e, axis=-1) for e in earlier])
    return np.clip((apart - IMAGE_OFFSET * zb) / (2.0 * zb), 0.0, 1.0)


def _exit_points(shape, starts, directions, length: float):
    """Where rays entering ``shape`` at ``starts`` along ``directions`` leave it again (lengths in scene units)."""
    back = starts - 1e-9 * length * directions
    return starts + np.maximum(shape.interval(back, directions)[1], 0.0)[:, None] * directions


@dataclass(frozen=True)
class BeamGrid:
    """Beams sorted into the cubes of a regular grid (the paper's Sec. 4.3, one level): each cube's members and a
    representative beam, the cube's summed power at its members' power-weighted mean entry point and direction
    (``beam_grid``). ``gather`` takes a cube's representative instead of its members where the cube, seen from a
    chunk of camera rays, spans less than ``angle`` radians (Algorithm 1's solid-angle test)."""

    members: tuple  # per cube, the indices of its beams
    cube: float  # a cube's side
    centres: np.ndarray  # (C, 3) the cubes' centres
    radius: float  # half a cube's diagonal
    angle: float


def beam_grid(beams: Beams, cube: float, angle: float) -> BeamGrid:
    """``beams`` grouped in cubes of side ``cube`` (scene units); ``angle``: see ``BeamGrid``."""
    keys = np.floor(beams.entries / cube).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    members = tuple(np.flatnonzero(inverse == k) for k in range(int(inverse.max()) + 1 if len(inverse) else 0))
    centres = np.array([(keys[m[0]] + 0.5) * cube for m in members]).reshape(-1, 3)
    return BeamGrid(members, float(cube), centres, 0.5 * math.sqrt(3.0) * cube, float(angle))


UNIT_FIELDS = ("direction", "entry_image_direction", "exit_image_direction")


def _representatives(grid: BeamGrid, fields: dict) -> dict:
    """Per cube, its beams' ``fields`` (name -> per-beam array, ``gather``'s): the summed "power", and of every other
    field the power-weighted mean (the ``UNIT_FIELDS`` renormalised)."""
    powers = fields["power"]
    total = np.array([powers[m].sum() for m in grid.members])
    out = {"power": total}
    for name, values in fields.items():
        if name == "power":
            continue
        mean = np.stack([powers[m] @ values[m] for m in grid.members]) / np.maximum(total, 1e-300).reshape(
            (-1,) + (1,) * (values.ndim - 1))
        if name in UNIT_FIELDS:
            mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
        out[name] = mean
    return out


def _morton(keys: np.ndarray) -> np.ndarray:
    """Z-order codes of integer cube coordinates (N, 3): sorted by them, neighbours in space stay close."""
    keys = keys - keys.min(axis=0) if len(keys) else keys
    code = np.zeros(len(keys), dtype=np.int64)
    for bit in range(20):
        for axis in range(3):
            code |= ((keys[:, axis] >> bit) & 1) << (3 * bit + axis)
    return code


def _chosen_sources(grid: BeamGrid, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(beam indices, cube indices): the beams of the cubes that points (P, 3) see under ``grid.angle`` or more,
    and the cubes whose representative stands for their beams."""
    centre = points.mean(axis=0)
    spread = float(np.linalg.norm(points - centre, axis=1).max())
    distance = np.maximum(np.linalg.norm(grid.centres - centre, axis=1) - spread - grid.radius, 0.0)
    far = 2.0 * grid.radius < grid.angle * distance
    near = np.flatnonzero(~far)
    beams = np.concatenate([grid.members[k] for k in near]) if len(near) else np.zeros(0, dtype=int)
    return beams, np.flatnonzero(far)


def gather(tables: dict, mean_free_path: float, shape, beams: Beams, origins, directions, kinds=KINDS,
           steps: int = 24, chunk: int = 16, progress=None, images: Boundary | None = None,
           grid: BeamGrid | None = None) -> dict:
    """Radiance reaching ``origins`` along the rays ``-directions`` (camera rays: origins outside the shape,
    ``directions`` into it) from the double and multiple scattering of the ``beams``' light, one channel: the first
    segment of the camera ray inside the shape integrated with ``steps`` points of the exponential's quantiles,
    L = Integral exp(-s / l) Phi(x(s), -d) ds, and Phi(x, w) = Sum over beams of power x table(rho, z, theta, phi) /
    l^3 (``tables``: kind -> Table of this channel's albedo and g; lengths in the table are mean free paths
    ``l`` = ``mean_free_path`` scene units).

    The infinite-medium tables also count light that in the object would have left it (the method's approximation,
    Sec. 3.2). ``images`` (``boundary(albedo, g)``; needs ``shape.normal``) subtracts, from multiple scattering,
    each beam's images across the extrapolated tangent planes (z_b outside) where it enters and where it leaves the
    object, and across the planes where the camera ray enters and leaves; each image after the first is weighted by
    how far it lies from the earlier ones (``_distinct_weight``: 0 where two planes coincide, e.g. the lit side
    seen from the lit side, 1 where they are distinct, e.g. the far side of a thin part), the exit planes' images
    also by ``images.exits``; the difference is clamped at 0. Measured against the ground truth in
    docs/training.md. ``grid`` (``beam_grid`` of these beams): each chunk of rays gathers from the beams of the
    cubes it sees under ``grid.angle`` or more and from the other cubes' representatives (their images the mean of
    their members'). ``tables`` of ``segment_table`` (the paper's accumulated segments) are looked up once per ray
    where its segment enters, times ``segment_weight`` (``steps`` unused). ``progress(done, total)`` is called after
    each chunk of rays."""
    ell = float(mean_free_path)
    origins, directions = np.asarray(origins, dtype=np.float64), np.asarray(directions, dtype=np.float64)
    out = {kind: np.zeros(len(origins)) for kind in kinds}
    t0, t1 = shape.interval(origins, directions)
    rows = np.flatnonzero(np.isfinite(t0) & (t1 > t0))
    if grid is not None:  # rays entering close together share a chunk, so that more cubes are far from it
        entries = origins[rows] + np.maximum(t0[rows], 0.0)[:, None] * directions[rows]
        rows = rows[np.argsort(_morton(np.floor(entries / grid.cube).astype(np.int64)), kind="stable")]
    q = (np.arange(steps) + 0.5) / steps
    first = next(iter(tables.values()))
    accumulated = first.segment > 0.0
    fields = {"power": beams.powers, "entry": beams.entries, "direction": beams.directions}
    if images is not None:
        zb = float(images.zb) * ell
        entry_images = _mirror(beams.entries, beams.directions, beams.entries, shape.normal(beams.entries), zb)
        leave = _exit_points(shape, beams.entries, beams.directions, ell)
        exit_images = _mirror(beams.entries, beams.directions, leave, shape.normal(leave), zb)
        fields.update(entry_image=entry_images[0], entry_image_direction=entry_images[1], exit_image=exit_images[0],
                      exit_image_direction=exit_images[1],
                      exit_weight=images.exits * _distinct_weight(exit_images[0], [entry_images[0]], zb))
    per_cube = _representatives(grid, fields) if grid is not None else None
    for start in range(0, len(rows), chunk):
        r = rows[start:start + chunk]
        tau = (t1[r] - t0[r]) / ell
        enter = origins[r] + np.maximum(t0[r], 0.0)[:, None] * directions[r]
        if accumulated:  # the segment's integral is in the table: one point, the paper's weight
            weight, x = segment_weight(tau, first.segment) * ell, enter[:, None, :]
        else:
            reach = -np.expm1(-tau)  # the probability of a collision along the segment
            s = -np.log1p(-q[None, :] * reach[:, None]) * ell  # (R, S) quantiles of exp(-s / l) on the segment
            weight = reach * ell / steps  # Integral exp(-s / l) f ds = sum weight f(s)
            x = enter[:, None, :] + s[..., None] * directions[r, None, :]
        w = -directions[r]  # the light's propagation direction towards the camera
        src = fields
        if grid is not None:
            chosen, cubes = _chosen_sources(grid, x.reshape(-1, 3))
            src = {k: np.concatenate([v[chosen], per_cube[k][cubes]]) for k, v in fields.items()}
        powers, sources, beam_d = src["power"], src["entry"][None], src["direction"][None]
        if images is not None:
            beam_images = [src["entry_image"], src["exit_image"]]
            far = enter + (t1[r] - np.maximum(t0[r], 0.0))[:, None] * directions[r]
            camera_images = _mirror(sources, beam_d, enter[:, None, :], shape.normal(enter)[:, None, :], zb)
            far_images = _mirror(sources, beam_d, far[:, None, :], shape.normal(far)[:, None, :], zb)
            weighted = [((src["entry_image"][None], src["entry_image_direction"][None]), 1.0),
                        ((src["exit_image"][None], src["exit_image_direction"][None]),
                         src["exit_weight"][None, None, :]),
                        (camera_images, _distinct_weight(camera_images[0], beam_images, zb)[:, None, :]),
                        (far_images, images.exits * _distinct_weight(far_images[0], beam_images + [camera_images[0]],
                                                                     zb)[:, None, :])]
            at_images = [(tables["multiple"].locate(*_coordinates(x, *image, w, ell)), image_weight)
                         for image, image_weight in weighted]
        located = first.locate(*_coordinates(x, sources, beam_d, w, ell))
        for kind in kinds:
            value = tables[kind].at(located)
            if images is not None and kind == "multiple":
                subtracted = sum(image_weight * tables[kind].at(at) for at, image_weight in at_images)
                value = np.maximum(value - subtracted, 0.0)
            out[kind][r] += weight * (value @ powers).sum(axis=1) / ell ** 3
        if progress is not None:
            progress(min(start + chunk, len(rows)), len(rows))
    return out
